"""``tacbench sweep`` end to end with the local executor on tiny grids: members, idempotence,
kill -9 of a worker and of the whole sweep, Ctrl-C, a failing run among complete ones, and a
damaged member of a unit among healthy ones, a damaged calibration store."""

from __future__ import annotations

import io
import itertools
import json
import os
import signal
from pathlib import Path
from types import MappingProxyType

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench import hardware, training
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.sweep import calibration, driver, dry_run, plan
from tacbench.sweep.presets import Entry, Preset
from tests.helpers import (
    last_logged_step,
    past_checkpoint,
    run_cli,
    run_status,
    start_cli,
    wait_for,
)

pytestmark = pytest.mark.smoke

TAC_RUN = Path("runs/tac/Hopper-v4/q1-a0.2-ls500-bs32/seed0")


def _sweep_args(out: Path, *extra: str) -> list[str]:
    return ["sweep", "--preset", "smoke", "--out", str(out), *extra]


def _assert_complete_rows(run: Path, steps: int) -> None:
    """Every row the smoke config writes (learning from 500, evaluations every 500, losses
    every 250, and both at the end), each exactly once, as an uninterrupted run writes them."""
    evals = pd.read_csv(run / "eval.csv")["step"].tolist()
    assert evals == sorted({*range(500, steps + 1, 500), steps})
    losses = pd.read_csv(run / "losses.csv")
    expected = sorted({*range(500, steps + 1, 250), steps})
    assert losses["step"].tolist() == expected
    assert losses["updates"].tolist() == [1] + [b - a for a, b in itertools.pairwise(expected)]
    train_steps = pd.read_csv(run / "train.csv")["step"]
    assert train_steps.is_monotonic_increasing and train_steps.is_unique
    assert run_status(run)["state"] == "complete" and run_status(run)["step"] == steps


def test_local_sweep_with_members_then_rerun_skips_everything(tmp_path: Path) -> None:
    args = _sweep_args(tmp_path, "--algo", "tac", "--algo", "ppo")
    args += ["--steps", "600", "--workers", "1"]  # one worker: the four TAC runs in one unit
    runner = CliRunner()
    first = runner.invoke(cli, args)
    assert first.exit_code == 0, first.output
    assert "6 runs: 6 complete, 0 failed (0 given up), 0 partial, 0 not started" in first.output
    tac = sorted((tmp_path / "runs" / "tac" / "Hopper-v4").glob("*/seed*"))
    ppo = sorted((tmp_path / "runs" / "ppo" / "Hopper-v4").glob("*/seed*"))
    assert [p.parent.name for p in tac] == ["q1-a0.2-ls500-bs32"] * 2 + ["q2-a0.2-ls500-bs32"] * 2
    assert len(ppo) == 2
    every = [{"q": q, "alpha": 0.2, "seed": seed} for q in (1.0, 2.0) for seed in (0, 10)]
    for run in tac:  # the task's four TAC runs (two q, two seeds) as members of one unit
        assert json.loads((run / "config.json").read_text())["members"] == every
        _assert_complete_rows(run, 600)
    for run in ppo:
        assert pd.read_csv(run / "eval.csv")["step"].tolist() == [500, 600]
        assert run_status(run)["state"] == "complete"
    summary = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    assert summary["counts"]["complete"] == 6 and summary["unfinished"] == []
    assert summary["interrupted"] is False
    bill = summary["bill"]  # what it took beside what the dry run's pricing said at the start
    assert bill["cpu_class"] == hardware.cpu_class() and bill["workers"] == 1
    assert bill["wall_s"] > 0 and bill["priced_wall_s"] > 0 and bill["priced_core_hours"] > 0
    assert bill["cores"] == os.cpu_count() and bill["load_average"] >= 0  # this machine's load
    assert "the price" in first.output and "priced at the start" in first.output
    assert len(list((tmp_path / "sweep" / "logs").glob("*.log"))) == 3  # the TAC unit + 2 PPO

    before = {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/**/*") if p.is_file()}
    again = runner.invoke(cli, args)
    assert again.exit_code == 0, again.output
    assert "6 runs: 6 complete" in again.output
    assert "priced at the start" not in again.output  # nothing to train, nothing to bill
    assert before == {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/**/*") if p.is_file()}
    # the first sweep's bill stays (a rerun replaced it with a bill of nothing: wall_s 0)
    assert "this sweep trained nothing; its bill is what the runs took" in again.output
    assert "wrote " not in again.output  # said it wrote the summary it kept
    assert json.loads((tmp_path / "sweep" / "summary.json").read_text()) == summary
    dry = runner.invoke(cli, [*args, "--dry-run"])
    assert "6 runs: 6 complete, 0 partial, 0 failed" in dry.output
    assert "0 units to train" in dry.output and "measured: 4 runs under" in dry.output


def test_kill_9_of_a_worker_then_of_the_sweep_and_the_same_command_completes(
    tmp_path: Path,
) -> None:
    args = _sweep_args(tmp_path, "--algo", "tac", "--q", "1", "--seed", "0", "--steps", "2000")
    args += ["--checkpoint-every", "500", "--workers", "1"]
    run = tmp_path / TAC_RUN
    log = tmp_path / "sweep" / "logs" / "tac__Hopper-v4__q1-a0.2-ls500-bs32__seed0.log"
    proc = start_cli(args, session=True)
    try:
        # 1. SIGKILL the worker after its first checkpoint: the sweep records it and resumes
        wait_for(past_checkpoint(run, 500), timeout=90, proc=proc, what="the first checkpoint")
        worker_pid = int(log.read_text().split(" pid ")[1].split(":")[0])
        os.kill(worker_pid, signal.SIGKILL)
        # 2. SIGKILL the sweep and its worker after the resumed run's next checkpoint
        wait_for(lambda: log.read_text().count("=== ") == 2, timeout=90, proc=proc)
        wait_for(past_checkpoint(run, 1000), timeout=90, proc=proc, what="a checkpoint at 1000")
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        output = proc.communicate()[0]
    assert "failed (attempt 1, retrying)" in output and "killed by SIGKILL" in output
    history = json.loads((tmp_path / "sweep" / "state.json").read_text())["runs"]
    (failure,) = history[TAC_RUN.as_posix()]["failures"]
    assert failure["reason"].startswith("worker process killed by SIGKILL")
    assert failure["step"] >= 500
    # 3. the same command again: resumes from the checkpoint, every row exactly once
    again = run_cli(args)
    assert again.returncode == 0, again.stdout + again.stderr
    assert (
        "1 run: 1 complete" in again.stdout and "1 completed after failed attempts" in again.stdout
    )
    _assert_complete_rows(run, 2000)


def test_ctrl_c_checkpoints_and_the_same_command_resumes(tmp_path: Path) -> None:
    # long enough that the fast update cannot finish between the signal and the driver's stop
    args = _sweep_args(tmp_path, "--algo", "tac", "--q", "1", "--seed", "0", "--steps", "3000")
    args += ["--workers", "1"]
    run = tmp_path / TAC_RUN
    proc = start_cli(args, session=True)
    try:
        wait_for(lambda: last_logged_step(run / "losses.csv") >= 750, timeout=90, proc=proc)
        proc.send_signal(signal.SIGINT)  # to the driver only, as from a batch scheduler
        output = proc.communicate(timeout=60)[0]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, output
    assert "stopping: every running run checkpoints and returns" in output
    status = run_status(run)
    assert status["state"] == "interrupted" and 750 <= status["step"] < 3000
    assert status["reason"].startswith(f"interrupted at step {status['step']}; resume with: ")
    assert "tacbench sweep --preset smoke" in status["reason"]
    summary = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["counts"]["partial"] == 1
    again = run_cli(args)
    assert again.returncode == 0, again.stdout + again.stderr
    _assert_complete_rows(run, 3000)


def test_a_failing_run_is_recorded_and_retried_and_the_others_complete(tmp_path: Path) -> None:
    tiny = {"total_steps": 400, "learning_starts": 200, "batch_size": 32, "eval_every": 200}
    tiny |= {"eval_episodes": 1, "checkpoint_every": 100, "log_every": 100}
    preset = Preset(
        "failing",
        "Humanoid's joint ln_q overflows float32 at the first update (docs/tac.md, Numerics)",
        (
            Entry("tac", ("Humanoid",), (0,), (1.2,), MappingProxyType({**tiny, "lnq": "joint"})),
            Entry("tac", ("Hopper",), (0,), (1.0,), MappingProxyType(tiny)),
        ),
    )
    options = driver.Options(workers=2, max_retries=1)
    result = driver.run_sweep(preset, tmp_path, options)
    assert result.exit_code == 1
    counts = result.summary["counts"]
    assert (counts["complete"], counts["failed"], counts["given_up"]) == (1, 1, 1)
    (failed,) = result.summary["unfinished"]
    assert failed["run"] == "runs/tac/Humanoid-v4/q1.2-a0.05-joint-ls200-bs32/seed0"
    assert [f["step"] for f in failed["failures"]] == [200, 200]  # retried from step 100
    assert all(f["reason"].startswith("non-finite loss_v") for f in failed["failures"])
    assert "given up at step 200 after 2 failed attempts" in result.text
    run = tmp_path / "runs/tac/Hopper-v4/q1-a0.2-ls200-bs32/seed0"
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [200, 400]
    again = driver.run_sweep(preset, tmp_path, options)  # given up: not retried again
    assert again.exit_code == 1
    assert len(again.summary["unfinished"][0]["failures"]) == 2


def test_a_damaged_calibration_store_stops_a_dry_run_but_not_a_sweep(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The sweep prices itself for its bill before it trains: a damaged store stopped it."""
    monkeypatch.setenv("TACBENCH_CALIBRATION", str(tmp_path / "calibration"))
    calibration.store_path().parent.mkdir()
    calibration.store_path().write_text("{not json")
    tiny = {"total_steps": 400, "learning_starts": 200, "batch_size": 32, "eval_every": 200}
    tiny |= {"eval_episodes": 1, "checkpoint_every": 200, "log_every": 100}
    entry = Entry("tac", ("Hopper",), (0,), (1.0,), MappingProxyType(tiny))
    preset = Preset("tiny", "one tiny run", (entry,))
    out = tmp_path / "sweep"
    with pytest.raises(TacbenchError, match="is not a readable calibration store; delete it"):
        dry_run.describe_plan(driver.load_plan(preset, out, driver.Options())[0], 1, "task")
    stream = io.StringIO()
    result = driver.run_sweep(preset, out, driver.Options(workers=1), stream)
    assert result.exit_code == 0 and result.summary["counts"]["complete"] == 1
    warned = "is not a readable calibration store; delete it"
    assert (
        warned in stream.getvalue()
        and "trains all the same, priced without it" in stream.getvalue()
    )


def test_a_member_with_a_damaged_csv_fails_alone_and_its_unit_trains_on(tmp_path: Path) -> None:
    """One member's eval.csv changed before its checkpoint: that run cannot resume, but the
    healthy member of its unit completes in the same attempt (it used to fail every attempt
    with it and be given up), and the failure is recorded against the damaged run alone. The
    damaged run is not retried (it used to be, until given up, though every attempt is refused
    alike), and a refusal does not count towards --max-retries: even with none allowed, once
    its CSV is restored the same command completes it."""
    tiny = {"total_steps": 400, "learning_starts": 100, "batch_size": 32, "eval_every": 100}
    tiny |= {"eval_episodes": 1, "checkpoint_every": 100, "log_every": 100}
    preset = Preset(
        "damaged", "two members, one damaged", (Entry("tac", ("Hopper",), (0, 10), (1.0,), tiny),)
    )
    healthy, damaged = (r.config for r in plan.build_runs(preset))
    stopped = training.train([healthy, damaged], tmp_path, stop=lambda step: step >= 300)
    assert [o.state for o in stopped] == ["interrupted", "interrupted"]
    eval_csv = stopped[1].directory / "eval.csv"
    original = eval_csv.read_text()
    rows = original.splitlines(keepends=True)
    changed = rows[0] + rows[1].replace(",", ",9", 2) + "".join(rows[2:])
    eval_csv.write_text(changed)
    result = driver.run_sweep(preset, tmp_path, driver.Options(workers=1, max_retries=0))
    assert result.exit_code == 1
    counts = result.summary["counts"]
    assert (counts["complete"], counts["given_up"], counts["cannot_resume"]) == (1, 0, 1)
    assert "1 run cannot resume from its files, so the sweep did not retry it" in result.text
    assert "0 failed (0 given up), 1 partial, 0 not started; 1 cannot resume from its files" in (
        result.text
    )
    status = run_status(stopped[0].directory)
    assert (status["state"], status["step"]) == ("complete", 400)
    (failed,) = result.summary["unfinished"]
    assert failed["run"] == str(stopped[1].directory.relative_to(tmp_path))
    assert failed["state"] == "cannot resume"
    (failure,) = failed["failures"]
    assert failure["reason"].startswith(f"DamagedRun: cannot resume: {eval_csv} differs from")
    assert failure["refused"] is True
    assert eval_csv.read_text() == changed  # nothing was changed
    eval_csv.write_text(original)
    again = driver.run_sweep(preset, tmp_path, driver.Options(workers=1, max_retries=0))
    assert again.exit_code == 0
    assert (run_status(stopped[1].directory)["state"], again.summary["unfinished"]) == (
        "complete",
        [],
    )
