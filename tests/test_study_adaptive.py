"""The adaptive study's commands and tables (tacbench/studies/adaptive.py, docs/adaptive.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.bootstrap import mean_difference
from tacbench.cli import cli
from tacbench.report.load import load_runs
from tacbench.studies import adaptive as study
from tests.report_fixtures import write_run


@pytest.mark.unit
def test_the_commands_are_two_populations_and_the_same_seeds_fixed_and_learned_alpha() -> None:
    lines = study.commands("out")
    assert len(lines) == 8  # per task: two populations, the fixed runs, the learned alphas
    hopper = [line for line in lines if "Hopper-v4" in line]
    assert hopper[0].count("--seed") == hopper[1].count("--seed") == 8
    assert "--q auto" in hopper[0] and "--q 1 --q 2 " in hopper[2]
    assert hopper[2].count("--seed") == 16 and "--alpha auto" in hopper[3]


def _table() -> pd.DataFrame:
    rows = []
    for seed in range(0, 160, 10):
        population = "seeds " + ",".join(
            str(s) for s in (range(0, 80, 10) if seed < 80 else range(80, 160, 10))
        )
        rows.append(("Hopper-v4", "qauto-a0.2", np.nan, seed, population, 300.0 + seed))
        rows.append(("Hopper-v4", "q1-a0.2", 1.0, seed, "", 200.0 + seed))
        rows.append(("Hopper-v4", "q2-a0.2", 2.0, seed, "", 250.0 + seed))
    for seed in range(0, 50, 10):
        rows.append(("Hopper-v4", "q1-aauto0.2", 1.0, seed, "", 210.0 + seed))
    return pd.DataFrame(rows, columns=["env", "variant", "q", "seed", "population", "final"])


@pytest.mark.unit
def test_a_population_is_compared_with_the_fixed_runs_of_its_own_seeds() -> None:
    table, cautions = study.population_table(_table())
    table = table.set_index("population")
    assert len(table) == 2 and cautions == []
    first = table.loc["seeds 0,10,20,30,40,50,60,70"]
    assert first["q auto"] == pytest.approx(335.0)
    assert first["auto - q = 1"] == pytest.approx(100.0)
    assert first["auto - best q"] == pytest.approx(50.0)


@pytest.mark.unit
def test_learned_alpha_is_compared_with_the_fixed_runs_of_its_own_seeds() -> None:
    """Learned against fixed alpha on the learned runs' five seeds only (the fixed runs of the
    other eleven seeds left out), with the interval of the two groups resampled independently
    (docs/adaptive.md: a difference of means, not of pairs)."""
    table, cautions = study.alpha_table(_table(), reps=500)
    assert len(table) == 1  # no learned alpha at q = 2 here: said so
    assert cautions == ["Hopper-v4 q = 2: learned alpha left out, no finished q2-aauto0.2 run"]
    row = table.iloc[0]
    assert (row["q"], row["seeds"]) == (1.0, 5)
    assert row["auto - fixed"] == pytest.approx(10.0)  # every seed is 10 better
    seeds = np.arange(0, 50, 10)
    _, low, high = mean_difference(210.0 + seeds, 200.0 + seeds, 500, seed=0)
    assert (row["CI low"], row["CI high"]) == (low, high)
    assert low < 0 < high  # unpaired: the seeds' spread, not their common +10, sets the width


STUDY = Path(__file__).resolve().parents[1] / "results" / "studies" / "adaptive-q-100k"


@pytest.mark.smoke
def test_the_published_study_is_complete_and_its_tables_regenerate(tmp_path: Path) -> None:
    statuses = [json.loads(p.read_text()) for p in STUDY.glob("runs/tac/*/*/seed*/status.json")]
    assert len(statuses) == 116  # 32 population members, 64 fixed, 20 learned alpha
    assert {(s["state"], s["step"]) for s in statuses} == {("complete", 100_000)}
    assert not list(STUDY.glob("runs/**/checkpoint"))
    args = ["study", "adaptive", "analyse", "--results", str(STUDY), "--out", str(tmp_path)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    for table in sorted((STUDY / "analysis").glob("*.csv")):
        assert (tmp_path / table.name).read_text() == table.read_text(), table.name


@pytest.mark.unit
def test_a_folder_without_a_learned_q_population_is_a_clear_error(tmp_path: Path) -> None:
    write_run(
        tmp_path,
        algo="tac",
        env="Hopper-v4",
        variant="q1-a0.2",
        seed=0,
        steps=[1.0],
        returns=[1.0],
        q=1.0,
        alpha=0.2,
    )
    write_run(
        tmp_path,
        algo="ddpg",
        env="Hopper-v4",
        variant="default",
        seed=0,
        steps=[1.0],
        returns=[2.0],
    )
    table, _ = study.finals(load_runs(tmp_path, "eval"))
    assert list(table["variant"]) == ["q1-a0.2"]  # a baseline is not a member
    result = CliRunner().invoke(cli, ["study", "adaptive", "analyse", "--results", str(tmp_path)])
    assert (
        result.exit_code == 2
        and "no finished population of learned-q runs (--q auto)" in result.output
    )


def _population_run(
    root: Path, seed: int, members: range, q_at_end: str | None, state: str = "complete"
) -> Path:
    """A Hopper --q auto member of the population ``members`` (its losses.csv ends with
    ``q_at_end``; None: no losses.csv), of 100 steps, at step 50 unless complete."""
    steps = [50.0, 100.0] if state == "complete" else [50.0]
    run = write_run(
        root,
        algo="tac",
        env="Hopper-v4",
        variant="qauto-a0.2",
        seed=seed,
        steps=steps,
        returns=[300.0 + seed] * len(steps),
        q=0.5,
        alpha=0.2,
        total_steps=100,
        state=state,
        settings={"algo": "tac", "env": "Hopper-v4", "seed": seed, "q_mode": "auto"},
    )
    config = json.loads((run / "config.json").read_text())
    config["members"] = [{"seed": s} for s in members]
    (run / "config.json").write_text(json.dumps(config))
    if q_at_end is not None:
        (run / "losses.csv").write_text(f"step,q\n50,1.0\n100,{q_at_end}\n")
    return run


def _fixed_run(root: Path, variant: str, seed: int, state: str = "complete") -> None:
    q = float(variant[1 : variant.index("-")])
    steps = [50.0, 100.0] if state == "complete" else [50.0]
    write_run(
        root,
        algo="tac",
        env="Hopper-v4",
        variant=variant,
        seed=seed,
        steps=steps,
        returns=[200.0 + seed] * len(steps),
        q=q,
        alpha=0.2,
        total_steps=100,
        state=state,
    )


@pytest.mark.unit
def test_unfinished_runs_are_left_out_and_every_gap_is_said(tmp_path: Path) -> None:
    """An interrupted fixed run and a population with a running member used to count as
    finished (the population's mean and the differences wrong, exit 0); a comparison short of
    fixed runs gave empty columns, or its row was dropped, without a word."""
    first, second = range(0, 80, 10), range(80, 160, 10)
    for seed in first:
        _population_run(tmp_path, seed, first, "1.4")
        for variant in ("q1-a0.2", "q2-a0.2"):
            _fixed_run(
                tmp_path,
                variant,
                seed,
                "interrupted" if (seed, variant) == (0, "q1-a0.2") else "complete",
            )
    for seed in second:
        _population_run(tmp_path, seed, second, "1.6", "running" if seed == 150 else "complete")
    out = tmp_path / "analysis"
    args = ["study", "adaptive", "analyse", "--results", str(tmp_path), "--out", str(out)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    populations = pd.read_csv(out / "populations.csv")
    assert list(populations["population"]) == ["seeds 0,10,20,30,40,50,60,70"]
    row = populations.iloc[0]
    assert row["q auto"] == pytest.approx(335.0) and np.isnan(row["fixed q = 1"])
    assert row["fixed best q"] == pytest.approx(235.0)
    assert pd.read_csv(out / "final_q.csv")["final q"].tolist() == [1.4] * 8
    assert pd.read_csv(out / "cautions.csv")["caution"].tolist() == [
        "left out 2 runs short of the budget: tac/Hopper-v4/q1-a0.2/seed0 (interrupted at step "
        "50), tac/Hopper-v4/qauto-a0.2/seed150 (running at step 50)",
        "Hopper-v4: left out the population seeds 80,90,100,110,120,130,140,150: its member of "
        "seed 150 did not finish or cannot be used",
        "Hopper-v4 seeds 0,10,20,30,40,50,60,70: no finished q1-a0.2 run of seed 0; its "
        "'fixed q = 1' columns are empty",
        "Hopper-v4 q = 1: learned alpha left out, no finished q1-aauto0.2 run",
        "Hopper-v4 q = 2: learned alpha left out, no finished q2-aauto0.2 run",
        "HalfCheetah-v4: no finished run of the study",
    ]
    assert "caution: left out 2 runs short of the budget" in result.output
    assert {p.name for p in out.iterdir()} == {f"{name}.csv" for name in study.TABLES}


@pytest.mark.unit
@pytest.mark.parametrize(
    ("losses", "message"),
    [
        (None, "FileNotFoundError"),
        ("", "EmptyDataError"),
        ("step,loss_pi\n100,0.5\n", "ValueError"),
        ("step,q\n", "records no learned q in its last row"),
        ("step,q\n100,1.4\n200,0.6", "ends in a torn line"),  # 0.6 of 0.62: taken as the q
    ],
)
def test_a_members_losses_csv_without_its_q_is_a_one_line_error(
    tmp_path: Path, losses: str | None, message: str
) -> None:
    run = _population_run(tmp_path, 0, range(1), None)
    if losses is not None:
        (run / "losses.csv").write_text(losses)
    result = CliRunner().invoke(cli, ["study", "adaptive", "analyse", "--results", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert f"{run / 'losses.csv'}" in result.output and message in result.output
    assert "Traceback" not in result.output and "restore the run's losses.csv" in result.output


@pytest.mark.unit
def test_a_population_short_of_a_member_is_left_out_and_unreadable_runs_are_named(
    tmp_path: Path,
) -> None:
    """A population averaged over the members it had left (one missing, one whose config.json
    cannot be read) used to be compared as whole; a run the loader skipped went unmentioned."""
    first, second = range(0, 80, 10), range(80, 160, 10)
    for seed in first:
        _population_run(tmp_path, seed, first, "1.4")
    for seed in second:
        if seed != 90:  # its directory is gone
            _population_run(tmp_path, seed, second, "1.6")
    (tmp_path / "runs/tac/Hopper-v4/qauto-a0.2/seed10/config.json").write_text("{")
    table, cautions = study.finals(load_runs(tmp_path, "eval"))
    assert table.empty
    assert cautions == [
        "left out 1 run directory that cannot be used: tac/Hopper-v4/qauto-a0.2/seed10 "
        "(config.json unreadable: Expecting property name enclosed in double quotes: line 1 "
        "column 2 (char 1))",
        "Hopper-v4: left out the population seeds 0,10,20,30,40,50,60,70: its member of seed "
        "10 did not finish or cannot be used",
        "Hopper-v4: left out the population seeds 80,90,100,110,120,130,140,150: its member of "
        "seed 90 did not finish or cannot be used",
    ]
