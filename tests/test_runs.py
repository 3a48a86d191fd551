"""The run directory: layout, atomic JSON, CSV append/truncate, resume planning, progress."""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest

from tacbench import runs
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.progress import Progress

pytestmark = pytest.mark.unit

CONFIG = {"env": "Hopper-v4", "q": 1.5, "alpha": 0.2, "seed": 0, "device": "cpu"}


def test_layout() -> None:
    path = runs.run_directory(Path("results"), "tac", "Ant-v4", "q1.5-a0.2", 10)
    assert path == Path("results/runs/tac/Ant-v4/q1.5-a0.2/seed10")


def test_atomic_json_leaves_no_temporary_file(tmp_path: Path) -> None:
    path = tmp_path / "status.json"
    runs.atomic_write_json(path, {"state": "running", "step": 3})
    runs.atomic_write_json(path, {"state": "complete", "step": 5})
    assert runs.read_json(path) == {"state": "complete", "step": 5}
    assert [p.name for p in tmp_path.iterdir()] == ["status.json"]
    (tmp_path / "config.json").mkdir()  # said "... is is a directory"
    with pytest.raises(TacbenchError, match=r"config.json is a directory; restore"):
        runs.read_json(tmp_path / "config.json", "restore it")


def test_csv_rows_are_flushed_at_once_and_keep_full_precision(tmp_path: Path) -> None:
    log = runs.CsvLog(tmp_path / "eval.csv", runs.EVAL_COLUMNS)
    log.write([5000, 1.25, 1.5, 0.1 + 0.2, 0.0, 57.0])
    assert (tmp_path / "eval.csv").read_text() == (
        "step,wall_s,cpu_s,return_mean,return_std,length_mean\n"
        "5000,1.25,1.5,0.30000000000000004,0.0,57.0\n"
    )
    with pytest.raises(ValueError, match="6 columns"):
        log.write([1, 2])
    log.close()


def test_a_digest_a_checkpoint_records_is_of_rows_synced_to_the_device(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Rows were flushed to the OS but not synced before the manifest that records them was:
    a power loss could keep the manifest and lose the rows, and the resume would refuse."""
    log = runs.CsvLog(tmp_path / "train.csv", runs.TRAIN_COLUMNS)
    log.write([10, 0.1, 1.0, 10])
    synced: list[int] = []
    monkeypatch.setattr(runs.files.os, "fsync", synced.append)
    log.digest()
    assert synced == [log._handle.fileno()]
    log.close()


def test_reopening_keeps_the_checked_bytes_and_continues_the_digest(tmp_path: Path) -> None:
    path = tmp_path / "train.csv"
    log = runs.CsvLog(path, runs.TRAIN_COLUMNS)
    log.write([10, 0.1, 1.0, 10])
    log.write([20, 0.2, 2.0, 10])
    kept = path.read_bytes()
    log.write([30, 0.3, 3.0, 10])
    log.close()
    with path.open("a") as handle:
        handle.write("40,0.4")  # a torn line
    reopened = runs.CsvLog(path, runs.TRAIN_COLUMNS, kept)
    reopened.write([25, 0.25, 2.5, 5])
    reopened.close()
    assert path.read_text() == (
        "step,wall_s,return,length\n10,0.1,1.0,10\n20,0.2,2.0,10\n25,0.25,2.5,5\n"
    )
    fresh = runs.CsvLog(tmp_path / "fresh.csv", runs.TRAIN_COLUMNS)
    for row in ([10, 0.1, 1.0, 10], [20, 0.2, 2.0, 10], [25, 0.25, 2.5, 5]):
        fresh.write(row)
    assert fresh.digest().rows == 3
    assert fresh.digest().sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    fresh.close()


def _run(tmp_path: Path, state: str, step: int, config: dict | None = None) -> Path:
    directory = tmp_path / "run"
    directory.mkdir(exist_ok=True)
    runs.atomic_write_json(directory / "config.json", {"config": config or CONFIG})
    runs.atomic_write_json(
        directory / "status.json", {"state": state, "step": step, "reason": "nan in loss_v"}
    )
    (directory / "checkpoint").mkdir(exist_ok=True)  # the generation its step stands for
    (directory / "checkpoint" / f"manifest-{step:012d}.json").write_text("{}")
    return directory


def test_plan_new_directory_starts(tmp_path: Path) -> None:
    plan = runs.plan_run(tmp_path / "new", CONFIG, resume=False, force=False)
    assert plan.action == "start"


def test_plan_complete_run_is_skipped_unless_forced(tmp_path: Path) -> None:
    directory = _run(tmp_path, "complete", 1000)
    plan = runs.plan_run(directory, CONFIG, resume=True, force=False)
    assert plan.action == "skip"
    assert "already complete (1000 steps)" in plan.message
    assert runs.plan_run(directory, CONFIG, resume=False, force=True).action == "start"


def test_plan_failed_run_is_skipped_with_its_reason(tmp_path: Path) -> None:
    plan = runs.plan_run(_run(tmp_path, "failed", 700), CONFIG, resume=True, force=False)
    assert (plan.action, plan.message) == (
        "skip",
        "failed at step 700: nan in loss_v; --force retrains it",
    )


def test_plan_unfinished_run_needs_resume(tmp_path: Path) -> None:
    directory = _run(tmp_path, "running", 500)
    with pytest.raises(TacbenchError, match=r"unfinished run \(step 500\)\. Add --resume"):
        runs.plan_run(directory, CONFIG, resume=False, force=False)
    assert runs.plan_run(directory, CONFIG, resume=True, force=False).action == "resume"


def test_plan_refuses_another_config_naming_the_fields(tmp_path: Path) -> None:
    directory = _run(tmp_path, "running", 500)
    new = {**CONFIG, "q": 2.0, "alpha": 0.1}
    with pytest.raises(TacbenchError) as err:
        runs.plan_run(directory, new, resume=True, force=False)
    assert "alpha: 0.2 -> 0.1; q: 1.5 -> 2.0" in str(err.value)
    assert "--force" in str(err.value)
    neutral = {**CONFIG, "device": "cuda"}
    assert runs.plan_run(
        directory, neutral, resume=True, force=False, neutral=["device"]
    ).action == ("resume")


def test_a_run_written_before_a_setting_existed_reads_it_as_its_default(tmp_path: Path) -> None:
    """The published studies' configs lack the settings added since (matmul_precision, the
    density settings, ...): running their own commands again was refused for every run."""
    config = RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, seed=0)
    older = config.to_dict()
    for name in ("matmul_precision", "density_cap", "q_range", "alpha_mode", "target_entropy"):
        del older[name]
    directory = _run(tmp_path, "running", 500, older)
    with pytest.raises(TacbenchError, match=r"matmul_precision: '\(absent\)' -> 'float32'"):
        runs.plan_run(directory, config.to_dict(), resume=True, force=False)
    plan = runs.plan_run(directory, config.to_dict(), resume=True, force=False, read_as=config)
    assert plan.action == "resume"
    # as tacbench run plans it (the command path the published studies failed on)
    out = tmp_path / "out"
    in_place = runs.run_directory(out, config.algo, config.env, config.variant, config.seed)
    shutil.copytree(directory, in_place)
    skipped, active = runs.plan_runs([config], out, resume=True, force=False)
    assert not skipped and active == [(config, in_place)]
    # a value other than the default is another run, named so
    bf16 = RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, seed=0, density_cap="off")
    with pytest.raises(TacbenchError, match=r"density_cap: 'paper' -> 'off'"):
        runs.plan_run(directory, bf16.to_dict(), resume=True, force=False, read_as=bf16)
    # a default that the new config's other settings refuse stays absent: the run differs
    # (alpha_mode's default, fixed, refuses a target entropy; target_entropy's, None, is read)
    auto = RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, seed=0, alpha_mode="auto")
    auto = RunConfig(**{**auto.to_dict(), "target_entropy": -3.0})
    with pytest.raises(TacbenchError) as refused:
        runs.plan_run(directory, auto.to_dict(), resume=True, force=False, read_as=auto)
    assert "alpha_mode: '(absent)' -> 'auto'; target_entropy: None -> -3.0" in str(refused.value)


def test_run_writer_files(tmp_path: Path) -> None:
    writer = runs.RunWriter(tmp_path / "run", ["loss"])
    run = RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, seed=10)
    metadata = runs.run_metadata(run, "tacbench run --env Hopper-v4", run.q, members=[])
    writer.open(metadata, None)
    writer.eval_row(5000, SimpleNamespace(wall_s=1.0, cpu_s=0.75), [1.0, 3.0], [10, 20])
    writer.train_row(17, 0.5, 12.5, 17)
    writer.losses_row(1000, [0.25])
    writer.status("failed", 1200, "non-finite loss_v")
    writer.close()
    directory = tmp_path / "run"
    config = json.loads((directory / "config.json").read_text())
    assert config["config"] == run.to_dict()
    assert list(config)[:8] == [
        "algo",
        "env",
        "variant",
        "seed",
        "q",
        "alpha",
        "total_steps",
        "members",
    ]
    assert (config["algo"], config["variant"], config["seed"], config["q"]) == (
        "tac",
        run.variant,
        10,
        1.5,
    )
    assert config["command"] == "tacbench run --env Hopper-v4"
    assert set(config["versions"]) == {"python", *runs.VERSIONED_PACKAGES}
    assert config["versions"]["sb3_contrib"]  # TRPO's library: a TRPO run did not record it
    assert {"git_commit", "host", "created"} <= set(config)
    assert (directory / "eval.csv").read_text().splitlines()[1] == "5000,1.0,0.75,2.0,1.0,15.0"
    assert (directory / "train.csv").read_text().splitlines()[1] == "17,0.5,12.5,17"
    assert (directory / "losses.csv").read_text().splitlines() == ["step,loss", "1000,0.25"]
    status = json.loads((directory / "status.json").read_text())
    assert status["state"] == "failed"
    assert status["step"] == 1200
    assert status["reason"] == "non-finite loss_v"


def test_plain_progress_prints_a_line_per_interval() -> None:
    stream = io.StringIO()
    progress = Progress("TAC Hopper-v4", 3000, 0, 1000, quiet=False, stream=stream)
    for step in range(1, 3001):
        progress.update(step, 42.5 if step % 1000 == 0 else None)
    progress.close()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 3
    assert lines[0].startswith("TAC Hopper-v4: step 1000/3000 | ")
    assert "steps/s | eval 42.5 | ETA" in lines[0]


def test_plain_progress_without_an_evaluation_before_the_end_prints_every_5_percent() -> None:
    """--eval-every above --steps: a long run printed nothing until it ended."""
    for every in (0, 3000, 5000):
        stream = io.StringIO()
        progress = Progress("TAC", 3000, 0, every, quiet=True, stream=stream)
        for step in range(1, 3001):
            progress.update(step, None)
        progress.close()
        lines = stream.getvalue().splitlines()
        assert len(lines) == 20 and lines[0].startswith("TAC: step 150/3000 | "), every


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _train(progress: Progress, clock: list[float], learning_from: int, steps: int = 3000) -> None:
    """Steps on a fake clock (in exact binary fractions): warm-up steps take about 1 ms,
    learning steps 8 times as long."""
    for step in range(1, steps + 1):
        clock[0] += 1 / 1024 if step < learning_from else 1 / 128
        progress.update(step, None, learning=step >= learning_from)


def test_the_eta_counts_learning_steps_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """The warm-up's random steps are many times faster than learning steps: an ETA from a
    window that mixes them said a tenth of a run's time (2m35s for 24 minutes)."""
    clock = [0.0]
    monkeypatch.setattr("tacbench.progress.time.perf_counter", lambda: clock[0])
    stream = io.StringIO()
    _train(Progress("TAC", 3000, 0, 1000, quiet=False, stream=stream), clock, 501)
    etas = [line.split("| ETA ")[1] for line in stream.getvalue().splitlines()]
    assert etas == ["0m15s", "0m07s", "0m00s"]  # mixed with the warm-up, the first said 0m08s

    stream = io.StringIO()
    _train(Progress("TAC", 3000, 0, 1000, quiet=False, stream=stream), clock, 1501)
    assert stream.getvalue().splitlines()[0].endswith("| ETA - (warm-up)")

    bar = Progress("TAC", 3000, 0, 1000, quiet=False, stream=_Terminal())
    _train(bar, clock, 1501, steps=2000)  # the bar's rate: its last 2,000 steps, 1,500 warm-up
    bar.close()
    assert bar._bar.tasks[0].fields["eta"] == "0m07s"


def test_check_writable_probes_without_creating_anything(tmp_path: Path) -> None:
    runs.check_writable(tmp_path / "new" / "deeper")  # its nearest existing folder takes files
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "afile").write_text("")
    with pytest.raises(TacbenchError, match=r"cannot create or write the output folder .*--json"):
        runs.check_writable(tmp_path / "afile" / "sub", "--json")


def test_a_group_change_is_told_whatever_the_members_recorded() -> None:
    """A member resuming in another group than it trained in: its products round otherwise.
    An older config.json lists the seeds alone, and a damaged one anything: neither may stop
    a resume (a list of seeds was an AttributeError traceback)."""
    a, b = {"q": 1.5, "alpha": 0.2, "seed": 0}, {"q": 1.5, "alpha": 0.2, "seed": 10}
    changed = "the members resume in another group than they trained in"
    assert runs.group_changes([a, b], [a, b]) == []
    assert runs.group_changes([b, a], [a, b]) == []  # the order is not the group
    assert changed in runs.group_changes([a, b], [a])[0]  # one failed
    assert changed in runs.group_changes([a], [a, b])[0]  # a solo run resumed in a group
    assert runs.group_changes([0, 10], [a, b]) == []  # an older config.json: seeds alone
    assert changed in runs.group_changes([0], [a, b])[0]
    assert changed in runs.group_changes([{"seed": 0}, "x"], [a, b])[0]  # damaged: told
    assert runs.group_changes(None, [a]) == [] and runs.group_changes([a], []) == []
