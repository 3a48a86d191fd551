"""Write a :class:`Report` to its output folder: figures, CSV tables, report.md, index.html."""

from __future__ import annotations

import io
import shutil
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from tacbench.errors import TacbenchError, listing
from tacbench.report import plots
from tacbench.report.build import Report
from tacbench.report.page import (
    TITLE,
    best_q_display,
    q_ranges_display,
    sections,
    summary_display,
)
from tacbench.report.render import markdown_table, to_html, to_markdown

HTML_FORMAT = {"png": "png", "svg": "svg", "pdf": "png"}
"""Format each figure is embedded in index.html with (browsers do not show PDF images)."""


def _tables(report: Report) -> dict[str, pd.DataFrame]:
    skipped = pd.DataFrame(
        {
            "path": [s.path for s in report.runset.skipped],
            "reason": [s.reason for s in report.runset.skipped],
        }
    )
    return {
        # the note: on the page; rows dropped: in a caution (and the tables keep their columns)
        "runs": report.scores.drop(columns=["versions", "note", "dropped"]),
        "skipped": skipped,
        "summary": report.summary,
        "best_q": report.best_q,
        "curves": report.curves,
        "normalisation": report.anchors,
        "stats_per_task": report.per_task,
        "stats_aggregate": report.aggregate,
        "improvement": report.improvement,
        **({"baselines": report.baselines} if not report.baselines.empty else {}),
        "profiles": report.profiles,
        "q_ranges": report.q_ranges,
        **(
            {"sequential_decisions": report.sequential, "sequential_spending": report.spending}
            if not report.sequential.empty
            else {}
        ),
    }


STAGING = ".tacbench-report.new"  # in --out: the report is written here, then moved into place


def is_report(out: Path) -> bool:
    """Whether ``out`` holds a report tacbench wrote (its report.md, by its title)."""
    try:
        with (out / "report.md").open(encoding="utf-8") as handle:
            return handle.readline().strip() == f"# {TITLE}"
    except (OSError, UnicodeDecodeError):
        return False


def check_out(out: Path) -> None:
    """A TacbenchError, before any analysis, when ``out`` holds files of the kinds a report
    writes but no earlier report: a study's own tables (summary.csv, ...) would be replaced."""
    if not out.is_dir() or is_report(out):
        return
    found = sorted(p.name for p in out.iterdir() if p.is_file() and p.suffix in REPORT_SUFFIXES)
    if found:
        shown = listing(found)
        raise TacbenchError(
            f"--out {out} holds {shown}, which a report could overwrite, and no earlier report "
            "(report.md); give a new or empty --out, or the folder of an earlier report."
        )


def write_report(report: Report) -> list[Path]:
    """Write everything under ``report.options.out`` (:func:`check_out` first); returns the
    files written. They are written into a staging folder inside it and moved into place when
    all are written (the page last), so that a failure or a Ctrl-C while the report is made
    leaves an earlier report as it was."""
    out = report.options.out
    check_out(out)
    out.mkdir(parents=True, exist_ok=True)
    staging = out / STAGING
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir()
    try:
        names = [path.name for path in _write(report, staging)]
        # the page last: until it is replaced, the folder reads as the earlier report
        for name in sorted(names, key=lambda name: name in ("report.md", "index.html")):
            (staging / name).replace(out / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [out / name for name in names]


def _write(report: Report, out: Path) -> list[Path]:
    """Every file of the report, written into ``out``."""
    written: list[Path] = []
    for name, frame in _tables(report).items():
        path = out / f"{name}.csv"
        frame.to_csv(path, index=False)
        written.append(path)
    displays = {"summary": summary_display, "best_q": best_q_display, "q_ranges": q_ranges_display}
    for name, display in displays.items():
        path = out / f"{name}.md"
        path.write_text(markdown_table(display(report)) + "\n", encoding="utf-8")
        written.append(path)

    fmt = report.options.fmt
    files: dict[str, str] = {}
    images: dict[str, tuple[str, bytes]] = {}
    for name, fig in report.figures.items():
        path = out / f"{name}.{fmt}"
        plots.save(fig, path)
        written.append(path)
        files[name] = path.name
        kind = HTML_FORMAT[fmt]
        if kind == fmt:
            images[name] = (kind, path.read_bytes())
        else:
            buffer = io.BytesIO()
            plots.save(fig, buffer, kind)
            images[name] = (kind, buffer.getvalue())

    page = sections(report)
    for path, text in (
        (out / "report.md", to_markdown(TITLE, page, files)),
        (out / "index.html", to_html(TITLE, page, images)),
    ):
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


REPORT_SUFFIXES = (".csv", ".md", ".html", ".png", ".svg", ".pdf")  # what a report writes


def leftovers(out: Path, written: Sequence[Path]) -> list[str]:
    """The files in ``out`` of the kinds a report writes that this one did not write: an
    earlier report's (figures in another format, a table these runs have no rows for), which
    would read as this report's. Left in place: they may be the user's."""
    names = {path.name for path in written}
    return sorted(
        p.name
        for p in out.iterdir()
        if p.is_file() and p.suffix in REPORT_SUFFIXES and p.name not in names
    )
