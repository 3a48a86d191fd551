"""Percentile intervals from rliable's stratified bootstrap: the one bootstrap of the project.

Every confidence interval tacbench prints (the report's statistics, the statistical regression
tier, the parity study) comes from :func:`interval`. Its reference engine (``engine="rliable"``)
is a thin layer over ``rliable.library.get_interval_estimates`` with a list of score arrays,
which resamples each array with replacement on its own
(``rliable.library.StratifiedIndependentBootstrap``, on top of ``arch``'s bootstrap) and reads
the percentile interval off the replications. Each array is one *stratum*: the runs of one
method on one task, so runs are resampled within tasks and tasks are never resampled (rliable's
default, ``task_bootstrap=False``), and two methods' runs are resampled independently, as
rliable does for the probability of improvement. Passing every task as its own 1-D array lets
tasks have different numbers of runs, which rliable's matrices (runs x tasks) cannot hold.

rliable draws its indices from NumPy's global generator (``np.random.choice``; its
``random_state`` argument does not reach them), so :func:`interval` seeds that generator for
the duration of the call and restores its state afterwards: an interval is a function of the
scores and the seed alone. :func:`strata_seed` derives that seed from the scores themselves, so
that a report's intervals do not depend on which other intervals it computes.

The default engine (``engine="replay"``) gives the same intervals to the last digit at a small
fraction of the cost: rliable and arch call the statistic once per replication and draw each
stratum's indices with a call of ``np.random.choice`` each (about 0.17 ms a replication). The
replay engine draws the same indices from the same generator in the same order (``choice(n,
shape)`` is ``randint(0, n, shape)``, and the legacy generator's bounded integers take one 32-bit
word each, rejected or not, whatever the call's size) and evaluates the statistic on every
replication at once. So a statistic is written once, over replications: it takes each stratum as
an array of shape ``(replications, runs)`` and returns one value per replication (shape
``(replications,)``) or one row of values (``(replications, k)``), reducing over the last axis,
where NumPy sums each row as it sums a 1-D array. tests/test_bootstrap.py holds the two engines
to the same digits for every statistic the project uses.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from hashlib import blake2b
from typing import Literal

import numpy as np
import numpy.typing as npt
from rliable import library

CONFIDENCE = 0.95
"""The coverage of every interval."""

Statistic = Callable[..., np.ndarray]
"""A function of the strata, each of shape ``(replications, runs)`` in the order given, returning
one number per replication (shape ``(replications,)``) or a row of them
(``(replications, k)``)."""

_BLOCK_ELEMENTS = 1 << 22
"""The replay engine's replications at once, times the square of the strata's runs."""

Engine = Literal["replay", "rliable"]
"""How the replications are made: rliable's bootstrap itself (``"rliable"``, the reference), or
its draws replayed with the statistic on all replications at once (``"replay"``)."""


@contextmanager
def _global_numpy_seed(seed: int) -> Iterator[None]:
    # the legacy global generator is the one rliable's resampling reads
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def _rows(statistic: Statistic, strata: Sequence[np.ndarray]) -> np.ndarray:
    """``statistic`` of ``strata`` (each ``(replications, runs)``) as ``(replications, k)``."""
    values = np.asarray(statistic(*strata), dtype=np.float64)
    return values.reshape(len(strata[0]), -1)


def _rliable(
    statistic: Statistic, strata: Sequence[np.ndarray], reps: int
) -> tuple[np.ndarray, np.ndarray]:
    """The point and the (2, k) interval from rliable's bootstrap, one replication at a time."""

    def on_columns(*resampled: np.ndarray) -> np.ndarray:
        return _rows(statistic, [c[:, 0][None, :] for c in resampled])[0]

    points, intervals = library.get_interval_estimates(
        {"scores": [s.reshape(-1, 1) for s in strata]},
        on_columns,
        reps=reps,
        confidence_interval_size=CONFIDENCE,
    )
    return np.asarray(points["scores"]), np.asarray(intervals["scores"], dtype=np.float64)


def _indices(sizes: Sequence[int], reps: int) -> list[np.ndarray]:
    """Each stratum's resampling indices, ``(reps, n)``, drawn from the global generator in
    rliable's order: replication by replication, stratum by stratum within each."""
    if len(set(sizes)) == 1:  # one bound: every draw at once, in the same order
        n = sizes[0]
        drawn = np.random.randint(0, n, size=(reps, len(sizes), n))  # noqa: NPY002
        return [drawn[:, i] for i in range(len(sizes))]
    indices = [np.empty((reps, n), dtype=np.int64) for n in sizes]
    for rep in range(reps):
        for n, stratum in zip(sizes, indices, strict=True):
            stratum[rep] = np.random.randint(0, n, size=n)  # noqa: NPY002
    return indices


def _replay(
    statistic: Statistic, strata: Sequence[np.ndarray], reps: int
) -> tuple[np.ndarray, np.ndarray]:
    """rliable's point and (2, k) percentile interval, every replication at once."""
    point = _rows(statistic, [s[None, :] for s in strata])[0]
    indices = _indices([len(s) for s in strata], reps)
    # in blocks of replications, so that a statistic over pairs of runs (P(X > Y): replications
    # x runs x runs) holds a few million elements at most, however many runs there are
    block = max(1, _BLOCK_ELEMENTS // sum(len(s) for s in strata) ** 2)
    resampled = list(zip(strata, indices, strict=True))
    values = np.concatenate(
        [
            _rows(statistic, [s[i[start : start + block]] for s, i in resampled])
            for start in range(0, reps, block)
        ]
    )
    alpha = (1.0 - CONFIDENCE) / 2  # arch's percentiles, computed as arch computes them
    percentiles = [100 * alpha, 100 * (1.0 - alpha)]
    bounds = [np.percentile(values[:, i], percentiles) for i in range(values.shape[1])]
    return point, np.asarray(bounds, dtype=np.float64).T.reshape(2, -1)


def interval(
    statistic: Statistic,
    strata: Sequence[npt.ArrayLike],
    reps: int,
    seed: int,
    engine: Engine = "replay",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``statistic`` of ``strata``, and its 95 % percentile interval from ``reps`` replications.

    Returns (point, low, high), each an array of the statistic's shape (``(1,)`` for a number).
    """
    columns = [np.asarray(s, dtype=np.float64).ravel() for s in strata]
    if not columns or any(len(c) == 0 for c in columns):
        raise ValueError("every stratum needs at least one score")
    with _global_numpy_seed(seed):
        point, (low, high) = (_replay if engine == "replay" else _rliable)(statistic, columns, reps)
    return np.asarray(point, dtype=np.float64), low, high


def scalar_interval(
    statistic: Statistic,
    strata: Sequence[npt.ArrayLike],
    reps: int,
    seed: int,
    engine: Engine = "replay",
) -> tuple[float, float, float]:
    """:func:`interval` of a statistic that returns one number, as three floats."""
    point, low, high = interval(statistic, strata, reps, seed, engine)
    return float(point[0]), float(low[0]), float(high[0])


def strata_seed(base: int, strata: Sequence[npt.ArrayLike]) -> int:
    """A bootstrap seed that is a function of ``base`` and the scores it will resample alone.

    Drawing every interval's seed from one generator in turn would tie each interval to the
    number of intervals computed before it, so adding a task or a baseline to a study would move
    the intervals of every other comparison (and flip verdicts that sit at an edge), and the same
    comparison would get different intervals in two reports. This seed is a hash (BLAKE2b,
    through NumPy's ``SeedSequence``) of ``base`` and each stratum's scores, in order and framed
    by their counts: the same on every platform, in [0, 2**32). The scores are hashed at float32
    precision, so that one run's score summed in another order (a few ulps of float64 apart, as
    two reports may compute it) gives the same seed.
    """
    digest = blake2b(digest_size=16)
    for stratum in strata:
        scores = np.ascontiguousarray(stratum, dtype="<f4").ravel()
        digest.update(len(scores).to_bytes(8, "little") + scores.tobytes())
    words = np.frombuffer(digest.digest(), dtype="<u4")
    sequence = np.random.SeedSequence([base, *(int(word) for word in words)])
    return int(sequence.generate_state(1, dtype=np.uint32)[0])


def mean_difference(
    a: npt.ArrayLike, b: npt.ArrayLike, reps: int, seed: int
) -> tuple[float, float, float]:
    """mean(a) - mean(b) with its 95 % interval, a and b resampled independently."""
    return scalar_interval(_difference_of_means, [a, b], reps, seed)


def _difference_of_means(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return x.mean(axis=-1) - y.mean(axis=-1)
