"""The exact tier: short deterministic runs, and the theory figures' CSVs, compared to the last
printed digit.

A reference run is the output of one recorded ``tacbench run`` command: its ``eval.csv``,
``train.csv`` and ``losses.csv`` without the ``wall_s`` column, and its final status. The runs
are recorded per CPU class (``exact/<cpu class>/``, :func:`tacbench.hardware.cpu_class`). On
the same library versions and CPU class, a fresh run of that command must write the same text;
elsewhere the runs are skipped with the reason (float rounding legitimately differs there). The
theory CSVs depend on NumPy alone and are always compared.
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tacbench import runs
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.regress import manifest as mf
from tacbench.regress.outcome import Row, Status, TierResult
from tacbench.regress.specs import EXACT_RUNS, ReferenceRun

EXACT_FILES = ("eval.csv", "train.csv", "losses.csv")
THEORY_COMMAND = "tacbench figures --out DIR"
Log = Callable[[str], None]


# --- comparing CSV text ---------------------------------------------------------------------


def compare_csv(reference: str, fresh: str) -> tuple[Status, str]:
    """``match`` when the texts are equal, else ``drift`` with where and by how much."""
    if reference == fresh:
        return "match", f"{max(len(reference.splitlines()) - 1, 0)} rows"
    old, new = _rows(reference), _rows(fresh)
    if not old or not new or old[0] != new[0]:
        return "drift", f"columns {old[0] if old else []} -> {new[0] if new else []}"
    header, old_body, new_body = old[0], old[1:], new[1:]
    if old_body == new_body:
        return "drift", "the same rows, other bytes (a line ending or a blank line)"
    first = next(
        (i for i, (a, b) in enumerate(zip(old_body, new_body, strict=False)) if a != b),
        min(len(old_body), len(new_body)),
    )
    row = old_body[first] if first < len(old_body) else new_body[first]
    parts = [f"from row {first + 1} ({header[0]} {row[0]})"]
    if len(old_body) != len(new_body):
        parts.append(f"{len(old_body)} -> {len(new_body)} rows")
    parts.append(_largest_difference(header, old_body, new_body))
    return "drift", "; ".join(p for p in parts if p)


def _rows(text: str) -> list[list[str]]:
    return [row for row in csv.reader(io.StringIO(text)) if row]


def _largest_difference(
    header: Sequence[str], old: Sequence[Sequence[str]], new: Sequence[Sequence[str]]
) -> str:
    """How many cells of the rows both have differ, and the largest relative difference."""
    changed, worst = 0, (-1.0, "", "", "")
    for a_row, b_row in zip(old, new, strict=False):
        for name, a, b in zip(header, a_row, b_row, strict=False):
            if a == b:
                continue
            changed += 1
            try:
                x, y = float(a), float(b)
                scale = max(abs(x), abs(y))
                rel = abs(x - y) / scale if scale > 0 else 0.0
            except ValueError:
                rel = math.inf
            if not rel <= worst[0]:  # NaN (from inf - inf) counts as the largest
                worst = (rel, name, a, b)
    if not changed:
        return ""
    rel, name, a, b = worst
    return f"{changed} values differ, most in {name}: {a} -> {b} (relative {rel:.2g})"


# --- the runs -------------------------------------------------------------------------------


def _completed(name: str, result: mf.CommandResult) -> Path:
    """The one run directory of a reference command that must have completed."""
    if result.exit_code != 0 or len(result.directories) != 1:
        tail = "\n".join(result.output.splitlines()[-5:])
        raise TacbenchError(
            f"reference run {name} did not complete (exit status {result.exit_code}); "
            f"a reference must be a complete run. Its last output:\n{tail}"
        )
    return result.directories[0]


def update_exact(
    reference: Path,
    work: Path,
    specs: Sequence[ReferenceRun] = EXACT_RUNS,
    log: Log = print,
    runner: mf.Runner = mf.subprocess_runner,
) -> Path:
    """Run every spec and write ``<reference>/exact/<this CPU class>``: the CSVs and
    ``manifest.json`` (other CPU classes' references are kept)."""
    start = time.perf_counter()
    with mf.staged(reference, "exact") as staging:
        entries = []
        for spec in specs:
            t0 = time.perf_counter()
            directory = _completed(spec.name, runner(spec.args, work / spec.name))
            (staging / spec.name).mkdir()
            for name in EXACT_FILES:
                text = mf.without_clocks((directory / name).read_text())
                (staging / spec.name / name).write_text(text)
            status = runs.read_json(directory / "status.json")
            entries.append(
                {
                    "name": spec.name,
                    "command": mf.command_line(spec.args),
                    "args": list(spec.args),
                    "state": status["state"],
                    "step": status["step"],
                    "seconds": round(time.perf_counter() - t0, 1),
                    "config": runs.read_json(directory / "config.json")["config"],
                }
            )
            log(f"{spec.name}: {entries[-1]['seconds']} s")
        manifest = mf.provenance("exact", reference)
        manifest.update(
            files=list(EXACT_FILES),
            ignored_columns=list(mf.CLOCKS),
            seconds=round(time.perf_counter() - start, 1),
            runs=entries,
        )
        return mf.publish(staging, manifest, reference, "exact")


def check_exact(
    reference: Path,
    work: Path,
    names: Sequence[str] = (),
    log: Log = print,
    runner: mf.Runner = mf.subprocess_runner,
) -> TierResult:
    """Rerun the recorded commands (all, or those in ``names``) and compare their CSVs, against
    the references of this machine's CPU class (skipped where there are none)."""
    start, references = time.perf_counter(), mf.tier_directory(reference, "exact")
    recorded = mf.recorded_cpu_classes(reference)
    if recorded and references.name not in recorded:
        known = [
            run for cpu in recorded for run in mf.read_manifest(reference, "exact", cpu)["runs"]
        ]
        mf.select(known, names, reference)  # an unknown --only name is still an error
        return TierResult(
            "exact",
            str(references),
            skipped=(
                f"no exact references for this machine's CPU class {references.name}; they are "
                f"recorded for {', '.join(recorded)}. Float rounding differs between CPU "
                "classes, so exact results only reproduce on the class that made them; check "
                "with --tier stat, or record this class's on purpose with: "
                f"{mf.regenerate_command('exact', reference)}"
            ),
        )
    manifest = mf.read_manifest(reference, "exact")
    notes = [mf.provenance_note(manifest)]
    entries = mf.select(manifest["runs"], names, reference)
    expected = [references / e["name"] / file for e in entries for file in manifest["files"]]
    mf.require_files(expected, "exact", reference)
    differences = mf.environment_differences(manifest["environment"], mf.environment())
    if differences:
        return TierResult(
            "exact",
            str(references),
            notes=tuple(notes),
            skipped=(
                f"made with {'; '.join(differences)}. Exact results need the same versions and "
                f"CPU class; check with --tier stat, or regenerate on purpose with: "
                f"{manifest['regenerate']}"
            ),
        )
    rows: list[Row] = []
    for entry in entries:
        name = entry["name"]
        t0 = time.perf_counter()
        result = runner(entry["args"], work / name)
        log(f"{name}: exit status {result.exit_code} ({time.perf_counter() - t0:.1f} s)")
        if len(result.directories) != 1:
            detail = f"no run directory (exit status {result.exit_code}): {result.last_line}"
            rows.append(Row(name, "run", "missing", detail))
            continue
        directory = result.directories[0]  # the fresh run
        rows.append(_status_row(name, entry, runs.read_json(directory / "status.json")))
        for file in manifest["files"]:
            expected = (references / name / file).read_text()
            path = directory / file
            if not path.is_file():
                rows.append(Row(name, file, "missing", "not written"))
                continue
            status, detail = compare_csv(expected, mf.without_clocks(path.read_text()))
            rows.append(Row(name, file, status, detail))
        config = runs.read_json(directory / "config.json")["config"]
        reference_config = entry["config"]
        if config.get("algo") == "tac":  # settings added since: their defaults, as a resume reads
            reference_config = runs.as_read_now(reference_config, RunConfig.from_dict(config))
        changed = runs.differing_fields(reference_config, config)
        if changed:
            notes.append(f"{name}: config differs from the reference's: {'; '.join(changed)}")
    return TierResult(
        "exact",
        str(references),
        tuple(rows),
        tuple(notes),
        seconds=time.perf_counter() - start,
    )


def _status_row(name: str, entry: dict[str, Any], status: dict[str, Any]) -> Row:
    recorded, fresh = (entry["state"], entry["step"]), (status["state"], status["step"])
    if recorded == fresh:
        return Row(name, "status", "match", f"{fresh[0]} at step {fresh[1]}")
    detail = f"{recorded[0]} at step {recorded[1]} -> {fresh[0]} at step {fresh[1]}"
    reason = status.get("reason")
    return Row(name, "status", "drift", detail + (f" ({reason})" if reason else ""))


# --- the theory figures' CSVs ----------------------------------------------------------------


def _theory_csvs(work: Path) -> dict[str, str]:
    from tacbench.theory.figures import write_figures  # matplotlib only when this runs

    return {p.name: p.read_text() for p in write_figures(work / "figures") if p.suffix == ".csv"}


def update_theory(reference: Path, work: Path) -> Path:
    """Write ``<reference>/theory``: the CSVs of ``tacbench figures`` and ``manifest.json``."""
    with theory_staged(reference, work) as publish:
        return publish()


@contextmanager
def theory_staged(reference: Path, work: Path) -> Iterator[Callable[[], Path]]:
    """The theory references built in a staging folder (:func:`mf.staged`); the block calls the
    yielded function to publish them, or leaves the references as they were."""
    with mf.staged(reference, "theory") as staging:
        csvs = _theory_csvs(work)
        for name, text in csvs.items():
            (staging / name).write_text(text)
        manifest = mf.provenance("theory", reference)
        manifest.update(command=THEORY_COMMAND, files=sorted(csvs))
        yield lambda: mf.publish(staging, manifest, reference, "theory")


def check_theory(reference: Path, work: Path) -> TierResult:
    """Rewrite the theory figures and compare each recorded CSV's text."""
    start, manifest = time.perf_counter(), mf.read_manifest(reference, "theory")
    mf.require_files(
        [reference / "theory" / name for name in manifest["files"]], "theory", reference
    )
    notes = [mf.provenance_note(manifest)]
    fresh = _theory_csvs(work)
    rows = []
    for name in manifest["files"]:
        if name not in fresh:
            rows.append(Row(name, "csv", "missing", "tacbench figures no longer writes it"))
            continue
        status, detail = compare_csv((reference / "theory" / name).read_text(), fresh[name])
        rows.append(Row(name, "csv", status, detail))
    new = sorted(set(fresh) - set(manifest["files"]))
    if new:
        notes.append(f"not in the references (regenerate to include): {', '.join(new)}")
    differences = mf.environment_differences(manifest["environment"], mf.environment())
    if differences and any(r.status != "match" for r in rows):
        notes.append(f"the references were made with {'; '.join(differences)}")
    return TierResult(
        "theory",
        str(reference / "theory"),
        tuple(rows),
        tuple(notes),
        seconds=time.perf_counter() - start,
    )
