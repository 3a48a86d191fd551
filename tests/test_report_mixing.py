"""The report's cautions: several TAC settings or several budgets on one task."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.report import ReportOptions, analyse, write_report
from tacbench.report.mixing import cautions, eval_intervals, tac_setting, without_q
from tests.report_fixtures import write_run

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(
    ("variant", "setting"),
    [
        ("q1.5-a0.2", ""),
        ("q1.5-a0.2-bs32", "bs32"),
        ("qauto-aauto0.2-joint-log_std_min-5", "joint-log_std_min-5"),
        ("q1e-05-a0.2-ref", "ref"),
    ],
)
def test_a_tac_setting_is_its_variant_without_q_and_alpha(variant: str, setting: str) -> None:
    assert tac_setting(variant) == setting


@pytest.mark.parametrize(
    ("variant", "design"),
    [("q1.5-a0.2", "a0.2"), ("qauto-aauto0.2", "aauto0.2"), ("q1e-05-a0.2-bs32", "a0.2-bs32")],
)
def test_a_variant_without_q_names_its_runs_across_q(variant: str, design: str) -> None:
    assert without_q(variant) == design


def _runs(rows: list[tuple[str, str, str, float]], logged: int = 20) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=["algo", "env", "variant", "total_steps"])
    paths = [f"run{i}" for i in range(len(rows))]
    return frame.assign(rows=logged, dropped=0, partial=False, path=paths)


def test_several_settings_or_budgets_on_a_task_are_cautioned() -> None:
    alike = _runs([("tac", "H", "q1-a0.2", 1e5), ("tac", "H", "q2-a0.05", 1e5)])
    assert cautions(alike, 10) == []  # q and alpha are what a report compares
    settings = _runs([("tac", "H", "q1-a0.2-bs32", 1e5), ("tac", "H", "q2-a0.2", 1e5)])
    [caution] = cautions(settings, 10)
    assert caution.startswith("H: TAC runs of 2 settings (the defaults, `bs32`)")
    budgets = _runs([("tac", "H", "q1-a0.2", 1e3), ("td3", "H", "default", 1e5)])
    [caution] = cautions(budgets, 10)
    assert caution.startswith("H: runs planned for 2 budgets (1,000, 100,000 steps)")
    unknown = _runs([("tac", "H", "q1-a0.2", math.nan), ("td3", "H", "default", 1e5)])
    assert cautions(unknown, 10) == []


def test_float32_and_bf16_runs_are_no_mix_to_caution_of_but_settings_within_each_are() -> None:
    """float32 and bf16 runs are never compared or pooled with each other (each compares with
    its own q = 1; bf16 runs stay out of the q ranges): only settings within one are a mix."""
    products = _runs([("tac", "H", "q1-a0.2", 1e5), ("tac", "H", "q1.5-a0.2-bf16", 1e5)])
    assert cautions(products, 10) == []
    bf16 = _runs([("tac", "H", "q1-a0.2-bf16", 1e5), ("tac", "H", "q1-a0.2-bs32-bf16", 1e5)])
    [caution] = cautions(bf16, 10)
    assert caution.startswith("H: TAC runs of 2 settings (`bf16`, `bs32-bf16`); the comparisons")
    assert "with q = 1 take them as one family" in caution


def test_a_last_beyond_the_runs_logged_returns_is_cautioned() -> None:
    """--last longer than a run's rows makes its final return the mean of all of them, the
    first evaluations included: said once, with how many runs and the fewest rows."""
    runs = _runs([("tac", "H", "q1-a0.2", 1e5), ("td3", "H", "default", 1e5)], logged=20)
    assert cautions(runs, 20) == []
    runs.loc[1, "rows"] = 4
    assert cautions(runs, 1_000_000) == [
        "2 of 2 runs logged fewer returns than --last 1,000,000 (the fewest: 4): their final "
        "return is the mean of all of them, early ones included."
    ]


def test_runs_with_non_finite_returns_left_out_are_cautioned() -> None:
    """A diverged evaluation's row was dropped without a word: a complete run showed no note,
    and its final return was of the rows before."""
    runs = _runs([("tac", "H", "q1-a0.2", 1e5), ("td3", "H", "default", 1e5)])
    assert cautions(runs, 10) == []
    runs.loc[1, "dropped"] = 2
    assert cautions(runs, 10) == [
        "1 of 2 runs logged rows with a non-finite step or return (run1; 2 rows in all), which "
        "are left out: a diverged evaluation or episode is in none of their scores."
    ]


def test_a_complete_runs_dropped_rows_are_counted_on_the_page(tmp_path: Path) -> None:
    """docs/report.md: "the run's note says how many"; the page showed notes of partial runs
    only, and runs.csv has no note column, so a complete run's count was nowhere."""
    for seed, returns in ((0, [1.0, math.nan, 3.0, 4.0]), (1, [1.0, 2.0, 3.0, 4.0])):
        write_run(
            tmp_path,
            algo="tac",
            env="Hopper-v4",
            variant="q1-a0.2",
            seed=seed,
            steps=[100, 200, 300, 400],
            returns=returns,
            q=1.0,
            alpha=0.2,
        )
    write_report(analyse(ReportOptions(results=tmp_path, out=tmp_path / "out", reps=100)))
    page = (tmp_path / "out" / "report.md").read_text()
    assert "Complete runs with a note (included)" in page
    assert "| tac/Hopper-v4/q1-a0.2/seed0 | eval.csv: 1 row with a non-finite" in page
    assert "q1-a0.2/seed1 |" not in page.split("Complete runs with a note")[1]


def test_the_report_prints_and_shows_its_cautions(tmp_path: Path) -> None:
    for variant, q in (("q1-a0.2", 1.0), ("q2-a0.2-bs32", 2.0)):
        for seed in (0, 10):
            write_run(
                tmp_path,
                algo="tac",
                env="Hopper-v4",
                variant=variant,
                seed=seed,
                steps=[1.0, 2.0],
                returns=[1.0, 2.0 + seed],
                q=q,
                alpha=0.2,
            )
    out = tmp_path / "report"
    result = CliRunner().invoke(cli, ["report", "--results", str(tmp_path), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "caution: Hopper-v4: TAC runs of 2 settings" in result.output
    assert "Caution: Hopper-v4: TAC runs of 2 settings" in (out / "report.md").read_text()


def test_runs_evaluated_at_several_intervals_on_a_task_are_cautioned(tmp_path: Path) -> None:
    """q = 1 evaluated every 1,000 steps and q = 1.5 every 5,000, on one learning curve: the
    last 10 evaluations averaged 90,000-100,000 against 55,000-100,000, and the test called q =
    1.5 "smaller" (p = 0.002) without a word."""
    for q, every in ((1.0, 1000), (1.5, 5000)):
        for seed in (0, 10, 20):
            steps = [float(s) for s in range(every, 100_001, every)]
            write_run(
                tmp_path,
                algo="tac",
                env="Hopper-v4",
                variant=f"q{q:g}-a0.2",
                seed=seed,
                steps=steps,
                returns=[s / 100 + seed for s in steps],
                q=q,
                alpha=0.2,
            )
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "r", reps=100))
    spacing = [c for c in report.cautions if "evaluated every" in c]
    assert spacing == [
        "Hopper-v4: runs evaluated every 1,000, 5,000 steps; their final returns (the last 10 "
        "evaluations each) span 9,000, 45,000 steps of training, compared as if alike."
    ]
    assert eval_intervals(report.runset.data, 1) == []  # each run's final evaluation alike
    train = analyse(ReportOptions(results=tmp_path, out=tmp_path / "r", reps=100, metric="train"))
    assert not [c for c in train.cautions if "evaluated every" in c]  # episodes end anywhere
    alike = report.runset.data[report.runset.data["q"] == 1.0]
    assert eval_intervals(alike, 10) == []


def test_partial_runs_in_the_comparisons_are_cautioned() -> None:
    """Runs stopped at 30,000 of 100,000 steps were tested against complete ones ("smaller", p =
    0.008) with no word beside the verdicts."""
    runs = _runs([("tac", "H", "q1-a0.2", 1e5), ("tac", "H", "q1.5-a0.2", 1e5)])
    assert cautions(runs, 10) == []
    runs.loc[1, "partial"] = True
    [caution] = cautions(runs, 10)
    assert caution.startswith("1 of 2 runs are partial (run1): their final returns are taken")
