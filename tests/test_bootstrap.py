"""The project's one bootstrap (rliable's stratified bootstrap): strata, seeds, agreement."""

from __future__ import annotations

import numpy as np
import pytest
from rliable import library, metrics

from tacbench.bootstrap import interval, mean_difference, scalar_interval

pytestmark = pytest.mark.unit


def test_each_stratum_is_resampled_from_its_own_scores_only() -> None:
    strata = [np.array([1.0, 2.0, 3.0]), np.array([100.0, 200.0])]
    seen: list[tuple[set[float], set[float]]] = []

    def record(a: np.ndarray, b: np.ndarray) -> float:
        seen.append((set(a.tolist()), set(b.tolist())))
        return 0.0

    scalar_interval(record, strata, 300, seed=0)
    assert len(seen) == 302  # the point (rliable and arch each take it) and 300 replications
    assert set().union(*(a for a, _ in seen)) == {1.0, 2.0, 3.0}
    assert set().union(*(b for _, b in seen)) == {100.0, 200.0}
    assert any(len(a) < 3 for a, _ in seen[1:])  # with replacement


def test_an_interval_is_a_function_of_the_scores_and_the_seed() -> None:
    a, b = np.arange(8.0), np.arange(5.0) + 1.5
    state = np.random.get_state()  # noqa: NPY002
    first = mean_difference(a, b, 500, seed=3)
    assert first == mean_difference(a, b, 500, seed=3)
    assert first != mean_difference(a, b, 500, seed=4)
    assert first[0] == pytest.approx(a.mean() - b.mean())
    after = np.random.get_state()  # noqa: NPY002
    assert np.array_equal(state[1], after[1]) and state[2] == after[2]  # global state restored


def test_vector_statistics_get_pointwise_intervals() -> None:
    point, low, high = interval(lambda x: np.array([x.min(), x.mean()]), [np.arange(6.0)], 400, 0)
    assert point.tolist() == [0.0, 2.5]
    assert low.shape == high.shape == (2,)
    assert np.all(low <= point) and np.all(point <= high)


def test_per_task_strata_give_rliables_matrix_interval() -> None:
    """Tasks passed as separate strata: the same interval as rliable's runs x tasks matrix, to
    Monte Carlo error (the two draw different indices)."""
    matrix = np.random.default_rng(0).normal(size=(10, 3))
    mine = scalar_interval(
        lambda *tasks: metrics.aggregate_iqm(np.stack(tasks, axis=1)), list(matrix.T), 4000, 1
    )
    np.random.seed(1)  # noqa: NPY002 (rliable's own path reads the global generator)
    points, cis = library.get_interval_estimates(
        {"x": matrix}, lambda m: np.array([metrics.aggregate_iqm(m)]), reps=4000
    )
    assert mine[0] == pytest.approx(points["x"][0])
    width = cis["x"][1, 0] - cis["x"][0, 0]
    assert mine[1] == pytest.approx(cis["x"][0, 0], abs=0.05 * width)
    assert mine[2] == pytest.approx(cis["x"][1, 0], abs=0.05 * width)


def test_an_empty_stratum_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one score"):
        mean_difference(np.array([1.0]), np.array([]), 100, 0)
