"""Tsallis statistics: definitions, closed forms, the q-max theorem and the appendix identities."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import brentq
from scipy.special import logsumexp, softmax

from tacbench.errors import TacbenchError
from tacbench.theory.tsallis import (
    exp_q,
    log_q,
    q_max,
    q_potential,
    q_softmax,
    tsallis_entropy,
)

pytestmark = pytest.mark.unit

Q_VALUES = [0.1, 0.5, 0.7, 1.0, 1.2, 1.5, 1.7, 2.0, 2.5, 3.0, 5.0, 10.0, 50.0]
values_st = arrays(
    np.float64,
    st.integers(1, 12),
    elements=st.floats(-50, 50, allow_nan=False, allow_infinity=False),
)
# up to q = 5,000 (q -> infinity is plain RL): above about 100 the q > 2 solver's
# s**(q - 1) underflowed, and the probabilities summed to up to 1.47
q_st = st.sampled_from(Q_VALUES) | st.floats(0.1, 50.0) | st.floats(100.0, 5000.0)
alpha_st = st.floats(0.05, 5.0)


def test_exp_and_log_follow_the_paper_convention() -> None:
    x = np.linspace(-0.9, 3.0, 9)
    assert np.allclose(exp_q(x, 1.0), np.exp(x))
    assert np.allclose(exp_q(x, 2.0), np.maximum(1.0 + x, 0.0))  # [1 + (q-1) x]_+^(1/(q-1))
    assert np.allclose(exp_q(x, 3.0), np.sqrt(np.maximum(1.0 + 2.0 * x, 0.0)))
    p = np.linspace(0.05, 4.0, 9)
    assert np.allclose(log_q(p, 1.0), np.log(p))
    assert np.allclose(log_q(p, 2.0), p - 1.0)  # linear at q = 2 (paper, section 2)
    assert np.allclose(log_q(p, 0.5), (p**-0.5 - 1.0) / -0.5)


def test_exp_q_cuts_off_and_has_a_pole() -> None:
    assert exp_q(-1.0, 2.0) == 0.0  # outside the support for q > 1
    assert exp_q(-np.inf, 0.5) == 0.0
    assert exp_q(2.0, 0.5) == np.inf  # at the pole x = 1/(1-q) for q < 1
    assert log_q(0.0, 2.0) == -1.0 and log_q(0.0, 0.5) == -np.inf


@pytest.mark.parametrize("q", [0.5, 1.0, 2.0])
def test_exp_q_of_nan_is_nan(q: float) -> None:
    """It was 0 at q > 1 and +inf at q < 1: a NaN from upstream read as a probability or a pole."""
    assert np.isnan(exp_q(np.nan, q))
    assert exp_q(np.array([np.nan, 0.0]), q)[1] == 1.0


@pytest.mark.parametrize("q", Q_VALUES)
def test_log_q_inverts_exp_q(q: float) -> None:
    # where both directions are well conditioned (for large q, ln_q(p) -> -1/(q-1) as p -> 0)
    x = np.linspace(0.1, 1.0, 19)
    assert np.allclose(log_q(exp_q(x, q), q), x, rtol=1e-9)
    if q <= 5.0:
        p = np.geomspace(1e-3, 10.0, 50)
        assert np.allclose(exp_q(log_q(p, q), q), p, rtol=1e-8)


def test_q_logarithm_is_continuous_at_q_equal_one() -> None:
    p = np.geomspace(1e-8, 1e3, 20)
    assert np.allclose(log_q(p, 1.0 + 1e-12), np.log(p), rtol=1e-9, atol=1e-9)
    assert np.allclose(exp_q(np.linspace(-5, 5, 11), 1.0 - 1e-12), np.exp(np.linspace(-5, 5, 11)))


def test_entropy_special_cases() -> None:
    p = np.array([0.5, 0.25, 0.25, 0.0])
    assert np.isclose(tsallis_entropy(p, 1.0), -np.sum(p[:3] * np.log(p[:3])))
    assert np.isclose(tsallis_entropy(p, 2.0), 1.0 - np.sum(p**2))  # sparse Tsallis entropy
    for q in Q_VALUES:
        uniform = np.full(5, 0.2)
        assert np.isclose(tsallis_entropy(uniform, q), -log_q(0.2, q))  # maximum (appendix A)
        certain = tsallis_entropy(np.array([0.0, 1.0, 0.0]), q)
        assert certain == 0.0 and not np.signbit(certain)  # 0, not -0 (the theory CSVs' "-0")


def test_a_large_q_keeps_the_maximiser_normalised_and_the_bound() -> None:
    """The paper's q -> infinity end: exact values from a 50-digit solver of the same
    equations (mpmath)."""
    assert np.allclose(q_softmax([0.0, -0.1], 1000.0), [0.99769677, 0.00230323], atol=1e-8)
    assert q_max([0.0, -0.1], 1000.0) == pytest.approx(0.00067091, abs=1e-8)
    bandit = [2.0, 2.0, 2.0, 2.0, 4.0, 4.0, 4.5, 5.0]
    assert q_max(bandit, 300.0) == pytest.approx(5.00052, abs=1e-5)


@settings(max_examples=200, deadline=None)
@given(values_st, q_st, alpha_st)
def test_q_softmax_is_normalised(f: np.ndarray, q: float, alpha: float) -> None:
    pi = q_softmax(f, q, alpha)
    assert np.all(pi >= 0.0)
    assert abs(pi.sum() - 1.0) <= 1e-10


@settings(max_examples=200, deadline=None)
@given(values_st, q_st, alpha_st)
def test_q_max_bounds_of_theorem_bound(f: np.ndarray, q: float, alpha: float) -> None:
    """max f <= q-max f <= max f - alpha ln_q(1/|X|) (paper, theorem thm:bound)."""
    value = q_max(f, q, alpha)
    upper = f.max() - alpha * log_q(1.0 / f.size, q)
    tol = 1e-9 * (1.0 + np.abs(f).max())
    assert f.max() - tol <= value <= upper + tol


@settings(max_examples=150, deadline=None)
@given(values_st, q_st, alpha_st, st.integers(0, 2**32 - 1))
def test_q_max_is_the_value_at_q_softmax_and_is_not_beaten(
    f: np.ndarray, q: float, alpha: float, seed: int
) -> None:
    pi = q_softmax(f, q, alpha)
    value = q_max(f, q, alpha)
    objective = pi @ f + alpha * tsallis_entropy(pi, q)
    tol = 1e-9 * (1.0 + np.abs(f).max())
    assert abs(objective - value) <= tol
    rng = np.random.default_rng(seed)
    others = rng.dirichlet(np.full(f.size, 0.3), size=200)
    others = np.vstack([others, np.eye(f.size), np.full(f.size, 1.0 / f.size)])
    assert np.all(others @ f + alpha * tsallis_entropy(others, q) <= value + tol)


@settings(max_examples=150, deadline=None)
@given(values_st, st.floats(1.05, 50.0))
def test_support_condition_of_appendix_b(f: np.ndarray, q: float) -> None:
    """pi_a > 0 exactly where 1 + (q-1)(r_a/q - psi_q(r/q)) > 0 (appendix B, last step)."""
    pi = q_softmax(f, q)
    z = f / q
    base = 1.0 + (q - 1.0) * (z - q_potential(z, q))
    clear = np.abs(base) > 1e-9  # arms exactly at the edge may round either way
    assert np.array_equal((pi > 0)[clear], (base > 0)[clear])
    assert pi[np.argmax(f)] > 0


@pytest.mark.parametrize("q", [0.3, 0.8, 1.5, 2.0, 3.0, 7.0])  # 2.0: the sparsemax branch
def test_closed_form_value_identity_of_appendix_b(q: float) -> None:
    """E[r] + S_q(pi) = (q-1) sum_a (r_a/q) pi_a + psi_q(r/q)."""
    r = np.array([2.0, 2.0, 2.0, 2.0, 4.0, 4.0, 4.5, 5.0])
    pi = q_softmax(r, q)
    assert np.isclose(q_max(r, q), (q - 1.0) * np.sum(r / q * pi) + q_potential(r / q, q))


def test_q_near_one_matches_softmax_and_log_sum_exp() -> None:
    rng = np.random.default_rng(0)
    f = rng.normal(0.0, 3.0, size=(20, 7))
    for alpha in (0.1, 1.0, 2.0):
        assert np.allclose(q_softmax(f, 1.0, alpha), softmax(f / alpha, axis=-1))
        assert np.allclose(q_max(f, 1.0, alpha), alpha * logsumexp(f / alpha, axis=-1))
        for q in (1.0 - 1e-7, 1.0 + 1e-7):
            assert np.allclose(q_softmax(f, q, alpha), softmax(f / alpha, axis=-1), atol=1e-5)
            assert np.allclose(q_max(f, q, alpha), alpha * logsumexp(f / alpha, axis=-1), atol=1e-5)
    assert np.allclose(q_potential(f, 1.0), logsumexp(f, axis=-1))


def _sparsemax_by_root_finding(z: np.ndarray) -> np.ndarray:
    """Euclidean projection onto the simplex: [z - tau]_+ with tau from a scalar root finder."""
    # at max z - 2 the largest term alone is 2 > 1 (max z - 1 can round to a sum just below 1)
    tau = brentq(lambda t: np.maximum(z - t, 0.0).sum() - 1.0, z.max() - 2.0, z.max())
    return np.maximum(z - tau, 0.0)


@settings(max_examples=100, deadline=None)
@given(values_st, alpha_st)
def test_q_two_is_sparsemax(f: np.ndarray, alpha: float) -> None:
    expected = _sparsemax_by_root_finding(f / (2.0 * alpha))
    assert np.allclose(q_softmax(f, 2.0, alpha), expected, atol=1e-9)
    assert np.allclose(q_softmax(f, 2.0 + 1e-9, alpha), expected, atol=1e-6)


def test_paper_bandit_policies_sparsify_as_q_grows() -> None:
    r = np.array([2.0, 2.0, 2.0, 2.0, 4.0, 4.0, 4.5, 5.0])
    support = [int(np.sum(q_softmax(r, q) > 0)) for q in (0.5, 1.0, 2.0, 10.0)]
    assert support == [8, 8, 4, 2]
    assert np.allclose(q_softmax(r, 2.0), [0, 0, 0, 0, 0.0625, 0.0625, 0.3125, 0.5625])
    # q = 50: two arms, p_max^49 - p_2^49 = 49 * 0.5 / 50 (worked by hand), p_2 ~ 0.0145
    p = q_softmax(r, 50.0)
    assert np.isclose(p[7] ** 49 - p[6] ** 49, 49.0 * 0.5 / 50.0)
    assert q_max(r, 50.0) >= 5.0


def test_alpha_rescales_rewards() -> None:
    f = np.array([0.3, -1.0, 2.0, 2.0])
    for q in (0.5, 1.0, 2.0, 4.0):
        assert np.isclose(q_max(f, q, 0.25), 0.25 * q_max(f / 0.25, q, 1.0))
        assert np.allclose(q_softmax(f, q, 0.25), q_softmax(f / 0.25, q, 1.0))


@pytest.mark.parametrize("q", Q_VALUES)
def test_ties_minus_inf_and_huge_ranges(q: float) -> None:
    tied = q_softmax(np.array([1.0, 1.0, 1.0]), q)
    assert np.allclose(tied, 1.0 / 3.0)
    masked = q_softmax(np.array([0.0, -np.inf, 0.5, -np.inf]), q)
    assert masked[1] == 0.0 and masked[3] == 0.0 and np.isclose(masked.sum(), 1.0)
    huge = np.array([1e300, -1e300, 0.0, 1e300])
    assert np.allclose(q_softmax(huge, q), [0.5, 0.0, 0.0, 0.5])
    assert np.isfinite(q_max(huge, q)) and q_max(huge, q) >= 1e300
    tiny = np.array([1e-300, 0.0])
    assert np.allclose(q_softmax(tiny, q), 0.5)


@pytest.mark.parametrize("q", Q_VALUES)
def test_gaps_beyond_float64_weigh_nothing_and_warn_nothing(q: float) -> None:
    """Values near +-1e308 differ by more than float64 holds: such an arm gets probability 0,
    silently (numpy printed overflow warnings for results that were right)."""
    edge = np.array([1.7e308, -1.7e308, 0.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pi, value = q_softmax(edge, q), q_max(edge, q)
        potential = q_potential(np.array([-1e308, -1e308, 0.0]), q)
    assert pi[1:].tolist() == [0.0, 0.0] and pi[0] == pytest.approx(1.0)
    assert value == pytest.approx(1.7e308)
    assert potential == pytest.approx(0.0, abs=1e-12)  # one arm: psi_q = its value


@pytest.mark.parametrize("q", [0.5, 1.0, 1.5, 3.0])
def test_a_gap_past_float64_is_scaled_before_it_overflows(q: float) -> None:
    """1.7e308 - (-1.7e308) overflows float64, but over alpha * q it need not: the arm keeps
    its weight (it was given 0, and q-max the best value alone)."""
    f, alpha = np.array([1.7e308, -1.7e308]), 1e307
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pi, value = q_softmax(f, q, alpha), q_max(f, q, alpha)
    assert pi == pytest.approx(q_softmax(f / alpha, q), rel=1e-12)
    assert value == pytest.approx(alpha * q_max(f / alpha, q), rel=1e-12)
    assert pi[1] > 0.0 or q > 1.0  # q > 1: the arm lies beyond the support, weight 0
    assert q_softmax(f, 1.0, 1e308) == pytest.approx(softmax([1.7, -1.7]), rel=1e-12)


def test_weights_too_small_for_float64_that_q_below_one_counts_are_refused() -> None:
    """At q < 1, S_q counts a weight p as about p^q: at q = 0.001 an arm 1e306 below the best
    adds 0.49 to q-max although its weight (about 1e-309) rounds to 0, and q-max came out 0."""
    assert q_max([0.0, -1e304], 1e-3) == pytest.approx(0.4928, abs=1e-4)  # weight 1e-307: kept
    with pytest.raises(TacbenchError, match=r"1 arm\(s\) lie so far below .* adds up to 0.49"):
        q_max([0.0, -1e306], 1e-3)
    # at q = 0.1 the share lost (about 1e-33) is below the value's rounding
    assert q_max([0.0, -1e306], 0.1) == pytest.approx(0.0, abs=1e-12)


def test_vectorised_over_leading_axes() -> None:
    rng = np.random.default_rng(1)
    f = rng.normal(size=(3, 4, 6))
    for q in (0.5, 1.5, 3.0):
        batched = q_softmax(f, q, 0.7)
        rows = np.array([[q_softmax(row, q, 0.7) for row in block] for block in f])
        assert np.allclose(batched, rows)
        assert q_max(f, q).shape == (3, 4)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: q_max([1.0, 2.0], 0.0), "q must be"),
        (lambda: q_max([1.0, 2.0], -1.0), "q must be"),
        (lambda: q_softmax([1.0, 2.0], 1.5, alpha=0.0), "alpha must be"),
        (lambda: q_softmax([1.0, np.nan], 1.5), "NaN"),
        (lambda: q_softmax([], 1.5), "non-empty"),
        (lambda: q_max([-np.inf, -np.inf], 1.5), "at least one finite"),
        (lambda: q_max([np.inf, 0.0], 1.5), r"\+inf"),
        (lambda: tsallis_entropy([0.5, 0.6], 1.5), "sum to 1"),
        (lambda: log_q([-1.0], 1.5), "x >= 0"),
        (lambda: exp_q(1.0, float("nan")), "q must be"),
        # was the uniform policy with q-max 0.5, below max f = 1 (thm:bound)
        (lambda: q_max([0.0, 1.0], 1e300, alpha=1e10), r"alpha \* q = 1e\+10 \* 1e\+300 overflows"),
        (lambda: q_softmax([0.0, 1.0], 1e308, alpha=2.0), "overflows float64"),
        # was [nan, 0]: 0 / 0 at the best arm
        (lambda: q_softmax([1.0, 0.0], 1e-200, alpha=1e-200), "underflows float64 to 0"),
    ],
)
def test_bad_input_raises_the_project_error(call: object, message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        call()  # type: ignore[operator]
