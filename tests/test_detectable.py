"""What a "not distinguishable" verdict could have detected (tacbench.detectable)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tacbench.detectable import detectable_difference, detectable_shift
from tacbench.errors import TacbenchError

pytestmark = pytest.mark.unit


def test_the_detectable_difference_has_the_power_it_states() -> None:
    rng = np.random.default_rng(3)
    control, other = rng.normal(0.0, 1.0, 8), rng.normal(0.0, 1.0, 8)
    delta = detectable_difference(control, other, alpha=0.05, power=0.8, seed=4)
    assert 0.5 < delta < 4.0
    # fresh samples from the resampled runs, shifted by delta: about 80 % rejected
    check = np.random.default_rng(5)
    rejected, repeats, labellings = 0, 200, 200
    for _ in range(repeats):
        a = check.choice(control, 8)
        b = check.choice(other - other.mean() + control.mean(), 8) + delta
        both = np.concatenate([a, b])
        observed = abs(b.mean() - a.mean())
        null = [abs(np.diff([g.mean() for g in np.split(check.permutation(both), 2)])[0])]
        null += [
            abs(np.diff([g.mean() for g in np.split(check.permutation(both), 2)])[0])
            for _ in range(labellings - 1)
        ]
        rejected += (1 + sum(n >= observed for n in null)) / (labellings + 1) <= 0.05
    assert abs(rejected / repeats - 0.8) < 0.1
    assert detectable_difference([0.0, 1.0], [0.5, 0.7]) == math.inf  # 2 vs 2: p >= 1/3


def test_one_task_s_shift_is_its_difference_in_standard_deviations() -> None:
    rng = np.random.default_rng(7)
    control, other = rng.normal(0.0, 300.0, 6), rng.normal(100.0, 500.0, 5)
    spread = np.std(np.concatenate([control - control.mean(), other - other.mean()]), ddof=1)
    shift = detectable_shift([control], [other], seed=2)
    assert shift * spread == pytest.approx(detectable_difference(control, other, seed=2))


def test_more_tasks_detect_a_smaller_common_shift() -> None:
    rng = np.random.default_rng(8)
    controls = [rng.normal(0.0, scale, 5) for scale in (1.0, 100.0, 1e4, 10.0)]
    others = [rng.normal(0.0, scale, 5) for scale in (1.0, 100.0, 1e4, 10.0)]
    alone = [detectable_shift([c], [o]) for c, o in zip(controls, others, strict=True)]
    together = detectable_shift(controls, others)
    assert together < min(alone)  # four tasks' runs say more than any one task's
    rescaled = detectable_shift([c * 1e3 for c in controls], [o * 1e3 for o in others])
    assert rescaled == pytest.approx(together)  # in each task's own units: scale-free


def test_a_shift_needs_the_same_tasks_and_two_runs_a_side() -> None:
    with pytest.raises(TacbenchError, match="same tasks"):
        detectable_shift([[0.0, 1.0]], [])
    with pytest.raises(TacbenchError, match="at least two runs"):
        detectable_shift([[0.0, 1.0], [1.0]], [[0.0, 1.0], [2.0, 3.0]])
    assert detectable_shift([[0.0, 1.0]], [[0.5, 0.7]]) == math.inf  # 2 vs 2: p >= 1/3
