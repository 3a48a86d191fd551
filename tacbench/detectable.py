"""What a "not distinguishable" verdict could have detected: the smallest difference a
permutation test at the verdict's level finds with 80 % power on samples of the runs' sizes,
estimated by resampling the observed runs, so that "not distinguishable" reads as "no
difference larger than X" (Colas et al. 2018; docs/sequential.md).

:func:`detectable_difference` answers it for one task, in the task's return units;
:func:`detectable_shift` for several tasks at once, in standard deviations of each task's runs
(the tasks' returns are on different scales). Both are one computation,
:func:`_smallest_detectable`: a stratified permutation test of the mean over tasks of each
task's scaled difference of means, with a shift of the same size in every task's units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tacbench.errors import TacbenchError

DEFAULT_ALPHA = 0.05  # the usual 5% level, as the report's verdicts
Samples = Sequence[float] | np.ndarray


def detectable_difference(
    control: Samples,
    other: Samples,
    alpha: float = DEFAULT_ALPHA,
    power: float = 0.8,
    resamples: int = 400,
    permutations: int = 400,
    seed: int = 0,
) -> float:
    """The smallest difference of means that a two-sided permutation test of the mean
    difference, at level ``alpha``, finds with probability ``power`` on samples of these
    sizes, estimated by resampling the observed runs: each resample draws both groups with
    replacement from the runs (``other`` centred on ``control``'s mean, then shifted by the
    difference tried), so their spread is the observed one. Bisection over the difference with
    common random numbers; an upper bound when the test cannot reach ``alpha`` at these sizes
    (then ``inf``)."""
    a, b = _two_groups(control, other)
    return _smallest_detectable(
        [a], [b], [1.0], _spread(a, b), alpha, power, resamples, permutations, seed
    )


def detectable_shift(
    controls: Sequence[Samples],
    others: Sequence[Samples],
    alpha: float = DEFAULT_ALPHA,
    power: float = 0.8,
    resamples: int = 400,
    permutations: int = 400,
    seed: int = 0,
) -> float:
    """Over several tasks (``controls[i]`` against ``others[i]`` on task i): the smallest shift,
    in standard deviations of each task's runs (pooled within the two groups), that a
    stratified two-sided permutation test of the tasks' mean scaled difference of means, at
    level ``alpha``, finds with probability ``power`` when every task's ``other`` is shifted by
    it; resampled as :func:`detectable_difference` does, task by task."""
    if len(controls) != len(others) or not controls:
        raise TacbenchError("a detectable shift needs the same tasks, at least one, on each side.")
    pairs = [_two_groups(a, b) for a, b in zip(controls, others, strict=True)]
    scales = [_spread(a, b) for a, b in pairs]
    return _smallest_detectable(
        [a for a, _ in pairs],
        [b for _, b in pairs],
        scales,
        1.0,
        alpha,
        power,
        resamples,
        permutations,
        seed,
    )


def _two_groups(control: Samples, other: Samples) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(control, dtype=np.float64)
    b = np.asarray(other, dtype=np.float64)
    if len(a) < 2 or len(b) < 2:
        raise TacbenchError("a detectable difference needs at least two runs per method.")
    return a, b


def _spread(a: np.ndarray, b: np.ndarray) -> float:
    """The runs' standard deviation pooled within the two groups (1 where both are constant)."""
    return float(np.std(np.concatenate([a - a.mean(), b - b.mean()]), ddof=1)) or 1.0


def _smallest_detectable(
    controls: Sequence[np.ndarray],
    others: Sequence[np.ndarray],
    scales: Sequence[float],
    first_guess: float,
    alpha: float,
    power: float,
    resamples: int,
    permutations: int,
    seed: int,
) -> float:
    """The smallest d such that the test rejects with probability ``power`` when task i's
    ``other`` is shifted by ``d * scales[i]``; the statistic is the mean over tasks of each
    task's difference of means divided by ``scales[i]``, permuted within each task."""
    labellings = math.prod(
        math.comb(len(a) + len(b), len(a)) for a, b in zip(controls, others, strict=True)
    )
    if 2.0 / labellings > alpha:
        return math.inf  # no labelling of these sizes reaches the level
    rng = np.random.default_rng(seed)
    strata = []
    for a, b in zip(controls, others, strict=True):
        draws_a = a[rng.integers(0, len(a), (resamples, len(a)))]
        draws_b = (b - b.mean() + a.mean())[rng.integers(0, len(b), (resamples, len(b)))]
        order = np.argsort(rng.random((permutations, len(a) + len(b))), axis=1)
        strata.append((draws_a, draws_b, order))

    def power_at(d: float) -> float:
        observed = np.zeros(resamples)
        null = np.zeros((resamples, permutations))
        for (draws_a, draws_b, order), scale in zip(strata, scales, strict=True):
            n = draws_a.shape[1]
            both = np.concatenate([draws_a, draws_b + d * scale], axis=1)  # (resamples, pooled)
            observed += (both[:, n:].mean(1) - both[:, :n].mean(1)) / scale
            shuffled = both[:, order]  # (resamples, permutations, pooled)
            null += (shuffled[:, :, n:].mean(2) - shuffled[:, :, :n].mean(2)) / scale
        observed, null = np.abs(observed / len(strata)), np.abs(null / len(strata))
        p = (1 + (null >= observed[:, None]).sum(1)) / (permutations + 1)
        return float((p <= alpha).mean())

    low, high = 0.0, first_guess
    while power_at(high) < power:
        low, high = high, 2 * high
        if high > 1e3 * first_guess:
            return math.inf
    for _ in range(20):
        middle = (low + high) / 2
        low, high = (middle, high) if power_at(middle) < power else (low, middle)
    return high
