"""Sweep planning from run directories (counts, steps left, units), the failure history, the
lock, the cost estimate and the worker's helpers, on hand-made run directories."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
from click.testing import CliRunner

from tacbench import hardware, runs
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.members import resolve_compile
from tacbench.runs import Outcome, locks
from tacbench.sweep import cost, driver, dry_run, plan, state, summary, worker
from tacbench.sweep.presets import Narrowing, get_preset, narrow

pytestmark = pytest.mark.unit

SMOKE = get_preset("smoke")


def _fake_run(out: Path, run: plan.Run, status: dict[str, Any] | None, **config: Any) -> Path:
    directory = out / run.key
    directory.mkdir(parents=True)
    data = {**run.config.to_dict(), **config}
    if data.get("compile") == "auto":  # a run records what --compile auto resolved to
        data["compile"] = resolve_compile(run.config).compile
    runs.atomic_write_json(directory / "config.json", {"config": data, "members": [0]})
    if status is not None:
        runs.atomic_write_json(directory / "status.json", status)
        if status["state"] == "running" and status["step"]:  # its checkpoint, as a run leaves
            (directory / "checkpoint").mkdir()
            (directory / "checkpoint" / f"manifest-{status['step']:012d}.json").write_text("{}")
    return directory


def _plan(out: Path, options: driver.Options | None = None) -> plan.SweepPlan:
    return driver.load_plan(SMOKE, out, options or driver.Options(), save=False)[0]


@pytest.fixture
def smoke_out(tmp_path: Path) -> tuple[Path, list[plan.Run]]:
    """smoke's 8 runs: 1 complete, 1 partial at 500, 1 failed at 700 with its last checkpoint
    at 600, 5 not started."""
    all_runs = plan.build_runs(SMOKE)
    _fake_run(tmp_path, all_runs[0], {"state": "complete", "step": 1000})
    _fake_run(tmp_path, all_runs[1], {"state": "running", "step": 500})
    failed = {"state": "failed", "step": 700, "reason": "non-finite"}
    checkpoint = _fake_run(tmp_path, all_runs[4], failed) / "checkpoint"
    checkpoint.mkdir()
    (checkpoint / "manifest-000000000600.json").write_text("{}")
    return tmp_path, all_runs


def test_counts_and_steps_left_match_a_hand_count(smoke_out: tuple[Path, list[plan.Run]]) -> None:
    out, all_runs = smoke_out
    work = _plan(out)
    assert summary.counts(work) == {
        "runs": 8,
        "complete": 1,
        "partial": 1,
        "failed": 1,
        "new": 5,
        "to_retry": 1,
        "given_up": 0,
        "to_train": 7,
        "cannot_resume": 0,
    }
    assert summary.counts(work, refused={all_runs[1].key, all_runs[0].key})["cannot_resume"] == 1
    # the failed run's retry resumes at its checkpoint: 1000 - 600, not 1000 - 700
    assert work.steps_left() == 5 * 1000 + (1000 - 500) + (1000 - 600) == 5900
    assert [p.action for p in work.runs] == [
        "skip",
        "train",
        *["train"] * 2,
        "retry",
        *["train"] * 3,
    ]
    assert len(work.units) == 6  # the two new TAC runs (q2, both seeds) are members of one
    retry = [u for u in work.units if u.retry]
    assert retry == [plan.Unit((all_runs[4],), retry=(all_runs[4].key,))]
    text = dry_run.describe_plan(work, workers=2, group="none")
    assert "8 runs: 1 complete, 1 partial, 1 failed (1 to retry, 0 given up" in text
    assert "5 not started" in text
    assert "environment steps left: 5,900 of 8,000 (1,000 per run)" in text


def test_a_retried_run_counts_as_done_only_up_to_where_it_resumes(
    smoke_out: tuple[Path, list[plan.Run]],
) -> None:
    """The progress counted a failed run's 700 steps as done while its retry trained again from
    its checkpoint at 600 (the count never goes down): steps done ran ahead of the bar's total."""
    out, all_runs = smoke_out
    work, history = driver.load_plan(SMOKE, out, driver.Options(), save=False)
    sweep = driver._Driver(work, history, _DiedOfCtrlC({}), driver.Options(), stream=None)
    assert sweep.step[all_runs[4].key] == 600  # its status.json says 700
    assert sweep.step[all_runs[1].key] == 500 and sweep.step[all_runs[0].key] == 1000
    assert sum(sweep.step.values()) == 8000 - work.steps_left()


def test_a_sweep_refuses_runs_another_process_writes_before_it_trains(
    smoke_out: tuple[Path, list[plan.Run]],
) -> None:
    """Each attempt failed against the run's lock (a tacbench run into --out), counted as the
    run's failure: within seconds the sweep gave it up for good (state.json)."""
    out, all_runs = smoke_out
    busy = out / all_runs[1].key  # partial: this sweep would resume it
    assert locks.holder(busy) is None
    with locks.writing([busy]):
        assert locks.holder(busy) == f"PID {os.getpid()} on {socket.gethostname()}"
        before = sorted(p for p in out.rglob("*") if p.is_file())
        args = ["sweep", "--preset", "smoke", "--out", str(out)]
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 2, result.output
        told = " ".join(result.output.split())
        assert f"is being written by another tacbench process ({busy.relative_to(out)};" in told
        assert told.startswith("Error: 1 run of this sweep")
        assert not state.SweepState(out).failures(busy.relative_to(out).as_posix())
        written = sorted(p for p in out.rglob("*") if p.is_file() and "sweep" not in p.parts)
        assert written == [p for p in before if "sweep" not in p.parts]
    assert locks.holder(busy) is None  # released: the sweep may go on
    assert locks.holder(out / all_runs[2].key) is None  # a new run: no lock file, none made
    assert not locks.lock_path(out / all_runs[2].key).exists()


def test_a_run_failed_more_than_max_retries_is_given_up(
    smoke_out: tuple[Path, list[plan.Run]],
) -> None:
    out, all_runs = smoke_out
    history = state.SweepState(out)
    key = all_runs[4].key
    history.add_failure(key, 300, "worker process killed by SIGKILL")
    history.add_failure(key, 700, "non-finite")
    history.note_failed_status(key, 700, "non-finite")  # already the last one: not added again
    assert [f.step for f in state.SweepState(out).failures(key)] == [300, 700]
    work = _plan(out, driver.Options(max_retries=1))
    assert work.count(action="give-up") == 1 and work.count(action="retry") == 0
    assert work.steps_left() == 5000 + 500
    assert _plan(out, driver.Options(max_retries=2)).count(action="retry") == 1


def test_refusals_of_a_runs_files_do_not_count_towards_max_retries(tmp_path: Path) -> None:
    """A refused run needs its files fixed, not more retries: counted, it was given up after
    three sweeps (or at once with --max-retries 0) and stayed given up once they were fixed.
    A failure recorded before refusals were marked still reads, and counts."""
    (tmp_path / "sweep").mkdir()
    older = {"time": "2026-12-05T01:00:00+00:00", "host": "vm", "step": 300, "reason": "nan"}
    (tmp_path / "sweep" / "state.json").write_text(
        json.dumps({"runs": {"r": {"failures": [older]}}})
    )
    history = state.SweepState(tmp_path)
    history.add_failure("r", 300, "DamagedRun: cannot resume: ...", refused=True)
    history.add_failure("r", 300, "DamagedRun: cannot resume: ...", refused=True)
    assert [f.refused for f in state.SweepState(tmp_path).failures("r")] == [False, True, True]
    assert history.failure_counts() == {"r": 1} and history.attempts_failed("r") == 1


def test_a_failure_in_status_json_already_recorded_is_not_counted_again(tmp_path: Path) -> None:
    """A retry whose worker died before it reset status.json leaves the earlier failure there,
    behind the worker's own: it was counted again, and the run given up an attempt early."""
    history = state.SweepState(tmp_path)
    history.add_failure("run", 700, "non-finite loss_v")
    history.add_failure("run", 700, "worker process killed by SIGKILL")
    history.note_failed_status("run", 700, "non-finite loss_v")
    assert len(history.failures("run")) == 2
    history.note_failed_status("run", 900, "non-finite loss_v")  # a new failure: counted
    assert len(history.failures("run")) == 3


def test_another_config_in_a_run_directory_stops_the_plan(tmp_path: Path) -> None:
    run = plan.build_runs(SMOKE)[0]
    _fake_run(tmp_path, run, {"state": "running", "step": 0}, eval_every=123)
    with pytest.raises(TacbenchError, match=r"another config \(eval_every: 123 -> 500\)"):
        _plan(tmp_path)
    # result-neutral fields (threads, device, checkpoint_every) may differ
    other = tmp_path / "other"
    _fake_run(other, run, {"state": "running", "step": 0}, threads=4, checkpoint_every=7)
    assert _plan(other).runs[0].status == plan.Status("partial", 0)
    # a config.json without a run config: a one-line error, not a traceback
    config_json = tmp_path / run.key / "config.json"
    config_json.write_text(json.dumps({"config": "edited by hand"}))
    with pytest.raises(TacbenchError, match=r"holds no run config; restore it, or delete"):
        _plan(tmp_path)


def test_progress_no_checkpoint_holds_stops_the_plan(tmp_path: Path) -> None:
    """A partial run whose checkpoint was deleted (or whose status.json was, under rows
    already written) fails every attempt of its unit, which gave its healthy members up too:
    the plan stops first, saying what to do."""
    run = plan.build_runs(SMOKE)[0]
    directory = _fake_run(tmp_path, run, {"state": "running", "step": 500})
    shutil.rmtree(directory / "checkpoint")
    with pytest.raises(TacbenchError, match=r"status\.json records step 500, but .* holds no"):
        _plan(tmp_path)
    # Ray without a shared filesystem keeps checkpoints on its nodes: --out holds none (an
    # interrupted Ray sweep could never be resumed, nor its summary written)
    on_nodes = _plan(tmp_path, driver.Options(executor="ray", workers=1))
    assert on_nodes.runs[0].status == plan.Status("partial", 500)
    with pytest.raises(TacbenchError, match=r"holds no"):
        _plan(tmp_path, driver.Options(executor="ray", workers=1, shared_fs=True))
    (directory / "status.json").unlink()
    (directory / "eval.csv").write_text("step,wall_s,return_mean\n500,1.0,3.0\n")
    with pytest.raises(TacbenchError, match=r"has rows in eval\.csv but no status\.json"):
        _plan(tmp_path)


def test_a_run_directory_with_files_but_no_config_stops_the_plan(tmp_path: Path) -> None:
    """Its worker would refuse it half-way through the sweep (starting it afresh would delete
    the files): the plan stops first, saying so; an empty one is a new run."""
    run = plan.build_runs(SMOKE)[0]
    directory = tmp_path / run.key
    directory.mkdir(parents=True)
    assert _plan(tmp_path).runs[0].status == plan.Status("new")
    (directory / "eval.csv").write_text("step\n")
    with pytest.raises(TacbenchError, match=r"holds eval\.csv but no config\.json"):
        _plan(tmp_path)


def test_a_run_written_before_a_setting_existed_is_this_sweeps_run(tmp_path: Path) -> None:
    """The published studies lack settings added since (matmul_precision, ...): their own
    sweep commands were refused ("holds a run with another config")."""
    run = next(r for r in plan.build_runs(SMOKE) if r.config.algo == "tac")
    directory = _fake_run(tmp_path, run, {"state": "complete", "step": 1000})
    older = runs.read_json(directory / "config.json")
    del older["config"]["matmul_precision"], older["config"]["density_cap"]
    runs.atomic_write_json(directory / "config.json", older)
    statuses = {p.run.key: p.status for p in _plan(tmp_path).runs}
    assert statuses[run.key] == plan.Status("complete", 1000)


def test_compile_auto_matches_what_a_run_recorded_when_it_started(tmp_path: Path) -> None:
    run = next(r for r in plan.build_runs(SMOKE) if r.config.algo == "tac")
    assert run.config.compile == "auto"  # each worker resolves it for its own machine
    _fake_run(tmp_path, run, {"state": "running", "step": 0}, compile="on")
    statuses = {p.run.key: p.status for p in _plan(tmp_path).runs}
    assert statuses[run.key] == plan.Status("partial", 0)


def test_grouping_makes_member_units_at_equal_resume_steps(tmp_path: Path) -> None:
    tac = narrow(SMOKE, Narrowing(algos=("tac", "ppo")))
    all_runs = plan.build_runs(tac)
    _fake_run(tmp_path, all_runs[3], {"state": "running", "step": 500})  # q2 seed 10
    by_seed = driver.load_plan(tac, tmp_path, driver.Options(group="seeds"), save=False)[0]
    assert [u.key for u in by_seed.units] == [
        "runs/tac/Hopper-v4/q1-a0.2-ls500-bs32/seeds0,10",
        "runs/tac/Hopper-v4/q2-a0.2-ls500-bs32/seed0",
        "runs/tac/Hopper-v4/q2-a0.2-ls500-bs32/seed10",
        *(r.key for r in all_runs[4:]),  # baselines are never grouped
    ]
    by_task = driver.load_plan(tac, tmp_path, driver.Options(group="task"), save=False)[0]
    assert (
        [[r.key for r in u.runs] for u in by_task.units]
        == [
            [r.key for r in all_runs[:3]],  # q1 seeds 0 and 10, q2 seed 0: all at step 0
            [all_runs[3].key],  # resumes from step 500
            *([r.key] for r in all_runs[4:]),
        ]
    )
    assert by_task.units[0].key.startswith("runs/tac/Hopper-v4/members3-")
    text = dry_run.describe_plan(by_task, 1, "task")
    assert "4 units to train (one process or Ray task each; --group task: TAC runs" in text
    assert "  tac Hopper-v4: 2 units of 1-3 members, up to 0.1 GiB each" in text
    alone = driver.load_plan(tac, tmp_path, driver.Options(group="none"), save=False)[0]
    assert [u.key for u in alone.units] == [r.key for r in all_runs]


@pytest.mark.parametrize("shared_fs", [False, True])
def test_members_resume_together_only_on_the_node_holding_their_checkpoints(
    tmp_path: Path, shared_fs: bool
) -> None:
    """Without a shared filesystem each run's checkpoints stay on its Ray node: runs at the same
    step on two nodes used to share a unit, sent to one node, where the other started over."""
    tac = narrow(SMOKE, Narrowing(algos=("tac",), q=(1.0,)))
    seed0, seed10 = plan.build_runs(tac)
    history = state.SweepState(tmp_path)
    for run, node in ((seed0, "node-a"), (seed10, "node-b")):
        _fake_run(tmp_path, run, {"state": "running", "step": 500})
        history.set_node([run.key], node)
    options = driver.Options(executor="ray", workers=1, group="seeds", shared_fs=shared_fs)
    units = driver.load_plan(tac, tmp_path, options, save=False)[0].units
    together = [[seed0.key, seed10.key]]
    assert [[r.key for r in u.runs] for u in units] == (
        together if shared_fs else [[seed0.key], [seed10.key]]
    )
    history.set_node([seed10.key], "node-a")
    units = driver.load_plan(tac, tmp_path, options, save=False)[0].units
    assert [[r.key for r in u.runs] for u in units] == together


def test_the_reference_profile_groups_its_seeds_too(tmp_path: Path) -> None:
    """Members update at their own episode ends, so --profile reference runs are
    grouped like any other TAC runs."""
    tac = narrow(SMOKE, Narrowing(algos=("tac",)))
    reference = dataclasses.replace(
        tac,
        entries=tuple(
            dataclasses.replace(e, settings={**e.settings, "profile": "reference"})
            for e in tac.entries
        ),
    )
    units = driver.load_plan(reference, tmp_path, driver.Options(group="seeds"), save=False)[0]
    assert [u.key for u in units.units] == [
        "runs/tac/Hopper-v4/q1-a0.2-ref-ls500-bs32/seeds0,10",
        "runs/tac/Hopper-v4/q2-a0.2-ref-ls500-bs32/seeds0,10",
    ]
    assert all(r.config.update_schedule == "episode" for u in units.units for r in u.runs)


def test_a_q_by_seed_grid_is_split_into_near_equal_units_of_at_most_members(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(hardware, "memory_bytes", lambda: 64 << 30)  # 90 Hopper members fit
    grid = narrow(get_preset("paper-q-grid"), Narrowing(tasks=("Hopper",)))
    assert len(plan.build_runs(grid)) == 90
    cases = [(1, None, [90]), (2, None, [45, 45]), (1, 40, [30] * 3)]
    cases += [(1, 7, [7] * 12 + [6]), (1, 8, [8] * 6 + [7] * 6)]  # sizes differ by at most one
    for workers, members, sizes in cases:  # with 2 workers, each gets a unit
        options = driver.Options(group="task", members=members, workers=workers)
        work = driver.load_plan(grid, tmp_path, options, save=False)[0]
        assert [len(u.runs) for u in work.units] == sizes, members
        assert len({r.key for u in work.units for r in u.runs}) == 90
    assert cost.members_per_unit(90, 1 << 30, workers=2, groups=1, memory=16 << 30) == 6
    assert cost.members_per_unit(90, 1 << 20, workers=16, groups=6, memory=64 << 30) == 30
    assert cost.members_per_unit(3, 1 << 20, workers=1, groups=1, memory=8 << 30, limit=2) == 2


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"members": 0}, "--members must be at least 1"),
        ({"group": "q"}, "--group must be one of task, seeds, none"),
    ],
)
def test_bad_grouping_options_are_refused(options: dict[str, Any], message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        driver.Options(**options)


def test_measured_throughput_replaces_the_default(tmp_path: Path) -> None:
    run = plan.build_runs(SMOKE)[0]
    directory = _fake_run(tmp_path, run, {"state": "complete", "step": 1000})
    metadata = runs.read_json(directory / "config.json")
    runs.atomic_write_json(directory / "config.json", {**metadata, "members": [0, 10]})
    (directory / "eval.csv").write_text(
        "step,wall_s,return_mean,return_std,length_mean\n"
        "250,0.5,1,0,1\n500,1.0,1,0,1\n750,2.0,1,0,1\n1000,3.0,1,0,1\n"
    )
    # second half of the evaluations: (3.0 - 1.0) s / 500 steps, shared by 2 members
    assert cost.run_seconds_per_step(directory) == pytest.approx(0.002)
    ppo = next(r for r in plan.build_runs(SMOKE) if r.config.algo == "ppo")
    planned = {("tac", "Hopper-v4"): [run.config], ("ppo", "Hopper-v4"): [ppo.config]}
    rates = cost.rates(tmp_path, planned)
    assert rates[("tac", "Hopper-v4")] == cost.Rate(
        0.002, f"measured: 1 run under {tmp_path}, 1 by wall_s (no cpu_s over the window)"
    )
    assert rates[("ppo", "Hopper-v4")].source == cost.DEFAULT_SOURCE
    assert rates[("ppo", "Hopper-v4")].seconds_per_step > 0
    with (directory / "eval.csv").open("a") as handle:  # a damaged log: the price goes without
        handle.write("garbage\n")
    assert cost.run_seconds_per_step(directory) is None


def test_a_run_that_records_cpu_time_is_priced_by_it(tmp_path: Path) -> None:
    """A rate from wall time carries forward the load the run trained under: a resumed TD3
    sweep priced at 2.5x what it took, its partial runs measured beside CI and other sweeps.
    CPU seconds, which other work stretches much less, price a run that records them (its
    share already: a run resumed in a group of another size is priced by what it took); wall
    time still prices a run begun before eval.csv had cpu_s, or one whose window lacks it."""
    run = plan.build_runs(narrow(SMOKE, Narrowing(algos=("tac",))))[0]
    directory = _fake_run(tmp_path, run, {"state": "complete", "step": 1000})
    metadata = runs.read_json(directory / "config.json")
    settings = {**metadata["config"], "threads": 2}
    older = {**metadata, "config": settings, "members": [0, 10]}  # before members split cpu_s
    runs.atomic_write_json(directory / "config.json", {**older, "cpu_clock": "share"})
    header = "step,wall_s,cpu_s,return_mean,return_std,length_mean\n"
    # under load: the wall clock ran 6 s from step 500 to 1,000; this member's share of its
    # process's CPU seconds (2 threads, 2 members) 1 s
    (directory / "eval.csv").write_text(header + "500,4.0,1.5,1,0,1\n1000,10.0,2.5,1,0,1\n")
    assert cost.run_seconds_per_step(directory) == pytest.approx(1.0 / 500)
    planned = {("tac", "Hopper-v4"): [dataclasses.replace(run.config, threads=2)]}
    assert cost.rates(tmp_path, planned)[("tac", "Hopper-v4")] == cost.Rate(
        0.002, f"measured: 1 run under {tmp_path}"
    )
    runs.atomic_write_json(directory / "config.json", older)  # its cpu_s: the whole process's
    assert cost.run_seconds_per_step(directory) == pytest.approx(1.0 / 500 / 2)
    (directory / "eval.csv").write_text(header + "500,4.0,,1,0,1\n1000,10.0,3.5,1,0,1\n")
    assert cost.run_seconds_per_step(directory) == pytest.approx(6.0 / 500 * 2 / 2)
    assert cost.rates(tmp_path, planned)[("tac", "Hopper-v4")].source == (
        f"measured: 1 run under {tmp_path}, 1 by wall_s (no cpu_s over the window)"
    )


def test_only_runs_of_the_plans_kind_measure_its_price(tmp_path: Path) -> None:
    """Every run under --out priced the plan by algo and task alone: four 1,000-step smoke
    runs made the paper grid's price 13x its default. Runs of another kind (another setting
    but seed, q, alpha and steps), runs measured in their warm-up and runs with a damaged
    config.json (which crashed the dry run and the sweep) now price nothing."""
    run = plan.build_runs(narrow(SMOKE, Narrowing(algos=("tac",))))[0]
    rows = "step,wall_s,return_mean,return_std,length_mean\n500,1.0,1,0,1\n1000,2.0,1,0,1\n"
    other_kind = _fake_run(tmp_path, run, None, batch_size=64)
    (other_kind / "eval.csv").write_text(rows)
    longer = dataclasses.replace(run.config, seed=99, q=1.5, total_steps=4000)
    same_kind = plan.Run(longer)
    directory = _fake_run(tmp_path, same_kind, None)
    (directory / "eval.csv").write_text(rows.replace("2.0", "4.0"))
    planned = {("tac", "Hopper-v4"): [run.config]}
    assert cost.rates(tmp_path, planned)[("tac", "Hopper-v4")].seconds_per_step == 0.006
    (directory / "eval.csv").write_text(rows.replace("500,", "400,"))  # from inside its warm-up
    assert cost.rates(tmp_path, planned)[("tac", "Hopper-v4")].source == cost.DEFAULT_SOURCE
    (directory / "eval.csv").write_text(rows)
    for damaged in ('{"config": 5}', "{not json", '{"config": {"threads": "x"}}'):
        (other_kind / "config.json").write_text(damaged)
        assert cost.rates(tmp_path, planned)[("tac", "Hopper-v4")].seconds_per_step == 0.002
    metadata = runs.read_json(directory / "config.json")
    metadata["config"]["threads"] = "x"
    runs.atomic_write_json(directory / "config.json", metadata)
    assert cost.rates(tmp_path, planned)[("tac", "Hopper-v4")].source == cost.DEFAULT_SOURCE


def test_the_reference_profile_is_priced_on_its_own(tmp_path: Path) -> None:
    """TAC in --profile reference costs several times the paper profile per step: its runs are
    measured apart from the paper profile's, and its default is its own."""
    paper, reference = plan.build_runs(narrow(SMOKE, Narrowing(algos=("tac",))))[:2]
    reference = plan.Run(dataclasses.replace(reference.config, profile="reference"))
    for run, wall in ((paper, 1.0), (reference, 8.0)):
        directory = _fake_run(tmp_path, run, {"state": "complete", "step": 1000})
        (directory / "eval.csv").write_text(
            "step,wall_s,return_mean,return_std,length_mean\n"
            f"500,{wall},1,0,1\n1000,{2 * wall},1,0,1\n"
        )
    assert cost.cost_algo("tac", "reference") == cost.REFERENCE_TAC
    assert cost.cost_algo("tac", "authors-2019-01-11b") == cost.REFERENCE_TAC
    assert cost.cost_algo("tac", "paper") == "tac"
    assert cost.cost_algo("ppo", None) == "ppo"
    planned = {
        ("tac", "Hopper-v4"): [paper.config],
        (cost.REFERENCE_TAC, "Hopper-v4"): [reference.config],
    }
    measured = cost.rates(tmp_path, planned)
    assert measured[("tac", "Hopper-v4")].seconds_per_step == pytest.approx(0.002)
    assert measured[(cost.REFERENCE_TAC, "Hopper-v4")].seconds_per_step == pytest.approx(0.016)
    on_ant = {
        ("tac", "Ant-v4"): [dataclasses.replace(paper.config, env="Ant-v4")],
        (cost.REFERENCE_TAC, "Ant-v4"): [dataclasses.replace(reference.config, env="Ant-v4")],
    }
    defaults = cost.rates(tmp_path / "empty", on_ant)
    assert defaults[(cost.REFERENCE_TAC, "Ant-v4")].seconds_per_step > 5 * (
        defaults[("tac", "Ant-v4")].seconds_per_step
    )


def test_a_pair_without_a_default_of_its_own_is_priced_at_its_algorithms_mean_and_says_so(
    tmp_path: Path,
) -> None:
    """tac-ref has defaults on HalfCheetah and Hopper only: on Humanoid it is priced at their
    mean, though the paper profile's TAC costs ten times as much there as on HalfCheetah, and
    the plan now says so; a pair with its own default gets no such line."""
    own = [(cost.REFERENCE_TAC, "HalfCheetah-v4"), (cost.REFERENCE_TAC, "Hopper-v4")]
    assert cost.default_stand_ins(cost.REFERENCE_TAC, "Humanoid-v4") == own
    assert cost.default_stand_ins("tac", "Humanoid-v4") == []
    assert cost.default_stand_ins("tac", "Hopper-v5") == [("tac", "Hopper-v4")]  # another suite
    assert cost.default_stand_ins("not-an-algo", "Hopper-v4") == sorted(
        cost.DEFAULT_SECONDS_PER_STEP
    )
    humanoid = plan.build_runs(narrow(SMOKE, Narrowing(algos=("tac",))))[0].config
    humanoid = dataclasses.replace(humanoid, env="Humanoid-v4", profile="reference")
    rates = cost.rates(tmp_path, {(cost.REFERENCE_TAC, "Humanoid-v4"): [humanoid]})
    mean = (cost.DEFAULT_SECONDS_PER_STEP[own[0]] + cost.DEFAULT_SECONDS_PER_STEP[own[1]]) / 2
    assert rates[(cost.REFERENCE_TAC, "Humanoid-v4")].seconds_per_step == pytest.approx(mean)
    command = ["sweep", "--preset", "paper-q-grid", "--env", "Humanoid", "--env", "Hopper"]
    command += ["--q", "1", "--seed", "0", "--profile", "reference", "--dry-run"]
    result = CliRunner().invoke(cli, [*command, "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert (
        "tac-ref Humanoid-v4: no default of its own, priced at the mean of tac-ref's on "
        "HalfCheetah-v4, Hopper-v4; --calibrate measures it." in result.output
    )
    assert "tac-ref Hopper-v4: no default" not in result.output


def test_defaults_cover_every_paper_pair() -> None:
    pairs = {(r.config.algo, r.config.env) for r in plan.build_runs(get_preset("paper-comparison"))}
    assert pairs <= set(cost.DEFAULT_SECONDS_PER_STEP)
    assert all(0 < v < 0.1 for v in cost.DEFAULT_SECONDS_PER_STEP.values())


def _hold_lock(out: Path, write_holder: bool) -> subprocess.Popen[str]:
    """Another process that holds ``out``'s sweep lock until it is killed: as a sweep does
    (``write_holder``), or having taken it without writing its holder yet."""
    hold = (
        "import fcntl, os, sys, time; from pathlib import Path; from tacbench.sweep import state\n"
        "out = Path(sys.argv[1])\n"
        "if sys.argv[2] == 'sweep':\n"
        "    state.Lock(out).__enter__()\n"
        "else:\n"
        "    (out / 'sweep').mkdir(parents=True)\n"
        "    fd = os.open(out / 'sweep' / 'lock', os.O_RDWR | os.O_CREAT)\n"
        "    fcntl.flock(fd, fcntl.LOCK_EX)\n"
        "print('held', flush=True)\n"
        "time.sleep(60)\n"
    )
    holder = "sweep" if write_holder else "torn"
    proc = subprocess.Popen(
        [sys.executable, "-c", hold, str(out), holder], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stdout.readline() == "held\n"
    return proc


@pytest.mark.parametrize("write_holder", [True, False])
def test_lock_refuses_a_live_sweep_and_is_free_once_it_is_killed(
    tmp_path: Path, write_holder: bool
) -> None:
    """A live holder is refused, even one caught before it has written who it is (its lock
    file still empty: it used to be taken for a lock torn by a crash, deleted, and taken
    again, so that two sweeps wrote to one --out); once it is killed with SIGKILL the kernel
    has released the lock, and the next sweep takes it."""
    holder = _hold_lock(tmp_path, write_holder)
    try:
        named = (
            f"pid {holder.pid} on {socket.gethostname()}" if write_holder else "holder not recorded"
        )
        with pytest.raises(TacbenchError, match=f"another sweep \\({named}"):
            state.Lock(tmp_path).__enter__()
    finally:
        holder.kill()
        holder.wait()
    with state.Lock(tmp_path):
        assert json.loads((tmp_path / "sweep" / "lock").read_text())["pid"] == os.getpid()
        with pytest.raises(TacbenchError, match=f"another sweep \\(pid {os.getpid()} "):
            state.Lock(tmp_path).__enter__()
    with state.Lock(tmp_path):  # released when the sweep ended
        pass


@pytest.mark.parametrize("where", ["sweep", "sweep/lock"])
def test_a_file_or_folder_in_the_sweep_locks_place_is_a_clear_error(
    tmp_path: Path, where: str
) -> None:
    """Both were tracebacks (FileExistsError, IsADirectoryError)."""
    if where == "sweep":
        (tmp_path / "sweep").write_text("mine")
        message = "a file stands where the sweep's folder goes"
    else:
        (tmp_path / "sweep" / "lock").mkdir(parents=True)
        message = "lock is a folder, where tacbench keeps a lock file"
    with pytest.raises(TacbenchError, match=message):
        state.Lock(tmp_path).__enter__()
    assert where != "sweep" or (tmp_path / "sweep").read_text() == "mine"


def test_reset_failed_and_stop_hook(tmp_path: Path) -> None:
    runs.atomic_write_json(
        tmp_path / "status.json", {"state": "failed", "step": 7, "reason": "nan", "updated": "x"}
    )
    worker.reset_failed(tmp_path)
    status = runs.read_json(tmp_path / "status.json")
    # no checkpoint: the retry starts afresh, so the status says step 0 (a resume would refuse
    # a step that no checkpoint holds)
    assert (status["state"], status["step"], status["reason"]) == (
        "running",
        0,
        "retrying after: nan",
    )
    runs.atomic_write_json(tmp_path / "status.json", {"state": "failed", "step": 7, "reason": "x"})
    (tmp_path / "checkpoint").mkdir()
    (tmp_path / "checkpoint" / "manifest-000000000005.json").write_text("{}")
    worker.reset_failed(tmp_path)
    assert runs.read_json(tmp_path / "status.json")["step"] == 5  # where the retry resumes
    calls: list[int] = []
    hook = worker.StopHook(lambda step: calls.append(step) or step >= 5, every_s=3600)
    assert [hook(s) for s in range(10)] == [False] * 10  # asked once, at step 0
    assert calls == [0]
    eager = worker.StopHook(lambda step: step >= 5, every_s=0)
    assert [eager(s) for s in (4, 5)] == [False, True]


def test_cli_sweep_dry_run_and_option_errors(tmp_path: Path) -> None:
    runner = CliRunner()
    dry = runner.invoke(
        cli,
        [
            "sweep",
            "--preset",
            "paper-q-grid",
            "--dry-run",
            "--out",
            str(tmp_path),
            "--workers",
            "4",
        ],
    )
    assert dry.exit_code == 0, dry.output
    assert "540 runs: 0 complete, 0 partial, 0 failed" in dry.output
    assert "environment steps left: 540,000,000 of 540,000,000 (1,000,000 per run)" in dry.output
    assert "with 4 workers (--workers) about" in dry.output
    assert not (tmp_path / "sweep").exists()  # a dry run writes nothing
    for args, message in [
        (["--address", "auto"], "are Ray options: add --executor ray"),
        (["--cpus-per-run", "2"], "is a Ray or Slurm request: add --executor ray or slurm"),
        (["--gpus-per-run", "1.5"], "the local executor shares one GPU between its workers"),
        (["--max-retries", "-1"], "--max-retries must be 0 or more"),
        (["--env", "Walker2d"], "the presets train the paper's tasks"),
        (["--steps", "0"], "total_steps must be an integer >= 1"),
    ]:
        result = runner.invoke(cli, ["sweep", "--preset", "smoke", "--dry-run", *args])
        assert (result.exit_code, message in result.output) == (2, True), result.output
    (tmp_path / "afile").write_text("")
    below_a_file = ["--out", str(tmp_path / "afile" / "sub")]  # the sweep itself would refuse
    result = runner.invoke(cli, ["sweep", "--preset", "smoke", "--dry-run", *below_a_file])
    assert result.exit_code == 2 and "cannot create or write the output folder" in result.output
    cores = len(os.sched_getaffinity(0))
    many = ["--workers", str(cores + 1), "--out", str(tmp_path / "o")]
    result = runner.invoke(cli, ["sweep", "--preset", "smoke", "--dry-run", *many])
    assert result.exit_code == 0
    assert f"WARNING: --workers {cores + 1} is more than the {cores} cores" in result.output
    one = ["--workers", "1", "--out", str(tmp_path / "o")]
    result = runner.invoke(cli, ["sweep", "--preset", "smoke", "--dry-run", *one])
    assert result.exit_code == 0 and "WARNING" not in result.output


def test_the_wall_time_is_the_units_schedule_not_the_core_time_shared_out() -> None:
    assert cost.makespan([3.0, 2.0, 1.0, 1.0], 2) == 4.0  # 3 | 2 + 1, then 1 on either
    assert cost.makespan([5.0, 1.0, 1.0], 2) == 5.0  # the longest unit, not 7 / 2
    assert cost.makespan([5.0, 1.0, 1.0], 1) == 7.0
    assert cost.makespan([], 4) == 0.0


def test_the_dry_run_prices_the_wall_time_by_its_units(tmp_path: Path) -> None:
    """Five members in units of 3 and 2 on two workers take as long as the unit of 3."""
    five = narrow(
        get_preset("paper-q-grid"),
        Narrowing(("Hopper",), (1.0,), seeds=(0, 10, 20, 30, 40), settings={"total_steps": 10_000}),
    )
    work = driver.load_plan(five, tmp_path, driver.Options(members=3), save=False)[0]
    assert [len(u.runs) for u in work.units] == [3, 2]
    per_step = {("tac", "Hopper-v4"): 1e-3}
    assert dry_run.wall_seconds(work, per_step, 2) == pytest.approx(3 * 10_000 * 1e-3)
    assert dry_run.wall_seconds(work, per_step, 1) == pytest.approx(5 * 10_000 * 1e-3)
    assert "(one core per worker; each unit on one worker" in dry_run.describe_plan(work, 2, "task")


def test_a_plan_of_one_run_is_counted_in_the_singular(tmp_path: Path) -> None:
    """The dry run and the summary say "1 run", "1 unit", not "1 runs", "1 units"."""
    one = narrow(
        get_preset("paper-q-grid"),
        Narrowing(("Hopper",), (1.0,), seeds=(0,), settings={"total_steps": 10_000}),
    )
    work = driver.load_plan(one, tmp_path, driver.Options(), save=False)[0]
    text = dry_run.describe_plan(work, 1, "task")
    assert "\n1 run: 0 complete, 0 partial, 0 failed" in text
    assert "\n1 unit to train (one process" in text
    alone = {**summary.counts(work), "recovered_after_failures": 0}
    record = {"preset": "p", "out": "o", "counts": alone, "unfinished": [], "interrupted": True}
    assert "into o): 1 run: 0 complete" in summary.summary_text(record, "")


def test_the_summary_compares_the_bill_with_the_price_only_for_a_whole_plan() -> None:
    bill = {"cpu_class": "x", "workers": 2, "wall_s": 4140.0, "priced_wall_s": 3480.0}
    counts = dict.fromkeys(("runs", "complete", "failed", "given_up", "partial", "new"), 0)
    base = {
        "preset": "p",
        "out": "o",
        "counts": {**counts, "to_retry": 0, "to_train": 0, "cannot_resume": 0},
        "unfinished": [],
    }
    base["counts"]["recovered_after_failures"] = 0
    whole = summary.summary_text({**base, "interrupted": False, "bill": bill}, "")
    assert "took 1h09m on 2 workers (x); priced at the start 58m00s: 1.19x the price" in whole
    stopped = summary.summary_text({**base, "interrupted": True, "bill": bill}, "")
    assert "stopped after 1h09m on 2 workers (x); priced at the start 58m00s" in stopped
    assert "x the price" not in stopped  # a stopped sweep has no whole bill to compare
    # a local sweep's bill records the machine's load while it ran, and says what was not its own
    quiet = {**bill, "load_average": 2.1, "cores": 2}
    text = summary.summary_text({**base, "interrupted": False, "bill": quiet}, "")
    assert text.endswith("1.19x the price; the load averaged 2.1 on 2 cores")
    busy = {**bill, "load_average": 3.64, "cores": 2}
    text = summary.summary_text({**base, "interrupted": False, "bill": busy}, "")
    expected = "the load averaged 3.6 on 2 cores, 1.6 above its workers: other work shared"
    assert text.endswith(f"1.19x the price; {expected} the cores")


@pytest.mark.parametrize(
    ("partial", "given_up", "to_train", "cannot_resume", "advice"),
    [
        (1, 1, 0, 0, {"given up"}),  # an interrupted run given up: the same command trains nothing
        (1, 0, 1, 0, {"to continue"}),
        (0, 0, 0, 0, set()),
        (1, 0, 1, 1, {"fix"}),  # the same command alone would be refused again
        (2, 0, 2, 1, {"fix", "to continue"}),
    ],
)
def test_the_summary_says_what_continues_a_sweep(
    partial: int, given_up: int, to_train: int, cannot_resume: int, advice: set[str]
) -> None:
    counts = dict.fromkeys(("runs", "complete", "failed", "new", "to_retry"), 0)
    counts |= {"partial": partial, "given_up": given_up, "to_train": to_train}
    counts |= {"cannot_resume": cannot_resume, "recovered_after_failures": 0}
    record = {"preset": "p", "out": "o", "counts": counts, "unfinished": [], "interrupted": False}
    text = summary.summary_text(record, "c")
    assert ("to continue, run the same command again: c" in text) == ("to continue" in advice)
    assert ("a larger --max-retries to try again" in text) == ("given up" in advice)
    fix = "1 run cannot resume from its files, so the sweep did not retry it (every attempt"
    assert (fix in text) == ("fix" in advice)


class _DiedOfCtrlC:
    """An executor whose one unit dies of a Ctrl-C while starting up; the same Ctrl-C reaches
    the driver while it waits."""

    def __init__(self, received: dict[str, int]) -> None:
        self.received, self.units, self.stops = received, [], 0
        self.told = ["Slurm will not start job 7_0 (JobHeldUser): release it"]

    def capacity(self) -> int:
        return 1

    def running(self) -> int:
        return len(self.units)

    def submit(self, unit: plan.Unit, node: str | None = None) -> None:
        self.units.append(unit)

    def wait(self, timeout: float) -> list[Any]:
        from tacbench.sweep.executors import Finished

        self.received["count"] = 1  # the Ctrl-C
        died = [Finished(u, None, "worker process killed by SIGINT") for u in self.units]
        self.units = []
        return died

    def steps(self) -> dict[str, int]:
        return {}

    def notices(self) -> list[str]:
        told, self.told = self.told, []
        return told

    def request_stop(self) -> None:
        self.stops += 1

    def close(self, force: bool = False) -> None:
        pass


def test_a_unit_killed_by_the_ctrl_c_that_stops_the_sweep_is_not_a_failure(
    tmp_path: Path,
) -> None:
    """A worker starting up dies of the Ctrl-C before it can ignore it: the sweep stops, and
    the unit's runs are left to resume, not counted as failed (enough such stops gave them up)."""
    options = driver.Options(workers=1)
    work, history = driver.load_plan(SMOKE, tmp_path, options, save=False)
    received: dict[str, int] = {}
    executor = _DiedOfCtrlC(received)
    stream = io.StringIO()
    sweep = driver._Driver(work, history, executor, options, stream=stream)
    assert sweep.run(received) is True  # stopped early
    assert executor.stops == 1
    assert all(not history.failures(p.run.key) for p in work.runs)
    # what the executor has to tell (a job Slurm will not start) reaches the user, once
    assert stream.getvalue().count("Slurm will not start job 7_0 (JobHeldUser)") == 1


class _WorkersDie(_DiedOfCtrlC):
    """An executor whose every unit's worker is killed (no Ctrl-C)."""

    def wait(self, timeout: float) -> list[Any]:
        from tacbench.sweep.executors import Finished

        died = [Finished(u, None, "worker process killed by SIGKILL") for u in self.units]
        self.units = []
        return died


@pytest.mark.parametrize(
    ("executor", "host"), [("local", socket.gethostname()), ("ray", "unknown")]
)
def test_a_retried_runs_worker_that_dies_is_recorded_with_its_death(
    smoke_out: tuple[Path, list[plan.Run]], executor: str, host: str
) -> None:
    """Its status.json still says failed (the worker died before resetting it): each attempt
    used to record that old failure again, the death lost. A local worker ran on this machine;
    a cluster's died somewhere the driver cannot say (it used to record the driver's host)."""
    out, all_runs = smoke_out
    options = driver.Options(executor=executor, workers=1, max_retries=2)
    work, history = driver.load_plan(SMOKE, out, options, save=False)
    driver._Driver(work, history, _WorkersDie({}), options, stream=None).run({})
    failures = history.failures(all_runs[4].key)
    assert [f.reason for f in failures] == ["non-finite", *["worker process killed by SIGKILL"] * 2]
    assert {f.host for f in failures[1:]} == {host}


class _WorkersTerminated(_DiedOfCtrlC):
    """An executor whose every unit's worker gets a SIGTERM the sweep did not send: its trainer
    checkpoints, returns its runs interrupted, and the worker ends with a result."""

    def __init__(self, out: Path) -> None:
        super().__init__({})
        self.out = out

    def wait(self, timeout: float) -> list[Any]:
        from tacbench.sweep.executors import Finished

        done = []
        for unit in self.units:
            for run in unit.runs:
                status = {"state": "interrupted", "step": 300}
                (self.out / run.key).mkdir(parents=True, exist_ok=True)
                config = {"config": run.config.to_dict(), "members": [run.config.seed]}
                runs.atomic_write_json(self.out / run.key / "config.json", config)
                runs.atomic_write_json(self.out / run.key / "status.json", status)
            outcomes = tuple(
                Outcome(r.config.seed, self.out, "interrupted", 300) for r in unit.runs
            )
            done.append(Finished(unit, worker.JobResult(outcomes, host="h"), ""))
        self.units = []
        return done


def test_a_run_whose_worker_was_stopped_by_another_signal_is_retried_not_left(
    tmp_path: Path,
) -> None:
    """A worker killed by a SIGTERM the sweep did not send checkpoints and returns its runs
    interrupted: the sweep left them partial and exited 0 as if every run were complete. Such an
    attempt is a failure now, retried up to --max-retries, then given up (exit 1)."""
    options = driver.Options(workers=1, max_retries=1)
    work, history = driver.load_plan(SMOKE, tmp_path, options, save=False)
    driver._Driver(work, history, _WorkersTerminated(tmp_path), options, stream=None).run({})
    key = work.runs[0].run.key
    reasons = [f.reason for f in history.failures(key)]
    assert reasons == ["its worker ended at step 300; the sweep did not stop it"] * 2


@pytest.mark.parametrize(
    "damaged",
    ["{", '{"runs": []}', '{"runs": null}', '{"runs": {"k": {"failures": [{"bad": 1}]}}}'],
)
def test_a_damaged_failure_history_stops_the_sweep_before_anything_runs(
    tmp_path: Path, damaged: str
) -> None:
    """state.json torn, or of the wrong shape (which crashed the summary after every run had
    trained): refused at once, saying that deleting it loses the history, not to --force."""
    (tmp_path / "sweep").mkdir()
    (tmp_path / "sweep" / "state.json").write_text(damaged)
    with pytest.raises(TacbenchError, match=r"delete it \(the sweep's failure history is then"):
        _plan(tmp_path)


def test_a_file_where_the_sweeps_logs_go_stops_it_before_anything_trains(tmp_path: Path) -> None:
    """Every unit writes its log there: a file in its place failed each unit in turn until
    every run was given up on."""
    (tmp_path / "sweep").mkdir()
    (tmp_path / "sweep" / "logs").write_text("mine")
    with pytest.raises(TacbenchError, match="a file stands in its place; nothing was trained"):
        driver.run_sweep(SMOKE, tmp_path, driver.Options(workers=1))
    assert (tmp_path / "sweep" / "logs").read_text() == "mine"
    assert not (tmp_path / "runs").exists()
    (tmp_path / "sweep" / "logs").unlink()
    (tmp_path / "sweep" / "summary.json").mkdir()  # an IsADirectoryError once all had trained
    with pytest.raises(TacbenchError, match="is a folder, where the sweep writes its summary"):
        driver.run_sweep(SMOKE, tmp_path, driver.Options(workers=1))
    assert not (tmp_path / "runs").exists()


def test_a_run_given_up_counts_as_failed_whatever_its_status_says(tmp_path: Path) -> None:
    """A run whose workers died (kill -9, say) keeps a partial or new status.json; once given
    up it is one of the failed runs in the counts and in the per-task table, not partial or new
    beside "0 failed (1 given up)"."""
    all_runs = plan.build_runs(SMOKE)
    _fake_run(tmp_path, all_runs[1], {"state": "running", "step": 500})
    history = state.SweepState(tmp_path)
    for _ in range(3):
        history.add_failure(all_runs[1].key, 500, "worker process killed by SIGKILL")
    work = _plan(tmp_path, driver.Options(max_retries=2))
    counts = summary.counts(work)
    assert (counts["failed"], counts["given_up"], counts["partial"]) == (1, 1, 0)
    text = dry_run.describe_plan(work, workers=2, group="none")
    assert "0 partial, 1 failed (0 to retry, 1 given up" in text


def test_the_dry_run_says_when_tac_units_are_unlike_those_of_the_default(tmp_path: Path) -> None:
    """TAC's default rate is of compiled units of 45 members: a dry run of one eager member (the
    smoke preset) said 0m04s for what took 38 s, and now says the estimate is low; the paper's
    grid, grouped and compiled as the default was measured, says nothing of it, nor does it
    guess from this machine whether the workers can compile."""
    smoke = ["sweep", "--preset", "smoke", "--algo", "tac", "--q", "1", "--seed", "0"]
    result = CliRunner().invoke(cli, [*smoke, "--dry-run", "--out", str(tmp_path / "smoke")])
    assert result.exit_code == 0, result.output
    assert (
        "tac Hopper-v4: units of 1 member, not compiled, where the default was measured in "
        "compiled units of 45 with hidden layers (300,): each member-step costs more than it "
        "says, so the estimate is low" in result.output
    )
    # two units of 45 members on two workers, whatever this machine's cores and memory, and the
    # workers' own compilers decide the compilation, not this machine's (here: none)
    grid = ["sweep", "--preset", "paper-q-grid", "--env", "Hopper", "--dry-run", "--workers", "2"]
    with (
        mock.patch.object(hardware, "cpp_compiler", lambda: None),
        mock.patch.object(hardware, "memory_bytes", lambda: 64 << 30),
    ):
        result = CliRunner().invoke(cli, [*grid, "--out", str(tmp_path / "grid")])
        assert result.exit_code == 0, result.output
        assert "2 units of 45 members" in result.output and "default*" in result.output
        assert "where the default was measured" not in result.output
        result = CliRunner().invoke(cli, [*grid, "--members", "10", "--out", str(tmp_path / "g")])
    assert "units of 10 members, where the default was measured" in result.output
    compiled_off = [*grid, "--compile", "off", "--out", str(tmp_path / "off")]
    assert "units not compiled, where" in CliRunner().invoke(cli, compiled_off).output


def test_the_dry_run_says_when_tac_networks_are_unlike_those_of_the_default(
    tmp_path: Path,
) -> None:
    """The reference profile's default rate is of compiled units of 5 members with (400, 300)
    networks, the paper profile's of (300,): an authors' version with --hidden-sizes 300 (the
    authors'-versions study) was priced at 7.94 ms a member-step where it took 1.58, and now
    says the estimate is high; wider networks say low, and narrower ones not compiled that it
    may be off either way. A reference unit's size alone says nothing: batching members hardly
    speeds its (400, 300) products."""
    grid = ["sweep", "--preset", "paper-q-grid", "--env", "Hopper", "--q", "1", "--dry-run"]

    def note(*options: str) -> str:
        out = str(tmp_path / "-".join(options).replace(",", "_"))
        result = CliRunner().invoke(cli, [*grid, *options, "--out", out])
        assert result.exit_code == 0, result.output
        return result.output

    authors = ["--profile", "authors-2019-01-07b", "--seed", "0"]
    assert (
        "tac-ref Hopper-v4: units with hidden layers (300,), where the default was measured in "
        "compiled units of 5 with hidden layers (400, 300): each member-step costs less than it "
        "says, so the estimate is high" in note(*authors, "--hidden-sizes", "300")
    )
    assert "where the default was measured" not in note(*authors, "--compile", "on")
    assert "units not compiled, where" in note(*authors, "--compile", "off")
    wider = note(*authors, "--compile", "on", "--hidden-sizes", "400,400")
    assert "units with hidden layers (400, 400), where" in wider and "estimate is low" in wider
    paper = ["--seed", "0", "--seed", "10", "--workers", "1", "--compile", "on"]
    assert (
        "tac Hopper-v4: units of 2 members, with hidden layers (400, 300), where the default "
        "was measured in compiled units of 45 with hidden layers (300,): each member-step "
        "costs more" in note(*paper, "--hidden-sizes", "400,300")
    )
    assert "units of 2 members, with hidden layers (64,)" in note(*paper, "--hidden-sizes", "64")
    assert "the estimate may be off either way" in note(*paper, "--hidden-sizes", "64")


def test_the_warnings_of_a_runs_own_settings_are_told_apart_by_type_not_words() -> None:
    """What a sweep repeats of a run's notes: each warning about its budget or schedule (a
    RunWarning), whatever its words; not the compile note's warning of this machine."""
    from tacbench.settings import RunWarning
    from tacbench.trainers import make_configs

    short = {"total_steps": 300, "compile": "off"}
    cases = {
        "--learning-starts": ("tac", {**short, "learning_starts": 500}, {}),
        "--pbt-every": (
            "tac",
            {**short, "learning_starts": 100, "pbt_every": 500},
            {"q_mode": "auto"},
        ),
        "n_steps": ("ppo", {"total_steps": 300}, {}),
    }
    for words, (algo, settings, extra) in cases.items():
        seeds = [0, 10, 20, 30]  # a population of four for --q auto
        _, notes = make_configs(algo, "Hopper-v4", "Hopper", seeds, {**settings, **extra})
        (warning,) = [n for n in notes if n.startswith("WARNING")]
        assert isinstance(warning, RunWarning) and words in warning
    with mock.patch.object(hardware, "cpp_compiler", lambda: None):
        _, notes = make_configs("tac", "Hopper-v4", "Hopper", [0], {"total_steps": 100_000})
    (warning,) = [n for n in notes if n.startswith("WARNING")]
    assert "compile: off" in warning and not isinstance(warning, RunWarning)


def test_the_sweep_warns_of_runs_that_never_update(tmp_path: Path) -> None:
    """`tacbench run` warns of a run whose random steps fill its budget; a sweep of such runs
    says so too, in its dry run and as it trains (once per algorithm and task)."""
    args = ["sweep", "--preset", "smoke", "--algo", "td3", "--steps", "300", "--out", str(tmp_path)]
    warning = "WARNING: td3 Hopper-v4: td3's learning_starts 500 is not below --steps 300"
    dry = CliRunner().invoke(cli, [*args, "--dry-run"])
    assert dry.exit_code == 0, dry.output
    assert dry.output.count(warning) == 1
    trained = CliRunner().invoke(cli, [*args, "--seed", "0", "--workers", "1"])
    assert trained.exit_code == 0, trained.output
    assert trained.output.count(warning) == 1
    by = Narrowing(algos=("td3",), seeds=(0,), settings={"total_steps": 300})
    preset = narrow(get_preset("smoke"), by)
    told: tuple[str, ...] = ()
    for count in (1, 0):  # then told, as --until-decided's later interims are
        stream = io.StringIO()
        result = driver.run_sweep(preset, tmp_path, driver.Options(workers=1), stream, told=told)
        assert stream.getvalue().count(warning) == count
        (told_next,) = result.warnings
        assert told_next.startswith(warning)
        told = result.warnings
    plain = ["sweep", "--preset", "smoke", "--dry-run", "--out", str(tmp_path / "plain")]
    assert "WARNING" not in CliRunner().invoke(cli, plain).output
    # the compile note describes this machine, not where a unit trains: not a run's warning
    grid = ["sweep", "--preset", "paper-q-grid", "--env", "Hopper", "--dry-run"]
    with mock.patch.object(hardware, "cpp_compiler", lambda: None):
        result = CliRunner().invoke(cli, [*grid, "--out", str(tmp_path / "grid")])
    assert result.exit_code == 0, result.output
    assert "WARNING" not in result.output


def test_a_rerun_that_trains_nothing_keeps_a_bill_written_before_a_count_was_added(
    tmp_path: Path,
) -> None:
    """A summary written before ``cannot_resume`` counted lacks it: 0 there, so the rerun keeps
    that sweep's bill rather than replacing it with a bill of nothing."""
    counts = {"runs": 2, "complete": 2, "to_train": 0, "cannot_resume": 0}
    earlier = {"counts": {**counts}, "bill": {"priced_wall_s": 60.0, "wall_s": 70.0}}
    del earlier["counts"]["cannot_resume"]
    path = state.sweep_dir(tmp_path) / "summary.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(earlier))
    assert driver._billed_summary(tmp_path, {"counts": counts}) == path
    assert driver._billed_summary(tmp_path, {"counts": {**counts, "cannot_resume": 1}}) is None
    # the bill of another command's runs, as many and as complete (--seed 10, then --seed 0
    # again), was kept as this one's
    path.write_text(json.dumps({**earlier, "command": "tacbench sweep --seed 10"}))
    mine = {"counts": counts, "command": "tacbench sweep --seed 0"}
    assert driver._billed_summary(tmp_path, mine) is None
    assert driver._billed_summary(tmp_path, {**mine, "command": "tacbench sweep --seed 10"}) == path
