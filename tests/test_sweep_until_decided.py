"""``tacbench sweep --until-decided``: interims, decisions, what they cost and resuming.

Most tests train nothing: ``train`` writes each run of an interim's grid as a complete run
directory whose final return is a known function of q and seed, so the decisions are known.
One test trains the smoke grid for real through the CLI, the local executor and the report.
"""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.detectable import detectable_difference
from tacbench.errors import TacbenchError
from tacbench.progress import duration
from tacbench.report.build import ReportOptions, analyse
from tacbench.sweep import driver, dry_run, plan, sequential_design, until_decided
from tacbench.sweep.presets import Narrowing, Preset, get_preset, narrow
from tacbench.sweep.sequential_design import Design
from tacbench.sweep.until_decided import describe_design, run_until_decided
from tests.helpers import assert_same_results, past_checkpoint, start_cli, wait_for
from tests.report_fixtures import write_run

pytestmark = pytest.mark.unit

HOPPER = narrow(get_preset("paper-q-grid"), Narrowing(tasks=("Hopper",), q=(1.0, 2.0, 5.0)))


def level(q: float, seed: int) -> float:
    """The fake final return: q = 5 far below q = 1 and 2, which are alike."""
    return (100.0 if q == 5.0 else 1000.0) + (seed * 7919 % 97)


class FakeTrain:
    """Writes every run of the grid that is not complete as complete, with eval returns of
    ``level(q, seed)``; ``stop_after`` runs written, it stops as an interrupted sweep would."""

    def __init__(self, stop_after: int | None = None, warnings: tuple[str, ...] = ()) -> None:
        self.stop_after = stop_after
        self.warnings = warnings  # what its plans warn of
        self.trained: list[str] = []
        self.told: list[Collection[str]] = []  # the warnings it was told, interim by interim

    def __call__(
        self,
        grid: Preset,
        out: Path,
        options: driver.Options,
        stream: Any,
        *,
        told: Collection[str],
    ) -> driver.SweepResult:
        self.told.append(told)
        for run in plan.build_runs(grid):
            if plan.read_status(out, run).state == "complete":
                continue
            if self.stop_after is not None and len(self.trained) >= self.stop_after:
                counts = {"given_up": 0, "failed": 0, "cannot_resume": 0}
                return driver.SweepResult({"counts": counts}, "stopped", interrupted=True)
            _write_complete(out, run, level(run.config.q, run.config.seed))
            self.trained.append(run.key)
        counts = {"given_up": 0, "failed": 0, "cannot_resume": 0}
        return driver.SweepResult({"counts": counts}, "done", False, self.warnings)


def _write_complete(out: Path, run: plan.Run, value: float) -> None:
    c = run.config
    write_run(
        out,
        algo=c.algo,
        env=c.env,
        variant=c.variant,
        seed=c.seed,
        steps=range(c.total_steps - 9, c.total_steps + 1),
        returns=[value] * 10,
        q=c.q,
        alpha=0.2,
        total_steps=c.total_steps,
        settings=c.to_dict(),
    )


def test_seeds_are_the_presets_then_further_ones_at_its_spacing() -> None:
    assert sequential_design.seed_order((0, 10), 4) == (0, 10, 20, 30)
    assert sequential_design.seed_order(tuple(range(0, 100, 10)), 12)[-3:] == (90, 100, 110)
    assert sequential_design.seed_order((0, 10, 20), 2) == (0, 10)
    assert sequential_design.seed_order((5, 3), 4) == (5, 3, 15, 25)  # after the largest
    assert len(sequential_design.seed_order((0,), 100_000)) == 100_000  # linear: at once


def test_methods_are_labelled_as_the_report_labels_them_and_the_control_is_resolved() -> None:
    tasks = sequential_design.methods_of(HOPPER)
    assert [m.label for m in tasks["Hopper-v4"]] == ["SAC (TAC q=1)", "TAC q=2", "TAC q=5"]
    methods = tasks["Hopper-v4"]
    assert sequential_design.default_control(HOPPER) == "SAC (TAC q=1)"
    assert sequential_design.control_of(Design(control="q=2"), "Hopper-v4", methods) == "TAC q=2"
    assert sequential_design.control_of(Design(control="pairs"), "Hopper-v4", methods) is None
    with pytest.raises(TacbenchError, match=r"choose one of SAC .*TAC q=5, best-q or pairs"):
        sequential_design.control_of(Design(control="TD3"), "Hopper-v4", methods)
    comparison = narrow(get_preset("paper-comparison"), Narrowing(tasks=("HalfCheetah",)))
    assert sequential_design.default_control(comparison) == "best-q"
    cheetah = sequential_design.methods_of(comparison)["HalfCheetah-v4"]
    labels = [m.label for m in cheetah]
    assert labels == ["TAC q=1.5", "SAC (TAC q=1)", "DDPG", "TD3", "PPO", "TRPO", "SAC (SB3)"]
    best = sequential_design.control_of(Design(control="best-q"), "HalfCheetah-v4", cheetah)
    assert best == "TAC q=1.5"
    assert sequential_design.control_of(Design(control="td3"), "HalfCheetah-v4", cheetah) == "TD3"
    upper = sequential_design.control_of(Design(control="BEST-Q"), "HalfCheetah-v4", cheetah)
    assert upper == "TAC q=1.5"  # the keywords ignore case, as the method names do
    assert sequential_design.control_of(Design(control="Pairs"), "HalfCheetah-v4", cheetah) is None
    baselines = narrow(get_preset("paper-comparison"), Narrowing(algos=("td3", "ppo")))
    assert sequential_design.default_control(baselines) == "pairs"  # no TAC to compare them with
    with pytest.raises(TacbenchError, match="--control q=x: HalfCheetah-v4 has no such method"):
        sequential_design.control_of(Design(control="q=x"), "HalfCheetah-v4", cheetah)


def test_bad_designs_are_refused_with_what_to_change(tmp_path: Path) -> None:
    alone = narrow(HOPPER, Narrowing(q=(2.0,)))
    with pytest.raises(TacbenchError, match=r"Hopper-v4 has one \(TAC q=2\)"):
        run_until_decided(alone, tmp_path / "one", driver.Options(), Design(), train=FakeTrain())
    assert not (tmp_path / "one").exists()
    with pytest.raises(TacbenchError, match="--interim-runs and --interims"):
        Design(n=0)
    with pytest.raises(TacbenchError, match="--fwer"):
        Design(alpha=1.5)
    with pytest.raises(TacbenchError, match=r"x --interims 1000000 is 5,000,000 runs per method"):
        Design(K=1_000_000)  # the dry run used to hang planning five million seeds per method
    Design(n=10, K=100)
    # a grid without its default control: not blamed on a --control that was never given
    no_sac = narrow(HOPPER, Narrowing(q=(2.0, 5.0)))
    with pytest.raises(TacbenchError, match=r"Hopper-v4 has no SAC \(TAC q=1\), this grid's"):
        run_until_decided(no_sac, tmp_path / "x", driver.Options(), Design(), train=FakeTrain())
    with pytest.raises(TacbenchError, match=r"--control q=1: Hopper-v4 has no such method"):
        describe_design(no_sac, tmp_path / "x", driver.Options(), Design(control="q=1"))
    never = Design(n=2, K=2, alpha=0.05)
    with pytest.raises(TacbenchError, match=r"can ever be decided.*--interim-runs 3 can"):
        run_until_decided(HOPPER, tmp_path, driver.Options(), never, train=FakeTrain())
    assert not (tmp_path / "runs").exists()
    # the dry run refuses it too, naming the n that can (it used to price it, saying "never")
    with pytest.raises(TacbenchError, match=r"can ever be decided.*--interim-runs 3 can"):
        describe_design(HOPPER, tmp_path, driver.Options(), never)


def test_runs_without_evaluations_are_refused_before_anything_trains(tmp_path: Path) -> None:
    """Each interim is scored by its runs' final evaluation returns: --eval-every 0 trained a
    whole interim and then stopped on the first eval.csv without rows, and a changed
    --eval-every was then refused as another config."""
    blind = narrow(HOPPER, Narrowing(settings={"eval_every": 0}))
    train = FakeTrain()
    with pytest.raises(TacbenchError, match=r"would make none \(--eval-every 0\)"):
        run_until_decided(blind, tmp_path, driver.Options(), Design(), train=train)
    assert train.trained == [] and not (tmp_path / "runs").exists()
    with pytest.raises(TacbenchError, match="--eval-every a number of steps"):
        describe_design(blind, tmp_path, driver.Options(), Design())


def test_runs_given_up_are_told_to_rerun_with_more_retries(tmp_path: Path) -> None:
    """After a run was given up the command said both 'a larger --max-retries' (the sweep) and
    'rerun the same command' (which trains nothing and gives up again)."""

    def gives_up(grid: Preset, out: Path, *args: Any, **kw: Any) -> driver.SweepResult:
        counts = {"given_up": 2, "failed": 2, "cannot_resume": 0}
        return driver.SweepResult({"counts": counts}, "2 failed (2 given up)", False)

    outcome = run_until_decided(HOPPER, tmp_path, driver.Options(), Design(), train=gives_up)
    assert outcome.text.endswith(
        "interim 1 gave up on 2 runs after too many failures; see why above, then rerun it "
        "with a larger --max-retries to continue."
    )
    assert "rerun the same command" not in outcome.text


def test_runs_that_cannot_resume_are_told_to_be_fixed(tmp_path: Path) -> None:
    """A run refused for its damaged files is not retried: the same command alone would be
    refused again, so the command says to fix them first."""

    def refuses(grid: Preset, out: Path, *args: Any, **kw: Any) -> driver.SweepResult:
        counts = {"given_up": 0, "failed": 0, "cannot_resume": 1}
        return driver.SweepResult({"counts": counts}, "1 run cannot resume", False)

    outcome = run_until_decided(HOPPER, tmp_path, driver.Options(), Design(), train=refuses)
    assert outcome.exit_code == 1
    assert outcome.text.endswith(
        "interim 1 could not resume every run from its files; see why above, fix them, then "
        "rerun the same command to continue it."
    )


def test_a_decided_comparison_stops_spending_runs(tmp_path: Path) -> None:
    train = FakeTrain()
    outcome = run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2), train=train)
    result = outcome.results["Hopper-v4"]
    assert result.decisions == {
        ("TAC q=2", "SAC (TAC q=1)"): "not distinguishable",
        ("TAC q=5", "SAC (TAC q=1)"): "smaller",
    }
    assert result.decided_at(("TAC q=5", "SAC (TAC q=1)")) == 1
    assert result.runs_spent == 5 + 10 + 10 < result.fixed_runs == 30
    q5 = sorted(key for key in train.trained if "/q5-" in key)
    assert [key.rsplit("seed", 1)[1] for key in q5] == ["0", "10", "20", "30", "40"]
    record = json.loads((tmp_path / "sweep" / "sequential.json").read_text())
    assert record["design"]["control"] == "SAC (TAC q=1)"
    second = record["interims"]["Hopper-v4"][1]
    assert second["seeds"]["TAC q=5"] == [0, 10, 20, 30, 40]
    assert second["scores"]["TAC q=2"] == [level(2.0, s) for s in range(0, 100, 10)]
    summary = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    assert summary["counts"]["complete"] == 25
    rows = {r["method"]: r for r in summary["sequential"]}
    assert rows["TAC q=5"] == {
        "env": "Hopper-v4",
        "method": "TAC q=5",
        "against": "SAC (TAC q=1)",
        "decision": "smaller",
        "interim": 1,
        "runs": 10,
    }
    assert "25 runs (a fixed design of 5 x 2 seeds: 30)" in outcome.text


def test_the_plans_warnings_are_printed_at_the_first_interim_only(tmp_path: Path) -> None:
    """Each interim's sweep is told what the earlier ones warned of (it printed them every
    interim before)."""
    warning = "WARNING: tac Hopper-v4: --learning-starts 500 is not below --steps 300"
    train = FakeTrain(warnings=(warning,))
    run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2), train=train)
    assert train.told == [frozenset(), {warning}]


def test_the_report_says_what_an_open_comparison_could_have_detected(tmp_path: Path) -> None:
    run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2), train=FakeTrain())
    table = analyse(ReportOptions(results=tmp_path, out=tmp_path / "r", reps=100)).sequential
    rows = table.set_index("method")
    assert rows.loc["TAC q=2", "decision"] == "not distinguishable"
    scores = {q: [level(q, s) for s in range(0, 100, 10)] for q in (1.0, 2.0)}
    expected = detectable_difference(scores[1.0], scores[2.0])
    assert rows.loc["TAC q=2", "detectable"] == pytest.approx(expected)
    assert np.isnan(rows.loc["TAC q=5", "detectable"])  # decided: nothing to bound


def test_a_sweep_stopped_mid_interim_continues_to_the_same_decisions(tmp_path: Path) -> None:
    whole = run_until_decided(
        HOPPER, tmp_path / "a", driver.Options(), Design(n=5, K=2), train=FakeTrain()
    )
    stopped = FakeTrain(stop_after=17)  # interim 1's 15 runs and 2 of interim 2's 10
    first = run_until_decided(
        HOPPER, tmp_path / "b", driver.Options(), Design(n=5, K=2), train=stopped
    )
    assert first.exit_code == 130 and "rerun the same command" in first.text
    again = FakeTrain()
    second = run_until_decided(
        HOPPER, tmp_path / "b", driver.Options(), Design(n=5, K=2), train=again
    )
    assert len(again.trained) == 8  # only what interim 2 still lacked
    assert second.results["Hopper-v4"] == whole.results["Hopper-v4"]
    assert second.exit_code == 0


def test_a_record_of_another_design_or_an_edited_decision_is_refused(tmp_path: Path) -> None:
    run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2), train=FakeTrain())
    with pytest.raises(TacbenchError, match=r"another sequential design.*another --out"):
        run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=3))
    with pytest.raises(TacbenchError, match=r"another sequential design"):
        run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2, control="q=2"))
    # runs of other settings under the same labels: their scores would have joined the record's
    other = narrow(HOPPER, Narrowing(settings={"learning_starts": 500}))
    with pytest.raises(TacbenchError, match=r"interims of runs with other settings"):
        run_until_decided(other, tmp_path, driver.Options(), Design(n=5, K=2), train=FakeTrain())
    same = Design(n=5, K=2, control="q=1")  # the recorded default control, spelled another way
    resumed = run_until_decided(HOPPER, tmp_path, driver.Options(), same, train=FakeTrain())
    assert resumed.exit_code == 0
    path = tmp_path / "sweep" / "sequential.json"
    record = json.loads(path.read_text())
    record["interims"]["Hopper-v4"][0]["decisions"][1]["decision"] = "continue"
    path.write_text(json.dumps(record))
    with pytest.raises(TacbenchError, match=r"replays to .*not the recorded"):
        run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2))


@pytest.mark.parametrize(
    ("damage", "fault"),
    [
        (lambda r: r["interims"].pop("Hopper-v4"), r"interims of \[\], methods of \['Hopper-v4'\]"),
        (lambda r: r["methods"].pop("Hopper-v4"), r"interims of \['Hopper-v4'\], methods of \[\]"),
        (lambda r: r.pop("design"), "no 'design' object"),
        (lambda r: r["design"].pop("K"), "its design lacks n, K or alpha"),
        (lambda r: r["interims"]["Hopper-v4"][1].pop("scores"), "an interim of Hopper-v4 without"),
        (lambda r: r.update(interims=[]), "no 'interims' object"),
    ],
)
def test_a_damaged_record_is_refused_by_the_sweep_its_dry_run_and_the_report(
    tmp_path: Path, damage: Any, fault: str
) -> None:
    """Each was a KeyError or AttributeError traceback in one of the three, or, in the report,
    a task's interims silently dropped."""
    run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2), train=FakeTrain())
    path = tmp_path / "sweep" / "sequential.json"
    record = json.loads(path.read_text())
    damage(record)
    path.write_text(json.dumps(record))
    expected = rf"sequential.json is damaged \({fault}.*or move it away"
    with pytest.raises(TacbenchError, match=expected):
        run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2), train=FakeTrain())
    with pytest.raises(TacbenchError, match=expected):
        describe_design(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2))
    with pytest.raises(TacbenchError, match=expected):
        analyse(ReportOptions(results=tmp_path, out=tmp_path / "report"))
    assert json.loads(path.read_text()) == record  # nothing rewritten


def test_the_dry_run_states_the_most_it_can_cost(tmp_path: Path) -> None:
    text = until_decided.describe_design(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2))
    assert "Hopper-v4: 3 methods (each against SAC (TAC q=1))" in text
    assert "earliest possible decision: interim 1" in text
    assert "at most 30 runs (a fixed design of 5 x 2 seeds: 30)" in text
    assert "cost estimate:" in text
    assert not (tmp_path / "sweep").exists()


def test_the_dry_run_prices_the_interims_one_after_another(tmp_path: Path) -> None:
    """Its wall time packed every interim's units onto the workers at once: on 6 workers, 30
    runs in units of 5 (the fixed design's plan) where each interim trains 15 in units of 3."""
    options = driver.Options(workers=6, members=5)
    text = describe_design(HOPPER, tmp_path, options, Design(n=5, K=2))
    first = narrow(HOPPER, Narrowing(seeds=(0, 10, 20, 30, 40)))
    interim = driver.load_plan(first, tmp_path, options, save=False)[0]
    assert [len(unit.runs) for unit in interim.units] == [3] * 5
    each = dry_run.price(interim, 6).wall_seconds
    assert f"about {duration(2 * each)} (" in text and "; 2 interims one after another)" in text


def test_the_dry_run_counts_what_the_record_has_decided(tmp_path: Path) -> None:
    """After interim 1 decided q = 5 (smaller), it trains no further: 5 + 10 + 10 at most."""
    stopped = FakeTrain(stop_after=15)  # interim 1 complete, nothing of interim 2
    run_until_decided(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2), train=stopped)
    text = until_decided.describe_design(HOPPER, tmp_path, driver.Options(), Design(n=5, K=2))
    assert "decisions so far: TAC q=2 vs SAC (TAC q=1): continue" in text
    assert "TAC q=5 vs SAC (TAC q=1): smaller" in text
    assert "at most 25 runs (a fixed design of 5 x 2 seeds: 30)" in text


def test_sequential_flags_need_until_decided() -> None:
    result = CliRunner().invoke(cli, ["sweep", "--preset", "smoke", "--interims", "3"])
    assert result.exit_code == 2
    assert "--interims only applies with --until-decided" in result.output
    result = CliRunner().invoke(
        cli, ["sweep", "--preset", "smoke", "--interims", "3", "--fwer", "0.1"]
    )
    assert "--interims and --fwer only apply with --until-decided" in result.output
    decided = ["sweep", "--preset", "smoke", "--until-decided", "--dry-run"]
    result = CliRunner().invoke(cli, [*decided, "--seed", "0"])
    assert result.exit_code == 2 and "leave --seed out" in result.output
    for flag in ("--calibrate", "--recalibrate"):
        result = CliRunner().invoke(cli, [*decided, flag])
        assert result.exit_code == 2 and f"{flag} prices a plain sweep's plan" in result.output


def test_q_auto_is_refused_in_one_line_saying_where_populations_train(tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["sweep", "--preset", "smoke", "--q", "auto", "--until-decided", "--out", str(out)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2
    [line] = result.output.strip().splitlines()
    assert "--q auto trains one population" in line and "tacbench run" in line
    assert not out.exists()


def test_an_adaptive_smoke_sweep_killed_mid_interim_resumes_to_the_same_decisions(
    tmp_path: Path,
) -> None:
    """The real thing, as small as a decidable design gets: TAC q = 1 and 2 on Hopper, two
    interims of two runs, family-wise error rate 0.2 (lower cannot decide with 8 runs). Killed
    (SIGKILL to the sweep and its worker, as when a machine goes down) once interim 2's first
    run has checkpointed and trained on, then run again, against one run straight through."""
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--until-decided"]
    args += ["--interim-runs", "2", "--fwer", "0.2", "--workers", "1", "--out"]
    straight = CliRunner().invoke(cli, [*args, str(tmp_path / "straight")])
    assert straight.exit_code == 0, straight.output
    out = tmp_path / "killed"
    killed_run = out / "runs/tac/Hopper-v4/q1-a0.2-ls500-bs32/seed20"  # interim 2's first
    proc = start_cli([*args, str(out)], session=True)
    try:
        wait_for(past_checkpoint(killed_run, 500), timeout=180, proc=proc, what="interim 2")
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        output = proc.communicate()[0]
    assert "interim 2 of 2" in output and "not distinguishable" not in output
    again = CliRunner().invoke(cli, [*args, str(out)])
    assert again.exit_code == 0, again.output
    assert "interim 1 of 2" not in again.output  # interim 1 is not trained or decided again
    record = json.loads((out / "sweep" / "sequential.json").read_text())
    expected = json.loads((tmp_path / "straight" / "sweep" / "sequential.json").read_text())
    assert record == expected  # the same seeds, final returns and decisions
    seeds = [interim["seeds"]["TAC q=2"] for interim in record["interims"]["Hopper-v4"]]
    assert seeds == [[0, 10], [0, 10, 20, 30]]
    assert straight.output.splitlines()[-3:-1] == again.output.splitlines()[-3:-1]
    assert_same_results(killed_run, tmp_path / "straight" / killed_run.relative_to(out))
    report = CliRunner().invoke(cli, ["report", "--results", str(out), "--out", str(out / "r")])
    assert report.exit_code == 0, report.output
    page = (out / "r" / "report.md").read_text()
    assert "Sequential decisions" in page and "TAC q=2" in page
    spending = (out / "r" / "sequential_spending.csv").read_text().splitlines()
    assert spending == ["env,interims,runs,fixed_design_runs", "Hopper-v4,2,8,8"]
