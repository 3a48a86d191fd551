"""The project's one bootstrap (rliable's stratified bootstrap): strata, seeds, agreement, and
the replay engine against rliable's own."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
from rliable import library, metrics

from tacbench.bootstrap import (
    Engine,
    _difference_of_means,
    interval,
    mean_difference,
    scalar_interval,
)
from tacbench.report import stats

pytestmark = pytest.mark.unit


@pytest.mark.parametrize("engine", ["replay", "rliable"])
def test_each_stratum_is_resampled_from_its_own_scores_only(engine: Engine) -> None:
    strata = [np.array([1.0, 2.0, 3.0]), np.array([100.0, 200.0])]
    seen: list[tuple[set[float], set[float]]] = []

    def record(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        assert a.ndim == b.ndim == 2 and len(a) == len(b)  # (replications, runs)
        seen.extend((set(x.tolist()), set(y.tolist())) for x, y in zip(a, b, strict=True))
        return np.zeros(len(a))

    scalar_interval(record, strata, 300, seed=0, engine=engine)
    # the point (rliable and arch each take it; the replay engine once) and 300 replications
    assert len(seen) == (302 if engine == "rliable" else 301)
    assert seen[0] == ({1.0, 2.0, 3.0}, {100.0, 200.0})
    assert set().union(*(a for a, _ in seen)) == {1.0, 2.0, 3.0}
    assert set().union(*(b for _, b in seen)) == {100.0, 200.0}
    assert any(len(a) < 3 for a, _ in seen[1:])  # with replacement


def _profile(*strata: np.ndarray) -> np.ndarray:
    return stats._fractions_above(np.linspace(-2.0, 2.0, 41), *strata)


STATISTICS = {
    "iqm and mean": stats._iqm_and_mean,
    "difference of means": _difference_of_means,
    "probability of improvement": partial(stats._averaged_improvement, 2),
    "performance profile": _profile,
}


@pytest.mark.parametrize(
    ("statistic", "sizes"),
    [
        ("iqm and mean", (5, 5, 5, 5)),
        ("iqm and mean", (5, 7, 1, 4)),
        ("iqm and mean", (10,)),
        ("iqm and mean", (200, 150, 150)),  # NumPy sums 8 or more numbers pairwise
        ("difference of means", (5, 5)),
        ("difference of means", (300, 40)),
        ("difference of means", (1, 4)),
        ("probability of improvement", (5, 5, 5, 5)),
        ("probability of improvement", (5, 7, 1, 4)),
        ("performance profile", (10, 10, 10)),
        ("performance profile", (3, 8)),
    ],
)
def test_the_replay_engine_gives_rliables_intervals_to_the_last_digit(
    statistic: str, sizes: tuple[int, ...]
) -> None:
    """Every statistic the project bootstraps, on strata of equal sizes (one draw for all) and
    unequal ones (a draw per stratum and replication), a single run, and ties."""
    rng = np.random.default_rng(sum(sizes))
    strata = [np.sort(np.round(rng.normal(size=n), 1)) for n in sizes]  # rounded: ties
    function = STATISTICS[statistic]
    replayed = interval(function, strata, 500, seed=7)
    reference = interval(function, strata, 500, seed=7, engine="rliable")
    for mine, theirs in zip(replayed, reference, strict=True):
        assert mine.tobytes() == theirs.tobytes()


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
    point, low, high = interval(
        lambda x: np.stack([x.min(axis=-1), x.mean(axis=-1)], axis=-1), [np.arange(6.0)], 400, 0
    )
    assert point.tolist() == [0.0, 2.5]
    assert low.shape == high.shape == (2,)
    assert np.all(low <= point) and np.all(point <= high)


def test_per_task_strata_give_rliables_matrix_interval() -> None:
    """Tasks passed as separate strata: the same interval as rliable's runs x tasks matrix, to
    Monte Carlo error (the two draw different indices)."""
    matrix = np.random.default_rng(0).normal(size=(10, 3))
    mine = scalar_interval(stats.iqm, list(matrix.T), 4000, 1)
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
