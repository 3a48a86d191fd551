"""Tabular Tsallis MDPs: policy evaluation, TPI, TVI, J(pi), the paper's grid world and its bounds.

A Tsallis MDP (paper section 4, eq. ``def:tsallis_mdp``) maximises
``E[sum_t gamma^t (R_t + alpha S_q(pi(.|s_t)))]``. With ``r(s,a) = sum_s' P(s'|s,a) R(s,a,s')``:

- Tsallis Bellman expectation (TBE) operator (eq. ``def:tbe_op_q``):
  ``[T^pi F](s,a) = r(s,a) + gamma sum_s' P(s'|s,a) V_F(s')`` with
  ``V_F(s) = sum_a pi(a|s) [F(s,a) - alpha ln_q pi(a|s)] = E_pi[F] + alpha S_q(pi(.|s))``.
- Tsallis Bellman optimality (TBO) operator (eq. ``def:tbo_op``): the same with
  ``V_F(s) = q-max_alpha F(s,.)``; its maximiser ``q_softmax(F(s,.))`` is the policy improvement
  step (eq. ``def:tp_imp``).

Both operators are gamma-contractions in the sup norm, so every iteration below stops on the
Bellman residual and reports how many sweeps it took. ``tol`` always bounds the sup-norm distance
of the returned Q to the exact fixed point: a gamma-contraction T with fixed point F* satisfies
``||F - F*|| <= ||T F - F|| / (1 - gamma)`` and ``||T F - F*|| <= gamma ||T F - F|| / (1 - gamma)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tacbench.errors import TacbenchError
from tacbench.theory.tsallis import (
    Array,
    ArrayLike,
    check_alpha,
    check_q,
    log_q,
    q_max,
    q_softmax,
    tsallis_entropy,
)

DEFAULT_TOL = 1e-10
"""Default sup-norm accuracy of returned Q-values (ours: far below anything a plot can show)."""
DEFAULT_MAX_ITER = 10_000
"""Default cap on value-iteration sweeps (ours): tol 1e-10 needs about 2,700 at gamma = 0.99."""
DEFAULT_MAX_POLICY_ITER = 1_000
"""Default cap on TPI rounds (ours): TPI converges in a handful (5-7 on the grid world)."""

GRID_MAP: tuple[str, ...] = ("SFFH", "FHFF", "FHFF", "FFHG")
"""The paper's grid world (fig. ``error_bounds``), rows top to bottom (REFERENCE.md)."""
GRID_ACTIONS: tuple[str, ...] = ("Left", "Down", "Right", "Up")
"""Action order of the grid world (REFERENCE.md)."""
GRID_GAMMA = 0.7
"""Discount of the grid-world experiment (REFERENCE.md)."""
GRID_ALPHA = 0.1
"""Entropy coefficient of the grid-world experiment (REFERENCE.md)."""
GRID_QS: tuple[float, ...] = (1.0, 1.2, 1.5, 1.7, 2.0, 2.5, 3.0, 5.0, 7.0, 10.0)
"""Entropic indices of the paper's performance-error-bounds figure (REFERENCE.md)."""
_SLIP = (0.8, 0.1, 0.1)
"""Intended move, each perpendicular move (REFERENCE.md)."""
_CELL_REWARD = {"G": 2.0, "H": -0.5}
"""Reward for entering a goal or hole cell; every other transition gives 0 (REFERENCE.md)."""


@dataclass(frozen=True)
class TabularMDP:
    """A finite MDP: ``P[s, a, s']``, rewards ``R[s, a, s']``, discount gamma, ``start[s]``.

    Arrays are validated and stored as float64; construct it with plain lists or arrays.
    """

    P: Array
    R: Array
    gamma: float
    start: Array

    def __post_init__(self) -> None:
        p = np.asarray(self.P, dtype=np.float64)
        r = np.asarray(self.R, dtype=np.float64)
        start = np.asarray(self.start, dtype=np.float64)
        gamma = float(self.gamma)
        if p.ndim != 3 or p.shape[0] != p.shape[2] or 0 in p.shape:
            raise TacbenchError(
                f"P must have shape (S, A, S) with S, A >= 1 (got {p.shape}); "
                "P[s, a, s'] is the probability of s' after action a in state s."
            )
        if r.shape != p.shape:
            raise TacbenchError(f"R must have the shape of P, {p.shape} (got {r.shape}).")
        if start.shape != (p.shape[0],):
            raise TacbenchError(
                f"start must be a distribution over the {p.shape[0]} states (got {start.shape})."
            )
        if not (np.isfinite(p).all() and np.isfinite(r).all() and np.isfinite(start).all()):
            raise TacbenchError("P, R and start must be finite (no NaN or inf).")
        if (p < 0).any() or not np.allclose(p.sum(axis=2), 1.0, rtol=0.0, atol=1e-8):
            raise TacbenchError(
                "every row P[s, a, :] must be a probability distribution (>= 0, summing to 1)."
            )
        if (start < 0).any() or not np.isclose(start.sum(), 1.0, rtol=0.0, atol=1e-8):
            raise TacbenchError("start must be a probability distribution (>= 0, summing to 1).")
        if not 0.0 < gamma < 1.0:
            raise TacbenchError(f"gamma must lie strictly between 0 and 1 (got {gamma}).")
        for name, value in (("P", p), ("R", r), ("start", start), ("gamma", gamma)):
            object.__setattr__(self, name, value)

    @property
    def n_states(self) -> int:
        """Number of states S."""
        return int(self.P.shape[0])

    @property
    def n_actions(self) -> int:
        """Number of actions A."""
        return int(self.P.shape[1])

    @property
    def expected_reward(self) -> Array:
        """``r(s, a) = sum_s' P(s'|s,a) R(s,a,s')``, shape (S, A)."""
        return np.einsum("sat,sat->sa", self.P, self.R)


@dataclass(frozen=True)
class Solution:
    """Result of an iterative method: Q (S, A), V (S,), policy (S, A) and sweeps used."""

    Q: Array
    V: Array
    policy: Array
    iterations: int


def _check_policy(mdp: TabularMDP, policy: ArrayLike) -> Array:
    pi = np.asarray(policy, dtype=np.float64)
    if pi.shape != (mdp.n_states, mdp.n_actions):
        raise TacbenchError(
            f"policy must have shape (S, A) = {(mdp.n_states, mdp.n_actions)} (got {pi.shape})."
        )
    if not np.isfinite(pi).all() or (pi < 0).any():
        raise TacbenchError("policy probabilities must be finite and >= 0.")
    if not np.allclose(pi.sum(axis=1), 1.0, rtol=0.0, atol=1e-8):
        raise TacbenchError("every policy row pi(.|s) must sum to 1.")
    return pi


def _check_values(mdp: TabularMDP, values: ArrayLike) -> Array:
    f = np.asarray(values, dtype=np.float64)
    if f.shape != (mdp.n_states, mdp.n_actions):
        raise TacbenchError(
            f"Q must have shape (S, A) = {(mdp.n_states, mdp.n_actions)} (got {f.shape})."
        )
    if not np.isfinite(f).all():
        raise TacbenchError("Q-values must be finite.")
    return f


def _check_stop(tol: float, max_iter: int) -> None:
    if not (np.isfinite(tol) and tol > 0):
        raise TacbenchError(f"tol must be a finite number > 0 (got {tol}).")
    if not (np.isfinite(max_iter) and max_iter >= 1):  # int(inf) would raise OverflowError
        raise TacbenchError(f"max_iter must be a finite number of at least 1 (got {max_iter}).")


def _not_converged(method: str, max_iter: int, residual: float, tol: float) -> TacbenchError:
    return TacbenchError(
        f"{method} did not reach tol={tol:g} within max_iter={max_iter} iterations "
        f"(last Bellman residual {residual:.3g}); raise max_iter or tol."
    )


def entropy_bonus(policy: ArrayLike, q: float, alpha: float) -> Array:
    """``alpha S_q(pi(.|s))`` per state, shape (S,), with ``0 ln_q 0 = 0``."""
    return check_alpha(alpha) * tsallis_entropy(policy, q)


def backup(mdp: TabularMDP, values: ArrayLike) -> Array:
    """``Q(s,a) = sum_s' P(s'|s,a) [R(s,a,s') + gamma V(s')]`` for state values V of shape (S,)."""
    return mdp.expected_reward + mdp.gamma * (mdp.P @ np.asarray(values, dtype=np.float64))


def tbe_operator(
    mdp: TabularMDP, policy: ArrayLike, values: ArrayLike, q: float, alpha: float
) -> Array:
    """The TBE operator ``T^pi_q`` (eq. ``def:tbe_op_q``) applied to F of shape (S, A)."""
    pi, f = _check_policy(mdp, policy), _check_values(mdp, values)
    return backup(mdp, np.sum(pi * f, axis=1) + entropy_bonus(pi, q, alpha))


def tbo_operator(mdp: TabularMDP, values: ArrayLike, q: float, alpha: float) -> Array:
    """The TBO operator ``T_q`` (eq. ``def:tbo_op``) applied to F of shape (S, A)."""
    return backup(mdp, q_max(_check_values(mdp, values), q, alpha))


def policy_improvement(values: ArrayLike, q: float, alpha: float) -> Array:
    """``pi(.|s) = argmax_pi E_pi[Q(s,.)] + alpha S_q(pi)`` (eq. ``def:tp_imp``): q-softmax rows."""
    return q_softmax(values, q, alpha)


def evaluate_policy(
    mdp: TabularMDP,
    policy: ArrayLike,
    q: float,
    alpha: float,
    *,
    exact: bool = True,
    tol: float = DEFAULT_TOL,
    max_iter: int = DEFAULT_MAX_ITER,
) -> Solution:
    """Tsallis policy evaluation: ``Q^pi_q`` and ``V^pi_q`` of a fixed policy.

    ``exact=True`` solves ``(I - gamma P_pi) V = r_pi + alpha S_q(pi)`` (0 iterations);
    ``exact=False`` iterates the TBE operator from F = 0 (theorem ``thm:tpe``) until the
    returned Q is within ``tol`` of the fixed point.
    """
    pi = _check_policy(mdp, policy)
    bonus = entropy_bonus(pi, q, alpha)
    if exact:
        p_pi = np.einsum("sa,sat->st", pi, mdp.P)
        r_pi = np.sum(pi * mdp.expected_reward, axis=1)
        v = np.linalg.solve(np.eye(mdp.n_states) - mdp.gamma * p_pi, r_pi + bonus)
        return Solution(Q=backup(mdp, v), V=v, policy=pi, iterations=0)
    _check_stop(tol, max_iter)
    f = np.zeros((mdp.n_states, mdp.n_actions))
    threshold = tol * (1.0 - mdp.gamma) / mdp.gamma
    residual = np.inf
    for k in range(1, int(max_iter) + 1):
        v = np.sum(pi * f, axis=1) + bonus
        f_next = backup(mdp, v)
        residual = float(np.max(np.abs(f_next - f)))
        f = f_next
        if residual <= threshold:
            return Solution(Q=f, V=np.sum(pi * f, axis=1) + bonus, policy=pi, iterations=k)
    raise _not_converged("Tsallis policy evaluation", max_iter, residual, tol)


def tsallis_value_iteration(
    mdp: TabularMDP,
    q: float,
    alpha: float,
    *,
    tol: float = DEFAULT_TOL,
    max_iter: int = DEFAULT_MAX_ITER,
) -> Solution:
    """TVI (theorem ``thm:optimality``): ``F_{k+1} = T_q F_k`` from F = 0.

    Stops when ``||F_{k+1} - F_k|| <= tol (1 - gamma) / gamma``, so ``||Q - Q*_q|| <= tol``.
    Returns Q, ``V = q-max Q`` and ``pi = q-softmax Q`` (the TBO equations, theorem ``thm:tbo``).
    """
    q, alpha = check_q(q), check_alpha(alpha)
    _check_stop(tol, max_iter)
    f = np.zeros((mdp.n_states, mdp.n_actions))
    threshold = tol * (1.0 - mdp.gamma) / mdp.gamma
    residual = np.inf
    for k in range(1, int(max_iter) + 1):
        f_next = backup(mdp, q_max(f, q, alpha))
        residual = float(np.max(np.abs(f_next - f)))
        f = f_next
        if residual <= threshold:
            return Solution(Q=f, V=q_max(f, q, alpha), policy=q_softmax(f, q, alpha), iterations=k)
    raise _not_converged("Tsallis value iteration", max_iter, residual, tol)


def tsallis_policy_iteration(
    mdp: TabularMDP,
    q: float,
    alpha: float,
    *,
    tol: float = DEFAULT_TOL,
    max_iter: int = DEFAULT_MAX_POLICY_ITER,
) -> Solution:
    """TPI (theorem ``thm:opt_tpi``): exact evaluation, then q-softmax improvement, from uniform.

    After evaluating ``pi_k`` it stops when the Bellman optimality residual
    ``||T_q Q^pi_k - Q^pi_k|| <= tol (1 - gamma)``, so ``||Q^pi_k - Q*_q|| <= tol``. It returns
    ``Q = Q^pi_k``, ``V = V^pi_k`` and the improved policy ``q-softmax(Q)`` (the TBO equation's
    policy, whose value lies between Q and Q*_q); ``iterations`` counts evaluations.
    """
    q, alpha = check_q(q), check_alpha(alpha)
    _check_stop(tol, max_iter)
    pi = np.full((mdp.n_states, mdp.n_actions), 1.0 / mdp.n_actions)
    residual = np.inf
    for k in range(1, int(max_iter) + 1):
        sol = evaluate_policy(mdp, pi, q, alpha)
        residual = float(np.max(np.abs(backup(mdp, q_max(sol.Q, q, alpha)) - sol.Q)))
        pi = policy_improvement(sol.Q, q, alpha)
        if residual <= tol * (1.0 - mdp.gamma):
            return Solution(Q=sol.Q, V=sol.V, policy=pi, iterations=k)
    raise _not_converged("Tsallis policy iteration", max_iter, residual, tol)


def value_iteration(
    mdp: TabularMDP, *, tol: float = DEFAULT_TOL, max_iter: int = DEFAULT_MAX_ITER
) -> Solution:
    """Plain value iteration (no entropy): Q*, V* = max Q*, and the greedy policy (first argmax)."""
    _check_stop(tol, max_iter)
    f = np.zeros((mdp.n_states, mdp.n_actions))
    threshold = tol * (1.0 - mdp.gamma) / mdp.gamma
    residual = np.inf
    for k in range(1, int(max_iter) + 1):
        f_next = backup(mdp, f.max(axis=1))
        residual = float(np.max(np.abs(f_next - f)))
        f = f_next
        if residual <= threshold:
            greedy = np.eye(mdp.n_actions)[np.argmax(f, axis=1)]
            return Solution(Q=f, V=f.max(axis=1), policy=greedy, iterations=k)
    raise _not_converged("value iteration", max_iter, residual, tol)


def expected_return(mdp: TabularMDP, policy: ArrayLike) -> float:
    """``J(pi) = E_{s0 ~ start}[sum_t gamma^t R_t]``: discounted reward, no entropy, exact solve."""
    pi = _check_policy(mdp, policy)
    p_pi = np.einsum("sa,sat->st", pi, mdp.P)
    r_pi = np.sum(pi * mdp.expected_reward, axis=1)
    v = np.linalg.solve(np.eye(mdp.n_states) - mdp.gamma * p_pi, r_pi)
    return float(mdp.start @ v)


_MOVES = ((0, -1), (1, 0), (0, 1), (-1, 0))
"""(row, column) step of Left, Down, Right, Up."""


def grid_world(grid: Sequence[str] = GRID_MAP, gamma: float = GRID_GAMMA) -> TabularMDP:
    """The paper's slippery grid world (fig. ``error_bounds``; REFERENCE.md).

    States are cells in row-major order. The intended move happens with probability 0.8 and each
    perpendicular move with 0.1; a move into the wall stays put. Entering G gives +2, entering H
    gives -0.5, every other transition 0. H and G are absorbing: every action stays there with
    reward 0, and the entropy term still applies there. The start distribution is the S cell.
    """
    rows = [str(row) for row in grid]
    if not rows or any(len(row) != len(rows[0]) for row in rows):
        raise TacbenchError("grid must be a non-empty list of equally long strings.")
    cells = "".join(rows)
    if set(cells) - set("SFHG") or cells.count("S") != 1:
        raise TacbenchError("grid cells must be S, F, H or G, with exactly one S.")
    height, width = len(rows), len(rows[0])
    n = height * width
    p = np.zeros((n, 4, n))
    r = np.zeros((n, 4, n))
    for s, cell in enumerate(cells):
        if cell in "HG":
            p[s, :, s] = 1.0
            continue
        row, col = divmod(s, width)
        for a in range(4):
            for prob, move in zip(_SLIP, (a, (a - 1) % 4, (a + 1) % 4), strict=True):
                nr, nc = row + _MOVES[move][0], col + _MOVES[move][1]
                if not (0 <= nr < height and 0 <= nc < width):
                    nr, nc = row, col
                s_next = nr * width + nc
                p[s, a, s_next] += prob
                r[s, a, s_next] = _CELL_REWARD.get(cells[s_next], 0.0)
    start = np.zeros(n)
    start[cells.index("S")] = 1.0
    return TabularMDP(P=p, R=r, gamma=gamma, start=start)


@dataclass(frozen=True)
class BoundRow:
    """One q of theorem ``thm:error_bounds``: J(pi*_q) and its lower and upper bounds."""

    q: float
    J: float
    lower_bound: float
    upper_bound: float
    iterations: int


def error_bounds(
    mdp: TabularMDP, qs: Sequence[float], alpha: float, *, tol: float = DEFAULT_TOL
) -> list[BoundRow]:
    """Theorem ``thm:error_bounds`` per q: ``J(pi*) + alpha ln_q(1/|A|) / (1 - gamma)``, J(pi*_q)
    from TVI, and ``J(pi*)`` from plain value iteration's greedy policy.
    """
    alpha = check_alpha(alpha)
    upper = expected_return(mdp, value_iteration(mdp, tol=tol).policy)
    rows = []
    for q in qs:
        sol = tsallis_value_iteration(mdp, q, alpha, tol=tol)
        slack = alpha * float(log_q(1.0 / mdp.n_actions, q)) / (1.0 - mdp.gamma)
        rows.append(
            BoundRow(
                q=float(q),
                J=expected_return(mdp, sol.policy),
                lower_bound=upper + slack,
                upper_bound=upper,
                iterations=sol.iterations,
            )
        )
    return rows
