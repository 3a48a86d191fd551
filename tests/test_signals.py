"""Signals on the command line: SIGTERM and SIGHUP stop like Ctrl-C (checkpoint, the state
``interrupted``, exit 128 + the signal's number), and a second signal stops at once with the
same exit status and the resume command, the run resumable from its last checkpoint."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from tacbench.interrupts import (
    SAME_REQUEST_S,
    SecondSignal,
    exit_status,
    resume_command,
    stop_signals,
)
from tests.helpers import checkpoint_state, interrupt_cli, run_cli

pytestmark = pytest.mark.smoke

ARGS = ["run", "--env", "Hopper-v4", "--learning-starts", "1000", "--eval-episodes", "1"]


def _status(out: Path) -> dict:
    (run,) = (out / "runs").glob("tac/Hopper-v4/*/seed0")
    return json.loads((run / "status.json").read_text())


# Ctrl-C's first signal is tests/test_resume.py's; SIGTERM's takes the same path
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGHUP, 129)], ids=["SIGHUP"])
def test_a_signal_checkpoints_records_interrupted_and_exits_128_plus_its_number(
    tmp_path: Path, sig: int, code: int
) -> None:
    args = [*ARGS, "--steps", "2000", "--eval-every", "500", "--out", str(tmp_path)]
    exit_code, output = interrupt_cli(args, "step 1000/", signals=[sig])
    assert exit_code == code, output
    status = _status(tmp_path)
    assert status["state"] == "interrupted" and 1000 <= status["step"] < 2000
    assert status["reason"].startswith(f"interrupted at step {status['step']}; resume with:")
    (run,) = (tmp_path / "runs").glob("tac/Hopper-v4/*/seed0")
    assert checkpoint_state(run)["step"] == status["step"]


# a second Ctrl-C takes the same path, with 130
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143)], ids=["SIGTERM"])
def test_a_second_signal_stops_at_once_with_the_resume_command(
    tmp_path: Path, sig: int, code: int
) -> None:
    args = [*ARGS, "--steps", "1500", "--eval-every", "500", "--out", str(tmp_path)]
    args += ["--checkpoint-every", "100000"]  # the first signal's checkpoint is the only one
    exit_code, output = interrupt_cli(
        args,
        "step 1000/",
        signals=[sig, sig],
        gap=1.0,
        env={"TACBENCH_CHECKPOINT_PAUSE": "3"},  # the second signal lands in that checkpoint
    )
    assert exit_code == code, output
    name = signal.Signals(sig).name
    assert f"stopped at once by a second {name}" in output and "--resume" in output
    assert "Traceback" not in output and "Aborted" not in output
    status = _status(tmp_path)
    assert (status["state"], status["step"]) == ("interrupted", 0)  # no checkpoint was made
    assert "resume with:" in status["reason"] and "(from step 0)" in status["reason"]
    resumed = run_cli([*args, "--resume"])
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert _status(tmp_path)["state"] == "complete"


@pytest.mark.unit
def test_one_signal_delivered_twice_at_once_is_one_request() -> None:
    """timeout(1) sends its signal to the command and to the command's process group, so the
    command can get it twice, microseconds apart. Taken as a second signal, it stopped a run at
    once, without a checkpoint, and made a sweep kill its workers (one was cut between writing
    its status and renaming it: status.json still said "running"). The same signal again within
    SAME_REQUEST_S is the same request; later, it is a second one."""
    with stop_signals() as received:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGTERM)
        assert received == {"count": 1, "signal": signal.SIGTERM}
        time.sleep(SAME_REQUEST_S)
        with pytest.raises(SecondSignal):
            os.kill(os.getpid(), signal.SIGTERM)
    with stop_signals(second_interrupts=False) as received:
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)
    assert received == {"count": 1, "signal": signal.SIGINT}


@pytest.mark.unit
def test_the_exit_status_is_128_plus_the_first_signal() -> None:
    with stop_signals() as received:
        os.kill(os.getpid(), signal.SIGTERM)
    assert received == {"count": 1, "signal": signal.SIGTERM}
    assert exit_status() == 143
    with stop_signals(second_interrupts=False) as received:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)
    assert received == {"count": 2, "signal": signal.SIGINT}
    assert exit_status() == 143  # the first, not the last
    with stop_signals():
        pass
    assert exit_status() == 130  # no signal: a stop asked for otherwise


@pytest.mark.unit
def test_the_resume_command_adds_resume_to_a_run_and_leaves_a_sweep_as_it_is() -> None:
    """A sweep resumes by being run again: it has no --resume (the advice in a sweep's runs'
    status.json after a second Ctrl-C named one, which click refused)."""
    run = "tacbench run --env Hopper-v4 --q 1.5"
    assert resume_command(run) == f"{run} --resume"
    assert resume_command(f"{run} --resume") == f"{run} --resume"
    sweep = "tacbench sweep --preset smoke --out results"
    assert resume_command(sweep) == sweep
    assert resume_command("") == "train(..., resume=True)"
    # a run started with --force resumes without it (--resume refuses it beside it)
    assert (
        resume_command(f"{run} --force --out 'my results'") == f"{run} --out 'my results' --resume"
    )
    # the results moved: their folder replaces --out, or is added where the default was used
    moved = Path("moved results")
    assert resume_command(f"{run} --out old", moved) == f"{run} --out 'moved results' --resume"
    assert resume_command(run, moved) == f"{run} --out 'moved results' --resume"


@pytest.mark.unit
def test_a_hangup_ignored_as_nohup_asks_stays_ignored() -> None:
    """Under nohup the hangup of a closed session used to stop a run (or a Slurm sweep, which
    cancelled its jobs); SIGINT and SIGTERM are still caught, and SIGHUP where not ignored."""
    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with stop_signals() as received:
            assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGHUP)
            assert received == {}
            assert signal.getsignal(signal.SIGTERM) not in (signal.SIG_IGN, signal.SIG_DFL)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        with stop_signals() as received:
            os.kill(os.getpid(), signal.SIGHUP)
        assert received == {"count": 1, "signal": signal.SIGHUP}
    finally:
        signal.signal(signal.SIGHUP, before)
