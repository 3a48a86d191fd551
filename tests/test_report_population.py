"""The report's ``TAC q=auto``: one value per population in the statistics, the members in the
curves and the summary, and a figure of each member's q."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tacbench.report import ReportOptions, analyse, write_report
from tests.report_fixtures import write_run

pytestmark = pytest.mark.unit

STEPS = [1000.0, 2000.0, 3000.0]


def _population(root: Path, seeds: list[int], level: float) -> list[Path]:
    members = [{"q": 1.0, "alpha": 0.2, "seed": s} for s in seeds]
    paths = []
    for i, seed in enumerate(seeds):
        path = write_run(
            root,
            algo="tac",
            env="Hopper-v4",
            variant="qauto-a0.2",
            seed=seed,
            steps=STEPS,
            returns=[level + i, level + 10 + i, level + 20 + i],
            q=0.5 * 10 ** (i / (len(seeds) - 1)),
            alpha=0.2,
        )
        config = json.loads((path / "config.json").read_text())
        config["members"] = members
        config["config"]["q_mode"] = "auto"
        (path / "config.json").write_text(json.dumps(config))
        (path / "losses.csv").write_text("step,q\n1000,0.5\n2000,1.2\n3000,1.44\n")
        paths.append(path)
    return paths


def test_statistics_count_one_value_per_population(tmp_path: Path) -> None:
    _population(tmp_path, [0, 1, 2, 3], 100.0)
    _population(tmp_path, [4, 5, 6, 7], 250.0)  # q=auto's mean above q = 1's (below)
    for seed in range(8):
        write_run(
            tmp_path,
            algo="tac",
            env="Hopper-v4",
            variant="q1-a0.2",
            seed=seed,
            steps=STEPS,
            returns=[150.0, 160.0, 121.0 + 0.25 * seed],  # among population 1's members
            q=1.0,
            alpha=0.2,
        )
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "report", reps=200, last=1))
    assert "TAC q=auto" in report.methods
    per_task = report.per_task.set_index("method")
    assert per_task.loc["TAC q=auto", "runs"] == 2  # two populations, not eight members
    # population means of the final returns: 121.5 and 271.5
    assert per_task.loc["TAC q=auto", "mean"] == pytest.approx((121.5 + 271.5) / 2)
    assert per_task.loc["SAC (TAC q=1)", "runs"] == 8
    summary = report.summary.set_index("method")
    assert summary.loc["TAC q=auto", "seeds"] == 8  # the summary shows the members
    (improvement,) = report.improvement[report.improvement["method"] == "TAC q=auto"].itertuples()
    # P(population mean > q = 1 run), ties half: 121.5 beats 121 and 121.25 and ties 121.5 of
    # 121..122.75, 271.5 beats all; the eight members one by one would give 5.625 / 8
    assert improvement.p == pytest.approx((2.5 / 8 + 1) / 2)
    assert report.aggregate.set_index("method").loc["TAC q=auto", "runs"] == 2
    assert "q_trajectories" in report.figures
    assert set(report.trajectories["population"]) == {"seeds 0,1,2,3", "seeds 4,5,6,7"}
    starts = report.trajectories[report.trajectories["step"] == 0].sort_values("seed")
    assert np.allclose(starts["q"], [0.5 * 10 ** (i / 3) for i in range(4)] * 2)  # config's q
    logged = report.trajectories[report.trajectories["step"] > 0]
    assert np.allclose(logged["q"].unique(), [0.5, 1.2, 1.44])
    # q=auto's final mean (196.5) is above q = 1's (121.875), but it is no fixed q to name
    assert report.best_q["best_q"].tolist() == [1.0]
    # the comparison figure is the paper's: best q, SAC and baselines (q=auto was drawn there)
    assert "TAC q=auto" in report.tac_methods
    assert report.comparison_methods == ["SAC (TAC q=1)"]
    write_report(report)
    page = (tmp_path / "report" / "report.md").read_text()
    assert "count one value per population" in page
    assert (tmp_path / "report" / "q_trajectories.png").exists()


def test_members_without_a_readable_q_log_show_their_start_and_a_caution(tmp_path: Path) -> None:
    """Results copied without losses.csv made the whole report fail (FileNotFoundError): a
    member without a readable q column now shows its starting q alone, and the report says so."""
    paths = _population(tmp_path, [0, 1, 2, 3], 100.0)
    (paths[0] / "losses.csv").unlink()
    (paths[1] / "losses.csv").write_text("step,value_loss\n1000,0.5\n")  # no q column
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "report", reps=100, last=1))
    steps = report.trajectories.groupby("seed")["step"].count()
    assert steps.to_dict() == {0: 1, 1: 1, 2: 4, 3: 4}
    assert report.cautions == [
        "Hopper-v4: 2 TAC q=auto members whose losses.csv is missing or has no readable q "
        "column: the q trajectories show their starting q alone."
    ]
    write_report(report)
    page = (tmp_path / "report" / "report.md").read_text()
    assert "Caution: Hopper-v4: 2 TAC q=auto members" in page
