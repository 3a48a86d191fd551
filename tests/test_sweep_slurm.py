"""``tacbench sweep --executor slurm`` against a real Slurm: a single-node cluster on this machine
(``bash .ci/slurm-cluster start``, which .ci/run runs as root). Skipped, with the reason, where no
cluster answers."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tests.helpers import wait_for

pytest.importorskip("submitit")
# one after another on one xdist worker: both submit to the one single-node cluster (a second
# array would wait for the node, or take its CPUs from the job whose requeue is being timed),
# and the requeue test's clean-up cancels every job named tacbench-sweep, the other test's too
pytestmark = [pytest.mark.smoke, pytest.mark.xdist_group("slurm")]


def _cluster_problem() -> str:
    if shutil.which("sbatch") is None:
        return "no Slurm on this machine (Debian: apt-get install slurm-wlm munge)"
    answer = subprocess.run(["sinfo", "-h", "-o", "%t"], capture_output=True, text=True)
    if answer.returncode != 0 or not answer.stdout.strip():
        return f"no Slurm cluster answers ({answer.stderr.strip().splitlines()[-1:]})"
    return ""


PROBLEM = _cluster_problem()
if PROBLEM:
    pytest.skip(
        f"{PROBLEM}: start one with `bash .ci/slurm-cluster start` (root) and export the "
        "SLURM_CONF it prints",
        allow_module_level=True,
    )

SMOKE_TAC = ["sweep", "--preset", "smoke", "--algo", "tac", "--q", "1", "--seed", "0"]


def _run_dir(out: Path) -> Path:
    (run,) = out.glob("runs/tac/Hopper-v4/*/seed0")
    return run


def test_the_smoke_preset_runs_as_one_job_array(tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--algo", "ppo", "--seed", "0"]
    result = CliRunner().invoke(cli, [*args, "--executor", "slurm", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "3 runs: 3 complete, 0 failed" in result.output
    for run in out.glob("runs/*/Hopper-v4/*/seed0"):
        assert json.loads((run / "status.json").read_text())["state"] == "complete"
        assert pd.read_csv(run / "eval.csv")["step"].tolist() == [500, 1000]
    tasks = [name for name in _job_folders(out) if "_" in name]
    assert len(tasks) >= 2 and len({name.split("_")[0] for name in tasks}) == 1  # one array


def _job_folders(out: Path) -> list[str]:
    """submitit's folder per job (``<id>``, ``<array>_<task>``; not its hidden ones)."""
    return [p.name for p in (out / "sweep" / "slurm").iterdir() if not p.name.startswith(".")]


def _slurm(*args: str) -> None:
    subprocess.run(args, check=True, capture_output=True)


def _step(out: Path) -> int:
    try:
        return int(json.loads((_run_dir(out) / "status.json").read_text())["step"])
    except (ValueError, OSError, json.JSONDecodeError):
        return 0


def test_a_requeued_and_a_time_limited_job_resume_exactly(tmp_path: Path) -> None:
    """`scontrol requeue` (SIGTERM) and the time-limit signal (SIGUSR2, sent here by hand): the
    trainer checkpoints, the job comes back and resumes; the rows equal an uninterrupted run's."""
    out, reference = tmp_path / "slurm", tmp_path / "local"
    budget = ["--steps", "5000"]  # the second signal comes near step 3,000-3,500, before the end
    driver = subprocess.Popen(
        [sys.executable, "-m", "tacbench", *SMOKE_TAC, *budget, "--executor=slurm", f"--out={out}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        wait_for(
            lambda: _step(out) >= 1500, timeout=240, poll=0.5, what="the job to train 1,500 steps"
        )
        (job_id,) = _job_folders(out)
        _slurm("scontrol", "requeue", job_id)
        wait_for(
            lambda: _pending(job_id), timeout=60, poll=0.5, what="the requeued job to be pending"
        )
        first = _step(out)
        wait_for(
            lambda: _step(out) >= first + 1500,
            timeout=240,
            poll=0.5,
            what="the requeued job to train on",
        )
        _slurm("scancel", "--signal=USR2", job_id)  # what Slurm sends near the time limit
        wait_for(lambda: _pending(job_id), timeout=60, poll=0.5, what="the job to requeue itself")
        output, _ = driver.communicate(timeout=300)
    finally:
        if driver.poll() is None:
            driver.kill()
            subprocess.run(["scancel", "--name", "tacbench-sweep"], check=False)
    assert driver.returncode == 0, output
    assert "1 run: 1 complete, 0 failed" in output

    run = _run_dir(out)
    log = next((out / "sweep" / "logs").glob("*.log")).read_text()
    assert log.count(f"(Slurm job {job_id})") == 3  # three attempts of the same job
    local = CliRunner().invoke(cli, [*SMOKE_TAC, *budget, "--out", str(reference)])
    assert local.exit_code == 0, local.output
    for name in ("eval.csv", "train.csv", "losses.csv"):
        fresh, whole = pd.read_csv(run / name), pd.read_csv(_run_dir(reference) / name)
        assert fresh["step"].is_unique, name
        pd.testing.assert_frame_equal(
            fresh.drop(columns=["wall_s", "cpu_s"], errors="ignore"),
            whole.drop(columns=["wall_s", "cpu_s"], errors="ignore"),
        )


def _pending(job_id: str) -> bool:
    shown = subprocess.run(
        ["squeue", "-h", "-j", job_id, "-o", "%T"], capture_output=True, text=True, check=False
    )
    return shown.stdout.strip() == "PENDING"


def test_squeue_gives_the_reason_a_held_job_waits() -> None:
    """The reason the driver tells its user of a job that Slurm will not start, read from a
    real squeue: an array's pending tasks each with its own, a running one's empty."""
    from tacbench.sweep import slurm

    held = ["--hold", "--array=0-1", f"--job-name={slurm.JOB_NAME}", "--output=/dev/null"]
    held += ["--wrap", "sleep 60"]
    submitted = subprocess.run(
        ["sbatch", "--parsable", *held],
        capture_output=True,
        text=True,
        check=True,
    )
    array = submitted.stdout.strip().split(";")[0]
    try:
        _slurm("scontrol", "release", f"{array}_1")
        running = lambda: slurm._queued([array]).get(f"{array}_1") == ""  # noqa: E731
        wait_for(running, timeout=60, poll=0.5, what=f"job {array}_1 to run")
        assert slurm._queued([array])[f"{array}_0"] == "JobHeldUser"
    finally:
        _slurm("scancel", array)
