"""Tsallis statistics: q-exponential, q-logarithm, Tsallis entropy, q-potential, q-max, q-softmax.

Conventions follow the paper (section 2, eqs. ``def:qexp``, ``def:qlog``, ``def:tsallis_ent``),
which uses q' = 2 - q relative to Amari's: ``exp_q(x) = [1 + (q-1) x]_+^(1/(q-1))``,
``ln_q(x) = (x^(q-1) - 1) / (q-1)``, ``S_q(P) = E_P[-ln_q P(X)]``. q = 1 is Shannon, q = 2 the
sparse Tsallis entropy, q -> infinity no entropy at all.

Everything is NumPy, float64 and vectorised over the last axis. The q-max operator with a
temperature alpha is ``q-max_alpha(f) = max_{P in simplex} E_P[f] + alpha S_q(P)``; its maximiser
is ``q_softmax``. Both use the paper's closed form (appendix B, ``def:optsol_qmax``)
``pi(a) = exp_q(z_a - psi_q(z))`` with ``z = f / (alpha q)`` and the q-potential psi_q fixed by
normalisation. psi_q is closed-form at q = 1 (log-sum-exp) and q = 2 (simplex projection,
sparsemax); otherwise it is found by vectorised bisection: on psi inside the exact bracket
``[max z, max z - ln_q(1/n)]`` for q < 2, and for q > 2 (where exp_q is infinitely steep at the
edge of its support) on the smallest supported probability once the support is known.

Values near +-1e308 may differ by more than float64 holds: the difference is then taken after
scaling by 1/(alpha q), and an arm whose scaled gap is still past float64 gets weight 0. That is
exact for q >= 1; at q < 1, where S_q counts a weight p as about p^q, ``q_max`` refuses inputs
whose weights float64 cannot hold when they would change its value beyond rounding (q below
about 0.05).

TAC's torch version, ``ln_q`` of a density given its log with q per member, is
:func:`tacbench.tac.maths.log_q_of_log`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.special import logsumexp

from tacbench.errors import TacbenchError

Array = npt.NDArray[np.float64]
ArrayLike = npt.ArrayLike

_MAX_ITER = 200


def check_q(q: float) -> float:
    """Return q as a float, or raise if it is not a finite number > 0."""
    q = float(q)
    if not np.isfinite(q) or q <= 0:
        raise TacbenchError(
            f"entropic index q must be a finite number > 0 (got {q}); "
            "the paper covers q > 0, where S_q is concave."
        )
    return q


def check_alpha(alpha: float) -> float:
    """Return alpha as a float, or raise if it is not a finite number > 0."""
    alpha = float(alpha)
    if not np.isfinite(alpha) or alpha <= 0:
        raise TacbenchError(f"entropy coefficient alpha must be a finite number > 0 (got {alpha}).")
    return alpha


def _as_values(f: ArrayLike, what: str) -> Array:
    """Values for q-max/q-softmax: non-empty, no NaN, no +inf, at least one finite per row."""
    arr = np.asarray(f, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] == 0:
        raise TacbenchError(
            f"{what} needs a non-empty array along its last axis (got shape {arr.shape})."
        )
    if np.isnan(arr).any():
        raise TacbenchError(f"{what} got NaN values; check the rewards or Q-values you pass in.")
    if np.isposinf(arr).any():
        raise TacbenchError(f"{what} got +inf values; only finite values and -inf are allowed.")
    if not np.isfinite(arr).any(axis=-1).all():
        raise TacbenchError(f"{what} needs at least one finite value along the last axis.")
    return arr


def exp_q(x: ArrayLike, q: float) -> Array:
    """q-exponential ``[1 + (q-1) x]_+^(1/(q-1))`` (``exp`` at q = 1), elementwise.

    For q < 1 the function has a pole at ``x = 1/(1-q)``; at and beyond it the result is +inf.
    """
    q = check_q(q)
    x = np.asarray(x, dtype=np.float64)
    if q == 1.0:
        return np.exp(x)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        base = 1.0 + (q - 1.0) * x
        value = np.exp(np.log1p((q - 1.0) * x) / (q - 1.0))
        outside = 0.0 if q > 1.0 else np.inf
        return np.where(base <= 0, outside, value)  # NaN in, NaN out (as np.exp at q = 1)


def log_q(x: ArrayLike, q: float) -> Array:
    """q-logarithm ``(x^(q-1) - 1) / (q-1)`` (``log`` at q = 1), for x >= 0.

    Computed as ``expm1((q-1) log x) / (q-1)``, accurate for q near 1. ``log_q(0)`` is its
    limit: ``-1/(q-1)`` for q > 1 and ``-inf`` for q <= 1.
    """
    q = check_q(q)
    x = np.asarray(x, dtype=np.float64)
    if (x < 0).any() or np.isnan(x).any():
        raise TacbenchError("log_q is defined for x >= 0 only; got negative or NaN input.")
    with np.errstate(divide="ignore", over="ignore"):
        log_x = np.log(x)
        if q == 1.0:
            return log_x
        return np.expm1((q - 1.0) * log_x) / (q - 1.0)


def tsallis_entropy(p: ArrayLike, q: float) -> Array:
    """Tsallis entropy ``S_q(p) = -sum_a p_a ln_q(p_a)`` over the last axis (0 ln_q 0 = 0)."""
    q = check_q(q)
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] == 0:
        raise TacbenchError(
            f"tsallis_entropy needs a non-empty distribution (got shape {p.shape})."
        )
    if np.isnan(p).any() or (p < 0).any():
        raise TacbenchError("tsallis_entropy needs probabilities >= 0 without NaN.")
    if not np.allclose(p.sum(axis=-1), 1.0, atol=1e-6):
        raise TacbenchError(
            "tsallis_entropy needs distributions that sum to 1 along the last axis."
        )
    return _entropy(p, q)[..., 0]


def _sparsemax_threshold(y: Array) -> Array:
    """tau with ``sum_a [y_a - tau]_+ = 1`` (Euclidean projection onto the simplex), per row."""
    y_sorted = -np.sort(-y, axis=-1)
    k = np.arange(1, y.shape[-1] + 1, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):  # sums past -1e308: -inf, outside
        cumsum = np.cumsum(y_sorted, axis=-1)
        in_support = 1.0 + k * y_sorted > cumsum
    support = np.sum(in_support, axis=-1, keepdims=True)
    cumsum_support = np.take_along_axis(cumsum, support.astype(np.intp) - 1, axis=-1)
    return (cumsum_support - 1.0) / support


def _entropy(p: Array, q: float) -> Array:
    """``-sum_a p_a ln_q(p_a)`` over the last axis with ``0 ln_q 0 = 0``; no input checks."""
    safe = np.where(p > 0, p, 1.0)
    # 0 - sum, not -sum: a certain policy's entropy is 0, not -0 (the theory CSVs wrote "-0")
    return 0.0 - np.sum(np.where(p > 0, p * log_q(safe, q), 0.0), axis=-1, keepdims=True)


def _shifted_potential(y: Array, q: float) -> Array:
    """psi' with ``sum_a exp_q(y_a - psi') = 1`` for rows y with max 0 (others <= 0 or -inf), q < 2.

    The root lies in ``[0, -ln_q(1/n)]``: at psi' = 0 the maximal term alone is 1, and at
    ``-ln_q(1/n)`` every term is at most 1/n. The sum is monotone in psi', so bisection halves
    the bracket until it is one rounding step wide (at most ~75 steps for n up to 10^6). For
    q < 2, ``exp_q`` is flat at the edge of its support, so psi' determines pi well.
    """
    n = np.sum(np.isfinite(y), axis=-1, keepdims=True).astype(np.float64)
    lo = np.zeros_like(n)
    hi = -log_q(1.0 / n, q)
    eps = np.finfo(np.float64).eps
    for _ in range(_MAX_ITER):
        mid = 0.5 * (lo + hi)
        if np.all(hi - lo <= 2.0 * eps * np.maximum(1.0, hi)):
            break
        above = np.sum(exp_q(y - mid, q), axis=-1, keepdims=True) > 1.0
        lo = np.where(above, mid, lo)
        hi = np.where(above, hi, mid)
    return 0.5 * (lo + hi)


def _steep_solution(y: Array, q: float) -> tuple[Array, Array]:
    """(psi', pi) for q > 2, rows y with max 0, where ``exp_q`` is infinitely steep at 0.

    There ``pi_a = (c_a - m)_+^(1/(q-1))`` with ``c = (q-1) y`` and one unknown level m, but a
    small supported pi_a needs ``c_a - m`` to far more digits than m carries. So the support is
    found first, from the breakpoints ``m = c_(k)`` of the sorted c (binary search on k), and then
    the smallest supported probability s is bisected on; every supported arm's
    ``pi_(j) = (c_(j) - c_(K) + s^(q-1))^(1/(q-1))`` is then accurate.
    """
    expo = 1.0 / (q - 1.0)
    with np.errstate(over="ignore"):  # (q - 1) y past -1e308: -inf, an arm outside the support
        c = -np.sort(-(q - 1.0) * y, axis=-1)
    n = c.shape[-1]

    def mass_at_breakpoint(k: npt.NDArray[np.intp]) -> Array:
        ck = np.take_along_axis(c, k, axis=-1)
        with np.errstate(invalid="ignore"):
            gaps = np.where(c > ck, c - ck, 0.0)
        return np.sum(gaps**expo, axis=-1, keepdims=True)

    lo = np.zeros((*c.shape[:-1], 1), dtype=np.intp)  # mass < 1 at c_(lo); c_(0) = max
    hi = np.full_like(lo, n)  # mass >= 1 at c_(hi), or hi = n (no such breakpoint)
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        below = mass_at_breakpoint(np.minimum(mid, n - 1)) < 1.0
        lo = np.where((hi - lo > 1) & below, mid, lo)
        hi = np.where((hi - lo > 1) & ~below, mid, hi)
    c_last = np.take_along_axis(c, lo, axis=-1)
    c_next = np.take_along_axis(c, np.minimum(lo + 1, n - 1), axis=-1)
    gap_next = np.where(lo + 1 < n, c_last - c_next, np.inf)
    in_support = np.arange(n) <= lo
    d = np.where(in_support, c - c_last, 0.0)

    s_lo = np.zeros_like(c_last)
    s_hi = np.minimum(1.0, gap_next**expo)
    for _ in range(_MAX_ITER):
        s = 0.5 * (s_lo + s_hi)
        if np.all(s_hi - s_lo <= np.finfo(np.float64).eps):
            break
        total = np.sum(np.where(in_support, _root(d, s, q), 0.0), axis=-1, keepdims=True)
        s_lo = np.where(total < 1.0, s, s_lo)
        s_hi = np.where(total < 1.0, s_hi, s)
    s = 0.5 * (s_lo + s_hi)
    pi_sorted = np.where(in_support, _root(d, s, q), 0.0)
    psi = (1.0 + c_last - s ** (q - 1.0)) / (q - 1.0)
    order = np.argsort(-y, axis=-1, kind="stable")
    pi = np.empty_like(pi_sorted)
    np.put_along_axis(pi, order, pi_sorted, axis=-1)
    return psi, pi


def _root(d: Array, s: Array, q: float) -> Array:
    """``(d + s**(q - 1)) ** (1 / (q - 1))``, a supported arm's probability in
    :func:`_steep_solution`. For a large q, ``s**(q - 1)`` underflows (below 1e-308 once s is
    under ``10**(-308 / (q - 1))``): the last supported arm's probability, ``s`` itself, then
    came out 0, the bisection stopped at that jump, and the probabilities no longer summed to 1
    (1.47 at q = 1,000). There the same root is taken through logarithms; elsewhere as written,
    so every value of a q up to about 100 is unchanged to the last bit."""
    power = s ** (q - 1.0)
    direct = (d + power) ** (1.0 / (q - 1.0))
    normal = power >= np.finfo(np.float64).tiny
    if np.all(normal):  # every q up to about 100: no logarithms in the bisection's loop
        return direct
    with np.errstate(divide="ignore"):  # log 0 = -inf: an arm at the threshold, or s = 0
        through_logs = np.exp(np.logaddexp(np.log(d), (q - 1.0) * np.log(s)) / (q - 1.0))
    return np.where(normal, direct, through_logs)


class _Solution(NamedTuple):
    """:func:`_solve`'s parts, each keepdims over the last axis."""

    values: Array  # f
    f_max: Array
    gap: Array  # f - max f: -inf where the difference lies past float64's range (``past``)
    past: npt.NDArray[np.bool_]  # finite inputs near +-1e308 whose gap overflowed
    psi: Array  # the shifted potential psi' of y
    pi: Array  # the maximiser


def _solve(f: ArrayLike, q: float, alpha: float, what: str) -> _Solution:
    """Shared core: ``y = (f - max f) / (alpha q)``, so that huge value ranges keep full
    precision, its potential and the maximiser."""
    q, alpha = check_q(q), check_alpha(alpha)
    if not np.isfinite(alpha * q):  # y would be 0 everywhere: the uniform policy, for any f
        raise TacbenchError(
            f"{what}: alpha * q = {alpha:g} * {q:g} overflows float64; use a smaller q or alpha "
            "(q -> infinity is the plain maximum)."
        )
    if alpha * q == 0.0:  # y would be 0 / 0 at the best arm: a NaN policy
        raise TacbenchError(
            f"{what}: alpha * q = {alpha:g} * {q:g} underflows float64 to 0; use a larger q or "
            "alpha (alpha -> 0 is the plain maximum)."
        )
    values = _as_values(f, what)
    f_max = np.max(values, axis=-1, keepdims=True)
    with np.errstate(over="ignore", invalid="ignore"):  # inputs near +-1e308: a gap may lie
        gap = values - f_max  # past float64's range (inf - inf: only where np.where drops it)
        y = gap / (alpha * q)
        past = np.isneginf(gap) & np.isfinite(values)
        if np.any(past):  # scaled first, y may be in range (else -inf: a weight float64 lacks)
            y = np.where(past, values / (alpha * q) - f_max / (alpha * q), y)
    if q == 1.0:
        psi = logsumexp(y, axis=-1, keepdims=True)
        pi = np.exp(y - psi)
    elif q == 2.0:
        tau = _sparsemax_threshold(y)
        psi = 1.0 + tau
        pi = np.maximum(y - tau, 0.0)
    elif q < 2.0:
        psi = _shifted_potential(y, q)
        pi = exp_q(y - psi, q)
    else:
        psi, pi = _steep_solution(y, q)
    return _Solution(values, f_max, gap, past, psi, pi)


def q_potential(z: ArrayLike, q: float) -> Array:
    """The q-potential ``psi_q(z)``: the unique psi with ``sum_a exp_q(z_a - psi) = 1``.

    The paper writes it at ``z = r / q`` (``def:qpoten``); q = 1 gives log-sum-exp.
    """
    solved = _solve(z, q, 1.0 / check_q(q), "q_potential")
    return (solved.f_max + solved.psi)[..., 0]


def q_softmax(f: ArrayLike, q: float, alpha: float = 1.0) -> Array:
    """The maximiser of ``E_P[f] + alpha S_q(P)``: ``exp_q(f/(alpha q) - psi_q(f/(alpha q)))``.

    Softmax of ``f/alpha`` at q = 1, sparsemax of ``f/(2 alpha)`` at q = 2; -inf entries get
    probability 0. Rows along the last axis sum to 1.
    """
    return _solve(f, q, alpha, "q_softmax").pi


def q_max(f: ArrayLike, q: float, alpha: float = 1.0) -> Array:
    """The q-maximum ``max_P E_P[f] + alpha S_q(P)`` over the last axis (paper ``def:qmax``).

    Evaluated at the maximiser pi as ``max f + E_pi[f - max f] + alpha S_q(pi)``, which equals
    appendix B's ``alpha [(q-1) sum_a z_a pi_a + psi_q(z)]`` and is well conditioned (its
    gradient in f is pi). Bounds (theorem ``thm:bound``):
    ``max f <= q_max(f) <= max f - alpha ln_q(1/n)``.
    """
    values, f_max, gap, past, _, pi = _solve(f, q, alpha, "q_max")
    if q < 1.0:
        _check_lost_weights(values, f_max, pi, q, alpha)
    with np.errstate(invalid="ignore", over="ignore"):  # a gap past float64: weighed apart
        terms = np.where(past, values * pi - f_max * pi, gap * pi)
        mean_gap = np.sum(np.where(pi > 0, terms, 0.0), axis=-1, keepdims=True)
    return (f_max + mean_gap + alpha * _entropy(pi, q))[..., 0]


def _check_lost_weights(values: Array, f_max: Array, pi: Array, q: float, alpha: float) -> None:
    """At q < 1 every arm has weight, and S_q counts a weight p as about p^q, which stays large
    for small q however small p is. An arm whose weight float64 cannot hold (its scaled gap past
    float64's range, or the weight below the smallest subnormal) is dropped, and the q-maximum
    with it by up to ``alpha p^q``: refused where that exceeds the value's rounding."""
    lost = np.sum((pi == 0.0) & np.isfinite(values), axis=-1, keepdims=True)
    huge = np.finfo(np.float64).max
    log_p = max(np.log(np.nextafter(0.0, 1.0)), -np.log((1.0 - q) * huge) / (1.0 - q))
    share = alpha * np.exp(q * log_p)  # what one lost arm may carry, at most
    rounding = np.finfo(np.float64).eps * np.maximum(np.abs(f_max), alpha)
    if np.any(lost * share > rounding):
        raise TacbenchError(
            f"q_max: at q = {q:g}, {int(lost.max())} arm(s) lie so far below the best (their "
            f"gap over alpha * q beyond float64) that their weights round to 0, yet each adds "
            f"up to {share:.2g} to the q-maximum; scale f down, or use a larger alpha or q."
        )
