"""Table numbers against hand-computed values; curves on the common grid; method labels."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tacbench import memory
from tacbench.errors import TacbenchError
from tacbench.paper import task_name, task_sort_key
from tacbench.report import Report, ReportOptions, analyse
from tacbench.report.curves import on_grid, run_matrix, seed_curves, task_grid
from tacbench.report.load import load_runs
from tacbench.report.methods import (
    BEST_Q_LABEL,
    SAC_LABEL,
    assign_methods,
    method_sort_key,
    style_of,
)
from tacbench.report.page import best_q_display, summary_display
from tacbench.report.tables import best_q_rows, normalise, run_scores
from tacbench.verdicts import CHOSEN_ON_THESE_RUNS
from tests.report_fixtures import synthetic_tree, write_run

pytestmark = pytest.mark.unit


def test_run_scores_by_hand(tmp_path: Path) -> None:
    common = {"env": "Hopper-v4", "variant": "default", "algo": "td3"}
    write_run(tmp_path, seed=0, steps=[10, 20, 40], returns=[1.0, 3.0, 5.0], **common)
    write_run(tmp_path, seed=1, steps=[10], returns=[7.0], **common)
    data = load_runs(tmp_path).data
    scores = run_scores(data, last=2)
    assert scores.loc[0, "final"] == pytest.approx(4.0)  # (3 + 5) / 2
    assert scores.loc[0, "best"] == 5.0
    # trapezoids: 10 * (1 + 3) / 2 + 20 * (3 + 5) / 2 = 100 over 30 steps
    assert scores.loc[0, "auc"] == pytest.approx(100 / 30)
    assert scores.loc[1].tolist() == [7.0, 7.0, 7.0]
    assert run_scores(data, last=10).loc[0, "final"] == pytest.approx(3.0)


def test_a_run_of_huge_returns_leaves_the_next_runs_final_as_it_is() -> None:
    """The finals were differences of one running sum over every run: 1e17 made 2.5 read 0."""
    data = pd.DataFrame(
        {"run": [0, 0, 1, 1], "step": [1, 2, 1, 2], "return": [1e17, 1e17, 2.0, 3.0]}
    )
    scores = run_scores(data, last=2)
    assert scores["final"].tolist() == [1e17, 2.5]


def _flat_runs(root: Path, env: str, algo: str, q: float | None, levels: list[float]) -> None:
    for seed, level in enumerate(levels):
        write_run(
            root,
            algo=algo,
            env=env,
            variant="default" if q is None else f"q{q:g}-a0.2",
            seed=seed,
            q=q,
            alpha=None if q is None else 0.2,
            steps=[1000, 2000, 3000, 4000],
            returns=[0.0, level / 2, level, level],
        )


@pytest.fixture(scope="module")
def flat_report(tmp_path_factory: pytest.TempPathFactory) -> Report:
    root = tmp_path_factory.mktemp("flat")
    _flat_runs(root, "Humanoid-v4", "tac", 1.0, [100.0, 200.0, 600.0])
    _flat_runs(root, "Humanoid-v4", "tac", 1.2, [400.0, 500.0, 600.0])
    _flat_runs(root, "Humanoid-v4", "tac", 2.0, [300.0, 300.0, 300.0])
    _flat_runs(root, "Humanoid-v4", "ddpg", None, [50.0, 150.0])
    write_run(
        root,
        algo="ddpg",
        env="Humanoid-v4",
        variant="default",
        seed=7,
        steps=[1000],
        returns=[0.0],
        state="failed",
        reason="diverged",
    )
    options = ReportOptions(results=root, out=root / "report", reps=200, last=2, grid_points=4)
    return analyse(options)


def test_summary_numbers_equal_hand_computed_ones(flat_report: Report) -> None:
    summary = flat_report.summary.set_index("method")
    sac = summary.loc[SAC_LABEL]
    assert sac["seeds"] == 3 and sac["partial"] == 0 and sac["failed"] == 0
    assert sac["final_mean"] == pytest.approx(300.0)
    # sample std of 100, 200, 600 around 300: sqrt((200^2 + 100^2 + 300^2) / 2)
    assert sac["final_std"] == pytest.approx(math.sqrt(70_000))
    assert sac["best_mean"] == pytest.approx(300.0)
    # curve 0, L/2, L, L at 1k..4k steps: area 1000 * (L/4 + 3L/4 + L) = 2000 L over 3000 steps
    assert sac["auc_mean"] == pytest.approx(300.0 * 2 / 3)
    assert sac["steps_min"] == 4000 and sac["planned"] == 4000
    ddpg = summary.loc["DDPG"]
    assert ddpg["seeds"] == 2 and ddpg["failed"] == 1
    assert ddpg["final_mean"] == pytest.approx(100.0)
    assert summary.loc["TAC q=2", "final_std"] == 0.0


def test_best_q_table_ranks_and_compares_with_the_paper(flat_report: Report) -> None:
    row = flat_report.best_q.iloc[0]
    assert row["env"] == "Humanoid-v4"
    assert row["best_q"] == 1.2 and row["best_final"] == pytest.approx(500.0)
    assert row["ranking"] == "1.2 > 1 > 2"
    assert row["paper_q"] == "1.2" and row["paper_q_rank"] == "1 of 3"
    assert row["agrees"] == "yes" and row["best_in_1_2"] == "yes"
    # q=1.2 finals {400, 500, 600} vs q=1 {100, 200, 600}: 6 wins and 1 tie of 9 pairs
    assert row["p_best_over_q1"] == pytest.approx(6.5 / 9)


def test_a_ranking_of_unequal_seed_counts_gives_each_q_its_count(tmp_path: Path) -> None:
    """A q on one seed could top the ranking on that seed's luck, unmarked: where the counts
    differ, each q carries its own."""
    _flat_runs(tmp_path, "Hopper-v4", "tac", 1.0, [100.0, 200.0, 300.0])
    _flat_runs(tmp_path, "Hopper-v4", "tac", 2.0, [900.0])
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "out", reps=100, last=2))
    [row] = report.best_q.to_dict("records")
    assert row["best_q"] == 2.0 and row["ranking"] == "2 (n=1) > 1 (n=3)"


def test_best_q_table_ranks_each_setting_of_a_task_apart(tmp_path: Path) -> None:
    """The adaptive study's HalfCheetah ranked its fixed- and learned-alpha runs together
    ("1 > 1.5 > 1 > 1.5", best q = 1 of the learned alpha, P of the learned-alpha pair): a task
    gets a row per setting now, each ranking its own q values, its P read for its own best q."""
    finals = {"a0.2": {1.0: 100.0, 1.5: 300.0}, "aauto0.2": {1.0: 500.0, 1.5: 200.0}}
    for setting, by_q in finals.items():
        for q, final in by_q.items():
            for seed in range(3):
                write_run(
                    tmp_path,
                    algo="tac",
                    env="Hopper-v4",
                    variant=f"q{q:g}-{setting}",
                    seed=seed,
                    q=q,
                    alpha=0.2,
                    steps=[1000.0, 2000.0],
                    returns=[0.0, final + seed],
                )
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "out", reps=100, last=1))
    table = report.best_q.set_index("setting")
    assert table["env"].tolist() == ["Hopper-v4"] * 2
    assert table.loc["a0.2", "ranking"] == "1.5 > 1" and table.loc["a0.2", "best_q"] == 1.5
    assert table.loc["aauto0.2", "ranking"] == "1 > 1.5" and table.loc["aauto0.2", "best_q"] == 1
    assert table.loc["a0.2", "paper_q_rank"] == "not run"  # the paper's Hopper q is 2
    assert table.loc["a0.2", "p_best_over_q1"] == 1.0  # 300s against the fixed alpha's 100s
    assert table.loc["aauto0.2", "p_best_over_q1"] == 0.0  # 200s against 500s
    shown = best_q_display(report)["task"].tolist()
    assert shown == ["Hopper-v4 [a0.2]", "Hopper-v4 [aauto0.2]"]


def test_a_q_whose_every_run_failed_keeps_its_rows(tmp_path: Path) -> None:
    """The authors' 2019-01-11b runs of q = 3 and 5 all failed at their first update and were
    missing from the summary and the best-q ranking (leaving out diverged runs flatters a
    method): such a method has a summary row of its failures, in its q's place, and the
    ranking names it; here it is the paper's best q of the task."""
    for q, state in ((1.0, "complete"), (2.0, "failed"), (3.0, "complete")):
        for seed in range(2):
            write_run(
                tmp_path,
                algo="tac",
                env="Hopper-v4",
                variant=f"q{q:g}-a0.2",
                seed=seed,
                q=q,
                alpha=0.2,
                steps=[1000.0, 2000.0],
                returns=[0.0, 100.0 * q + seed],
                state=state,
                reason="non-finite loss" if state == "failed" else "",
            )
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "out", reps=100))
    summary = report.summary.set_index("method")
    assert summary.index.tolist() == [SAC_LABEL, "TAC q=2", "TAC q=3"]
    assert summary.loc["TAC q=2", ["seeds", "failed"]].tolist() == [0, 2]
    assert math.isnan(summary.loc["TAC q=2", "final_mean"])
    shown = summary_display(report).set_index("method").loc["TAC q=2"]
    assert (shown["steps reached"], shown["final (last 10)"]) == ("n/a", "n/a")
    [row] = report.best_q.to_dict("records")
    assert row["ranking"] == "3 > 1; every run failed: 2"
    assert row["paper_q_rank"] == "every run failed" and row["best_q_not_1"] == 3.0
    assert row["agrees"] == "not tested"  # the paper's q (2 here) has no run to rank


def test_tac_best_q_is_of_the_papers_design_where_a_task_has_it() -> None:
    """The adaptive study's TAC (best q) was HalfCheetah's learned-alpha q = 1.5 beside Hopper's
    fixed-alpha q = 2, so its "all tasks" comparison mixed the two: it is chosen among fixed-
    alpha float32 runs where a task has any, else among all."""
    rows = [
        ("A", "TAC q=1.5 [q1.5-a0.2]", "q1.5-a0.2", 1.5, 100.0),
        ("A", "TAC q=1.5 [q1.5-aauto0.2]", "q1.5-aauto0.2", 1.5, 500.0),
        ("A", "TAC q=2 [q2-a0.2-bf16]", "q2-a0.2-bf16", 2.0, 900.0),
        ("A", SAC_LABEL, "q1-a0.2", 1.0, 1000.0),
        ("B", "TAC q=2 [q2-aauto0.2]", "q2-aauto0.2", 2.0, 50.0),
    ]
    summary = pd.DataFrame(rows, columns=["env", "method", "variant", "q", "final_mean"])
    best = best_q_rows(summary.assign(algo="tac", seeds=3))
    assert best.set_index("env")["method"].to_dict() == {
        "A": "TAC q=1.5 [q1.5-a0.2]",
        "B": "TAC q=2 [q2-aauto0.2]",
    }
    assert best.set_index("env")["candidates"].to_dict() == {"A": 1, "B": 1}


def test_a_best_q_picked_among_several_carries_no_test(tmp_path: Path) -> None:
    """TAC (best q) picked among several q by these runs was tested against q = 1 and the
    baselines as if chosen beforehand: nine equal q on six tasks were called "larger" in 62 % of
    simulated grids. Its rows keep P and the interval, without a p-value or verdict; with one
    q != 1 on the task (nothing picked) the test stands."""
    several = tmp_path / "several"
    for env in ("Humanoid-v4", "Hopper-v4"):  # two tasks: an "all tasks" row too
        for q, levels in ((1.0, [100.0, 200.0, 600.0]), (1.2, [400.0, 500.0, 600.0])):
            _flat_runs(several, env, "tac", q, levels)
        _flat_runs(several, env, "tac", 2.0, [300.0, 300.0, 300.0])
        _flat_runs(several, env, "ddpg", None, [50.0, 150.0])
    picked = analyse(ReportOptions(results=several, out=several / "report", reps=200, last=2))
    for table in (picked.improvement, picked.baselines):
        best = table[table["method"] == BEST_Q_LABEL]
        assert set(best["env"]) == {"all tasks", "Humanoid-v4", "Hopper-v4"}
        assert (best["verdict"] == CHOSEN_ON_THESE_RUNS).all()
        assert best["p_value"].isna().all() and best["p"].notna().all()
    sac = picked.baselines[picked.baselines["method"] == SAC_LABEL]
    assert len(sac) and sac["p_value"].notna().all()
    root = tmp_path / "one"
    _flat_runs(root, "Humanoid-v4", "tac", 1.0, [100.0, 200.0, 600.0])
    _flat_runs(root, "Humanoid-v4", "tac", 1.2, [400.0, 500.0, 600.0])
    _flat_runs(root, "Humanoid-v4", "ddpg", None, [50.0, 150.0])
    report = analyse(ReportOptions(results=root, out=root / "report", reps=200, last=2))
    for table in (report.improvement, report.baselines):
        best = table[table["method"] == BEST_Q_LABEL]
        assert len(best) and best["p_value"].notna().all()
        assert CHOSEN_ON_THESE_RUNS not in set(best["verdict"])
    # a baseline run only on tasks where nothing was picked: its "all tasks" row is tested
    mixed = tmp_path / "mixed"
    for env in ("Humanoid-v4", "Hopper-v4", "Ant-v4"):
        _flat_runs(mixed, env, "tac", 1.0, [100.0, 200.0, 600.0])
        _flat_runs(mixed, env, "tac", 1.2, [400.0, 500.0, 600.0])
    _flat_runs(mixed, "Ant-v4", "tac", 2.0, [300.0, 300.0, 300.0])  # picked among two here
    for env in ("Humanoid-v4", "Hopper-v4"):
        _flat_runs(mixed, env, "ddpg", None, [50.0, 150.0])
    report = analyse(ReportOptions(results=mixed, out=mixed / "report", reps=200, last=2))
    best = report.baselines[report.baselines["method"] == BEST_Q_LABEL].set_index("env")
    assert best.loc["all tasks", "tasks"] == 2 and best["p_value"].notna().all()
    assert (
        report.improvement.set_index(["method", "env"]).loc[(BEST_Q_LABEL, "all tasks"), "verdict"]
        == CHOSEN_ON_THESE_RUNS
    )


def test_normalisation_anchors_are_the_task_extremes(flat_report: Report) -> None:
    anchors = flat_report.anchors.set_index("env")
    assert anchors.loc["Humanoid-v4"].tolist() == [50.0, 600.0]
    scores = flat_report.scores
    expected = (scores["final"] - 50.0) / 550.0
    np.testing.assert_allclose(scores["score"], expected)
    frame = pd.DataFrame({"env": ["a", "a"], "final": [3.0, 3.0]})
    assert normalise(frame)[0].tolist() == [0.0, 0.0]


def test_eval_curves_interpolate_without_extrapolating() -> None:
    grid = task_grid(100.0, 4)
    np.testing.assert_array_equal(grid, [25.0, 50.0, 75.0, 100.0])
    out = on_grid(np.array([30.0, 70.0]), np.array([0.0, 8.0]), grid, "eval")
    np.testing.assert_allclose(out, [np.nan, 4.0, np.nan, np.nan])


def test_train_curves_average_episodes_per_interval_and_fill_gaps() -> None:
    grid = task_grid(100.0, 5)  # 20, 40, 60, 80, 100
    steps = np.array([30.0, 35.0, 90.0, 130.0])
    out = on_grid(steps, np.array([1.0, 3.0, 8.0, 99.0]), grid, "train")
    # (20, 40]: mean(1, 3) = 2; (40, 60] and (60, 80] empty: interpolated; (80, 100]: 8
    np.testing.assert_allclose(out, [np.nan, 2.0, 4.0, 6.0, 8.0])


def test_seed_curves_count_only_runs_that_reached_a_step() -> None:
    runs = pd.DataFrame({"env": ["e", "e"], "method": ["m", "m"], "q": [1.0, 1.0]})
    values = np.array([[1.0, 3.0, 5.0], [3.0, 5.0, np.nan]])
    curves = seed_curves({"e": np.array([1.0, 2.0, 3.0])}, values, runs)
    assert curves["mean"].tolist() == [2.0, 4.0, 5.0]
    assert curves["n"].tolist() == [2, 2, 1]
    np.testing.assert_allclose(curves["std"], [math.sqrt(2), math.sqrt(2), np.nan])


def test_the_curves_are_no_wider_than_the_rows_the_runs_logged(tmp_path: Path) -> None:
    """The curve array had --grid-points columns whatever the runs held: 1,000,000 made 8 MB a
    run of trailing NaNs."""
    _flat_runs(tmp_path, "Hopper-v4", "tac", 1.0, [100.0, 200.0])
    runset = load_runs(tmp_path, "eval")
    grids, values = run_matrix(runset.data, runset.runs, 1_000_000, "eval")
    assert values.shape == (2, 4) and len(grids["Hopper-v4"]) == 4


def test_a_bootstrap_too_large_for_the_machine_is_refused_with_its_estimate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The guard counted 24 bytes per replication and grid point (a curve bootstrap the report
    does not run) and nothing for the runs: it refused a huge --grid-points, which costs
    nothing, and let through a --reps that the profiles' bootstrap could not hold."""
    _flat_runs(tmp_path, "Hopper-v4", "tac", 1.0, [100.0, 200.0, 300.0])
    monkeypatch.setattr(memory, "machine_memory", lambda: 20 << 20)  # 20 MiB
    options = {"results": tmp_path, "out": tmp_path / "r", "last": 2}
    analyse(ReportOptions(**options, reps=200, grid_points=1_000_000))
    per_replication = 8 * (3 + 2 * 101)  # three runs; the profiles' 101 values, twice
    reps = (20 << 20) // per_replication + 1
    with pytest.raises(TacbenchError, match=r"this report would need about .* make --reps smaller"):
        analyse(ReportOptions(**options, reps=reps))
    assert not (tmp_path / "r").exists()


def test_curves_of_flat_runs_on_the_grid(flat_report: Report) -> None:
    curves = flat_report.curves
    sac = curves[curves["method"] == SAC_LABEL]
    assert sac["step"].tolist() == [1000.0, 2000.0, 3000.0, 4000.0]
    assert sac["mean"].tolist() == pytest.approx([0.0, 150.0, 300.0, 300.0])
    best = curves[curves["method"] == BEST_Q_LABEL]
    q12 = curves[curves["method"] == "TAC q=1.2"]
    assert best["mean"].tolist() == q12["mean"].tolist()


def test_method_labels() -> None:
    runs = pd.DataFrame(
        {
            "algo": ["tac", "tac", "tac", "tac", "td3", "ppo", "ppo", "newalgo"],
            "env": ["A-v4", "A-v4", "A-v4", "B-v4", "A-v4", "A-v4", "A-v4", "A-v4"],
            "variant": ["q1-a0.2", "q1.5-a0.2", "q1.5-a0.1", "q1.5-a0.05", "d", "x", "y", "d"],
            "q": [1.0, 1.5, 1.5, 1.5, np.nan, np.nan, np.nan, np.nan],
        }
    )
    assert assign_methods(runs).tolist() == [
        SAC_LABEL,
        "TAC q=1.5 [q1.5-a0.2]",
        "TAC q=1.5 [q1.5-a0.1]",
        "TAC q=1.5 [q1.5-a0.05]",
        "TD3",
        "PPO [x]",
        "PPO [y]",
        "NEWALGO",
    ]
    bf16 = pd.DataFrame(
        {"algo": ["tac"], "env": ["A-v4"], "variant": ["q1.5-a0.2-bf16"], "q": [1.5]}
    )
    assert assign_methods(bf16).tolist() == ["TAC q=1.5 [q1.5-a0.2-bf16]"]
    # a bf16 --q auto population too, though it is the task's only one (it was "TAC q=auto")
    populations = pd.DataFrame(
        {
            "algo": ["tac", "tac"],
            "env": ["A-v4", "B-v4"],
            "variant": ["qauto-a0.2", "qauto-a0.2-bf16"],
            "q": [np.nan, np.nan],
        }
    )
    assert assign_methods(populations).tolist() == ["TAC q=auto", "TAC q=auto [qauto-a0.2-bf16]"]


def test_styles_are_fixed_per_method() -> None:
    assert (style_of(SAC_LABEL).color, style_of(SAC_LABEL).marker) == ("#d62728", "s")
    assert style_of(BEST_Q_LABEL).marker == "p"
    colours = {style_of(f"TAC q={q:g}", q).color for q in (0.5, 0.7, 1.2, 1.5, 1.7, 2, 3, 5)}
    assert len(colours) == 8 and style_of(SAC_LABEL).color not in colours
    variant, base = style_of("TAC q=1.5 [q1.5-a0.1]", 1.5), style_of("TAC q=1.5", 1.5)
    assert (variant.color, variant.marker) == (base.color, base.marker)
    assert variant.linestyle != "-"
    # the same in every process, whatever Python's string hashing does there
    show = "from tacbench.report.methods import style_of; print(style_of('{}', {}))"
    for label, q in (("TAC q=1.7 [q1.7-a0.2-joint]", 1.7),):
        here = str(style_of(label, q))
        for hash_seed in ("1", "2"):
            env = {**os.environ, "PYTHONHASHSEED": hash_seed}
            shown = subprocess.run(
                [sys.executable, "-c", show.format(label, q)],
                capture_output=True,
                text=True,
                check=True,
                env=env,
            )
            assert shown.stdout.strip() == here


def test_orders_follow_the_paper() -> None:
    envs = ["Swimmer-v4", "Hopper-v5", "Ant-v4", "Walker2d-v4", "HalfCheetah-v4"]
    assert sorted(envs, key=task_sort_key) == [
        "HalfCheetah-v4",
        "Ant-v4",
        "Hopper-v5",
        "Swimmer-v4",
        "Walker2d-v4",
    ]
    assert task_name("Humanoid-v4") == "Humanoid" and task_name("Custom") == "Custom"
    methods = {"TRPO": np.nan, "TAC q=2": 2.0, BEST_Q_LABEL: np.nan, SAC_LABEL: 1.0, "DDPG": np.nan}
    assert sorted(methods, key=lambda m: method_sort_key(m, methods[m])) == [
        SAC_LABEL,
        "TAC q=2",
        BEST_Q_LABEL,
        "DDPG",
        "TRPO",
    ]


def test_synthetic_sweep_finds_the_known_best_q(tmp_path: Path) -> None:
    synthetic_tree(tmp_path, tasks=("Humanoid-v4",), seeds=2, n_eval=5, baselines=())
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "r", reps=100))
    row = report.best_q.iloc[0]
    assert row["best_q"] == 1.5 and row["ranking"] == "1.5 > 2 > 1 > 0.5"
    assert row["paper_q_rank"] == "not run" and row["agrees"] == "not tested"
