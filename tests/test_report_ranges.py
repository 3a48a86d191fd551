"""The q-range table (tacbench/report/ranges.py): TAC's runs pooled by range of q."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tacbench.report import ReportOptions, analyse, write_report
from tacbench.report.load import load_runs
from tacbench.report.ranges import q_range_table, within_run_spread
from tests.report_fixtures import synthetic_tree, write_run

pytestmark = pytest.mark.unit


def _ranges(root: Path, **tree: object) -> pd.DataFrame:
    synthetic_tree(root, **tree)  # type: ignore[arg-type]
    return analyse(ReportOptions(results=root, out=root / "report", reps=200)).q_ranges


def test_each_task_pools_its_runs_by_range_and_compares_the_outer_ranges(tmp_path: Path) -> None:
    # q_level: 1.5 best, then 1; q = 0.5 and 3 far below (20 noise, 3 seeds each)
    table = _ranges(tmp_path, qs=(0.5, 1.0, 1.5, 3.0), baselines=("td3",), spread=0.05)
    hopper = table[table["env"] == "Hopper-v4"].set_index("range")
    assert list(hopper.index) == ["0 < q < 1", "1 <= q < 2", "q >= 2"]
    assert list(hopper["qs"]) == ["0.5", "1, 1.5", "3"]
    assert list(hopper["runs"]) == [3, 6, 3]
    assert math.isnan(hopper.loc["1 <= q < 2", "p_middle"])
    for outer in ("0 < q < 1", "q >= 2"):
        row = hopper.loc[outer]
        assert row["p_middle"] == 1.0 and row["p_low"] == 1.0  # every middle run is higher
        assert row["iqm_low"] <= row["iqm"] <= row["iqm_high"]
        # the exact test: 2 of the C(9, 3) = 84 labellings are as far from 0.5
        assert (row["p_value"], row["verdict"]) == (pytest.approx(2 / 84), "larger")
    assert hopper.loc["1 <= q < 2", "iqm"] > hopper.loc["q >= 2", "iqm"]
    runset = load_runs(tmp_path, "eval")  # each range's spread: its runs' mean
    spread = within_run_spread(runset.data, ReportOptions(tmp_path, tmp_path).last)
    runs = runset.runs[(runset.runs["env"] == "Hopper-v4") & (runset.runs["algo"] == "tac")]
    for name, qs in (("0 < q < 1", [0.5]), ("1 <= q < 2", [1.0, 1.5]), ("q >= 2", [3.0])):
        members = runs.loc[runs["q"].isin(qs), "run"]
        assert hopper.loc[name, "spread"] == pytest.approx(spread[members].mean())
        assert hopper.loc[name, "spread"] > 0
    everything = table[table["env"] == "all tasks"].set_index("range")
    assert list(everything["runs"]) == [6, 12, 6]  # two tasks pooled
    assert (everything["iqm"].between(0.0, 1.0)).all()  # normalised scores
    assert everything["spread"].isna().all()
    assert (everything.loc[["0 < q < 1", "q >= 2"], "p_middle"] == 1.0).all()
    outer = everything.loc[["0 < q < 1", "q >= 2"], "p_value"].tolist()
    assert outer == pytest.approx([2 / 84**2] * 2)


def test_all_tasks_rows_only_for_the_ranges_every_task_has(tmp_path: Path) -> None:
    """A range that one task lacks got an "all tasks" row of the other tasks alone, beside rows
    of every task: all tasks pool the same tasks now, and the range keeps its per-task rows."""
    synthetic_tree(tmp_path, qs=(0.5, 1.0, 1.5, 3.0), baselines=())
    (lacking,) = tmp_path.glob("**/Hopper-v4/q0.5-a0.2")
    shutil.rmtree(lacking)
    table = analyse(ReportOptions(results=tmp_path, out=tmp_path / "report", reps=200)).q_ranges
    everything = table[table["env"] == "all tasks"].set_index("range")
    assert list(everything.index) == ["1 <= q < 2", "q >= 2"]
    assert list(everything["runs"]) == [12, 6]  # both tasks in each
    cheetah = table[table["env"] == "HalfCheetah-v4"]
    assert list(cheetah["range"]) == ["0 < q < 1", "1 <= q < 2", "q >= 2"]


def test_the_claim_is_of_a_fixed_alpha_learned_ones_are_left_out(tmp_path: Path) -> None:
    """Learned-alpha runs (-aauto) were pooled with the fixed ones, and runs without an alpha
    dropped by the grouping."""
    rows = []
    for run, (q, variant, alpha) in enumerate(
        [(q, f"q{q:g}-a0.2", 0.2) for q in (1.0, 1.5, 3.0) for _ in range(4)]
        + [(q, f"q{q:g}-aauto0.2", 0.2) for q in (1.0, 3.0) for _ in range(4)]
        + [(q, f"q{q:g}", math.nan) for q in (1.0, 3.0) for _ in range(4)]
    ):
        final = 100.0 * (q < 2 and variant != f"q{q:g}") + run  # no alpha: q = 3 ahead
        rows.append(
            dict(
                run=run,
                env="Hopper-v4",
                q=q,
                variant=variant,
                alpha=alpha,
                final=final,
                score=final / 200,
            )
        )
    scores = pd.DataFrame(rows)
    data = pd.DataFrame({"run": scores["run"].repeat(2), "return": 1.0})
    table = q_range_table(scores, data, last=2, reps=100, seed=0)
    fixed = table[table["alpha"] == 0.2].set_index("range")
    assert fixed["runs"].tolist() == [8, 4]  # the learned alpha's 8 runs are not among them
    assert table["alpha"].isna().sum() == 2  # the runs without an alpha have rows of their own
    verdicts = table.dropna(subset=["p_value"]).set_index("alpha", drop=False)["verdict"]
    assert verdicts.tolist() == ["larger", "smaller"]  # 1 <= q < 2 ahead, then behind q = 3


def test_bf16_runs_stay_out_of_the_ranges(tmp_path: Path) -> None:
    """The paper's claim is of float32 runs: bf16 runs (their own method, compared with their
    own q = 1) are not pooled into a range beside float32 ones."""
    synthetic_tree(tmp_path, tasks=("Hopper-v4",), qs=(0.5, 1.0, 1.5), baselines=())
    for seed in range(3):
        write_run(
            tmp_path,
            algo="tac",
            env="Hopper-v4",
            variant="q3-a0.2-bf16",
            seed=seed,
            q=3.0,
            alpha=0.2,
            steps=[5000.0, 10000.0],
            returns=[0.0, 10.0],
        )
    table = analyse(ReportOptions(results=tmp_path, out=tmp_path / "report", reps=100)).q_ranges
    assert table["range"].tolist() == ["0 < q < 1", "1 <= q < 2"]
    assert table["runs"].tolist() == [3, 6]


def test_a_sweep_inside_one_range_has_no_comparison(tmp_path: Path) -> None:
    table = _ranges(tmp_path, qs=(1.0, 1.5), baselines=())
    assert table.empty


def test_spread_is_the_std_of_each_runs_last_returns() -> None:
    data = pd.DataFrame(
        {
            "run": [0, 0, 0, 0, 1, 1],
            "step": [1, 2, 3, 4, 1, 2],
            "return": [100.0, 1.0, 2.0, 3.0, 5.0, 5.0],
        }
    )
    spread = within_run_spread(data, last=3)
    assert spread[0] == pytest.approx(np.std([1.0, 2.0, 3.0]))
    assert spread[1] == 0.0


def test_the_report_writes_and_shows_the_table(tmp_path: Path) -> None:
    root = synthetic_tree(tmp_path, qs=(0.5, 1.0, 1.5, 2.0), baselines=())
    write_report(analyse(ReportOptions(results=root, out=tmp_path / "out", reps=100)))
    assert (tmp_path / "out" / "q_ranges.csv").is_file()
    shown = (tmp_path / "out" / "q_ranges.md").read_text()
    assert "| HalfCheetah-v4 | 1 <= q < 2 | 1, 1.5 | 6 |" in shown
    assert "P(1 <= q < 2 > this range)" in (tmp_path / "out" / "report.md").read_text()


def test_a_task_run_at_several_alphas_names_each_rows_alpha(tmp_path: Path) -> None:
    """The shown table had no alpha column: a task run at two alphas gave pairs of rows that
    differed only in their figures."""
    root = synthetic_tree(tmp_path, tasks=("Hopper-v4",), qs=(1.0, 1.5, 3.0), baselines=())
    for variant in root.glob("runs/tac/Hopper-v4/q*-a0.2"):
        for seed in variant.glob("seed*"):
            returns = 1.5 * np.arange(1.0, 21.0) * float(variant.name[1:].split("-")[0])
            write_run(
                root,
                algo="tac",
                env="Hopper-v4",
                variant=variant.name.replace("a0.2", "a0.1"),
                seed=int(seed.name[4:]),
                steps=5000 * np.arange(1, 21),
                returns=returns,
                q=float(variant.name[1:].split("-")[0]),
                alpha=0.1,
            )
    write_report(analyse(ReportOptions(results=root, out=tmp_path / "out", reps=100)))
    tasks = [line.split(" | ")[0][2:] for line in (tmp_path / "out" / "q_ranges.md").open()][2:]
    assert sorted(tasks) == ["Hopper-v4 [a0.1]"] * 2 + ["Hopper-v4 [a0.2]"] * 2
