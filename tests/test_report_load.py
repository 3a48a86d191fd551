"""Loading run directories: the tidy frame, partial runs, and what is skipped and why."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tacbench.errors import TacbenchError
from tacbench.report.load import TIDY_COLUMNS, find_run_dirs, load_runs
from tests.report_fixtures import write_run

pytestmark = pytest.mark.unit


def _tac(root: Path, seed: int = 0, **kwargs: object) -> Path:
    args: dict[str, object] = {
        "algo": "tac",
        "env": "Hopper-v4",
        "variant": "q1.5-a0.2",
        "seed": seed,
        "q": 1.5,
        "alpha": 0.2,
        "steps": [100, 200, 300],
        "returns": [1.0, 2.0, 3.0],
    }
    args.update(kwargs)
    return write_run(root, **args)  # type: ignore[arg-type]


def test_tidy_frame_has_the_contract_columns_and_values(tmp_path: Path) -> None:
    _tac(tmp_path)
    write_run(
        tmp_path,
        algo="td3",
        env="Hopper-v4",
        variant="default",
        seed=3,
        steps=[100, 200],
        returns=[5.0, 7.0],
    )
    runset = load_runs(tmp_path)
    assert tuple(runset.data.columns) == TIDY_COLUMNS
    assert len(runset.data) == 5 and len(runset.runs) == 2 and not runset.skipped
    td3 = runset.data[runset.data["algo"] == "td3"]
    assert td3["return"].tolist() == [5.0, 7.0]
    assert td3["step"].tolist() == [100.0, 200.0]
    assert td3["wall_s"].tolist() == [1.0, 2.0]
    assert td3["q"].isna().all() and td3["alpha"].isna().all()
    assert set(td3["seed"]) == {3}
    tac = runset.runs[runset.runs["algo"] == "tac"].iloc[0]
    assert (tac["q"], tac["alpha"], tac["variant"]) == (1.5, 0.2, "q1.5-a0.2")
    assert tac["command"].startswith("tacbench run --algo tac")
    assert json.loads(tac["versions"])["torch"] == "2.13.0"
    assert runset.root == tmp_path / "runs"


def test_train_metric_reads_training_episodes(tmp_path: Path) -> None:
    _tac(tmp_path, train=([50, 120, 130], [-1.0, 4.0, 6.0]))
    runset = load_runs(tmp_path, metric="train")
    assert runset.data["step"].tolist() == [50.0, 120.0, 130.0]
    assert runset.data["return"].tolist() == [-1.0, 4.0, 6.0]


HEADER = "step,wall_s,return_mean,return_std,length_mean\n"


def test_non_finite_rows_are_dropped(tmp_path: Path) -> None:
    path = _tac(tmp_path)
    (path / "eval.csv").write_text(
        "step,wall_s,return_mean,return_std,length_mean\n"
        "100,1,1.0,0,1\n200,2.5,2.5,0,1\n300,3,nan,0,1\n400,4,4.0,0,1\n"
    )
    runset = load_runs(tmp_path)
    assert runset.data["step"].tolist() == [100.0, 200.0, 400.0]
    assert runset.data["return"].tolist() == [1.0, 2.5, 4.0]
    run = runset.runs.iloc[0]
    assert (run["rows"], run["dropped"]) == (3, 1)
    assert (
        run["note"]
        == "eval.csv: 1 row with a non-finite step or return left out, the last at step 300"
    )


def test_non_finite_last_rows_are_dropped_not_taken_for_lost_rows(tmp_path: Path) -> None:
    """Two diverged last evaluations read as rows lost from the end of the file ("restore the
    file"): they were logged, so the run is whole, its non-finite rows dropped and counted."""
    path = _tac(tmp_path, status_step=400, total_steps=400)
    (path / "eval.csv").write_text(
        HEADER + "100,1,1.0,0,1\n200,2,2.0,0,1\n300,3,-inf,0,1\n400,4,nan,0,1\n"
    )
    runset = load_runs(tmp_path)
    assert not runset.skipped
    assert runset.runs["dropped"].tolist() == [2] and not runset.runs["partial"].iloc[0]
    assert runset.runs["note"].iloc[0] == (
        "eval.csv: 2 rows with a non-finite step or return left out, the last at step 400"
    )
    (path / "eval.csv").write_text(HEADER + "100,1,1.0,0,1\nnan,2,2.0,0,1\n400,4,4.0,0,1\n")
    run = load_runs(tmp_path).runs.iloc[0]  # a non-finite step counts too, with no step to name
    assert (run["rows"], run["dropped"]) == (2, 1)
    assert run["note"] == "eval.csv: 1 row with a non-finite step or return left out"


@pytest.mark.parametrize(
    ("rows", "reason"),
    [
        (
            "100,1,1.0,0,1\n200,2,2.0,0,1\n1500,16.62,9",
            "eval.csv ends in a torn line '1500,16.62,9'",
        ),
        ("100,1,1.0,0,1\n200,2\n300,3,3.0,0,1\n", "eval.csv line 3 has 2 fields, not 5"),
        ("100,1,1.0,0,1\n200,2,x,0,1\n", "eval.csv line 3 is not numbers: '200,2,x,0,1'"),
        ("100,1,1.0,0,1\n100,1,1.0,0,1\n", "eval.csv line 3: step 100 does not follow step 100"),
        ("200,2,2.0,0,1\n100,1,1.0,0,1\n", "eval.csv line 3: step 100 does not follow step 200"),
    ],
)
def test_a_run_with_a_torn_or_inconsistent_row_is_skipped_with_the_line(
    tmp_path: Path, rows: str, reason: str
) -> None:
    _tac(tmp_path, seed=0)
    (_tac(tmp_path, seed=1) / "eval.csv").write_text(HEADER + rows)
    runset = load_runs(tmp_path)
    assert runset.runs["seed"].tolist() == [0]
    assert len(runset.skipped) == 1 and runset.skipped[0].reason.startswith(reason)


def test_a_running_runs_torn_last_line_is_dropped_as_a_writer_leaves_it(tmp_path: Path) -> None:
    path = _tac(tmp_path, state="running", status_step=200, total_steps=1000)
    (path / "eval.csv").write_text(HEADER + "100,1,1.0,0,1\n200,2,2.0,0,1\n300,3,3")
    runset = load_runs(tmp_path)
    assert runset.data["return"].tolist() == [1.0, 2.0] and not runset.skipped
    assert runset.runs["partial"].tolist() == [True]
    assert runset.runs["note"].tolist() == [
        "eval.csv: its torn last line, still being written, left out"
    ]


def test_a_run_planned_shorter_than_its_methods_others_is_partial(tmp_path: Path) -> None:
    _tac(tmp_path, seed=0, steps=[500, 1000, 1500], total_steps=1500)
    _tac(tmp_path, seed=1, steps=[1000, 3000, 5500], total_steps=5500)
    runs = load_runs(tmp_path).runs.set_index("seed")
    assert runs.loc[0, "partial"] and not runs.loc[1, "partial"]


def test_the_runs_folder_is_preferred_and_bare_trees_work(tmp_path: Path) -> None:
    _tac(tmp_path)
    _tac(tmp_path / "reference", seed=1)
    assert len(load_runs(tmp_path).runs) == 1
    bare = tmp_path / "copied"
    _tac(bare, seed=2)
    (bare / "runs").rename(bare / "elsewhere")
    runset = load_runs(bare)
    assert runset.runs["seed"].tolist() == [2]


def test_run_dirs_are_not_searched_below(tmp_path: Path) -> None:
    path = _tac(tmp_path)
    _tac(path / "checkpoint", seed=9)
    assert find_run_dirs(tmp_path / "runs") == [path]


def test_partial_runs_are_included_and_flagged(tmp_path: Path) -> None:
    _tac(tmp_path, seed=0, state="running", status_step=350, total_steps=1000)
    _tac(tmp_path, seed=1, state="complete", total_steps=1000)
    _tac(tmp_path, seed=2, state="complete", total_steps=300)
    no_status = _tac(tmp_path, seed=3, total_steps=300)
    (no_status / "status.json").unlink()
    runs = load_runs(tmp_path).runs.set_index("seed")
    assert runs.loc[0, "partial"] and runs.loc[0, "step_reached"] == 350
    assert runs.loc[0, "state"] == "running"
    assert runs.loc[1, "partial"] and runs.loc[1, "step_reached"] == 300
    assert runs.loc[2, "partial"]  # complete, but planned 300 steps beside runs of 1,000
    assert runs.loc[3, "partial"] and runs.loc[3, "state"] == "unknown"


def test_failed_unreadable_and_duplicate_runs_are_skipped_with_reasons(tmp_path: Path) -> None:
    _tac(tmp_path, seed=0)
    _tac(tmp_path, seed=1, state="failed", status_step=200, reason="NaN in critic loss")
    (_tac(tmp_path, seed=2) / "config.json").write_text("{not json")
    config = _tac(tmp_path, seed=3) / "config.json"
    config.write_text(json.dumps({**json.loads(config.read_text()), "seed": "three"}))
    (_tac(tmp_path, seed=4) / "eval.csv").unlink()
    (_tac(tmp_path, seed=5) / "eval.csv").write_text("step,wall_s,return_mean\n")
    (_tac(tmp_path, seed=9, state="running") / "eval.csv").write_text("step,wall_s,return_mean\n")
    (_tac(tmp_path, seed=6) / "eval.csv").write_text("step,reward\n1,2\n")
    (_tac(tmp_path, seed=7) / "eval.csv").write_text("")
    duplicate = _tac(tmp_path / "copy", seed=0).parent.parent.parent.parent.parent
    (duplicate / "runs").rename(tmp_path / "runs" / "zz-copy")
    config = _tac(tmp_path, seed=8) / "config.json"
    config.write_text(json.dumps({**json.loads(config.read_text()), "q": None}))

    runset = load_runs(tmp_path)
    assert runset.runs["seed"].tolist() == [0]
    reasons = {
        s.path.split("/")[-1] + ("-copy" if "zz" in s.path else ""): s for s in runset.skipped
    }
    assert reasons["seed1"].reason == "run failed at step 200: NaN in critic loss"
    assert reasons["seed1"].identity is not None and reasons["seed1"].identity["q"] == 1.5
    assert reasons["seed2"].reason.startswith("config.json unreadable")
    assert reasons["seed3"].reason == "config.json: 'seed' missing or not an integer"
    assert reasons["seed4"].reason == "eval.csv missing"
    assert reasons["seed5"].reason.startswith("eval.csv has no rows (the run made no evaluation")
    assert reasons["seed9"].reason == "eval.csv has no rows yet"  # still running
    assert reasons["seed6"].reason.startswith("eval.csv unreadable")
    assert reasons["seed7"].reason == "eval.csv is empty"
    assert reasons["seed8"].reason == "config.json: a TAC run needs a number q > 0"
    assert reasons["seed0-copy"].reason.startswith("duplicate of tac/Hopper-v4/q1.5-a0.2/seed0")
    assert len(runset.skipped) == 10


def test_of_duplicates_the_run_that_trained_further_is_kept(tmp_path: Path) -> None:
    """The first path in sorted order was kept, though it was an interrupted copy and the
    other complete: the complete one was skipped as its duplicate."""
    early = _tac(tmp_path / "a", state="interrupted", status_step=200, total_steps=300)
    (early / "eval.csv").write_text(HEADER + "100,1,1.0,0,1\n200,2,2.0,0,1\n")
    _tac(tmp_path / "b", status_step=300, total_steps=300)
    runset = load_runs(tmp_path)
    assert runset.runs["path"].tolist() == ["b/runs/tac/Hopper-v4/q1.5-a0.2/seed0"]
    assert not runset.runs["partial"].iloc[0] and runset.data["step"].max() == 300
    (skipped,) = runset.skipped
    assert skipped.path == "a/runs/tac/Hopper-v4/q1.5-a0.2/seed0"
    assert skipped.reason.startswith("duplicate of b/runs/tac/Hopper-v4/q1.5-a0.2/seed0")

    # of two partial copies the one that reached more steps; a complete copy before a partial
    # one that reached more (planned longer)
    def kept(*copies: tuple[str, dict[str, object]]) -> str:
        root = tmp_path / "-".join(name for name, _ in copies)
        for name, settings in copies:
            _tac(root / name, **settings)
        (path,) = load_runs(root).runs["path"]
        return str(path).split("/")[0]

    partial = {"state": "interrupted", "total_steps": 300, "returns": [1.0, 2.0]}
    fewer = {**partial, "status_step": 100, "steps": [50, 100]}
    assert kept(("f", fewer), ("g", {**partial, "status_step": 200, "steps": [100, 200]})) == "g"
    longer = {"state": "interrupted", "status_step": 400, "total_steps": 500}
    assert kept(("h", longer), ("i", {"status_step": 300, "total_steps": 300})) == "i"


def test_a_failed_run_with_a_rerun_or_a_failed_copy_is_counted_once(tmp_path: Path) -> None:
    """A failed seed rerun to completion in another folder was counted twice: as a seed, and
    as a failure of its method (5 seeds and 1 failed for 5 identities)."""
    failure = {"state": "failed", "status_step": 200, "reason": "NaN in critic loss"}
    _tac(tmp_path / "a", **failure)
    _tac(tmp_path / "b")
    _tac(tmp_path / "a", seed=1, **failure)
    _tac(tmp_path / "b", seed=1, **failure)
    runset = load_runs(tmp_path)
    assert runset.runs["path"].tolist() == ["b/runs/tac/Hopper-v4/q1.5-a0.2/seed0"]
    reasons = {s.path: s for s in runset.skipped}
    rerun = reasons["a/runs/tac/Hopper-v4/q1.5-a0.2/seed0"]
    assert rerun.identity is None
    assert rerun.reason == (
        "duplicate of b/runs/tac/Hopper-v4/q1.5-a0.2/seed0 (same algo, env, variant, seed); "
        "run failed at step 200: NaN in critic loss"
    )
    assert reasons["a/runs/tac/Hopper-v4/q1.5-a0.2/seed1"].identity is not None
    copy = reasons["b/runs/tac/Hopper-v4/q1.5-a0.2/seed1"]
    assert copy.identity is None
    assert copy.reason.startswith("duplicate of a/runs/tac/Hopper-v4/q1.5-a0.2/seed1 (same")
    assert [s.identity["seed"] for s in runset.skipped if s.identity] == [1]


def test_no_runs_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(TacbenchError, match="does not exist"):
        load_runs(tmp_path / "missing")
    (tmp_path / "runs").mkdir()
    with pytest.raises(TacbenchError, match="no run directories under"):
        load_runs(tmp_path)
    (_tac(tmp_path) / "eval.csv").unlink()
    with pytest.raises(TacbenchError, match=r"none of the 1 run directories .*eval.csv missing"):
        load_runs(tmp_path)


@pytest.mark.parametrize("where", [".", "exact/x86_64-some-class"])
def test_regression_references_are_not_mistaken_for_damaged_runs(
    tmp_path: Path, where: str
) -> None:
    """The report used to advise fixing or removing references that had no config.json."""
    tier = tmp_path / where
    run = tier / "tac-Hopper-v4-q1"
    run.mkdir(parents=True)
    (run / "eval.csv").write_text("step,mean_return\n")
    (tier / "manifest.json").write_text('{"tier": "exact", "format": 1}')
    with pytest.raises(TacbenchError, match=r"regress`'s exact references \(.*manifest.json\)"):
        load_runs(tmp_path)


def test_a_run_folder_may_hold_other_manifests(tmp_path: Path) -> None:
    (_tac(tmp_path) / "manifest.json").write_text('["not a tier"]')
    assert len(load_runs(tmp_path).runs) == 1


def test_unknown_metric_is_a_user_error(tmp_path: Path) -> None:
    _tac(tmp_path)
    with pytest.raises(TacbenchError, match="unknown metric"):
        load_runs(tmp_path, metric="test")  # type: ignore[arg-type]


def test_step_reached_uses_the_later_of_status_and_data(tmp_path: Path) -> None:
    _tac(tmp_path, state="running", status_step=120, total_steps=1000)
    runs = load_runs(tmp_path).runs
    assert runs["step_reached"].iat[0] == 300
    assert math.isclose(float(np.asarray(runs["total_steps"])[0]), 1000.0)


def test_a_complete_run_whose_evaluations_stop_short_of_its_end_is_skipped(
    tmp_path: Path,
) -> None:
    """A complete run's eval.csv cut at a line boundary (rows lost) would give an early final
    return as its final: it is skipped with the reason, as a damaged file is; so is a run whose
    config.json gives no step count. Evaluations ending within one interval of the end are
    whole (a budget that is not a multiple of the evaluation interval)."""
    _tac(tmp_path, seed=0, status_step=350, total_steps=350)  # every 100, the last at 300
    _tac(tmp_path, seed=1, status_step=1000, total_steps=1000)  # 300 of 1000: rows lost
    _tac(tmp_path, seed=2, steps=[100], returns=[1.0], status_step=1000, total_steps=1000)
    _tac(tmp_path, seed=3, state="interrupted", status_step=1000, total_steps=1000)  # partial
    config = _tac(tmp_path, seed=4) / "config.json"
    config.write_text(json.dumps({**json.loads(config.read_text()), "total_steps": "lots"}))
    runset = load_runs(tmp_path)
    assert runset.runs["seed"].tolist() == [0, 3]
    reasons = {s.path.split("/")[-1]: s.reason for s in runset.skipped}
    assert reasons["seed1"] == (
        "eval.csv ends at step 300, though the run completed 1,000 steps and evaluates every "
        "100 at most: its last rows were lost; restore the file"
    )
    assert reasons["seed2"].startswith("eval.csv ends at step 100, though the run completed 1,000")
    assert reasons["seed4"] == "config.json: 'total_steps' is 'lots', not a step count"


def test_a_complete_runs_training_episodes_cut_short_are_skipped(tmp_path: Path) -> None:
    """With --metric train a complete run whose train.csv lost its last 80,000 steps of
    episodes was scored by its early returns: episodes must reach the end to within twice the
    task's time limit (the unfinished last one is never logged, a resume may drop one more;
    Hopper's limit is 1,000 steps)."""
    steps = list(range(1000, 100_001, 1000))
    cut = steps[:20]
    _tac(tmp_path, seed=0, steps=steps, returns=[1.0] * 100, train=(cut, [1.0] * 20))
    # its last episode unfinished at the end, and one more dropped by a resume just before
    _tac(tmp_path, seed=1, steps=steps, returns=[1.0] * 100, train=(steps[:-2], [1.0] * 98))
    _tac(tmp_path, seed=2, steps=steps, returns=[1.0] * 100, train=(steps[:-3], [1.0] * 97))
    runset = load_runs(tmp_path, metric="train")
    assert runset.runs["seed"].tolist() == [1]
    reasons = {s.path[-5:]: s.reason for s in runset.skipped}
    assert reasons["seed0"] == (
        "train.csv ends at step 20,000, though the run completed 100,000 steps and its "
        "episodes last at most 1,000 steps (the time limit; twice that allowed): its last rows "
        "were lost; restore the file"
    )
    assert reasons["seed2"].startswith("train.csv ends at step 97,000, though")
