"""What a "not distinguishable" verdict could have detected: the smallest difference a
permutation test at the verdict's level finds with 80 % power on samples of the runs' sizes,
drawn from normal distributions with the runs' pooled standard deviation, so that "not
distinguishable" reads as "no difference larger than X" (Colas et al. 2018, who take the
runs as normal too; docs/sequential.md). Drawing the samples from the observed runs instead,
with replacement, overstated the power: resamples of four or five runs spread less than fresh
runs, and at five runs a side the difference it called detectable was found in 71 % of fresh
normal samples, at four in 46 %.

:func:`detectable_difference` answers it for one task, in the task's return units;
:func:`detectable_shift` for several tasks at once, in standard deviations of each task's runs
(the tasks' returns are on different scales). Both are one computation,
:func:`_smallest_detectable`: a stratified permutation test of the mean over tasks of each
task's scaled difference of means, with a shift of the same size in every task's units. In
those units the answer depends only on the run counts (and the level, power and seed).
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
    sizes drawn from normal distributions with the runs' pooled standard deviation (the
    second shifted by the difference tried). Bisection over the difference with common
    random numbers; ``inf`` when the test cannot reach ``alpha`` at these sizes."""
    a, b = _two_groups(control, other)
    spread = _spread(a, b)
    shift = _smallest_detectable([(len(a), len(b))], alpha, power, resamples, permutations, seed)
    return shift * spread


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
    it; each task's samples drawn as :func:`detectable_difference` draws them."""
    if len(controls) != len(others) or not controls:
        raise TacbenchError("a detectable shift needs the same tasks, at least one, on each side.")
    pairs = [_two_groups(a, b) for a, b in zip(controls, others, strict=True)]
    sizes = [(len(a), len(b)) for a, b in pairs]
    return _smallest_detectable(sizes, alpha, power, resamples, permutations, seed)


def _two_groups(control: Samples, other: Samples) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(control, dtype=np.float64)
    b = np.asarray(other, dtype=np.float64)
    if len(a) < 2 or len(b) < 2:
        raise TacbenchError("a detectable difference needs at least two runs per method.")
    return a, b


def _spread(a: np.ndarray, b: np.ndarray) -> float:
    """The runs' standard deviation pooled within the two groups, on n + m - 2 degrees of
    freedom (1 where both are constant)."""
    residuals = np.concatenate([a - a.mean(), b - b.mean()])
    return float(np.sqrt((residuals**2).sum() / (len(residuals) - 2))) or 1.0


def _smallest_detectable(
    sizes: Sequence[tuple[int, int]],
    alpha: float,
    power: float,
    resamples: int,
    permutations: int,
    seed: int,
) -> float:
    """The smallest d such that the test rejects with probability ``power`` when each task's
    (``sizes[i]``: n control and m other runs) samples are standard normal and its other runs
    are shifted by ``d``; the statistic is the mean over tasks of each task's difference of
    means, its runs permuted within each task."""
    labellings = math.prod(math.comb(n + m, n) for n, m in sizes)
    if 2.0 / labellings > alpha:
        return math.inf  # no labelling of these sizes reaches the level
    rng = np.random.default_rng(seed)
    strata = []
    for n, m in sizes:
        samples = rng.standard_normal((resamples, n + m))
        order = np.argsort(rng.random((permutations, n + m)), axis=1)
        strata.append((n, samples, order))

    def power_at(d: float) -> float:
        observed = np.zeros(resamples)
        null = np.zeros((resamples, permutations))
        for n, samples, order in strata:
            both = samples.copy()
            both[:, n:] += d  # (resamples, pooled)
            observed += both[:, n:].mean(1) - both[:, :n].mean(1)
            shuffled = both[:, order]  # (resamples, permutations, pooled)
            null += shuffled[:, :, n:].mean(2) - shuffled[:, :, :n].mean(2)
        observed, null = np.abs(observed / len(strata)), np.abs(null / len(strata))
        p = (1 + (null >= observed[:, None]).sum(1)) / (permutations + 1)
        return float((p <= alpha).mean())

    low, high = 0.0, 1.0
    while power_at(high) < power:
        low, high = high, 2 * high
        if high > 1e3:
            return math.inf
    for _ in range(20):
        middle = (low + high) / 2
        low, high = (middle, high) if power_at(middle) < power else (low, middle)
    return high
