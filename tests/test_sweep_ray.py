"""``tacbench sweep --executor ray`` on a local Ray with 2 CPUs: the tasks write into a scratch
folder (as on a cluster without a shared filesystem) and return the small files, which the
driver writes into --out; checkpoints stay in the scratch folder."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tests.helpers import wait_for

ray = pytest.importorskip("ray")

# a Ray test starts a local Ray and checks that its raylet and GCS processes are gone at the end:
# Ray tests run one after another on one xdist worker, so that no other test's Ray is counted
pytestmark = [pytest.mark.smoke, pytest.mark.xdist_group("ray")]


def _ray_processes() -> set[int]:
    """Ids of this machine's raylet and GCS server processes."""
    found = set()
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            text = cmdline.read_bytes().decode(errors="replace")
        except OSError:
            continue
        if "raylet" in text or "gcs_server" in text:
            found.add(int(cmdline.parent.name))
    return found


def test_ray_executor_returns_small_files_and_keeps_checkpoints_on_the_node(
    tmp_path: Path,
) -> None:
    before = _ray_processes()
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--algo", "ppo", "--seed", "0"]
    args += ["--executor", "ray", "--workers", "2", "--scratch", str(scratch), "--out", str(out)]
    runner = CliRunner()
    result = runner.invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "3 runs: 3 complete, 0 failed" in result.output
    assert not ray.is_initialized()

    run_dirs = sorted(out.glob("runs/*/Hopper-v4/*/seed0"))
    assert [d.parts[-4] for d in run_dirs] == ["ppo", "tac", "tac"]
    (node_root,) = scratch.iterdir()  # <scratch>/<digest of --out>
    history = json.loads((out / "sweep" / "state.json").read_text())["runs"]
    for run in run_dirs:
        key = run.relative_to(out).as_posix()
        assert sorted(p.name for p in run.iterdir()) == [
            "config.json",
            "eval.csv",
            "losses.csv",
            "status.json",
            "train.csv",
        ]
        assert json.loads((run / "status.json").read_text())["state"] == "complete"
        assert pd.read_csv(run / "eval.csv")["step"].tolist() == [500, 1000]
        assert (run / "eval.csv").read_bytes() == (node_root / key / "eval.csv").read_bytes()
        assert list((node_root / key / "checkpoint").glob("manifest-*.json"))
        assert len(history[key]["node"]) > 10  # the Ray node holding its checkpoint
    logs = sorted((out / "sweep" / "logs").glob("*.log"))
    assert len(logs) == 3 and all("1000/1000" in log.read_text() for log in logs)

    # a run deleted from --out trains again, as docs/sweep.md says: its node's copy came back
    # (a failed one failed again without training, one of other settings stopped the sweep)
    created = json.loads((run_dirs[0] / "config.json").read_text())["created"]
    shutil.rmtree(run_dirs[0])
    again = runner.invoke(cli, args)
    assert again.exit_code == 0, again.output
    assert pd.read_csv(run_dirs[0] / "eval.csv")["step"].tolist() == [500, 1000]
    assert json.loads((run_dirs[0] / "config.json").read_text())["created"] > created
    assert _ray_processes() <= before  # ray.shutdown() stopped the local Ray


def _task_processes(session: int) -> list[int]:
    """Ids of the Ray worker processes running a sweep task (titled ``ray::ray_main``) in the
    session ``session`` (the driver's: another Ray on this machine is not counted)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            pid = int(cmdline.parent.name)
            if cmdline.read_bytes().startswith(b"ray::ray_main") and os.getsid(pid) == session:
                found.append(pid)
        except OSError:
            continue
    return found


def test_a_task_killed_on_its_node_is_recorded_with_its_node_and_host(tmp_path: Path) -> None:
    """A task killed there (out of memory) returns no result: its node used to be lost, so the
    retry could start over elsewhere, its checkpoints left behind, and its host was unknown."""
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--q", "1", "--seed", "0"]
    args += ["--steps", "50000", "--executor", "ray", "--workers", "1", "--max-retries", "0"]
    args += ["--scratch", str(scratch), "--out", str(out)]
    driver = subprocess.Popen(
        [sys.executable, "-m", "tacbench", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # its Ray's processes in a session of their own
    )
    try:
        started = lambda: any(scratch.glob("*/runs/tac/*/*/seed0/status.json"))  # noqa: E731
        wait_for(started, timeout=180, proc=driver, poll=0.1, what="the task to start training")
        (task,) = _task_processes(os.getsid(driver.pid))
        niceness = os.getpriority(os.PRIO_PROCESS, task)
        os.kill(task, signal.SIGKILL)
        output, _ = driver.communicate(timeout=180)
    finally:  # the driver and its Ray's processes, should the test fail half-way
        with contextlib.suppress(ProcessLookupError):
            os.killpg(driver.pid, signal.SIGKILL)
    assert niceness == 0  # Ray's default, 15, would let any busy process starve the training
    assert driver.returncode == 1, output
    assert "Ray task failed" in output
    (entry,) = json.loads((out / "sweep" / "state.json").read_text())["runs"].values()
    assert len(entry["node"]) > 10  # the node holding its checkpoints, for the retry
    (failure,) = entry["failures"]
    assert failure["host"] == socket.gethostname() and "Ray task failed" in failure["reason"]


class _Actor:
    """A Ray actor handle whose methods run at once: ``handle.name.remote(...)``."""

    def __init__(self, target: object) -> None:
        self.target = target

    def __getattr__(self, name: str) -> SimpleNamespace:
        return SimpleNamespace(remote=getattr(self.target, name))


def test_a_unit_submitted_again_forgets_where_its_last_attempt_ran(tmp_path: Path) -> None:
    """A retry that died before it reported was recorded on the last attempt's node and host
    (the board is keyed by unit)."""
    from tacbench.sweep import executors, plan, presets

    board = executors._Board()
    executor = object.__new__(executors.RayExecutor)
    executor.ray = SimpleNamespace(get=lambda value: value)
    executor._board, executor._refs = _Actor(board), {}
    executor._task = SimpleNamespace(remote=lambda job, board: object())
    executor.root, executor.command, executor.cpus, executor.shared_fs = tmp_path, "", 1, True
    unit = plan.Unit((plan.build_runs(presets.get_preset("smoke"))[0],))
    board.started(unit.key, "node-a", "host-a")
    executor.submit(unit, "node-a")
    assert board.where(unit.key) == ("", "")
    assert len(executor._refs) == 1
