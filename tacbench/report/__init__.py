"""``tacbench report``: run directories -> tidy DataFrame -> rliable statistics -> figures -> pages.

Layers, each its own module: :mod:`~tacbench.report.load` (run directories to one tidy frame),
:mod:`~tacbench.report.tables` and :mod:`~tacbench.report.curves` (per-run scores, summaries,
curves on a common grid), :mod:`~tacbench.report.stats` (rliable estimators, vectorised
stratified bootstrap), :mod:`~tacbench.report.plots` (figures), :mod:`~tacbench.report.page` and
:mod:`~tacbench.report.render` (Markdown and self-contained HTML), :mod:`~tacbench.report.write`.
The report imports neither torch nor the trainers: it needs nothing but the run files.
"""

from __future__ import annotations

from pathlib import Path

from tacbench.report.build import Report, ReportOptions, analyse
from tacbench.report.load import RunSet, Skipped, load_runs
from tacbench.report.write import write_report

__all__ = [
    "Report",
    "ReportOptions",
    "RunSet",
    "Skipped",
    "analyse",
    "load_runs",
    "make_report",
    "write_report",
]


def make_report(options: ReportOptions) -> list[Path]:
    """Analyse the runs under ``options.results`` and write the report to ``options.out``."""
    return write_report(analyse(options))
