"""What a "not distinguishable" verdict could have detected: the smallest difference that the
verdict's own test (:mod:`tacbench.verdicts`, the permutation test of P(X > Y) at its level)
finds with 80 % power on samples of the runs' sizes, drawn from normal distributions with the
runs' pooled standard deviation, so that "not distinguishable" reads as "no difference larger
than X" (Colas et al. 2018, who take the runs as normal too; docs/sequential.md). Drawing the
samples from the observed runs instead, with replacement, overstated the power: resamples of
four or five runs spread less than fresh runs, and at five runs a side the difference it
called detectable was found in 71 % of fresh normal samples, at four in 46 %; so did taking a
test of the difference of means, which has more power than the rank test that decides.

:func:`detectable_difference` answers it for one task, in the task's return units;
:func:`detectable_shift` for several tasks at once, in standard deviations of each task's runs
(the tasks' returns are on different scales): every task's other runs shifted by the same
number of its standard deviations, the statistic P(X > Y) averaged over the tasks, the runs
permuted within each task. Both are one computation, :func:`_smallest_detectable`; in those
units the answer depends only on the run counts (and the level, power and seed).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tacbench.errors import TacbenchError
from tacbench.verdicts import LEVEL, labellings, null_improvements, p_values

Samples = Sequence[float] | np.ndarray


def detectable_difference(
    control: Samples,
    other: Samples,
    alpha: float = LEVEL,
    power: float = 0.8,
    samples: int = 1000,
    seed: int = 0,
) -> float:
    """The smallest difference of means that the verdict's two-sided test, at level ``alpha``,
    finds with probability ``power`` on ``samples`` samples of these sizes drawn from normal
    distributions with the runs' pooled standard deviation (``other``'s shifted by the
    difference tried). Bisection over the difference with common random numbers; ``inf`` when
    the test cannot reach ``alpha`` at these sizes, NaN when each side's runs are all equal
    (no spread to scale by)."""
    a, b = _two_groups(control, other)
    return _smallest_detectable([(len(a), len(b))], alpha, power, samples, seed) * _spread(a, b)


def detectable_shift(
    controls: Sequence[Samples],
    others: Sequence[Samples],
    alpha: float = LEVEL,
    power: float = 0.8,
    samples: int = 1000,
    seed: int = 0,
) -> float:
    """Over several tasks (``controls[i]`` against ``others[i]`` on task i): the smallest shift,
    in standard deviations of each task's runs (pooled within the two groups), that the
    verdict's test over the tasks, at level ``alpha``, finds with probability ``power`` when
    every task's ``other`` is shifted by it; each task's samples drawn as
    :func:`detectable_difference` draws them."""
    if len(controls) != len(others) or not controls:
        raise TacbenchError("a detectable shift needs the same tasks, at least one, on each side.")
    pairs = [_two_groups(a, b) for a, b in zip(controls, others, strict=True)]
    sizes = [(len(a), len(b)) for a, b in pairs]
    return _smallest_detectable(sizes, alpha, power, samples, seed)


def _two_groups(control: Samples, other: Samples) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(control, dtype=np.float64)
    b = np.asarray(other, dtype=np.float64)
    if len(a) < 2 or len(b) < 2:
        raise TacbenchError("a detectable difference needs at least two runs per method.")
    return a, b


def _spread(a: np.ndarray, b: np.ndarray) -> float:
    """The runs' standard deviation pooled within the two groups, on n + m - 2 degrees of
    freedom; NaN where both are constant (it was 1, in the returns' units: an arbitrary size)."""
    residuals = np.concatenate([a - a.mean(), b - b.mean()])
    return float(np.sqrt((residuals**2).sum() / (len(residuals) - 2))) or math.nan


def _smallest_detectable(
    sizes: Sequence[tuple[int, int]], alpha: float, power: float, samples: int, seed: int
) -> float:
    """The smallest d such that the verdict's test rejects with probability ``power`` when
    each task's (``sizes[i]``: n control and m other runs) samples are standard normal and its
    other runs are shifted by ``d``."""
    if 2.0 / labellings(sizes) > alpha:
        return math.inf  # no labelling of these sizes reaches the level
    # untied runs rank 1, ..., n + m whatever their values: one null serves every sample
    others = [np.arange(m, dtype=np.float64) for _, m in sizes]
    controls = [np.arange(m, m + n, dtype=np.float64) for n, m in sizes]
    _, null, exact = null_improvements(others, controls, seed)
    rng = np.random.default_rng(seed)
    draws = [(n, rng.standard_normal((samples, n + m))) for n, m in sizes]

    def power_at(d: float) -> float:
        observed = np.zeros(samples)
        for n, drawn in draws:  # P(other > control) of each sample, on its task
            control, other = drawn[:, :n], drawn[:, n:] + d
            observed += (other[:, :, None] > control[:, None, :]).mean(axis=(1, 2))
        return float((p_values(observed / len(draws), null, exact) <= alpha).mean())

    low, high = 0.0, 1.0
    while power_at(high) < power:
        low, high = high, 2 * high
        if high > 1e3:
            return math.inf
    for _ in range(20):
        middle = (low + high) / 2
        low, high = (middle, high) if power_at(middle) < power else (low, middle)
    return high
