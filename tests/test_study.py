"""The published q-grid studies (results/studies/; docs/results.md, docs/authors-versions.md):
each committed report regenerates, table for table, from its committed run directories, and
the runs are what the pages say."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pandas as pd
import pytest

from tacbench.report import ReportOptions, analyse, write_report
from tacbench.sweep import bills
from tacbench.sweep.summary import shared_cores
from tests.helpers import Q_GRID_STUDIES, STUDIES

pytestmark = pytest.mark.smoke

# study folder -> its runs, each of 100,000 steps: the paper's 9 q x 5 seeds per task (Humanoid
# 3 q x 3 seeds), the authors' code versions, and the comparison with the baselines
RUNS = {
    "paper-q-grid-100k": 2 * 9 * 5,
    "paper-q-grid-100k-ant": 9 * 5,
    "paper-q-grid-100k-swimmer": 9 * 5,
    "paper-q-grid-100k-pusher": 9 * 5,
    "paper-q-grid-100k-humanoid": 5 * 3,  # q = 0.5, 0.7, 1, 1.2, 2 x seeds 0, 10, 20
    # HalfCheetah, one folder per version of the authors' code: 5 q x 5 seeds
    "authors-versions-100k/authors-2019-01-07b": 5 * 5,
    "authors-versions-100k/authors-2019-01-11b": 5 * 5,
    "authors-versions-100k/authors-2019-01-16c": 5 * 5,
    "authors-versions-100k/authors-2019-01-22": 5 * 5,
    # the "Final plot" version with the authors' (400, 300) networks: 5 q x 5 seeds
    "authors-versions-100k/authors-2019-01-16c-h400x300": 5 * 5,
    # the same version, networks and commands at q = 1, 1.5 and 5, run again on the AMD EPYC AVX2
    # class (the runs above: Zen 4): 3 q x 5 seeds
    "authors-versions-100k/authors-2019-01-16c-h400x300-avx2": 3 * 5 + 2 * 5,
    # 2019-01-07b with the authors' (400, 300) networks: 5 q x 5 seeds
    "authors-versions-100k/authors-2019-01-07b-h400x300": 5 * 5,
    # 2019-01-11b with the authors' (400, 300) networks: q = 2, 3 and 5 x 5 seeds (its q = 1 and
    # 1.5 are the "Final plot" version's formulas)
    "authors-versions-100k/authors-2019-01-11b-h400x300": 3 * 5,
    # Hopper, the closest version: 2 q x 5 seeds
    "authors-versions-100k/authors-2019-01-07b-hopper": 2 * 5,
    # Hopper and HalfCheetah: PPO, TRPO, DDPG, SB3's SAC and TD3 x 5 seeds, and TAC at q = 1
    # and the paper's best q (2 and 1.5) from paper-q-grid-100k; Swimmer, Pusher and Ant: PPO
    # and TRPO x 5 seeds, and TAC at q = 1 and the best q from the task's q-grid study; DDPG,
    # TD3 and SB3's SAC on Swimmer, Pusher and Ant x 5 seeds; Humanoid: PPO, TRPO, DDPG, SB3's
    # SAC and TAC at q = 1 and 1.2 x 3 seeds
    "comparison-100k": 2 * 7 * 5 + 3 * 4 * 5 + 3 * 5 + 3 * 5 + 3 * 5 + 7 * 3,
    # Hopper and HalfCheetah: two `--q auto` populations of 8, fixed q = 1 and the paper's best q
    # x 16 seeds, and `--alpha auto` at both q x 5 seeds (docs/adaptive.md)
    "adaptive-q-100k": 2 * (2 * 8 + 2 * 16 + 2 * 5),
}
# runs recorded as failed (a non-finite loss): how many at each step. In 2019-01-11b q = 3 and 5
# overflow float32 at their first update; with (400, 300) networks q = 5 does, and q = 3's seeds
# at steps 1,000 to 84,000
FAILED = {
    "authors-versions-100k/authors-2019-01-11b": {1_000: 2 * 5},
    "authors-versions-100k/authors-2019-01-11b-h400x300": {
        1_000: 5 + 1,
        30_000: 1,
        60_000: 1,
        63_000: 1,
        84_000: 1,
    },
}


def _tables(study: str) -> list[str]:
    report = STUDIES / study / "report"
    return sorted(p.name for p in report.glob("*") if p.suffix in (".csv", ".md", ".html"))


@pytest.mark.parametrize("study", RUNS)
def test_the_study_holds_its_runs_complete(study: str) -> None:
    folder = STUDIES / study
    statuses = [json.loads(p.read_text()) for p in folder.glob("runs/*/*/*/seed*/status.json")]
    assert len(statuses) == RUNS[study]
    failed = FAILED.get(study, {})
    ends = [(s["state"], s["step"]) for s in statuses]
    assert Counter(step for state, step in ends if state == "failed") == failed
    assert ends.count(("complete", 100_000)) == RUNS[study] - sum(failed.values())
    assert not list(folder.glob("runs/**/checkpoint"))  # CSV and JSON only


@pytest.mark.parametrize("study", RUNS)
def test_the_report_has_the_tables_the_page_quotes(study: str) -> None:
    assert {"summary.md", "best_q.md", "q_ranges.md", "stats_per_task.csv"} <= set(_tables(study))


@pytest.mark.parametrize(
    ("study", "table"), [(study, table) for study in RUNS for table in _tables(study)]
)
def test_the_committed_report_tables_regenerate_exactly(
    regenerated: dict[str, Path], study: str, table: str
) -> None:
    """The page too (report.md and index.html), with the paths it names made the committed
    ones: a change to the page's text leaves no published page behind."""
    expected = (STUDIES / study / "report" / table).read_text()
    fresh = (regenerated[study] / table).read_text()
    if table in ("report.md", "index.html"):
        here = f"results/studies/{study}"
        fresh = fresh.replace(str(regenerated[study]), f"{here}/report")
        fresh = fresh.replace(str(STUDIES / study), here)
    assert fresh == expected, table


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each study's report, made again with the CLI's defaults."""
    outs = {}
    for study in RUNS:
        out = tmp_path_factory.mktemp(study.replace("/", "-"))
        write_report(analyse(ReportOptions(results=STUDIES / study, out=out)))
        outs[study] = out
    return outs


def test_the_last_code_repeats_final_plot_on_halfcheetah() -> None:
    """docs/authors-versions.md: 24 of 25 runs of 2019-01-22 evaluate as 2019-01-16c's."""
    final_plot = STUDIES / "authors-versions-100k" / "authors-2019-01-16c"
    last = STUDIES / "authors-versions-100k" / "authors-2019-01-22"
    same = []
    for path in sorted(final_plot.glob("runs/tac/*/*/seed*/eval.csv")):
        relative = path.relative_to(final_plot).as_posix().replace("20190116c", "20190122")
        returns = pd.read_csv(path)["return_mean"].tolist()
        same.append(returns == pd.read_csv(last / relative)["return_mean"].tolist())
    assert (len(same), sum(same)) == (25, 24)


def test_the_comparisons_tac_runs_are_the_q_grid_studys() -> None:
    """docs/results.md: the comparison study reuses each task's TAC runs from its q-grid
    study, not retrains them."""
    comparison = STUDIES / "comparison-100k"
    copies = sorted(p for p in comparison.glob("runs/tac/**/*") if p.is_file())
    # five tasks with two q and 5 seeds, Humanoid with two q and 3 seeds; 5 files each
    assert len(copies) == (5 * 2 * 5 + 2 * 3) * 5
    for path in copies:
        relative = path.relative_to(comparison)
        original = STUDIES / Q_GRID_STUDIES[relative.parts[2]] / relative
        assert path.read_bytes() == original.read_bytes(), path


def test_every_committed_sweeps_bill_is_within_a_quarter_of_its_price() -> None:
    """docs/sweep.md, "The price and the bill": every sweep that trained a committed study's
    runs and billed the whole of it, none failing, took within 25 % of the price its dry run gave
    it when it started, unless other work shared its cores (its bill's load, as the bill says):
    the price is of a machine that runs nothing else. Those record their runs' CPU time."""
    billed = [t for t in bills.sweeps(STUDIES) if t.source == bills.BILL and t.comparable]
    shared = [t for t in billed if shared_cores(t.load_average, t.workers or 0)]
    assert len(billed) > len(shared)  # the first: 2019-01-07b with (400, 300) networks
    assert all(t.cpu_s for t in shared)
    for took in (t for t in billed if t not in shared):
        assert took.priced_at_start_s is not None
        assert bills.within(took.wall_s, took.priced_at_start_s), took.command
