"""Report speed on a sweep-sized results tree: 1,008 runs with 200 evaluation rows each.

6 tasks x (9 q values + 5 baselines) x 12 seeds, as a full paper sweep would produce. Run with
``pytest -m bench tests/bench/test_report_bench.py``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from tacbench.paper import Q_GRID
from tacbench.report import ReportOptions, load_runs, make_report
from tests.report_fixtures import BASELINES, synthetic_tree

pytestmark = pytest.mark.bench

TASKS = ("HalfCheetah-v4", "Ant-v4", "Pusher-v5", "Humanoid-v4", "Hopper-v4", "Swimmer-v4")
SEEDS = 12
EVALUATIONS = 200
RUNS = len(TASKS) * (len(Q_GRID) + len(BASELINES)) * SEEDS


@pytest.fixture(scope="module")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return synthetic_tree(
        tmp_path_factory.mktemp("sweep"),
        tasks=TASKS,
        qs=Q_GRID,
        baselines=BASELINES,
        seeds=SEEDS,
        n_eval=EVALUATIONS,
        noise=100.0,
        spread=0.05,
    )


def test_load_1000_runs(benchmark: BenchmarkFixture, sweep: Path) -> None:
    runset = benchmark.pedantic(load_runs, args=(sweep,), rounds=3, iterations=1)
    assert RUNS >= 1000
    assert len(runset.runs) == RUNS and len(runset.data) == RUNS * EVALUATIONS


def test_full_report_1000_runs(benchmark: BenchmarkFixture, sweep: Path, tmp_path: Path) -> None:
    options = ReportOptions(results=sweep, out=tmp_path / "report")
    written = benchmark.pedantic(make_report, args=(options,), rounds=3, iterations=1)
    names = {path.name for path in written}
    for figure in ("q_sweep", "comparison", "intervals", "intervals_per_task", "profiles"):
        assert f"{figure}.png" in names
    best = pd.read_csv(tmp_path / "report" / "best_q.csv")
    assert len(best) == len(TASKS) and (best["best_q"] == 1.5).all()
