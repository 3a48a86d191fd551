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
    table = study.population_table(_table()).set_index("population")
    assert len(table) == 2
    first = table.loc["seeds 0,10,20,30,40,50,60,70"]
    assert first["q auto"] == pytest.approx(335.0)
    assert first["auto - q = 1"] == pytest.approx(100.0)
    assert first["auto - best q"] == pytest.approx(50.0)


@pytest.mark.unit
def test_learned_alpha_is_compared_with_the_fixed_runs_of_its_own_seeds() -> None:
    """Learned against fixed alpha on the learned runs' five seeds only (the fixed runs of the
    other eleven seeds left out), with the interval of the two groups resampled independently
    (docs/adaptive.md: a difference of means, not of pairs)."""
    table = study.alpha_table(_table(), reps=500)
    assert len(table) == 1  # no learned alpha at q = 2 here
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
    assert list(study.finals(tmp_path)["variant"]) == ["q1-a0.2"]  # a baseline is not a member
    result = CliRunner().invoke(cli, ["study", "adaptive", "analyse", "--results", str(tmp_path)])
    assert result.exit_code == 2 and "no population of learned-q runs (--q auto)" in result.output
