"""The sweep's progress display: steps and runs counted over the grid, and an ETA from the rate
of learning steps, not of the warm-up's random ones (tacbench.sweep.progress)."""

from __future__ import annotations

import io

import pytest

from tacbench.sweep import progress
from tacbench.sweep.progress import SweepProgress

pytestmark = pytest.mark.unit

# two runs of 10,000 steps, the first 1,000 random (9,000 learning steps each)
BUDGETS = {"a": (10_000, 9_000), "b": (10_000, 9_000)}


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> Clock:
    fake = Clock()
    monkeypatch.setattr(progress.time, "monotonic", fake)
    return fake


def _display(steps: dict[str, int]) -> SweepProgress:
    return SweepProgress(BUDGETS, steps, set(), io.StringIO(), every_s=1e9)


def test_the_eta_waits_for_the_warm_up_then_times_the_learning_steps(clock: Clock) -> None:
    display = _display({"a": 0, "b": 0})
    assert display.line().endswith("ETA -")  # nothing trained yet
    clock.now += 2.0
    display.update({"a": 1_000, "b": 1_000}, set())  # the warm-ups, fast
    assert display.line().endswith("ETA - (warm-up)")
    clock.now += 10.0
    display.update({"a": 2_000, "b": 2_000}, set())  # 2,000 learning steps in 10 s
    # 16,000 learning steps left at 200/s; the rate of all steps (4,000 in 12 s) would say 48 s
    assert display.line() == "runs 0/2 | steps 4,000/20,000 | 333 steps/s | ETA 1m20s"


def test_a_resumed_sweep_times_its_learning_from_the_start(clock: Clock) -> None:
    display = _display({"a": 5_000, "b": 500})  # a resumes past its warm-up, b within it
    clock.now += 10.0
    display.update({"a": 6_000, "b": 1_000}, set())  # a's 1,000 learning steps, b's random ones
    assert display.line().endswith("ETA 2m10s")  # 13,000 left at 100/s


def test_a_run_given_up_counts_whole_but_leaves_nothing_to_time(clock: Clock) -> None:
    stream = io.StringIO()
    display = SweepProgress(BUDGETS, {"a": 0, "b": 0}, set(), stream, every_s=1e9)
    clock.now += 1.0
    display.update({"a": 1_000, "b": 1_000}, set())
    clock.now += 9.0
    display.update({"a": 4_000, "b": 1_000}, {"b"})  # b given up at its first update
    # a line when a run ends; 3,000 learning steps in 9 s, only a's 6,000 left; 5,000 steps
    # trained in 10 s (b's 9,000 steps credited when it was given up made it 1,400 steps/s)
    expected = "sweep: runs 1/2 | steps 14,000/20,000 | 500 steps/s | ETA 0m18s\n"
    assert stream.getvalue() == expected


def test_with_no_learning_steps_left_the_rate_of_all_steps_is_used(clock: Clock) -> None:
    display = SweepProgress({"r": (1_000, 0)}, {"r": 0}, set(), io.StringIO())
    clock.now += 2.0
    display.update({"r": 500}, set())
    assert display.line().endswith("250 steps/s | ETA 0m02s")
