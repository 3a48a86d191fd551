"""What a "not distinguishable" verdict could have detected (tacbench.detectable)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tacbench.detectable import detectable_difference, detectable_shift
from tacbench.errors import TacbenchError
from tacbench.verdicts import improvement_verdict

pytestmark = pytest.mark.unit


def _pooled_sd(a: np.ndarray, b: np.ndarray) -> float:
    residuals = np.concatenate([a - a.mean(), b - b.mean()])
    return float(np.sqrt((residuals**2).sum() / (len(a) + len(b) - 2)))


@pytest.mark.parametrize("n", [5, 8])
def test_the_detectable_difference_has_the_power_it_states_on_fresh_runs(n: int) -> None:
    """Fresh normal runs with the observed runs' pooled standard deviation, the second shifted
    by the detectable difference: the verdict decides in about 80 % of them. Resampling the
    observed runs, with a test of the difference of means, named a difference the verdict found
    in 70 % of fresh runs at five a side."""
    rng = np.random.default_rng(3)
    control, other = rng.normal(0.0, 3.0, n), rng.normal(1.0, 3.0, n)
    delta = detectable_difference(control, other, power=0.8, seed=4)
    sd = _pooled_sd(control, other)
    check = np.random.default_rng(5)
    verdicts = [
        improvement_verdict([check.normal(delta, sd, n)], [check.normal(0.0, sd, n)], seed=0)[1]
        for _ in range(400)
    ]
    assert abs(verdicts.count("larger") / len(verdicts) - 0.8) < 0.06


def test_the_detectable_difference_is_a_multiple_of_the_pooled_sd_set_by_the_run_counts() -> None:
    """The rank test has a little less power than a t-test, whose 80 % lie at 2.02 SD (five
    runs a side) and 1.32 (ten)."""
    rng = np.random.default_rng(6)
    for n, low, high in ((5, 2.15, 2.45), (10, 1.33, 1.5)):
        control, other = rng.normal(0.0, 50.0, n), rng.normal(0.0, 80.0, n)
        ratio = detectable_difference(control, other) / _pooled_sd(control, other)
        assert low < ratio < high
    assert detectable_difference([0.0, 1.0], [0.5, 0.7]) == math.inf  # 2 vs 2: p >= 1/3


def test_one_task_s_shift_is_its_difference_in_standard_deviations() -> None:
    rng = np.random.default_rng(7)
    control, other = rng.normal(0.0, 300.0, 6), rng.normal(100.0, 500.0, 5)
    shift = detectable_shift([control], [other], seed=2)
    assert shift * _pooled_sd(control, other) == pytest.approx(
        detectable_difference(control, other, seed=2)
    )


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


def test_the_shift_is_pinned_where_the_level_is_reachable_exactly() -> None:
    """Five runs a side: 2.30 standard deviations (docs/report.md's "about 2.3"), with the
    bisection's precision and the default seed's samples. Tasks of (3, 3) and (2, 3) runs can
    reach p = 0.05 itself, which counts as a rejection (p <= the level), as in the verdict."""
    assert detectable_shift([np.arange(5.0)], [np.arange(5.0)]) == pytest.approx(2.2983, abs=1e-4)
    shift = detectable_shift([[0.0, 1, 2], [0.0, 1, 3]], [[0.0, 1, 2], [0.0, 1]])
    assert shift == pytest.approx(2.1260, abs=1e-4)


def test_constant_runs_have_no_detectable_difference_to_state() -> None:
    """Every run alike leaves no spread to scale by: the difference was stated in units of 1
    (2.3 return units at five runs a side, whatever the task's scale), and 0 would claim that
    any difference is detectable. It is NaN (the page's n/a); the shift, in SD, stays defined."""
    assert math.isnan(detectable_difference([5.0] * 5, [5.0] * 5))
    assert detectable_shift([[5.0] * 5], [[5.0] * 5]) == pytest.approx(2.2983, abs=1e-4)
