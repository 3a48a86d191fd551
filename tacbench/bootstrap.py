"""Percentile intervals from rliable's stratified bootstrap: the one bootstrap of the project.

Every confidence interval tacbench prints (the report's statistics, the statistical regression
tier, the parity study) comes from :func:`interval`, a thin layer over
``rliable.library.get_interval_estimates`` with a list of score arrays, which resamples each
array with replacement on its own (``rliable.library.StratifiedIndependentBootstrap``, on top of
``arch``'s bootstrap) and reads the percentile interval off the replications. Each array is one
*stratum*: the runs of one method on one task, so runs are resampled within tasks and tasks are
never resampled (rliable's default, ``task_bootstrap=False``), and two methods' runs are
resampled independently, as rliable does for the probability of improvement. Passing every
task as its own 1-D array lets tasks have different numbers of runs, which rliable's matrices
(runs x tasks) cannot hold.

rliable draws its indices from NumPy's global generator (``np.random.choice``; its
``random_state`` argument does not reach them), so :func:`interval` seeds that generator for
the duration of the call and restores its state afterwards: an interval is a function of the
scores and the seed alone. :func:`strata_seed` derives that seed from the scores themselves, so
that a report's intervals do not depend on which other intervals it computes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from hashlib import blake2b

import numpy as np
import numpy.typing as npt
from rliable import library

CONFIDENCE = 0.95
"""The coverage of every interval."""

Statistic = Callable[..., float | np.ndarray]
"""A function of the strata (1-D arrays, in the order given) returning a number or a 1-D array."""


@contextmanager
def _global_numpy_seed(seed: int) -> Iterator[None]:
    # the legacy global generator is the one rliable's resampling reads
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def interval(
    statistic: Statistic, strata: Sequence[npt.ArrayLike], reps: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``statistic`` of ``strata``, and its 95 % percentile interval from ``reps`` replications.

    Returns (point, low, high), each an array of the statistic's shape (``(1,)`` for a number).
    """
    columns = [np.asarray(s, dtype=np.float64).reshape(-1, 1) for s in strata]
    if not columns or any(len(c) == 0 for c in columns):
        raise ValueError("every stratum needs at least one score")

    def on_columns(*resampled: np.ndarray) -> np.ndarray:
        return np.atleast_1d(np.asarray(statistic(*(c[:, 0] for c in resampled)), float))

    with _global_numpy_seed(seed):
        points, intervals = library.get_interval_estimates(
            {"scores": columns},
            on_columns,
            reps=reps,
            confidence_interval_size=CONFIDENCE,
        )
    low, high = np.asarray(intervals["scores"], dtype=np.float64)
    return np.asarray(points["scores"], dtype=np.float64), low, high


def scalar_interval(
    statistic: Statistic, strata: Sequence[npt.ArrayLike], reps: int, seed: int
) -> tuple[float, float, float]:
    """:func:`interval` of a statistic that returns one number, as three floats."""
    point, low, high = interval(statistic, strata, reps, seed)
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
    return scalar_interval(lambda x, y: x.mean() - y.mean(), [a, b], reps, seed)
