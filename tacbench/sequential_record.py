"""``<out>/sweep/sequential.json``, what a ``tacbench sweep --until-decided`` decided
(:class:`tacbench.sweep.until_decided.Record` writes it): read and checked here for the sweep
that continues it and for the report that shows it."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tacbench.errors import TacbenchError
from tacbench.runs.files import read_json
from tacbench.sequential import Interim, SequentialResult

RECORD_FILE = "sequential.json"  # in <out>/sweep/: what a sweep --until-decided decided
ADVICE = (
    "restore it from the sweep that wrote it, or move it away (a sweep --until-decided then "
    "decides again from interim 1)"
)


def read_record(path: Path) -> dict[str, Any]:
    """The record at ``path``; a TacbenchError, naming the file and its first fault, unless it
    has the structure the sweep writes: a design, each task's methods, and the same tasks'
    interims, each with its number, seeds, scores and decisions."""
    record = read_json(path, ADVICE)
    fault = _fault(record)
    if fault:
        raise TacbenchError(f"{path} is damaged ({fault}); {ADVICE}.")
    return record


def _fault(record: dict[str, Any]) -> str:
    for key in ("design", "methods", "interims"):
        if not isinstance(record.get(key), dict):
            return f"no {key!r} object"
    if not all(isinstance(record["design"].get(k), int | float) for k in ("n", "K", "alpha")):
        return "its design lacks n, K or alpha"
    if set(record["interims"]) != set(record["methods"]):
        return f"interims of {sorted(record['interims'])}, methods of {sorted(record['methods'])}"
    fields = (("number", int), ("seeds", dict), ("scores", dict), ("decisions", list))
    for env, interims in record["interims"].items():
        for interim in interims if isinstance(interims, list) else [None]:
            if not isinstance(interim, dict) or not all(
                isinstance(interim.get(key), kind) for key, kind in fields
            ):
                return f"an interim of {env} without its number, seeds, scores or decisions"
    return ""


def results_of_record(record: Mapping[str, Any]) -> dict[str, SequentialResult]:
    """Each task's interims as a sequential sweep recorded them (``sweep/sequential.json``,
    :mod:`tacbench.sweep.until_decided`)."""
    design = record["design"]
    results = {}
    for env, interims in record["interims"].items():
        if not interims:
            continue
        kept = tuple(
            Interim(
                interim["number"],
                {m: len(seeds) for m, seeds in interim["seeds"].items()},
                {(d["method"], d["against"]): d["decision"] for d in interim["decisions"]},
            )
            for interim in interims
        )
        results[env] = SequentialResult(
            tuple(record["methods"][env]),
            tuple(kept[0].decisions),
            design["n"],
            design["K"],
            design["alpha"],
            kept,
        )
    return results
