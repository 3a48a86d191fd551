"""The parity study's commands and statistics (tacbench/studies/parity.py)."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner, Result

from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.studies import parity
from tests.report_fixtures import write_run

pytestmark = pytest.mark.unit


def test_commands_run_three_tacs_at_q1_and_sac_sb3_on_the_same_seeds_and_budget() -> None:
    lines = parity.commands(["Hopper-v4", "Humanoid-v4"], [0, 10], 5000, "out")
    assert [shlex.split(line)[:4] for line in lines] == [
        ["tacbench", "run", "--q", "1"],
        ["tacbench", "run", "--q", "1"],
        ["tacbench", "run", "--q", "1"],
        ["tacbench", "run", "--algo", "sac-sb3"],
    ] * 2
    assert ["--critic-target" in line for line in lines] == [False, True, False, False] * 2
    assert ["--profile reference" in line for line in lines] == [False, False, True, False] * 2
    for line in lines:
        assert "--seed 0 --seed 10 --steps 5000 --out out --quiet" in line
    assert "--alpha 0.05 --critic-target twin-q --env Humanoid-v4" in lines[5]  # paper alpha


@pytest.mark.parametrize(
    ("algo", "variant", "method"),
    [
        ("tac", "q1-a0.2", parity.TAC),
        ("tac", "q1-a0.2-twinq", parity.TAC_TWIN_Q),
        ("tac", "q1-a0.2-ref", parity.TAC_REFERENCE),
        ("tac", "q1-a0.2-ref-h300", parity.TAC_REFERENCE),
        ("tac", "q1-a0.2-reference_like", parity.TAC),  # a word, not the suffix
        ("sac-sb3", "default", parity.SB3),
    ],
)
def test_runs_are_named_by_profile_and_critic_target(algo: str, variant: str, method: str) -> None:
    assert parity._method(algo, variant) == method


def _frame() -> pd.DataFrame:
    rows = []
    for method, offset in (("TAC q=1", 100.0), ("SAC (SB3)", 0.0)):
        for seed in (0, 10, 20):
            for step in range(5000, 105_000, 5000):
                rows.append((method, "Hopper-v4", seed, step, offset + seed + step / 1000))
    return pd.DataFrame(rows, columns=["method", "env", "seed", "step", "return"])


def test_final_return_is_the_mean_over_the_last_tenth_of_the_steps() -> None:
    finals = parity.final_returns(_frame())
    row = finals[(finals["method"] == "SAC (SB3)") & (finals["seed"] == 10)]
    assert row["return"].item() == pytest.approx(10 + (90 + 95 + 100) / 3)  # 90k, 95k, 100k
    assert len(finals) == 6


@pytest.mark.parametrize("fraction", [0.45, 0.7, 0.8, 0.3])
def test_a_fraction_keeps_the_evaluation_at_its_boundary_whatever_the_rounding(
    fraction: float,
) -> None:
    """0.55 x 100,000 is 55,000.00000000001: the evaluation at 55,000 was left out at 0.45,
    kept at 0.4500000001."""
    finals = parity.final_returns(_frame(), fraction)
    row = finals[(finals["method"] == "SAC (SB3)") & (finals["seed"] == 10)]
    steps = range(round((1 - fraction) * 100), 101, 5)
    assert row["return"].item() == pytest.approx(10 + sum(steps) / len(steps))


def test_curves_and_summary() -> None:
    data = _frame()
    table = parity.curves(data)
    first = table[(table["method"] == "TAC q=1") & (table["step"] == 5000)]
    assert first["mean"].item() == pytest.approx(100 + 10 + 5) and first["seeds"].item() == 3
    assert first["std"].item() == pytest.approx(10.0)
    summary, cautions = parity.summary(parity.final_returns(data), reps=2000)
    assert list(summary["method"]) == [parity.TAC] and cautions == []  # no twin-q runs here
    row = summary.iloc[0]
    assert row["TAC - SB3"] == pytest.approx(100.0)
    # seeds (returns 0, 10, 20 above the method's offset) are resampled independently per method
    assert 80.0 <= row["CI low"] < 100.0 < row["CI high"] <= 120.0
    assert row["TAC seeds"] == row["SB3 seeds"] == 3


def test_bootstrap_interval_covers_the_difference_of_means() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(10.0, 2.0, 5), rng.normal(8.0, 2.0, 5)
    diff, low, high = parity.bootstrap_difference(a, b, reps=5000)
    assert diff == pytest.approx(a.mean() - b.mean())
    assert low < diff < high
    se = np.sqrt(a.var() / 5 + b.var() / 5)  # the interval is about +/- 2 standard errors
    assert 2.5 * se < high - low < 5.0 * se
    assert parity.bootstrap_difference(a, b, reps=5000) == (diff, low, high)  # seeded


def test_recorded_finals_join_the_runs_and_are_compared(tmp_path: Path) -> None:
    """SB3's finals from an earlier study, recorded in a CSV, are compared with new TAC runs."""
    finals = parity.final_returns(_frame())
    tac_only = finals[finals["method"] == parity.TAC]
    recorded = tmp_path / "sb3.csv"
    sb3 = finals[finals["method"] == parity.SB3].assign(measured="2026-11-22")
    sb3.to_csv(recorded, index=False)
    joined = parity.recorded_finals(recorded, tac_only)
    assert list(joined.columns) == list(parity.FINALS_COLUMNS)
    pd.testing.assert_frame_equal(
        parity.summary(joined, reps=2000)[0], parity.summary(finals, reps=2000)[0]
    )


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ("env,method,seed\nHopper-v4,SAC (SB3),0\n", "lacks the columns ['return']"),
        ("env,method,seed,return\nHopper-v4,SAC,0,1.0\n", "unknown methods ['SAC']"),
        ("env,method,seed,return\nHopper-v4,TAC q=1,0,1.0\n", "keep one source"),
        ("", "is not a readable CSV"),
        ("env,method,seed,return\nHopper-v4,SAC (SB3),0,abc\n", "row 1 is not a finite number"),
        ("env,method,seed,return\nHopper-v4,SAC (SB3),0,\n", "row 1 is not a finite number"),
        ("env,method,seed,return\nHopper-v4,SAC (SB3),0,1\nHopper-v4,SAC (SB3),0,1\n", "seed 0"),
        ("env,method,seed,return\nHopper,SAC (SB3),0,1.0\n", "write its Gymnasium id, 'Hopper-v4'"),
    ],
)
def test_recorded_finals_refuse_bad_files(tmp_path: Path, rows: str, message: str) -> None:
    path = tmp_path / "finals.csv"
    path.write_text(rows)
    with pytest.raises(TacbenchError, match=re.escape(message)):
        parity.recorded_finals(path, parity.final_returns(_frame()))


def _write_study(root: Path) -> None:
    """Two TAC variants and SB3 on Hopper, 3 seeds, evaluations at 10k..40k; the returns are
    the variant's level plus the seed."""
    levels = {("tac", "q1-a0.2"): 100.0, ("tac", "q1-a0.2-warmupon"): 300.0}
    levels[("sac-sb3", "default")] = 200.0
    for (algo, variant), level in levels.items():
        for seed in (0, 10, 20):
            write_run(
                root,
                algo=algo,
                env="Hopper-v4",
                variant=variant,
                seed=seed,
                steps=[10_000.0, 20_000.0, 30_000.0, 40_000.0],
                returns=[0.0, 0.0, level + seed, level + seed],
                q=1.0 if algo == "tac" else None,
                alpha=0.2 if algo == "tac" else None,
            )


def test_an_ablation_names_tac_runs_by_variant_and_scores_a_window(tmp_path: Path) -> None:
    """analyse --by-variant --fraction 0.25: each TAC variant is its own method, scored by the
    evaluations in the last quarter of the steps (30k and 40k), against SB3."""
    _write_study(tmp_path / "study")
    with pytest.raises(TacbenchError, match="several variants of one method"):
        parity.load(tmp_path / "study")
    out = tmp_path / "analysis"
    study = ["--results", str(tmp_path / "study"), "--out", str(out), "--reps", "200"]
    result = _analyse([*study, "--by-variant", "--fraction", "0.25"])
    assert result.exit_code == 0, result.output
    summary = pd.read_csv(out / "summary.csv").set_index("method")
    assert list(summary.index) == ["TAC q1-a0.2", "TAC q1-a0.2-warmupon"]
    assert summary.loc["TAC q1-a0.2", "TAC - SB3"] == pytest.approx(-100.0)
    assert summary.loc["TAC q1-a0.2-warmupon", "TAC - SB3"] == pytest.approx(100.0)
    assert (out / "curves.png").exists()
    refused = _analyse(["--results", str(tmp_path / "study"), "--fraction", "0"])
    assert refused.exit_code == 2 and "--fraction must be in (0, 1]" in refused.output


def _analyse(args: list[str]) -> Result:
    return CliRunner().invoke(cli, ["study", "parity", "analyse", *args])


STUDY = Path(__file__).resolve().parents[1] / "results" / "studies" / "parity-100k"
SB3_HALFCHEETAH = STUDY / "runs" / "sac-sb3" / "HalfCheetah-v4"


@pytest.mark.smoke
@pytest.mark.parametrize(
    ("folder", "options", "runs"),
    [
        ("", [], 4 * 2 * 5),  # three TACs and SB3's SAC, two tasks, five seeds
        ("ablation-40k", ["--by-variant", "--fraction", "0.375"], 25),
        ("ablation-100k", ["--by-variant", "--results", str(SB3_HALFCHEETAH)], 10),
    ],
    ids=["study", "ablation-40k", "ablation-100k"],
)
def test_the_published_study_is_complete_and_its_tables_regenerate(
    tmp_path: Path, folder: str, options: list[str], runs: int
) -> None:
    """docs/parity.md's numbers: every run complete, no checkpoints, and ``analyse`` with the
    options the study used writes the committed tables again, byte for byte."""
    results = STUDY / folder
    statuses = [json.loads(p.read_text()) for p in results.glob("runs/*/*/*/seed*/status.json")]
    assert len(statuses) == runs
    assert {s["state"] for s in statuses} == {"complete"}
    assert not list(results.glob("runs/**/checkpoint"))
    result = _analyse(["--results", str(results), *options, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    for table in sorted((results / "analysis").glob("*.csv")):
        assert (tmp_path / table.name).read_text() == table.read_text(), table.name


def test_the_studys_sb3_runs_are_the_comparison_studys() -> None:
    """SB3's SAC in the parity study is the comparison study's five runs per task (the same
    config, seeds and budget), copied: the copies stay theirs byte for byte."""
    comparison = STUDY.parent / "comparison-100k"
    copies = sorted(p for p in (STUDY / "runs" / "sac-sb3").rglob("*") if p.is_file())
    assert len(copies) == 2 * 5 * 5  # two tasks, five seeds, five files each
    for copy in copies:
        original = comparison / copy.relative_to(STUDY)
        assert copy.read_bytes() == original.read_bytes(), copy


def test_a_folder_without_the_studys_runs_is_a_clear_error(tmp_path: Path) -> None:
    write_run(
        tmp_path,
        algo="tac",
        env="Hopper-v4",
        variant="q2-a0.2",
        seed=0,
        steps=[1.0],
        returns=[1.0],
        q=2.0,
        alpha=0.2,
    )
    with pytest.raises(TacbenchError, match="no complete run of TAC at q = 1 or of sac-sb3"):
        parity.analyse(tmp_path)


def test_the_commands_refuse_what_tacbench_run_would_refuse() -> None:
    runner = CliRunner()
    result = runner.invoke(cli, ["study", "parity", "commands", "--env", "Nope-v0"])
    assert result.exit_code == 2 and "unknown environment 'Nope-v0'" in result.output
    for flag, value in (("--seed", "-1"), ("--steps", "0")):
        result = runner.invoke(cli, ["study", "parity", "commands", flag, value])
        assert result.exit_code == 2 and "is not in the range" in result.output
    result = runner.invoke(cli, ["study", "parity", "commands", "--env", "hopper"])
    assert result.exit_code == 0 and "--env Hopper-v4" in result.output
    # a task or seed given twice: each once (tacbench run refused "--seed 0 --seed 0")
    twice = ["--env", "hopper", "--env", "Hopper-v4", "--seed", "0", "--seed", "0"]
    result = runner.invoke(cli, ["study", "parity", "commands", *twice])
    alone = runner.invoke(cli, ["study", "parity", "commands", "--env", "hopper", "--seed", "0"])
    assert result.exit_code == 0 and result.output == alone.output
    assert "--seed 0 --seed 0" not in result.output


def _hopper(
    root: Path, algo: str, seed: int, total: int, state: str = "complete", level: float = 100.0
) -> None:
    steps = [total / 2, float(total)] if state == "complete" else [total / 2]
    write_run(
        root,
        algo=algo,
        env="Hopper-v4",
        variant="q1-a0.2" if algo == "tac" else "default",
        seed=seed,
        steps=steps,
        returns=[level + seed] * len(steps),
        q=1.0 if algo == "tac" else None,
        alpha=0.2 if algo == "tac" else None,
        total_steps=total,
        state=state,
    )


def test_runs_short_of_their_budget_or_of_another_budget_are_not_scored(tmp_path: Path) -> None:
    """A run stopped early used to be scored on its last evaluations beside runs trained to
    the budget; runs of two budgets on one task are refused (their final returns measure
    different things)."""
    for seed in (0, 10):
        _hopper(tmp_path, "tac", seed, 4000)
        _hopper(tmp_path, "sac-sb3", seed, 4000)
    _hopper(tmp_path, "tac", 20, 4000, "interrupted")
    finals = parity.final_returns(parity.load(tmp_path))
    assert sorted(finals.loc[finals["method"] == parity.TAC, "seed"]) == [0, 10]
    _hopper(tmp_path, "tac", 30, 1000)  # a shorter budget than its method's other runs
    finals = parity.final_returns(parity.load(tmp_path))
    assert sorted(finals.loc[finals["method"] == parity.TAC, "seed"]) == [0, 10]
    for seed in (0, 10):
        _hopper(tmp_path / "other", "tac", seed, 4000)
        _hopper(tmp_path / "other", "sac-sb3", seed, 1000)
    with pytest.raises(TacbenchError, match=r"Hopper-v4 under .* budgets of 1,000 and 4,000 "):
        parity.load(tmp_path / "other")


@pytest.mark.parametrize(
    ("algo", "caution"),
    [
        ("sac-sb3", "Hopper-v4: no finished TAC run; it has no row"),
        (
            "tac",
            "Hopper-v4: no finished SB3 run (nor recorded finals: --finals); its TAC - SB3 "
            "columns are empty",
        ),
    ],
)
def test_a_task_with_one_side_only_is_said(tmp_path: Path, algo: str, caution: str) -> None:
    """One side only used to give an empty summary (one byte of CSV) or one without the
    difference columns, with exit 0 and no word."""
    for seed in (0, 10):
        _hopper(tmp_path / "study", algo, seed, 4000)
    out = tmp_path / "analysis"
    result = _analyse(["--results", str(tmp_path / "study"), "--out", str(out), "--reps", "100"])
    assert result.exit_code == 0, result.output
    assert f"caution: {caution}" in result.output
    assert list(pd.read_csv(out / "summary.csv").columns) == list(parity.SUMMARY_COLUMNS)
    assert pd.read_csv(out / "cautions.csv")["caution"].tolist() == [caution]


def test_out_is_checked_before_the_analysis_and_never_replaces_an_input(tmp_path: Path) -> None:
    """--out holding the --finals file used to have it replaced by the combined table (the
    same command then refused its own output); a file in --out's path, or a folder where a
    table goes, failed only after the analysis, with a traceback."""
    for seed in (0, 10):
        _hopper(tmp_path / "study", "tac", seed, 4000)
    out = tmp_path / "analysis"
    out.mkdir()
    finals = out / "finals.csv"
    finals.write_text("env,method,seed,return,note\nHopper-v4,SAC (SB3),0,1.0,kept\n")
    study = ["--results", str(tmp_path / "study"), "--reps", "100"]
    result = _analyse([*study, "--finals", str(finals), "--out", str(out)])
    assert (
        result.exit_code == 2 and f"--out {out} would replace the input {finals}" in result.output
    )
    assert finals.read_text().endswith(",kept\n")
    (out / "summary.csv").mkdir()
    result = _analyse([*study, "--out", str(out)])
    assert result.exit_code == 2 and f"{out / 'summary.csv'} is a folder" in result.output
    result = _analyse([*study, "--out", str(finals / "sub")])
    assert result.exit_code == 2 and "cannot create or write the output folder" in result.output
    assert "Traceback" not in result.output


def test_analyse_writes_every_table_it_names(tmp_path: Path) -> None:
    for seed in (0, 10):
        _hopper(tmp_path / "study", "tac", seed, 4000)
        _hopper(tmp_path / "study", "sac-sb3", seed, 4000)
    out = tmp_path / "analysis"
    result = _analyse(["--results", str(tmp_path / "study"), "--out", str(out), "--reps", "100"])
    assert result.exit_code == 0, result.output
    files = {*(f"{name}.csv" for name in parity.TABLES), parity.FIGURE}
    assert {p.name for p in out.iterdir()} == files
    assert (out / "cautions.csv").read_text() == "caution\n"  # none, said by an empty table


def test_runs_left_out_are_named_in_the_cautions(tmp_path: Path) -> None:
    """A failed run (the loader skips it) and one short of its budget used to go unmentioned."""
    for seed in (0, 10):
        _hopper(tmp_path / "study", "tac", seed, 4000)
        _hopper(tmp_path / "study", "sac-sb3", seed, 4000)
    _hopper(tmp_path / "study", "tac", 20, 4000, "interrupted")
    _hopper(tmp_path / "study", "sac-sb3", 20, 4000, "failed")
    tables = parity.analyse(tmp_path / "study", reps=100)
    assert tables["cautions"]["caution"].tolist() == [
        "left out 1 run directory that cannot be used: sac-sb3/Hopper-v4/default/seed20 (run "
        "failed at step 2000: no reason given)",
        "left out 1 run short of the budget: tac/Hopper-v4/q1-a0.2/seed20 (interrupted at step "
        "2,000)",
    ]


def test_runs_of_several_folders_are_one_study_and_a_run_in_two_is_refused(
    tmp_path: Path,
) -> None:
    """--results is repeatable (an ablation's TAC runs beside the study's SB3 runs): the tables
    are those of one folder holding them all, a left-out run is named with its folder, and a
    run in two of the folders is refused rather than counted twice."""
    for folder, algo, level in (("tac", "tac", 300.0), ("sb3", "sac-sb3", 0.0)):
        for seed in (0, 10, 20):
            for root in (tmp_path / folder, tmp_path / "both"):
                _hopper(root, algo, seed, 4000, level=level)
    _hopper(tmp_path / "sb3", "sac-sb3", 30, 4000, "failed")
    apart = parity.analyse([tmp_path / "tac", tmp_path / "sb3"], reps=100)
    together = parity.analyse(tmp_path / "both", reps=100)
    for name in ("curves", "finals", "summary"):
        pd.testing.assert_frame_equal(apart[name], together[name])
    assert apart["summary"]["TAC - SB3"].tolist() == [pytest.approx(300.0)]
    assert apart["cautions"]["caution"].tolist() == [
        f"left out 1 run directory that cannot be used: {tmp_path / 'sb3'}/sac-sb3/Hopper-v4/"
        "default/seed30 (run failed at step 2000: no reason given)"
    ]
    out = tmp_path / "analysis"
    folders = ["--results", str(tmp_path / "tac"), "--results", str(tmp_path / "sb3")]
    result = _analyse([*folders, "--out", str(out), "--reps", "100"])
    assert result.exit_code == 0, result.output
    assert pd.read_csv(out / "summary.csv")["SB3 seeds"].tolist() == [3]
    with pytest.raises(TacbenchError, match=r"tac q1-a0.2 seed 0 on Hopper-v4 is in more than one"):
        parity.analyse([tmp_path / "tac", tmp_path / "both"], reps=100)
