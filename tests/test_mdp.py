"""Tabular Tsallis MDPs: operators, TPI, TVI, J(pi), the grid world and the paper's theorems."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp, softmax

from tacbench.errors import TacbenchError
from tacbench.theory.mdp import (
    GRID_ALPHA,
    GRID_QS,
    TabularMDP,
    error_bounds,
    evaluate_policy,
    expected_return,
    grid_world,
    policy_improvement,
    tbe_operator,
    tbo_operator,
    tsallis_policy_iteration,
    tsallis_value_iteration,
    value_iteration,
)
from tacbench.theory.tsallis import log_q, q_max, q_softmax

pytestmark = pytest.mark.unit

LEFT, DOWN, RIGHT, UP = range(4)
SETTINGS = settings(max_examples=15, deadline=None)


@st.composite
def small_mdps(draw: st.DrawFn) -> TabularMDP:
    """Random MDPs with 1-4 states, 1-3 actions, rewards in [-1, 1] and gamma in [0.3, 0.8]."""
    n_s = draw(st.integers(1, 4))
    n_a = draw(st.integers(1, 3))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    p = rng.exponential(size=(n_s, n_a, n_s)) * (rng.random((n_s, n_a, n_s)) < 0.7)
    p[..., 0] += 1e-3  # every row has some mass
    p /= p.sum(axis=-1, keepdims=True)
    gamma = draw(st.floats(0.3, 0.8))
    return TabularMDP(
        P=p, R=rng.uniform(-1, 1, size=p.shape), gamma=gamma, start=rng.dirichlet(np.ones(n_s))
    )


qs = st.sampled_from([0.5, 1.0, 1.5, 2.0, 3.0, 7.0])
alphas = st.floats(0.05, 2.0)


def random_policy(mdp: TabularMDP, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).dirichlet(np.ones(mdp.n_actions), size=mdp.n_states)


# --- the grid world -------------------------------------------------------------------------


def test_grid_world_matches_reference_layout() -> None:
    mdp = grid_world()
    assert mdp.P.shape == (16, 4, 16)
    assert mdp.gamma == 0.7
    np.testing.assert_array_equal(mdp.start, np.eye(16)[0])
    # S (0) going Right: 0.8 to cell 1, 0.1 up into the wall (stay), 0.1 down to cell 4.
    np.testing.assert_allclose(
        mdp.P[0, RIGHT], 0.8 * np.eye(16)[1] + 0.1 * np.eye(16)[[0, 4]].sum(0)
    )
    # S going Left: 0.8 + 0.1 (up) into walls, 0.1 down.
    assert mdp.P[0, LEFT, 0] == pytest.approx(0.9) and mdp.P[0, LEFT, 4] == pytest.approx(0.1)
    # Entering H (cell 3) costs 0.5, entering G (cell 15) pays 2; cell 2 Right: 0.8 into H.
    assert mdp.expected_reward[2, RIGHT] == pytest.approx(0.8 * -0.5)
    assert mdp.expected_reward[11, DOWN] == pytest.approx(0.8 * 2.0)
    assert mdp.expected_reward[11, LEFT] == pytest.approx(0.1 * 2.0)  # slips down into G
    assert mdp.expected_reward[14, RIGHT] == 0.0  # cell 14 is H: absorbing, no way to G
    # Cell 13 Right: 0.8 into H (14), 0.1 up into H (9), 0.1 down into the wall.
    assert mdp.expected_reward[13, RIGHT] == pytest.approx(0.9 * -0.5)
    for s in (3, 5, 9, 14, 15):  # holes and goal: every action stays, reward 0
        np.testing.assert_array_equal(mdp.P[s, :, s], 1.0)
        np.testing.assert_array_equal(mdp.R[s], 0.0)
    assert mdp.expected_reward[0, RIGHT] == 0.0
    assert mdp.expected_reward[1, RIGHT] == pytest.approx(0.1 * -0.5)  # slips down into H (5)


def test_grid_world_rejects_bad_maps() -> None:
    with pytest.raises(TacbenchError, match="exactly one S"):
        grid_world(("FFF", "FFG"))
    with pytest.raises(TacbenchError, match="equally long"):
        grid_world(("SF", "F"))


@pytest.mark.parametrize("q", [0.5, *GRID_QS])
def test_tvi_and_tpi_reach_the_same_q_on_the_grid_world(q: float) -> None:
    mdp = grid_world()
    tvi = tsallis_value_iteration(mdp, q, GRID_ALPHA)
    tpi = tsallis_policy_iteration(mdp, q, GRID_ALPHA)
    np.testing.assert_allclose(tvi.Q, tpi.Q, rtol=0, atol=2e-10)
    np.testing.assert_allclose(tvi.policy, tpi.policy, rtol=0, atol=1e-8)
    assert tpi.iterations < tvi.iterations  # policy iteration needs few (exact) evaluations


@pytest.mark.parametrize("q", GRID_QS)
def test_performance_error_bounds_hold_for_every_q(q: float) -> None:
    (row,) = error_bounds(grid_world(), [q], GRID_ALPHA)
    assert row.lower_bound <= row.J <= row.upper_bound
    assert row.lower_bound < row.upper_bound
    expected_gap = -GRID_ALPHA * float(log_q(0.25, q)) / 0.3
    assert row.upper_bound - row.lower_bound == pytest.approx(expected_gap)


def test_error_bounds_reference_numbers() -> None:
    rows = error_bounds(grid_world(), [1.0, 10.0], GRID_ALPHA)
    # J(pi*) from plain value iteration; computed by this module, pinned so a change shows.
    assert rows[0].upper_bound == pytest.approx(0.103976, abs=1e-6)
    # A larger q means less entropy, so pi*_q gets closer to the plain optimum.
    assert rows[0].J < rows[1].J < rows[1].upper_bound


def test_error_bounds_j_of_the_tsallis_policy() -> None:
    """J(pi*_q) as docs/theory.md quotes it, and the same from policy iteration's pi*_q at the
    same alpha: before, nothing pinned it, and J of a TVI policy at alpha/2 passed every test."""
    mdp = grid_world()
    rows = error_bounds(mdp, [1.0, 2.0, 3.0, 10.0], GRID_ALPHA)
    quoted = [-0.00017, 0.0401, 0.0649, 0.0958]
    assert [row.J for row in rows] == pytest.approx(quoted, abs=5e-5)
    for row in rows:
        by_policy_iteration = tsallis_policy_iteration(mdp, row.q, GRID_ALPHA).policy
        assert abs(row.J - expected_return(mdp, by_policy_iteration)) < 1e-8


def test_tsallis_value_is_at_least_the_plain_optimum() -> None:
    """Lemma of theorem ``thm:error_bounds``: V*_q >= V* (q-max >= max)."""
    mdp = grid_world()
    plain = value_iteration(mdp)
    for q in GRID_QS:
        assert (tsallis_value_iteration(mdp, q, GRID_ALPHA).V >= plain.V - 1e-9).all()


# --- the theorems on random MDPs ------------------------------------------------------------


@SETTINGS
@given(small_mdps(), qs, alphas)
def test_tvi_equals_tpi_on_random_mdps(mdp: TabularMDP, q: float, alpha: float) -> None:
    tvi = tsallis_value_iteration(mdp, q, alpha, tol=1e-9)
    tpi = tsallis_policy_iteration(mdp, q, alpha, tol=1e-9)
    np.testing.assert_allclose(tvi.Q, tpi.Q, rtol=0, atol=2e-9)


@SETTINGS
@given(small_mdps(), qs, alphas, st.integers(0, 1000))
def test_fixed_point_satisfies_tsallis_bellman_optimality(
    mdp: TabularMDP, q: float, alpha: float, seed: int
) -> None:
    sol = tsallis_value_iteration(mdp, q, alpha, tol=1e-10)
    v = q_max(sol.Q, q, alpha)
    np.testing.assert_allclose(sol.V, v, atol=1e-12)
    np.testing.assert_allclose(sol.Q, mdp.expected_reward + mdp.gamma * mdp.P @ v, atol=1e-9)
    np.testing.assert_allclose(sol.policy, q_softmax(sol.Q, q, alpha), atol=1e-12)
    # Q*_q is the value of pi*_q (TBE equation) and no other policy does better.
    own = evaluate_policy(mdp, sol.policy, q, alpha)
    np.testing.assert_allclose(own.Q, sol.Q, atol=1e-8)
    other = evaluate_policy(mdp, random_policy(mdp, seed), q, alpha)
    assert (other.V <= sol.V + 1e-8).all()


@SETTINGS
@given(small_mdps(), qs, alphas, st.integers(0, 1000))
def test_operators_are_gamma_contractions(
    mdp: TabularMDP, q: float, alpha: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    f1, f2 = rng.normal(scale=3.0, size=(2, mdp.n_states, mdp.n_actions))
    dist = np.max(np.abs(f1 - f2))
    tbo = np.max(np.abs(tbo_operator(mdp, f1, q, alpha) - tbo_operator(mdp, f2, q, alpha)))
    assert tbo <= mdp.gamma * dist + 1e-10
    pi = random_policy(mdp, seed)
    tbe = np.max(np.abs(tbe_operator(mdp, pi, f1, q, alpha) - tbe_operator(mdp, pi, f2, q, alpha)))
    assert tbe <= mdp.gamma * dist + 1e-10


@SETTINGS
@given(small_mdps(), qs, alphas, st.integers(0, 1000))
def test_policy_improvement_never_lowers_q(
    mdp: TabularMDP, q: float, alpha: float, seed: int
) -> None:
    old = evaluate_policy(mdp, random_policy(mdp, seed), q, alpha)
    new = evaluate_policy(mdp, policy_improvement(old.Q, q, alpha), q, alpha)
    assert (new.Q >= old.Q - 1e-9).all()


@SETTINGS
@given(small_mdps(), qs, st.integers(0, 1000))
def test_performance_error_bounds_on_random_mdps(mdp: TabularMDP, q: float, seed: int) -> None:
    alpha = 0.1 + seed / 1000
    (row,) = error_bounds(mdp, [q], alpha)
    assert row.lower_bound - 1e-9 <= row.J <= row.upper_bound + 1e-9


@SETTINGS
@given(small_mdps(), st.integers(0, 1000))
def test_iterated_and_exact_policy_evaluation_agree(mdp: TabularMDP, seed: int) -> None:
    pi = random_policy(mdp, seed)
    exact = evaluate_policy(mdp, pi, 1.5, 0.3)
    iterated = evaluate_policy(mdp, pi, 1.5, 0.3, exact=False, tol=1e-10)
    assert exact.iterations == 0 and iterated.iterations > 0
    np.testing.assert_allclose(iterated.Q, exact.Q, rtol=0, atol=1e-10)
    np.testing.assert_allclose(iterated.V, exact.V, rtol=0, atol=1e-10)


def test_q1_matches_soft_value_iteration() -> None:
    """q = 1 is Shannon entropy: V = alpha logsumexp(Q / alpha), pi = softmax(Q / alpha)."""
    mdp = grid_world()
    alpha = GRID_ALPHA
    f = np.zeros((mdp.n_states, mdp.n_actions))
    for _ in range(200):
        v = alpha * logsumexp(f / alpha, axis=1)
        f = mdp.expected_reward + mdp.gamma * mdp.P @ v
    sol = tsallis_value_iteration(mdp, 1.0, alpha)
    np.testing.assert_allclose(sol.Q, f, rtol=0, atol=1e-10)
    np.testing.assert_allclose(sol.policy, softmax(f / alpha, axis=1), rtol=0, atol=1e-10)


# --- small hand-checked cases ---------------------------------------------------------------


def test_one_state_policy_value_by_hand() -> None:
    """One state, two actions with rewards 1 and 3, uniform policy, gamma 0.5."""
    p = np.ones((1, 2, 1))
    r = np.array([1.0, 3.0]).reshape(1, 2, 1)
    mdp = TabularMDP(P=p, R=r, gamma=0.5, start=[1.0])
    pi = np.full((1, 2), 0.5)
    q, alpha = 2.0, 0.4
    entropy = 0.5  # S_2 of a fair coin: 1 - sum p^2
    v = (2.0 + alpha * entropy) / (1 - 0.5)
    sol = evaluate_policy(mdp, pi, q, alpha)
    assert sol.V[0] == pytest.approx(v)
    np.testing.assert_allclose(sol.Q[0], [1.0 + 0.5 * v, 3.0 + 0.5 * v])
    assert expected_return(mdp, pi) == pytest.approx(2.0 / 0.5)  # no entropy in J


def test_expected_return_of_a_chain() -> None:
    """0 -> 1 with reward 1, then 1 stays forever with reward 0.5: J = 1 + 0.9 * 0.5 / 0.1."""
    p = np.array([[[0.0, 1.0]], [[0.0, 1.0]]])
    r = np.array([[[0.0, 1.0]], [[0.0, 0.5]]])
    mdp = TabularMDP(P=p, R=r, gamma=0.9, start=[1.0, 0.0])
    assert expected_return(mdp, np.ones((2, 1))) == pytest.approx(1.0 + 0.9 * 0.5 / 0.1)


def test_tolerance_is_honoured_and_iterations_reported() -> None:
    mdp = grid_world()
    ref = tsallis_value_iteration(mdp, 1.5, GRID_ALPHA, tol=1e-13)
    loose = tsallis_value_iteration(mdp, 1.5, GRID_ALPHA, tol=1e-3)
    assert 0 < loose.iterations < ref.iterations
    assert np.max(np.abs(loose.Q - ref.Q)) <= 1e-3
    assert np.max(np.abs(loose.Q - ref.Q)) > 1e-8  # it did stop early


# --- bad input ------------------------------------------------------------------------------


def _valid() -> dict[str, object]:
    return {"P": np.full((2, 1, 2), 0.5), "R": np.zeros((2, 1, 2)), "gamma": 0.9, "start": [1, 0]}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"gamma": 1.0}, "gamma must lie strictly between 0 and 1"),
        ({"gamma": 0.0}, "gamma must lie strictly between 0 and 1"),
        ({"P": np.full((2, 1, 2), 0.6)}, "must be a probability distribution"),
        ({"P": np.array([[[1.5, -0.5]], [[0.5, 0.5]]])}, "must be a probability distribution"),
        ({"P": np.full((2, 2), 0.5)}, r"shape \(S, A, S\)"),
        ({"R": np.zeros((2, 2, 2))}, "R must have the shape of P"),
        ({"start": [0.5, 0.5, 0.0]}, "start must be a distribution over the 2 states"),
        ({"start": [0.7, 0.7]}, "start must be a probability distribution"),
        ({"R": np.full((2, 1, 2), np.nan)}, "must be finite"),
    ],
)
def test_bad_mdp_raises(change: dict[str, object], message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        TabularMDP(**{**_valid(), **change})


def test_bad_solver_arguments_raise() -> None:
    mdp = grid_world()
    with pytest.raises(TacbenchError, match="q must be a finite number > 0"):
        tsallis_value_iteration(mdp, 0.0, 0.1)
    with pytest.raises(TacbenchError, match="alpha must be a finite number > 0"):
        tsallis_policy_iteration(mdp, 1.5, -0.1)
    with pytest.raises(TacbenchError, match="tol must be"):
        tsallis_value_iteration(mdp, 1.5, 0.1, tol=0.0)
    with pytest.raises(TacbenchError, match=r"policy must have shape \(S, A\)"):
        evaluate_policy(mdp, np.full((16, 3), 1 / 3), 1.5, 0.1)
    with pytest.raises(TacbenchError, match="must sum to 1"):
        expected_return(mdp, np.full((16, 4), 0.3))
    with pytest.raises(TacbenchError, match=r"Q must have shape"):
        tbo_operator(mdp, np.zeros((4, 16)), 1.5, 0.1)
    with pytest.raises(TacbenchError, match=r"did not reach tol.*raise max_iter"):
        tsallis_value_iteration(mdp, 1.5, 0.1, max_iter=3)
    for endless in (float("inf"), float("nan")):  # int() of them: OverflowError, ValueError
        with pytest.raises(TacbenchError, match="max_iter must be a finite number of at least 1"):
            tsallis_value_iteration(mdp, 1.5, 0.1, max_iter=endless)  # type: ignore[arg-type]
