"""The published study (results/studies/, docs/results.md): its committed report regenerates,
table for table, from its committed run directories, and the runs are what the page says."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tacbench.report import ReportOptions, analyse, write_report

pytestmark = pytest.mark.smoke

STUDY = Path(__file__).resolve().parents[1] / "results" / "studies" / "paper-q-grid-100k"
TABLES = sorted(
    p.name
    for p in (STUDY / "report").glob("*")
    if p.suffix in (".csv", ".md") and p.stem != "report"
)


def test_the_study_holds_nine_q_by_five_seeds_on_both_tasks_complete() -> None:
    statuses = [json.loads(p.read_text()) for p in STUDY.glob("runs/tac/*/*/seed*/status.json")]
    assert len(statuses) == 2 * 9 * 5
    assert {(s["state"], s["step"]) for s in statuses} == {("complete", 100_000)}
    assert not list(STUDY.glob("runs/**/checkpoint"))  # CSV and JSON only


def test_the_report_has_the_tables_the_page_quotes() -> None:
    assert {"summary.md", "best_q.md", "q_ranges.md", "stats_per_task.csv"} <= set(TABLES)


@pytest.mark.parametrize("table", TABLES)
def test_the_committed_report_tables_regenerate_exactly(regenerated: Path, table: str) -> None:
    assert (regenerated / table).read_text() == (STUDY / "report" / table).read_text(), table


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("study-report")
    write_report(analyse(ReportOptions(results=STUDY, out=out)))  # the CLI's defaults
    return out
