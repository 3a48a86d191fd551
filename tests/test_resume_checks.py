"""A resume checks the run directory before it writes anything: a CSV that lost, repeated or
changed a row before the checkpoint, a deleted CSV or checkpoint, a status.json that records
progress no checkpoint holds, and ``--resume --force`` are refused with one line (exit 2) and
nothing changed; a torn last line is cut with a notice and the run continues exactly."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from tacbench import runs
from tacbench.errors import TacbenchError
from tacbench.runs.resume_checks import LogDigest, check_log
from tests.helpers import assert_same_results, run_cli, tiny_configs, train

COLUMNS = runs.TRAIN_COLUMNS
HEADER = b"step,wall_s,return,length\n"
ROWS = [b"10,0.1,1.0,10\n", b"20,0.2,2.0,10\n", b"30,0.3,3.0,10\n"]


def _digest(data: bytes) -> LogDigest:
    return LogDigest(data.count(b"\n") - 1, len(data), hashlib.sha256(data).hexdigest())


def _csv(tmp_path: Path, *lines: bytes) -> Path:
    path = tmp_path / "train.csv"
    path.write_bytes(b"".join(lines))
    return path


@pytest.mark.unit
def test_the_recorded_prefix_is_kept_and_what_follows_is_dropped(tmp_path: Path) -> None:
    recorded = _digest(HEADER + ROWS[0] + ROWS[1])
    path = _csv(tmp_path, HEADER, *ROWS, b"40,0.")
    kept, notes = check_log(path, COLUMNS, 20, recorded)
    assert kept == HEADER + ROWS[0] + ROWS[1]
    assert notes == ["train.csv: cut a torn last line"]


@pytest.mark.unit
def test_an_older_checkpoint_keeps_the_rows_up_to_its_step(tmp_path: Path) -> None:
    path = _csv(tmp_path, HEADER, *ROWS)
    assert check_log(path, COLUMNS, 25, None) == (HEADER + ROWS[0] + ROWS[1], [])


@pytest.mark.unit
@pytest.mark.parametrize(
    ("lines", "message"),
    [
        ((HEADER, ROWS[0], ROWS[2]), "holds 2 rows, but the checkpoint at step 30 recorded 3"),
        ((HEADER, ROWS[0], b"20,0.2,2.5,10\n", ROWS[2]), "differs from what the checkpoint"),
        ((HEADER, ROWS[0], ROWS[1], ROWS[1], ROWS[2]), "line 4: step 20 repeats step 20"),
        ((HEADER, ROWS[1], ROWS[0], ROWS[2]), "line 3: step 10 goes back from step 20"),
        ((HEADER, ROWS[0], b"abc,0.2,2.0,10\n", ROWS[2]), "line 3 has the step 'abc'"),
        ((HEADER, ROWS[0], b"20,0.2\n", ROWS[2]), "line 3 has 2 values for 4 columns"),
        ((b"step,return\n", *ROWS), "has the header 'step,return'"),
        ((), "has the header 'nothing'"),
    ],
    ids=[
        "missing",
        "changed",
        "duplicated",
        "out-of-order",
        "non-number",
        "width",
        "header",
        "empty",
    ],
)
def test_a_damaged_csv_is_refused(tmp_path: Path, lines: tuple[bytes, ...], message: str) -> None:
    recorded = _digest(HEADER + b"".join(ROWS))
    path = _csv(tmp_path, *lines)
    before = path.read_bytes()
    with pytest.raises(TacbenchError, match=re.escape(message)) as refused:
        check_log(path, COLUMNS, 30, recorded)
    assert "--force to start the run over" in str(refused.value)
    assert path.read_bytes() == before


@pytest.mark.unit
def test_a_missing_csv_is_refused(tmp_path: Path) -> None:
    with pytest.raises(TacbenchError, match=r"train\.csv is missing"):
        check_log(tmp_path / "train.csv", COLUMNS, 30, None)


# --- a stopped tiny TAC run, damaged one way per test, then resumed -------------------------


@pytest.fixture(scope="module")
def stopped(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The output folder of a tiny TAC run stopped at step 1,000 (checkpointed there)."""
    out = tmp_path_factory.mktemp("stopped")
    (outcome,) = train(out, tiny_configs("tac"), stop=lambda step: step >= 1000)
    assert (outcome.state, outcome.step) == ("interrupted", 1000)
    return out


def _copy(stopped: Path, tmp_path: Path) -> tuple[Path, Path]:
    out = tmp_path / "out"
    shutil.copytree(stopped, out)
    (run,) = (out / "runs").glob("tac/*/*/seed0")
    return out, run


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def _append(text: str) -> Callable[[Path], None]:
    def damage(run: Path) -> None:
        with (run / "eval.csv").open("a") as handle:
            handle.write(text)

    return damage


def _duplicate_first_row(run: Path) -> None:
    lines = (run / "eval.csv").read_text().splitlines(keepends=True)
    (run / "eval.csv").write_text("".join([lines[0], lines[1], *lines[1:]]))


def _replace_checkpoint_by_a_file(run: Path) -> None:
    shutil.rmtree(run / "checkpoint")
    (run / "checkpoint").write_text("not a checkpoint")


def _newest_cut_and_eval_deleted(run: Path) -> None:
    """The newest generation damaged (so the resume falls back to the one before, deleting the
    newer one only once every CSV can continue) and a CSV the resume then refuses."""
    state = run / "checkpoint" / "state-000000001000.pt"
    state.write_bytes(state.read_bytes()[: state.stat().st_size // 2])
    (run / "eval.csv").unlink()


DAMAGES: dict[str, tuple[Callable[[Path], None], str]] = {
    "checkpoint-deleted": (
        lambda run: shutil.rmtree(run / "checkpoint"),
        "status.json records step 1000, but .* holds no checkpoint",
    ),
    "checkpoint-a-file": (_replace_checkpoint_by_a_file, "checkpoint is a file"),
    "manifests-deleted": (
        lambda run: [p.unlink() for p in (run / "checkpoint").glob("manifest-*.json")],
        "holds no checkpoint",
    ),
    "eval-deleted": (lambda run: (run / "eval.csv").unlink(), "eval.csv is missing"),
    "eval-duplicated-row": (_duplicate_first_row, "eval.csv line 3: step 500 repeats step 500"),
    "eval-non-number": (_append("oops,1,2,3,4,5\n"), "eval.csv line 4 has the step 'oops'"),
    "status-empty": (lambda run: (run / "status.json").write_text(""), "status.json is empty"),
    "checkpoint-and-status-deleted": (
        lambda run: [shutil.rmtree(run / "checkpoint"), (run / "status.json").unlink()],
        "rows in eval.csv but no status.json",
    ),
    "config-invalid": (lambda run: (run / "config.json").write_text("{"), "not valid JSON"),
    "newest-cut-and-eval-deleted": (_newest_cut_and_eval_deleted, "eval.csv is missing"),
}


@pytest.mark.unit
@pytest.mark.parametrize("damage", DAMAGES)
def test_a_damaged_run_is_refused_and_left_as_it_was(
    stopped: Path, tmp_path: Path, damage: str
) -> None:
    out, run = _copy(stopped, tmp_path)
    hurt, message = DAMAGES[damage]
    hurt(run)
    before = _snapshot(out)
    with pytest.raises(TacbenchError, match=message):
        train(out, tiny_configs("tac"), resume=True)
    assert _snapshot(out) == before


@pytest.mark.unit
def test_a_baseline_refused_after_falling_back_keeps_its_newest_generation(
    tmp_path: Path,
) -> None:
    """As TAC's: the newer generation a refused resume would fall back from is not deleted."""
    configs = tiny_configs("ddpg")
    (stopped,) = train(tmp_path, configs, stop=lambda step: step >= 1000)
    _newest_cut_and_eval_deleted(stopped.directory)
    before = _snapshot(tmp_path)
    with pytest.raises(TacbenchError, match=r"eval\.csv is missing"):
        train(tmp_path, configs, resume=True)
    assert _snapshot(tmp_path) == before


@pytest.mark.unit
def test_the_command_line_refuses_resume_and_force_with_one_line(tmp_path: Path) -> None:
    args = ["run", "--env", "Hopper-v4", "--steps", "1500", "--out", str(tmp_path)]
    refused = run_cli([*args, "--resume", "--force"])
    assert refused.returncode == 2
    assert "--resume continues a run and --force deletes it" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert not (tmp_path / "runs").exists()


@pytest.mark.unit
def test_resume_and_force_together_are_refused(stopped: Path, tmp_path: Path) -> None:
    out, _ = _copy(stopped, tmp_path)
    before = _snapshot(out)
    with pytest.raises(TacbenchError, match="pass one of them"):
        train(out, tiny_configs("tac"), resume=True, force=True)
    assert _snapshot(out) == before


@pytest.mark.unit
def test_a_torn_last_line_is_cut_with_a_notice_and_the_run_continues_exactly(
    stopped: Path, tmp_path: Path, uninterrupted: Callable[[str], Path]
) -> None:
    out, run = _copy(stopped, tmp_path)
    _append("1500,16.62,9")(run)
    (outcome,) = train(out, tiny_configs("tac"), resume=True)
    assert outcome.state == "complete"
    assert (
        "eval.csv: cut a torn last line" in json.loads((run / "status.json").read_text())["reason"]
    )
    assert_same_results(uninterrupted("tac"), run)
