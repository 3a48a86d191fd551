"""The summary printed at the end of a sweep and written to ``<out>/sweep/summary.{json,txt}``:
counts by state and by what a rerun does, every unfinished run with its failures, the bill."""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

from tacbench import runs
from tacbench.errors import plural
from tacbench.progress import duration
from tacbench.sweep import state
from tacbench.sweep.plan import PlannedRun, SweepPlan


def shown_state(planned: PlannedRun) -> str:
    """A run's state as the summaries count it: a run given up on is failed, whatever its
    status.json says (a worker that died left it partial or new)."""
    return "failed" if planned.action == "give-up" else planned.status.state


def counts(plan: SweepPlan, refused: Collection[str] = ()) -> dict[str, int]:
    """Runs by state (complete, partial, failed, new: :func:`shown_state`), failed runs by what
    happens next, the runs that the same command would train (``to_train``: new, partial or to
    retry, none of them given up) and of those the runs that a sweep found unable to resume
    from their files (``cannot_resume``: the keys in ``refused``)."""
    by_state = Counter(shown_state(p) for p in plan.runs)
    to_train = [p for p in plan.runs if p.action in ("train", "retry")]
    return {
        "runs": len(plan.runs),
        **{name: by_state.get(name, 0) for name in ("complete", "partial", "failed", "new")},
        "to_retry": plan.count(action="retry"),
        "given_up": plan.count(action="give-up"),
        "to_train": len(to_train),
        "cannot_resume": sum(p.run.key in refused for p in to_train),
    }


def summarize(
    plan: SweepPlan,
    sweep_state: state.SweepState,
    *,
    refused: Collection[str] = (),
    **fields: Any,
) -> dict[str, Any]:
    """The summary of a finished (or stopped) sweep as a JSON-ready dict: ``fields`` (command,
    interrupted, ...), counts by state, and every run not complete with its failures; the runs
    in ``refused`` (by key) could not resume from their files in this sweep."""
    unfinished = []
    for p in plan.runs:
        if p.status.state == "complete":
            continue
        shown = "cannot resume" if p.run.key in refused else p.status.state
        unfinished.append(
            {
                "run": p.run.key,
                "state": "given up" if p.action == "give-up" else shown,
                "step": p.status.step,
                "total_steps": p.run.total_steps,
                "failures": [vars(f) for f in sweep_state.failures(p.run.key)],
            }
        )
    recovered = sum(
        1 for p in plan.runs if p.status.state == "complete" and sweep_state.failures(p.run.key)
    )
    return {
        **fields,
        "preset": plan.preset.name,
        "out": str(plan.out),
        "finished": runs.now_iso(),
        "counts": {**counts(plan, refused), "recovered_after_failures": recovered},
        "unfinished": unfinished,
    }


OTHER_WORK = 0.5
"""The load above a sweep's workers that the bill calls other work (the rest is the driver,
compilation threads and the load average's lag)."""


def shared_cores(load: float | None, workers: int) -> bool:
    """Whether a bill's load says that other work shared the cores: :data:`OTHER_WORK` or more
    above its workers (False where the bill does not record the load)."""
    return load is not None and load - workers >= OTHER_WORK


def load_note(load: float | None, cores: int | None, workers: int) -> str:
    """What a local sweep's bill says of the machine's load while it ran (empty where the bill
    does not record it): the price assumes a core per worker and nothing else running."""
    if load is None or cores is None:
        return ""
    note = f"the load averaged {load:.1f} on {plural(cores, 'core')}"
    if shared_cores(load, workers):
        note += f", {load - workers:.1f} above its workers: other work shared the cores"
    return note


def summary_text(summary: dict[str, Any], command: str) -> str:
    """The summary as printed at the end of the sweep."""
    c = summary["counts"]
    lines = [
        f"sweep summary ({summary['preset']} into {summary['out']}): {plural(c['runs'], 'run')}: "
        f"{c['complete']} complete, {c['failed']} failed ({c['given_up']} given up), "
        f"{c['partial']} partial, {c['new']} not started"
        + (
            f"; {c['cannot_resume']} cannot resume from "
            f"{'its' if c['cannot_resume'] == 1 else 'their'} files"
            if c["cannot_resume"]
            else ""
        )
        + (
            f"; {c['recovered_after_failures']} completed after failed attempts"
            if c["recovered_after_failures"]
            else ""
        )
    ]
    bill = summary.get("bill")
    if bill and bill["priced_wall_s"] > 0:
        took = (
            f"{'stopped after' if summary['interrupted'] else 'took'} {duration(bill['wall_s'])} "
            f"on {plural(bill['workers'], 'worker')} "
            f"({bill['cpu_class']}); priced at the start {duration(bill['priced_wall_s'])}"
        )
        ratio = bill["wall_s"] / bill["priced_wall_s"]  # only a whole plan's bill is compared
        took = took if summary["interrupted"] else f"{took}: {ratio:.2f}x the price"
        load = load_note(bill.get("load_average"), bill.get("cores"), bill["workers"])
        lines.append(f"{took}; {load}" if load else took)
    failed = [u for u in summary["unfinished"] if u["failures"]]
    if failed:
        lines.append("failures:")
    for entry in failed:
        n = len(entry["failures"])
        lines.append(
            f"  {entry['run']}: {entry['state']} at step {entry['step']:,} after "
            f"{plural(n, 'failed attempt')}"
        )
        for i, failure in enumerate(entry["failures"], 1):
            lines.append(
                f"    {i}. {failure['time']} {failure['host']}, step {failure['step']:,}: "
                f"{failure['reason']}"
            )
    if c["given_up"]:
        lines.append(
            f"{plural(c['given_up'], 'run')} given up after more than "
            "--max-retries failures: fix what the failures say, then run the same command with "
            "a larger --max-retries to try again"
        )
    if n := c["cannot_resume"]:
        its, it = ("their", "them") if n > 1 else ("its", "it")
        lines.append(
            f"{plural(n, 'run')} cannot resume from {its} files, so the sweep did not "
            f"retry {it} (every attempt would be refused alike): fix what the failures say, then "
            "run the same command"
        )
    if c["to_train"] > c["cannot_resume"]:
        lines.append(
            f"to continue, run the same command again: {command}"
            if command
            else "to continue, run the same sweep again"
        )
    return "\n".join(lines)


def write_summary(out: Path, summary: dict[str, Any], text: str) -> Sequence[Path]:
    """Write ``<out>/sweep/summary.json`` and ``summary.txt``; return their paths."""
    directory = state.sweep_dir(out)
    directory.mkdir(parents=True, exist_ok=True)
    runs.atomic_write_json(directory / "summary.json", summary)
    tmp = directory / "summary.txt.tmp"
    tmp.write_text(text + "\n")
    tmp.replace(directory / "summary.txt")
    return directory / "summary.json", directory / "summary.txt"
