"""Calibrated prices (tacbench.sweep.calibration): the arithmetic, the keys, the store, the plan's
price, and one short real measurement."""

from __future__ import annotations

import dataclasses
import os
import signal
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from tacbench import hardware
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.members import make_run_configs
from tacbench.sweep import calibration, unit_timing
from tacbench.sweep.calibration import Calibration
from tests.helpers import smoke_tac_unit

pytestmark = pytest.mark.unit


@pytest.fixture(autouse=True)
def _own_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACBENCH_CALIBRATION", str(tmp_path / "calibration"))


def test_a_run_is_priced_by_phase_and_by_evaluation() -> None:
    c = Calibration(random=1e-4, learn=2e-3, eval_step=5e-5, measured="2026-12-03", members=1)
    # 10,000 random steps, 90,000 learning steps, 20 evaluations of 10 episodes of 1,000 steps
    whole = c.seconds(100_000, 10_000, 5_000, 10, 1_000, steps_left=100_000)
    assert whole == pytest.approx(10_000 * 1e-4 + 90_000 * 2e-3 + 20 * 10 * 1_000 * 5e-5)
    # resumed at step 60,000: no random steps, 8 evaluations left (65,000 ... 100,000)
    rest = c.seconds(100_000, 10_000, 5_000, 10, 1_000, steps_left=40_000)
    assert rest == pytest.approx(40_000 * 2e-3 + 8 * 10 * 1_000 * 5e-5)
    assert c.seconds(100_000, 10_000, 0, 10, 1_000, steps_left=0) == 0.0
    # learning would start after the end (--steps 400, 10,000 random steps): all 400 random
    assert c.seconds(400, 10_000, 0, 10, 1_000, steps_left=400) == pytest.approx(400 * 1e-4)


def test_an_evaluation_episode_is_priced_halfway_between_a_random_policys_and_the_limit() -> None:
    """Priced at the limit, a TAC grid of nine Hopper runs whose evaluation episodes averaged 135
    steps cost 1.15-1.75x its CPU time (docs/sweep.md)."""
    hopper = Calibration(1e-4, 2e-3, 5e-5, "2026-12-07", 1, random_episode=22.0)
    assert hopper.evaluation_episode(1_000) == 511.0
    rest = hopper.seconds(100_000, 10_000, 5_000, 10, 1_000, steps_left=40_000)
    assert rest == pytest.approx(40_000 * 2e-3 + 8 * 10 * 511 * 5e-5)
    longer = dataclasses.replace(hopper, random_episode=2_000.0)  # never more than the limit
    assert longer.evaluation_episode(1_000) == 1_000.0
    stored_before = dataclasses.replace(hopper, random_episode=None)
    assert stored_before.evaluation_episode(1_000) == 1_000.0


@pytest.mark.parametrize(("env", "episode"), [("Hopper-v4", (10, 40)), ("HalfCheetah-v4", 1_000)])
def test_random_steps_give_a_tasks_step_and_a_random_policys_episode(
    env: str, episode: Any
) -> None:
    steps = unit_timing.random_steps(env, 400)  # HalfCheetah: no episode ends, so its limit
    assert 0 < steps.seconds < 0.01
    if isinstance(episode, tuple):
        assert episode[0] < steps.episode < episode[1]
    else:
        assert steps.episode == episode


def test_the_key_ignores_the_members_identity_and_budget_but_not_their_networks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(hardware, "cpp_compiler", lambda: "g++")
    five, _ = make_run_configs("Hopper-v4", "Hopper", [0, 10, 20, 30, 40], qs=[1.0, 2.0])
    other, _ = make_run_configs("Hopper-v4", "Hopper", [1, 2], qs=[1.5], total_steps=500_000)
    assert calibration.unit_key(five[:2]) == calibration.unit_key(other)
    assert "K=10" in calibration.unit_key(five)  # at most one chunk is measured
    wide, _ = make_run_configs("Hopper-v4", "Hopper", [1, 2], hidden_sizes=(400, 300))
    assert calibration.unit_key(wide) != calibration.unit_key(other)
    short, _ = make_run_configs("Hopper-v4", "Hopper", [1, 2], qs=[1.5], total_steps=20_000)
    assert calibration.unit_key(short) != calibration.unit_key(other)  # auto: eager, not compiled


def test_calibrations_are_stored_per_cpu_class_and_merged() -> None:
    a = Calibration(1e-4, 1e-3, 1e-4, "2026-12-03", 1)
    b = Calibration(2e-4, 2e-3, 2e-4, "2026-12-03", 2)
    calibration.save({"a": a})
    path = calibration.save({"b": b})
    assert path.name.endswith(".json") and path.parent.name == "calibration"
    assert calibration.load() == {"a": a, "b": b}
    assert calibration.load("another-class") == {}


@pytest.mark.parametrize("damaged", ['{"units": []}', '{"units": {"a": {"random": 1}}}', "{not"])
def test_a_damaged_store_is_a_clear_error_not_a_traceback(damaged: str) -> None:
    """A store of another shape raised AttributeError or TypeError in every sweep, dry run and
    study bills; invalid JSON was met with a run folder's advice (--force)."""
    path = calibration.store_path()
    path.parent.mkdir(parents=True)
    path.write_text(damaged)
    with pytest.raises(TacbenchError, match=r"is not a readable calibration store; delete it"):
        calibration.load()


def test_an_unwritable_store_is_refused_before_anything_is_measured(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With TACBENCH_CALIBRATION naming a file, --calibrate measured every unit and then lost
    them to a FileExistsError."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("TACBENCH_CALIBRATION", str(blocker))
    measured: list[Any] = []
    monkeypatch.setattr(calibration, "measure", measured.append)
    configs, _ = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(16,))
    with pytest.raises(TacbenchError, match="TACBENCH_CALIBRATION"):
        calibration.calibrate([configs], report=lambda line: None)
    assert measured == []


def test_the_dry_run_uses_the_calibration_of_every_unit_and_says_so(tmp_path: Path) -> None:
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--dry-run", "--out", str(tmp_path)]
    before = CliRunner().invoke(cli, args)
    assert before.exit_code == 0, before.output
    assert "default*" in before.output and "--dry-run --calibrate" in before.output
    configs = smoke_tac_unit()
    key = calibration.unit_key(configs[:2])
    calibration.save({key: Calibration(1e-4, 2e-3, 5e-5, "2026-12-03", 2)})
    after = CliRunner().invoke(cli, args)
    assert after.exit_code == 0, after.output
    row = next(line for line in after.output.splitlines() if line.startswith("tac "))
    assert (
        row.endswith("calibrated**") and "** calibrated: measured on this CPU class" in after.output
    )
    # per run: 500 random steps, 500 learning steps, 2 evaluations of 2 full-length episodes
    per_run = 500 * 1e-4 + 500 * 2e-3 + 2 * 2 * 1_000 * 5e-5
    assert f"{per_run / 1_000 * 1e3:.2f}" in row


@pytest.mark.parametrize("flag", ["--calibrate", "--recalibrate"])
def test_calibrate_needs_a_dry_run(tmp_path: Path, flag: str) -> None:
    result = CliRunner().invoke(cli, ["sweep", "--preset", "smoke", flag, "--out", str(tmp_path)])
    assert result.exit_code == 2 and f"{flag} prices a plan: give it with --dry-run" in (
        result.output
    )


def test_recalibrate_measures_every_unit_again_and_replaces_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A calibration of 6 December priced TRPO on HalfCheetah 1.4x short on 7 December on a
    machine of the same class: --calibrate measured nothing (the unit was known), and only
    deleting the store would measure it again. Each kind of unit is measured once."""
    measured: list[int] = []

    def measure(configs: Any) -> Calibration:
        measured.append(len(configs))
        return Calibration(2e-4, 3e-3, 6e-5, "2026-12-07", len(configs))

    monkeypatch.setattr(calibration, "measure", measure)
    configs = smoke_tac_unit()[:2]
    key = calibration.unit_key(configs)
    calibration.save({key: Calibration(1e-4, 2e-3, 5e-5, "2026-12-06", 2)})
    assert calibration.calibrate([configs], report=lambda line: None)[key].learn == 2e-3
    assert measured == []
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--dry-run", "--out", str(tmp_path)]
    result = CliRunner().invoke(cli, [*args, "--recalibrate"])
    assert result.exit_code == 0, result.output
    assert measured == [2] * calibration.ROUNDS and calibration.load()[key].learn == 3e-3
    assert "calibrating 1/1, round 3/3: tac Hopper-v4, 2 member(s)" in result.output


def test_a_unit_that_cannot_be_measured_again_keeps_its_calibration_and_says_so(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def fails(configs: Any) -> Calibration:
        raise TacbenchError("every member failed before the timed window")

    monkeypatch.setattr(calibration, "measure", fails)
    configs = smoke_tac_unit()[:2]
    key = calibration.unit_key(configs)
    calibration.save({key: Calibration(1e-4, 2e-3, 5e-5, "2026-12-06", 2)})
    lines: list[str] = []
    assert calibration.calibrate([configs], lines.append, again=True)[key].learn == 2e-3
    assert calibration.load()[key].measured == "2026-12-06"
    assert lines[-1].endswith(
        "failed before the timed window; the calibration of 2026-12-06 is kept"
    )


def test_a_short_measurement_times_random_and_learning_steps(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(unit_timing, "RANDOM_STEPS", 100)
    monkeypatch.setattr(unit_timing, "WARMUP_STEPS", 5)
    monkeypatch.setattr(unit_timing, "LEARN_STEPS", 100)
    configs, _ = make_run_configs("Pendulum-v1", None, [0, 10], hidden_sizes=(32,))
    measured = unit_timing.measure(configs)
    assert measured.members == 2
    assert 0 < measured.random < measured.learn  # an update costs more than a random step
    assert measured.eval_step > 0
    assert measured.random_episode == 200  # Pendulum's episodes run to their limit
    stored = calibration.calibrate([configs], report=lambda line: None)
    assert list(stored) == [calibration.unit_key(configs)]


def _fail_at_first_update(monkeypatch: pytest.MonkeyPatch, hidden: tuple[int, ...], k: int) -> None:
    """Members ``0 .. k-1`` of the units with ``hidden`` layers get non-finite losses at their
    first update (as the authors' 2019-01-11b version at q = 3 does), so the loop retires them
    with no row in losses.csv."""
    from tacbench.tac import update as tac_update
    from tacbench.training import loop

    def failing(agent: Any, sample: Any, c: Any, subset: Any) -> Any:
        metrics = tac_update.update(agent, sample, c, subset)
        if agent.config.hidden_sizes == hidden:
            metrics[:k] = float("nan")
        return metrics

    monkeypatch.setattr(loop, "update", failing)
    monkeypatch.setattr(unit_timing, "RANDOM_STEPS", 100)
    monkeypatch.setattr(unit_timing, "WARMUP_STEPS", 5)
    monkeypatch.setattr(unit_timing, "LEARN_STEPS", 100)


def test_a_member_that_fails_at_its_first_update_leaves_the_others_measured(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _fail_at_first_update(monkeypatch, (32,), k=1)
    configs, _ = make_run_configs("Pendulum-v1", None, [0, 10], hidden_sizes=(32,))
    measured = unit_timing.measure(configs)
    assert 0 < measured.random < measured.learn


def test_a_unit_whose_members_all_fail_is_reported_and_the_others_stored(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _fail_at_first_update(monkeypatch, (32,), k=2)
    failing, _ = make_run_configs("Pendulum-v1", None, [0, 10], hidden_sizes=(32,))
    other, _ = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(16,))
    lines: list[str] = []
    stored = calibration.calibrate([failing, other], report=lines.append)
    assert list(stored) == [calibration.unit_key(other)]
    assert calibration.load() == stored
    assert any("not calibrated" in line and "members failed" in line for line in lines)


def test_a_stop_signal_stops_the_calibration_and_keeps_the_units_measured_before(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A SIGTERM (or Ctrl-C) stops a measurement's training cleanly: the calibration then called
    the unit not measurable ("members failed") and went on to the next unit, so a stop signal
    never stopped it. It now stops, keeps the units measured before, and the command exits with
    the signal's status."""
    from tacbench.tac import update as tac_update
    from tacbench.training import loop

    def signalled(agent: Any, sample: Any, c: Any, subset: Any) -> Any:
        if agent.config.hidden_sizes == (16,):
            os.kill(os.getpid(), signal.SIGTERM)
        return tac_update.update(agent, sample, c, subset)

    monkeypatch.setattr(loop, "update", signalled)
    monkeypatch.setattr(unit_timing, "RANDOM_STEPS", 100)
    monkeypatch.setattr(unit_timing, "WARMUP_STEPS", 5)
    monkeypatch.setattr(unit_timing, "LEARN_STEPS", 100)
    first, stopped, never = (
        make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(h,))[0] for h in (32, 16, 8)
    )
    lines: list[str] = []
    with pytest.raises(unit_timing.Interrupted):
        calibration.calibrate([first, stopped, never], report=lines.append)
    assert list(calibration.load()) == [calibration.unit_key(first)]
    assert lines[-1].startswith("  calibration interrupted; the units measured before it are")
    assert not any("3/3" in line for line in lines)

    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--hidden-sizes", "16"]
    result = CliRunner().invoke(cli, [*args, "--dry-run", "--calibrate", "--out", str(tmp_path)])
    assert result.exit_code == 143, result.output
    assert "calibration interrupted; nothing was stored" in result.output
    assert result.output.rstrip().endswith("interrupted by SIGTERM")


class _Clock:
    """A CPU clock for the measurement: 0.01 s each time it is read (once per step) and 1 s per
    member-update."""

    def __init__(self) -> None:
        self.now = 0.0

    def process_time(self) -> float:
        self.now += 0.01
        return self.now


@pytest.mark.parametrize("schedule", ["step", "episode"])
def test_a_learning_step_is_priced_with_one_update_in_either_schedule(
    schedule: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    from tacbench.tac import update as tac_update
    from tacbench.training import loop

    clock = _Clock()
    monkeypatch.setattr(unit_timing, "time", clock)
    monkeypatch.setattr(unit_timing, "random_steps", lambda env: unit_timing.RandomSteps(0, 1))

    def counted(agent: Any, sample: Any, c: Any, subset: list[int] | None) -> Any:
        clock.now += float(sum(subset) if subset is not None else agent.alive.numel())
        return tac_update.update(agent, sample, c, subset)

    monkeypatch.setattr(loop, "update", counted)
    monkeypatch.setattr(unit_timing, "RANDOM_STEPS", 100)
    monkeypatch.setattr(unit_timing, "WARMUP_STEPS", 5)
    monkeypatch.setattr(unit_timing, "LEARN_STEPS", 100)
    configs, _ = make_run_configs(
        "Pendulum-v1", None, [0, 10], hidden_sizes=(32,), update_schedule=schedule
    )
    measured = unit_timing.measure(configs)
    # the episode schedule updates in bursts of 200 at Pendulum's episode ends, the step
    # schedule once a step: either way a learning step is a step and one update
    assert measured.random == pytest.approx(0.01 / 2)
    assert measured.learn == pytest.approx(0.01 / 2 + 1.0)


def test_updates_during_warm_up_are_priced_from_the_first_episode_end() -> None:
    (paper,), _ = make_run_configs("HalfCheetah-v4", "HalfCheetah", [0])
    (authors,), _ = make_run_configs("HalfCheetah-v4", "HalfCheetah", [0], profile="reference")
    assert paper.warmup_updates == "off" and authors.warmup_updates == "on"
    assert calibration.run_pricing(paper)[0] == paper.learning_starts == 10_000
    assert calibration.run_pricing(authors)[0] == 1_000  # HalfCheetah's episodes: 1,000 steps
    early = dataclasses.replace(authors, learning_starts=300)  # still the first episode's end
    assert calibration.run_pricing(early)[0] == 1_000


def test_each_unit_is_measured_in_rounds_in_turn_and_its_median_stored(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """One host of a class measured a TRPO unit at 0.97-1.54 ms a step in six calibrations in a
    row (docs/notes/performance-history.md): one measurement is a sample of a speed that moves."""
    a = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(32,))[0]
    b = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(16,))[0]
    learn = {(32,): iter([3e-3, 2e-3, 1e-3]), (16,): iter([5e-3, 4e-3, 9e-3])}
    order: list[tuple[int, ...]] = []

    def measure(configs: Any) -> Calibration:
        hidden = configs[0].hidden_sizes
        order.append(hidden)
        value = next(learn[hidden])
        return Calibration(value / 10, value, value / 40, "2026-12-07", 1)

    monkeypatch.setattr(calibration, "measure", measure)
    lines: list[str] = []
    stored = calibration.calibrate([a, b], lines.append, rounds=3)
    assert order == [(32,), (16,)] * 3  # in turn, so that a unit's rounds lie minutes apart
    median = Calibration(2e-4, 2e-3, 5e-5, "2026-12-07", 1, rounds=3)  # each time's median
    assert stored[calibration.unit_key(a)] == pytest.approx(median)
    assert calibration.load()[calibration.unit_key(b)].learn == 5e-3
    assert "calibrating 2/2, round 3/3: tac Pendulum-v1, 1 member(s) ..." in lines
    assert (
        "tac Pendulum-v1: 1.00, 2.00, 3.00 ms per member-step learning in 3 rounds "
        "(3.00x apart); stored the median, 2.00" in lines
    )


def test_a_unit_that_fails_is_measured_no_more_and_keeps_its_rounds_before(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    a = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(32,))[0]
    b = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(16,))[0]
    calls = {(32,): 0, (16,): 0}

    def measure(configs: Any) -> Calibration:
        hidden = configs[0].hidden_sizes
        calls[hidden] += 1
        if hidden == (16,) or calls[hidden] == 2:  # b at once, a in its second round
            raise TacbenchError("every member failed before the timed window")
        return Calibration(1e-4, 2e-3, 5e-5, "2026-12-07", 1)

    monkeypatch.setattr(calibration, "measure", measure)
    lines: list[str] = []
    stored = calibration.calibrate([a, b], lines.append, rounds=3)
    assert calls == {(32,): 2, (16,): 1}
    assert list(stored) == [calibration.unit_key(a)] and stored[calibration.unit_key(a)].rounds == 1
    assert "  not measured again: every member failed before the timed window; the rounds " in (
        "\n".join(lines)
    )


def test_a_stop_signal_in_a_later_round_stores_the_rounds_measured(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    a = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(32,))[0]
    b = make_run_configs("Pendulum-v1", None, [0], hidden_sizes=(16,))[0]
    learn = iter([1e-3, 5e-3, 3e-3])  # a, b, a: then b is stopped

    def measure(configs: Any) -> Calibration:
        value = next(learn, None)
        if value is None:
            raise unit_timing.Interrupted
        return Calibration(1e-4, value, 5e-5, "2026-12-07", 1)

    monkeypatch.setattr(calibration, "measure", measure)
    with pytest.raises(unit_timing.Interrupted):
        calibration.calibrate([a, b], report=lambda line: None, rounds=3)
    stored = calibration.load()
    assert stored[calibration.unit_key(a)].learn == pytest.approx(2e-3)
    assert stored[calibration.unit_key(a)].rounds == 2
    assert stored[calibration.unit_key(b)].learn == 5e-3
