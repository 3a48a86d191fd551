"""What the trainers and the sweep share: planning a call's run directories and stop signals."""

from __future__ import annotations

import dataclasses
import os
import signal
from pathlib import Path

import pytest

from tacbench import interrupts, runs
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.interrupts import stop_signals
from tacbench.runs import plan_runs

pytestmark = pytest.mark.unit


def _configs(*seeds: int) -> list[RunConfig]:
    return [RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, seed=seed) for seed in seeds]


def _store(directory: Path, config: RunConfig, state: str, step: int) -> None:
    directory.mkdir(parents=True)
    runs.atomic_write_json(directory / "config.json", {"config": config.to_dict()})
    runs.atomic_write_json(directory / "status.json", {"state": state, "step": step})


def test_plan_runs_skips_complete_runs_and_empties_the_ones_that_start_afresh(
    tmp_path: Path,
) -> None:
    done, fresh, forced = _configs(0, 10, 20)
    folder = {
        c.seed: runs.run_directory(tmp_path, c.algo, c.env, c.variant, c.seed)
        for c in (done, fresh, forced)
    }
    _store(folder[0], done, "complete", 1000)
    _store(folder[20], forced, "failed", 10)
    (folder[20] / "leftover.csv").write_text("x\n")
    skipped, active = plan_runs([done, fresh], tmp_path, resume=False, force=False)
    assert [(o.seed, o.state) for o in skipped] == [(0, "skipped")]
    assert "already complete" in skipped[0].message
    assert active == [(fresh, folder[10])]
    _, active = plan_runs([forced], tmp_path, resume=False, force=True)
    assert active == [(forced, folder[20])] and not folder[20].exists()


def test_plan_runs_refuses_an_unfinished_run_without_resume_and_touches_nothing(
    tmp_path: Path,
) -> None:
    (config,) = _configs(0)
    directory = runs.run_directory(tmp_path, config.algo, config.env, config.variant, 0)
    _store(directory, config, "running", 500)
    (directory / "checkpoint").mkdir()
    (directory / "checkpoint" / "manifest-000000000500.json").write_text("{}")
    with pytest.raises(TacbenchError, match="--resume"):
        plan_runs([config], tmp_path, resume=False, force=False)
    assert (directory / "status.json").exists()
    _, active = plan_runs([config], tmp_path, resume=True, force=False)
    assert active == [(config, directory)] and (directory / "status.json").exists()


@pytest.mark.parametrize("state", ["paused", None, 3])
def test_a_status_of_an_unknown_state_is_refused_not_resumed(
    tmp_path: Path, state: str | int | None
) -> None:
    """It was treated as an unfinished run: --resume continued it, whatever it was."""
    (config,) = _configs(0)
    directory = runs.run_directory(tmp_path, config.algo, config.env, config.variant, 0)
    _store(directory, config, "running", 500)
    status = {"step": 500} if state is None else {"state": state, "step": 500}
    runs.atomic_write_json(directory / "status.json", status)
    before = (directory / "status.json").read_bytes()
    shown = "None" if state is None else repr(state)
    for resume in (True, False):
        with pytest.raises(TacbenchError, match=rf"the state {shown}, not one of running, "):
            plan_runs([config], tmp_path, resume=resume, force=False)
    assert (directory / "status.json").read_bytes() == before


def test_a_resume_with_other_settings_quotes_the_runs_own_command(tmp_path: Path) -> None:
    """Resuming without a setting the run was started with (--steps) differs from its config:
    the refusal says how to continue it, not only how to delete it."""
    (config,) = _configs(0)
    directory = runs.run_directory(tmp_path, config.algo, config.env, config.variant, 0)
    short = dataclasses.replace(config, total_steps=30_000)
    _store(directory, short, "interrupted", 500)
    command = "tacbench run --env Hopper-v4 --q 1.5 --steps 30000"
    runs.atomic_write_json(
        directory / "config.json", {"config": short.to_dict(), "command": command}
    )
    with pytest.raises(TacbenchError) as refused:
        plan_runs([config], tmp_path, resume=True, force=False)
    here = f"{command} --out {tmp_path} --resume"  # the default folder, named: it may move
    assert f"To continue it, repeat its own command: {here}; or pass --force" in str(refused.value)
    with pytest.raises(TacbenchError, match=r"1000000\)\. Pass --force to replace it"):
        plan_runs([config], tmp_path, resume=False, force=False)
    # recorded with an --out the results have since left: the advice names where they are now
    moved = "tacbench run --env Hopper-v4 --q 1.5 --steps 30000 --out /elsewhere"
    runs.atomic_write_json(directory / "config.json", {"config": short.to_dict(), "command": moved})
    with pytest.raises(TacbenchError) as refused:
        plan_runs([config], tmp_path, resume=True, force=False)
    here = f"tacbench run --env Hopper-v4 --q 1.5 --steps 30000 --out {tmp_path} --resume"
    assert f"repeat its own command: {here};" in str(refused.value)
    # made by a sweep: the sweep resumes it, run again as it was (it has no --resume)
    sweep = "tacbench sweep --preset smoke --steps 30000 --out /elsewhere"
    runs.atomic_write_json(directory / "config.json", {"config": short.to_dict(), "command": sweep})
    with pytest.raises(TacbenchError) as refused:
        plan_runs([config], tmp_path, resume=True, force=False)
    assert f"To continue it, run its sweep again: {sweep}; or pass --force" in str(refused.value)
    # a complete run has nothing to continue: no such advice
    runs.atomic_write_json(directory / "status.json", {"state": "complete", "step": 30_000})
    with pytest.raises(TacbenchError, match=r"1000000\)\. Pass --force to replace it"):
        plan_runs([config], tmp_path, resume=True, force=False)


def test_stop_signals_record_then_interrupt_on_the_second_and_restore_the_handlers() -> None:
    before = signal.getsignal(signal.SIGINT)
    with stop_signals() as received:
        os.kill(os.getpid(), signal.SIGTERM)
        assert received == {"count": 1, "signal": signal.SIGTERM}
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is before


def test_stop_signals_can_count_instead_of_interrupting(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(interrupts, "SAME_REQUEST_S", 0.0)  # a person's second Ctrl-C, later
    with stop_signals(second_interrupts=False) as received:
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)
    assert received == {"count": 2, "signal": signal.SIGINT}


def test_a_folder_without_config_json_is_kept_unless_it_holds_only_a_cut_write(
    tmp_path: Path,
) -> None:
    """A run writes config.json first: a folder without it that holds other files is not
    deleted to start afresh (they may be a run whose config.json was lost, or the user's);
    an empty folder, or one with only a crash's temporary file, starts afresh."""
    (config,) = _configs(0)
    directory = runs.run_directory(tmp_path, config.algo, config.env, config.variant, 0)
    directory.mkdir(parents=True)
    (directory / "status.json").write_text('{"state": "running", "step": 2275}')
    (directory / "notes.txt").write_text("mine")
    for resume in (False, True):
        with pytest.raises(TacbenchError, match=r"notes.txt, status.json but no config.json"):
            plan_runs([config], tmp_path, resume=resume, force=False)
    assert (directory / "notes.txt").read_text() == "mine"
    _, active = plan_runs([config], tmp_path, resume=False, force=True)  # --force: as asked
    assert active == [(config, directory)] and not directory.exists()
    directory.mkdir()
    (directory / "config.json.tmp").write_text("{")  # a crash inside the first write
    _, active = plan_runs([config], tmp_path, resume=True, force=False)
    assert active == [(config, directory)] and not directory.exists()


def test_a_folder_without_config_json_names_its_first_files_and_counts_the_rest(
    tmp_path: Path,
) -> None:
    (config,) = _configs(0)
    directory = runs.run_directory(tmp_path, config.algo, config.env, config.variant, 0)
    directory.mkdir(parents=True)
    for name in ("train.csv", "eval.csv", "status.json", "notes.txt", "losses.csv"):
        (directory / name).write_text("")
    with pytest.raises(
        TacbenchError, match=r"holds eval.csv, losses.csv, notes.txt and 2 more but no config"
    ):
        plan_runs([config], tmp_path, resume=True, force=False)


@pytest.mark.parametrize("kind", ["file", "link"])
def test_a_file_or_link_where_the_run_directory_goes_is_refused_and_kept(
    tmp_path: Path, kind: str
) -> None:
    (config,) = _configs(0)
    directory = runs.run_directory(tmp_path, config.algo, config.env, config.variant, 0)
    directory.parent.mkdir(parents=True)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    if kind == "file":
        directory.write_text("mine")
    else:
        directory.symlink_to(elsewhere)
    for force in (False, True):
        with pytest.raises(TacbenchError, match=f"is a {kind}, where this run's directory goes"):
            plan_runs([config], tmp_path, resume=False, force=force)
    assert directory.is_symlink() if kind == "link" else directory.read_text() == "mine"


def test_a_refused_member_leaves_the_others_forced_runs_in_place(tmp_path: Path) -> None:
    """--force emptied seed 0's complete run, then refused seed 1's folder, a file, saying
    that nothing was changed."""
    kept, refused = _configs(0, 1)
    directory = runs.run_directory(tmp_path, kept.algo, kept.env, kept.variant, 0)
    _store(directory, kept, "complete", 1000)
    runs.run_directory(tmp_path, kept.algo, kept.env, kept.variant, 1).write_text("mine")
    with pytest.raises(TacbenchError, match="nothing was changed"):
        plan_runs([kept, refused], tmp_path, resume=False, force=True)
    assert runs.read_json(directory / "status.json")["state"] == "complete"


@pytest.mark.parametrize(
    ("where", "says"),
    [
        ("runs/tac/Hopper-v4/q1.5-a0.2/seed0", "is the run directory"),
        ("runs/tac/Hopper-v4/q1.5-a0.2/seed0/more", "is inside the run directory"),
        ("runs", "is the runs/ folder of the results folder"),
        ("runs/tac/Hopper-v4", "is inside the runs/ folder of the results folder"),
    ],
)
def test_an_out_in_another_results_folders_runs_is_refused_and_nothing_written(
    tmp_path: Path, where: str, says: str
) -> None:
    """The new runs nested there (`<run>/runs/tac/...`, `runs/runs/tac/...`): a report of the
    folder above missed them, or loaded them and set the runs beside them aside as duplicates."""
    [config] = _configs(0)
    _store(tmp_path / "runs/tac/Hopper-v4/q1.5-a0.2/seed0", config, "complete", 100)
    before = sorted(tmp_path.rglob("*"))
    planned = runs.planned_runs(_configs(1), tmp_path / where, resume=False, force=False)
    with pytest.raises(TacbenchError, match=f"{says}.*give"), planned:
        pass
    assert sorted(tmp_path.rglob("*")) == before


def test_a_folder_named_runs_without_runs_in_it_is_a_results_folder_like_any(
    tmp_path: Path,
) -> None:
    with runs.planned_runs(_configs(0), tmp_path / "runs", resume=False, force=False) as planned:
        assert [directory for _, directory in planned[1]] == [
            tmp_path / "runs/runs/tac/Hopper-v4/q1.5-a0.2/seed0"
        ]


def test_a_project_folder_with_a_config_json_is_no_run_directory(tmp_path: Path) -> None:
    """Only a run directory (``seed<k>``) holding a config.json refuses an --out inside it."""
    (tmp_path / "config.json").write_text("{}")
    (tmp_path / "status.json").write_text("{}")
    runs.check_results_folder(tmp_path / "results")
