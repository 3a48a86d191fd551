"""Real faults, no mocks of the file system: an output folder that cannot be created or is
read-only, damaged checkpoint files (truncated, bit-flipped), ``kill -9`` at chosen and at
random moments (inside a checkpoint write too), and a full disk (a small tmpfs: these machines
run as root). Each ends with the CSVs of an uninterrupted run, byte for byte apart from the
wall-clock columns, or with one clear line and exit status 2 and nothing lost."""

from __future__ import annotations

import json
import random
import shutil
import signal
import subprocess
import sys
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.runs.resume_checks import START_OVER
from tests.helpers import assert_same_results, run_cli, start_cli, tiny_configs, train, wait_for

pytestmark = pytest.mark.smoke

# the command-line twin of tiny_configs("tac"): the same config, so the same run directory
TINY_TAC_ARGS = [
    "run", "--env", "Hopper-v4", "--q", "1.5", "--alpha", "0.2", "--seed", "0",
    "--steps", "1500", "--eval-every", "500", "--eval-episodes", "2",
    "--checkpoint-every", "500", "--log-every", "250", "--learning-starts", "1000",
    "--batch-size", "32", "--quiet",
]  # fmt: skip
TINY_TAC_RUN = Path("runs/tac/Hopper-v4/q1.5-a0.2-ls1000-bs32/seed0")


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Callable[[str], Path]]:
    """Mount a tmpfs with the given options under ``tmp_path`` (skip where mounting is not
    allowed); every mount is removed afterwards."""
    mounted: list[Path] = []

    def mount(options: str, where: Path | None = None) -> Path:
        point = where or tmp_path / f"tmpfs-{uuid.uuid4().hex[:8]}"
        point.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(point)],
            capture_output=True,
            check=False,
        )
        if done.returncode:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
        mounted.append(point)
        return point

    yield mount
    for point in reversed(mounted):
        subprocess.run(["umount", "-l", str(point)], check=False)


def _tree(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()
    }


def _generations(run: Path) -> list[int]:
    """The steps of a run's checkpoint generations (none yet: [])."""
    return sorted(int(p.stem.split("-")[1]) for p in (run / "checkpoint").glob("manifest-*.json"))


def _error_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.startswith("Error: ")]
    assert len(lines) == 1 and "Traceback" not in output, output
    return lines[0]


# --- output folders --------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_an_output_folder_that_cannot_be_created_is_one_clear_line(
    tmp_path: Path, tmpfs: Callable[..., Path], command: str
) -> None:
    args = ["run", "--env", "Hopper-v4", "--steps", "100"]
    if command == "sweep":
        args = ["sweep", "--preset", "smoke", "--algo", "tac", "--steps", "100"]
    runner = CliRunner()
    for out in (Path("/proc/tacbench-out"), tmpfs("ro") / "out"):
        result = runner.invoke(cli, [*args, "--out", str(out)])
        assert result.exit_code == 2, result.output
        line = _error_line(result.output)
        assert f"cannot create or write the output folder {out}" in line, line
        assert "choose one you can write with --out" in line


def test_a_sweep_records_a_run_it_cannot_write_as_failed_and_goes_on(
    tmp_path: Path, tmpfs: Callable[..., Path]
) -> None:
    tmpfs("ro", tmp_path / "runs/tac/Hopper-v4/q2-a0.2-ls500-bs32")  # the q=2 runs' folder
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--seed", "0", "--steps", "300"]
    args += ["--group", "none", "--max-retries", "0", "--workers", "1", "--out", str(tmp_path)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 1, result.output  # a run failed for good, the other completed
    assert "2 runs: 1 complete, 1 failed (1 given up), 0 partial, 0 not started" in result.output
    history = json.loads((tmp_path / "sweep" / "state.json").read_text())["runs"]
    (failure,) = history["runs/tac/Hopper-v4/q2-a0.2-ls500-bs32/seed0"]["failures"]
    assert "read-only file system; choose a folder you can write with --out" in failure["reason"]
    status = json.loads(
        (tmp_path / "runs/tac/Hopper-v4/q1-a0.2-ls500-bs32/seed0/status.json").read_text()
    )
    assert status["state"] == "complete"


# --- damaged checkpoints ---------------------------------------------------------------------


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _flip_a_bit(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))


DAMAGES = {"truncated": _truncate, "bit-flipped": _flip_a_bit}


def _file_of(run: Path, kind: str, step: int) -> Path:
    checkpoint = run / "checkpoint"
    if kind == "replay":
        (chunk,) = checkpoint.glob(f"replay/*-{step:012d}.npz")
        return chunk
    return checkpoint / (f"state-{step:012d}.pt" if kind == "state" else f"model-{step:012d}.zip")


@pytest.mark.parametrize(
    ("learner", "kind", "damage"),
    [
        ("tac", "state", "truncated"),
        ("tac", "replay", "bit-flipped"),
        ("ddpg", "model", "truncated"),
        ("ddpg", "replay", "truncated"),
        ("ppo", "state", "bit-flipped"),  # stops at its rollout's end: 1024
    ],
)
def test_a_damaged_checkpoint_resumes_from_the_previous_generation(
    tmp_path: Path, uninterrupted: Callable[[str], Path], learner: str, kind: str, damage: str
) -> None:
    configs = tiny_configs(learner)
    stop_at = 730 if learner == "ppo" else 1100
    (stopped,) = train(tmp_path, configs, stop=lambda step: step >= stop_at)
    assert stopped.state == "interrupted"
    run = stopped.directory
    previous, newest = _generations(run)
    assert newest == stopped.step
    damaged = _file_of(run, kind, newest)
    DAMAGES[damage](damaged)
    (resumed,) = train(tmp_path, configs, resume=True)
    assert resumed.state == "complete"
    assert_same_results(uninterrupted(learner), run)
    reason = json.loads((run / "status.json").read_text())["reason"]
    name = damaged.relative_to(run / "checkpoint").as_posix()
    assert reason.startswith(f"resumed from step {previous}: "), reason
    assert f"the checkpoint at step {newest} is damaged ({name}: " in reason


def test_no_usable_checkpoint_is_one_clear_line_and_nothing_is_deleted(
    tmp_path: Path, uninterrupted: Callable[[str], Path]
) -> None:
    configs = tiny_configs("tac")
    (stopped,) = train(tmp_path, configs, stop=lambda step: step >= 1100)
    run = stopped.directory
    shared = run / "checkpoint/replay/000000000000-000000000500.npz"  # in both generations
    _flip_a_bit(shared)
    before = _tree(run)
    result = run_cli([*TINY_TAC_ARGS, "--out", str(tmp_path), "--resume"])
    assert result.returncode == 2, result.stdout + result.stderr
    line = _error_line(result.stderr)
    assert "no usable checkpoint to resume from" in line
    assert "replay/000000000000-000000000500.npz: its checksum does not match" in line
    assert line.endswith("Nothing was deleted; " + START_OVER + ".")
    assert _tree(run) == before
    forced = run_cli([*TINY_TAC_ARGS, "--out", str(tmp_path), "--force"])
    assert forced.returncode == 0, forced.stderr
    assert_same_results(uninterrupted("tac"), run)


# --- kill -9 ---------------------------------------------------------------------------------


def _start(out: Path, *extra: str, pause: float = 0.0) -> subprocess.Popen[str]:
    env = {"TACBENCH_CHECKPOINT_PAUSE": str(pause)}
    return start_cli([*TINY_TAC_ARGS, "--out", str(out), *extra], env=env)


def _wait_for(proc: subprocess.Popen[str], condition: Callable[[], bool]) -> None:
    wait_for(condition, timeout=120, proc=proc, poll=0.01)  # often: moments inside a write


def _kill_when(proc: subprocess.Popen[str], condition: Callable[[], bool]) -> None:
    _wait_for(proc, condition)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()


def _resume_to_the_end(out: Path) -> None:
    finished = run_cli([*TINY_TAC_ARGS, "--out", str(out), "--resume"])
    assert finished.returncode == 0, finished.stdout + finished.stderr
    assert not list((out / TINY_TAC_RUN).rglob("*.tmp"))


def test_kill_9_in_the_middle_of_writing_a_checkpoint_file(
    tmp_path: Path, uninterrupted: Callable[[str], Path]
) -> None:
    run = tmp_path / TINY_TAC_RUN
    checkpoint = run / "checkpoint"
    proc = _start(tmp_path, pause=0.5)
    # in the second checkpoint, a file synced but not yet renamed
    _kill_when(proc, lambda: bool(_generations(run)) and any(checkpoint.rglob("*.tmp")))
    assert list(checkpoint.rglob("*.tmp")) and _generations(run) == [500]
    _resume_to_the_end(tmp_path)
    assert_same_results(uninterrupted("tac"), tmp_path / TINY_TAC_RUN)


def test_kill_9_after_a_checkpoints_files_but_before_its_manifest(
    tmp_path: Path, uninterrupted: Callable[[str], Path]
) -> None:
    checkpoint = tmp_path / TINY_TAC_RUN / "checkpoint"
    state, manifest = (
        checkpoint / "state-000000001000.pt",
        checkpoint / "manifest-000000001000.json",
    )
    proc = _start(tmp_path, pause=0.5)
    _kill_when(proc, lambda: state.exists() and not manifest.exists())
    assert _generations(tmp_path / TINY_TAC_RUN) == [500]  # the unfinished one does not count
    _resume_to_the_end(tmp_path)
    assert_same_results(uninterrupted("tac"), tmp_path / TINY_TAC_RUN)


def test_kill_9_at_random_moments_then_resume(
    tmp_path: Path, uninterrupted: Callable[[str], Path]
) -> None:
    """Four kills at seeded random moments: one in start-up, then three once the run is under
    way (its status written: warm-up, learning, a checkpoint write, where each write pauses
    0.1 s, so a good share of the time is spent inside one), each resumed from what the kill
    before left. Timed from the run's own status, not the process start, so that a slow start
    on a loaded machine cannot turn every kill into a start-up one."""
    moments = random.Random(2026)
    status = tmp_path / TINY_TAC_RUN / "status.json"
    for attempt in range(4):
        before = status.stat().st_mtime_ns if status.exists() else None
        proc = _start(tmp_path, *(("--resume",) if attempt else ()), pause=0.1)
        if attempt:
            _wait_for(proc, lambda was=before: status.exists() and status.stat().st_mtime_ns != was)
        try:
            proc.communicate(timeout=moments.uniform(0.2, 1.0 if attempt == 0 else 2.5))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
        else:
            break  # it finished first
    _resume_to_the_end(tmp_path)
    assert_same_results(uninterrupted("tac"), tmp_path / TINY_TAC_RUN)


# --- a full disk ---------------------------------------------------------------------------


def _fill(disk: Path) -> Path:
    """Fill ``disk`` to the last byte, as another program would; the file that did it."""
    filler = disk / "filler"
    with filler.open("wb") as handle:
        try:
            while True:
                handle.write(b"\0" * 65536)
                handle.flush()
        except OSError:
            pass
    return filler


@pytest.mark.parametrize("how", ["too-small", "filled-mid-run"])
def test_a_full_disk_is_one_clear_line_and_the_run_resumes_when_there_is_room(
    tmpfs: Callable[..., Path], uninterrupted: Callable[[str], Path], how: str
) -> None:
    # the run needs about 1 MB at its peak; 512 KiB holds its first checkpoint, not its second
    disk = tmpfs("size=512k" if how == "too-small" else "size=8m")
    run = disk / TINY_TAC_RUN
    proc = _start(disk)
    if how == "filled-mid-run":
        _wait_for(proc, lambda: bool(_generations(run)))
        filler = _fill(disk)
    output = proc.communicate(timeout=120)[0]
    assert proc.returncode == 2, output
    line = _error_line(output)
    assert "cannot write the run's files (" in line and "): the disk is full; free some" in line
    assert "rerun with --resume" in line
    status = json.loads((run / "status.json").read_text())
    assert status["state"] == "running" and status["step"] in _generations(run)
    if how == "filled-mid-run":
        filler.unlink()
    else:
        subprocess.run(["mount", "-o", "remount,size=8m", str(disk)], check=True)
    _resume_to_the_end(disk)
    assert_same_results(uninterrupted("tac"), run)


def test_a_full_disk_stops_the_sweep_with_one_clear_line(
    tmpfs: Callable[..., Path],
) -> None:
    disk = tmpfs("size=8m")
    # two runs (q = 1 and 2, seed 0), one after another: the disk fills in the first
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--seed", "0", "--steps", "1500"]
    args += ["--workers", "1", "--group", "none", "--out", str(disk)]
    proc = start_cli(args)
    runs = disk / "runs"
    _wait_for(proc, lambda: any(runs.glob("**/manifest-*.json")))
    filler = _fill(disk)
    output = proc.communicate(timeout=120)[0]
    assert proc.returncode == 2, output
    line = _error_line(output)
    assert "the sweep stopped: " in line and "is full; free some space" in line, line
    history = json.loads((disk / "sweep" / "state.json").read_text())["runs"]
    assert all(not entry.get("failures") for entry in history.values())  # not the runs' fault
    filler.unlink()
    again = subprocess.run(
        [sys.executable, "-m", "tacbench", *args], capture_output=True, text=True, timeout=300
    )
    assert again.returncode == 0, again.stdout + again.stderr
    assert "2 runs: 2 complete, 0 failed" in again.stdout
    shutil.rmtree(runs)  # the tmpfs goes with the test


def test_a_full_disk_under_a_command_without_runs_is_one_clear_line(
    tmpfs: Callable[..., Path],
) -> None:
    """`figures` (like `report` or `bench --json`) was a traceback with exit status 1."""
    disk = tmpfs("size=256k")
    _fill(disk)
    done = subprocess.run(
        [sys.executable, "-m", "tacbench", "figures", "--out", str(disk / "figures")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    line = _error_line(done.stdout + done.stderr)
    assert line.startswith("Error: cannot write "), line  # matplotlib's errors name no file
    assert line.endswith("the disk is full; free some space, then run the command again."), line


def test_a_full_disk_under_a_sweeps_files_names_the_sweeps_way_to_resume(
    tmpfs: Callable[..., Path],
) -> None:
    """It said "rerun with --resume", an option `sweep` does not have."""
    disk = tmpfs("size=256k")
    _fill(disk)
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--seed", "0", "--q", "1"]
    result = CliRunner().invoke(cli, [*args, "--steps", "300", "--out", str(disk / "sweep")])
    assert result.exit_code == 2, result.output
    line = _error_line(result.output)
    assert "the disk is full; free some space, then rerun the same command" in line, line
    assert "--resume" not in line
