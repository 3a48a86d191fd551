"""The verdict's permutation test of P(X > Y): its level, its exact and Monte-Carlo p-values."""

from __future__ import annotations

from itertools import combinations, product

import numpy as np
import pytest
from scipy.stats import mannwhitneyu, permutation_test

from tacbench.report.stats import pairwise_improvement
from tacbench.sequential import NOT_DISTINGUISHABLE
from tacbench.verdicts import (
    LEVEL,
    PERMUTATIONS,
    TOO_FEW_RUNS,
    decidable,
    improvement_test,
    improvement_verdict,
)

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(
    ("sizes", "enough"),
    [
        ([(1, 1)], False),
        ([(2, 2)], False),  # its bootstrap interval was [0, 0] below: "smaller"
        ([(3, 3)], False),  # the most extreme ranking: 2 in 20 when alike
        ([(3, 4)], False),  # 2 in 35
        ([(3, 5)], True),  # 2 in 56
        ([(4, 4)], True),  # 2 in 70
        ([(5, 5)], True),
        ([(3, 3), (3, 3)], True),  # over two tasks: 2 in 400
        ([(1, 5), (1, 5)], False),  # 2 in 36
        ([(1, 3), (2, 3)], True),  # 2 in 40: exactly 5 %
    ],
)
def test_a_verdict_needs_runs_enough_for_any_ranking_to_be_evidence(
    sizes: list[tuple[int, int]], enough: bool
) -> None:
    """Two runs a side, all below, gave P = 0 [0, 0], "smaller"; one a side gave "larger"."""
    xs = [np.arange(n, dtype=float) for n, _ in sizes]
    ys = [np.arange(m, dtype=float) + 100 for _, m in sizes]
    assert decidable(xs, ys) is enough


def test_two_alike_methods_get_a_verdict_in_at_most_five_percent_of_their_rankings() -> None:
    """At five runs a side the bootstrap interval's verdict came out for 24 of the 252 equally
    likely rankings of two alike methods (9.5 %); the test's, for the 8 whose exact two-sided
    Mann-Whitney p-value is at most 5 %."""
    scores = np.arange(10.0)
    verdicts = []
    for chosen in combinations(range(10), 5):
        x, y = scores[list(chosen)], np.delete(scores, list(chosen))
        verdicts.append(improvement_verdict([x], [y], seed=0)[1])
    decided = sum(v in ("larger", "smaller") for v in verdicts)
    assert decided == 8 and decided / len(verdicts) <= LEVEL
    assert verdicts.count("larger") == verdicts.count("smaller") == 4


@pytest.mark.parametrize(("n", "m"), [(4, 4), (5, 5), (3, 7), (6, 8)])
def test_the_exact_p_value_is_mann_whitneys_without_ties(n: int, m: int) -> None:
    rng = np.random.default_rng(n * 10 + m)
    for shift in (0.0, 1.0, 3.0):
        x, y = rng.normal(size=n) + shift, rng.normal(size=m)
        observed, p_value = improvement_test([x], [y], seed=0)
        assert observed == pytest.approx(pairwise_improvement(np.sort(x), np.sort(y)))
        assert p_value == pytest.approx(mannwhitneyu(x, y, method="exact").pvalue)


def test_ties_count_a_half_as_in_an_exact_permutation_test_of_u() -> None:
    x, y = np.array([1.0, 1.0, 2.0, 2.0, 2.0]), np.array([1.0, 2.0, 3.0, 3.0])

    def distance(a: np.ndarray, b: np.ndarray, axis: int) -> np.ndarray:
        wins = (a[..., :, None] > b[..., None, :]).mean((-1, -2))
        ties = (a[..., :, None] == b[..., None, :]).mean((-1, -2))
        return np.abs(wins + ties / 2 - 0.5)

    expected = permutation_test(
        (x, y), distance, n_resamples=np.inf, alternative="greater", vectorized=True
    ).pvalue
    assert improvement_test([x], [y], seed=0)[1] == pytest.approx(expected)


def test_over_tasks_the_runs_are_relabelled_within_each_task() -> None:
    """Two tasks of 3 + 3 runs: every pair of labellings (400), counted by brute force."""
    xs = [np.array([3.0, 5.0, 6.0]), np.array([10.0, 12.0, 13.0])]
    ys = [np.array([1.0, 2.0, 4.0]), np.array([11.0, 8.0, 9.0])]

    def mean_p(labels: tuple[tuple[int, ...], ...]) -> float:
        ps = []
        for pooled, chosen in zip((np.r_[xs[0], ys[0]], np.r_[xs[1], ys[1]]), labels, strict=True):
            mask = np.isin(np.arange(6), chosen)
            ps.append(pairwise_improvement(pooled[mask], pooled[~mask]))
        return float(np.mean(ps))

    observed = mean_p(((0, 1, 2), (0, 1, 2)))
    labellings = list(product(combinations(range(6), 3), repeat=2))
    far = sum(abs(mean_p(labels) - 0.5) >= abs(observed - 0.5) - 1e-12 for labels in labellings)
    assert len(labellings) == 400
    assert improvement_test(xs, ys, seed=0) == pytest.approx((observed, far / 400))


def test_beyond_the_exact_count_random_labellings_keep_the_level() -> None:
    """Ten runs a side (184,756 labellings): near the exact p-value, the same for the same
    scores in any order, and no more verdicts than the level allows when both are alike."""
    rng = np.random.default_rng(3)
    x, y = rng.normal(size=10) + 1.0, rng.normal(size=10)
    observed, p_value = improvement_test([x], [y], seed=0)
    assert p_value == pytest.approx(mannwhitneyu(x, y, method="exact").pvalue, abs=0.01)
    assert improvement_test([x[::-1]], [y[::-1]], seed=0) == (observed, p_value)
    # nor, with as many runs a side, which side is X, nor the order of the tasks
    assert improvement_test([y], [x], seed=0) == (pytest.approx(1 - observed), p_value)
    z, w = rng.normal(size=8), rng.normal(size=8)
    assert improvement_test([x, z], [y, w], seed=0)[1] == improvement_test([z, x], [w, y], 0)[1]
    assert p_value >= 1 / (1 + PERMUTATIONS)
    # nor, with other counts a side (the smaller side larger on one task), which side is X
    u, v = rng.normal(size=16) + 0.5, rng.normal(size=5)
    observed, p_value = improvement_test([u, z[:3]], [y, w], seed=0)
    assert improvement_test([y, w], [u, z[:3]], seed=0) == (
        pytest.approx(1 - observed),
        pytest.approx(p_value, abs=1e-12),
    )
    assert improvement_test([v], [u], seed=0)[1] == pytest.approx(
        improvement_test([u], [v], seed=0)[1], abs=1e-12
    )
    verdicts = [
        improvement_verdict([rng.normal(size=10)], [rng.normal(size=10)], seed=0)[1]
        for _ in range(200)
    ]
    assert sum(v != NOT_DISTINGUISHABLE for v in verdicts) <= 0.05 * 200 + 2


def test_the_verdict_takes_the_side_of_the_observed_probability() -> None:
    low, high = np.arange(5.0), np.arange(5.0) + 10
    assert improvement_verdict([high], [low], seed=0) == (pytest.approx(2 / 252), "larger")
    assert improvement_verdict([low], [high], seed=0) == (pytest.approx(2 / 252), "smaller")
    assert improvement_verdict([low], [low], seed=0) == (1.0, NOT_DISTINGUISHABLE)
    assert improvement_verdict([high[:3]], [low[:3]], seed=0) == (pytest.approx(0.1), TOO_FEW_RUNS)


def test_non_finite_scores_are_refused() -> None:
    with pytest.raises(ValueError, match="finite"):
        improvement_test([np.array([1.0, np.nan, 2.0])], [np.arange(3.0)], seed=0)


def test_a_p_value_at_the_level_is_a_verdict() -> None:
    """Tasks of (3, 3) and (2, 3) runs have 20 x 10 labellings, so the exact p-value can be 0.05
    itself: a rejection at 5 % (p <= LEVEL)."""
    xs = [np.array([1.5, 4.0, 5.0]), np.array([10.0, 11.0])]
    ys = [np.array([0.0, 2.0, 3.0]), np.array([0.0, 1.0, 2.0])]
    assert improvement_verdict(xs, ys, seed=0) == (0.05, "larger")


def test_the_monte_carlo_p_value_counts_the_observed_labelling_and_follows_the_seed() -> None:
    """Beyond the exact count, every run of X above every run of Y has p = 1 / (1 + B): the
    observed labelling is one of the B + 1. The random labellings come from the report's seed:
    the same seed, the same p-value; another seed, another draw."""
    x, y = np.arange(10.0) + 100, np.arange(10.0)
    assert improvement_test([x], [y], seed=0) == (1.0, 1 / (1 + PERMUTATIONS))
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=10), rng.normal(size=10) + 0.5
    p_value = improvement_test([a], [b], seed=0)[1]
    assert improvement_test([a], [b], seed=0)[1] == p_value
    assert improvement_test([a], [b], seed=1)[1] != p_value
