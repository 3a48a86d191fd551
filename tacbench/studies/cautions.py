"""What a study's analysis left out, as ``caution:`` lines: runs the loader could not use, and
runs short of their budget. ``tacbench study NAME analyse`` prints them and writes them to
``cautions.csv`` (``tacbench/cli/study.py``)."""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd

from tacbench.errors import listing, plural
from tacbench.report.load import Skipped


def seeds(values: Sequence[int] | set[int]) -> str:
    """``seed 0``, ``seeds 0, 10``: in order."""
    ordered = sorted(values)
    return f"seed{'' if len(ordered) == 1 else 's'} {', '.join(map(str, ordered))}"


def skipped_runs(skipped: Sequence[Skipped]) -> list[str]:
    """A caution naming the run directories the loader could not use (failed, damaged or
    repeated), with why; none when there are none."""
    if not skipped:
        return []
    named = [f"{s.path} ({s.reason})" for s in skipped]
    folders = plural(len(named), "run directory", "run directories")
    return [f"left out {folders} that cannot be used: {listing(named)}"]


def short_runs(runs: pd.DataFrame) -> list[str]:
    """A caution naming the loader's ``partial`` rows among ``runs``: runs stopped before their
    budget, and complete runs planned shorter than the other runs of their variant."""
    partial = runs[runs["partial"]]
    if partial.empty:
        return []
    longest = runs.groupby(["algo", "env", "variant"])["total_steps"].transform("max")
    named = [
        f"{run.path} ({run.state} at step {run.step_reached:,.0f})"
        if run.state != "complete"
        else f"{run.path} ({run.total_steps:,.0f} steps, its variant's others {planned:,.0f})"
        for run, planned in zip(partial.itertuples(), longest[partial.index], strict=True)
    ]
    return [f"left out {plural(len(named), 'run')} short of the budget: {listing(named)}"]
