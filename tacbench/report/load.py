"""Find run directories and load them into one tidy DataFrame.

The report reads nothing but the run-directory contract (``docs/report.md``)::

    <results>/runs/<algo>/<env>/<variant>/seed<k>/{config.json, status.json, eval.csv, train.csv}

so it works on results copied from anywhere. Identity (algo, env, variant, q, alpha, seed) comes
from ``config.json``, not from the path. Runs that failed, or whose files cannot be read, are
skipped and listed with the reason; runs that are still going (or stopped early) are kept and
flagged ``partial``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tacbench.errors import TacbenchError, listing
from tacbench.report.series import METRIC_SOURCES, Metric, Unreadable, read_series
from tacbench.report.tables import run_scores
from tacbench.runs import read_json

CONTRACT_FILES = ("config.json", "status.json", "eval.csv", "train.csv")
STATES = ("running", "interrupted", "complete", "failed")
_SAME = "same algo, env, variant, seed"  # a duplicate's identity, as its reason names it

RUN_COLUMNS = (
    "run",
    "path",
    "algo",
    "env",
    "variant",
    "q",
    "alpha",
    "seed",
    "population",
    "state",
    "step_reached",
    "total_steps",
    "partial",
    "rows",
    "dropped",
    "note",
    "command",
    "git_commit",
    "host",
    "created",
    "versions",
)
TIDY_COLUMNS = ("run", "algo", "env", "variant", "q", "alpha", "seed", "step", "return", "wall_s")


@dataclass(frozen=True)
class Skipped:
    """A run directory left out of the report, and why.

    ``identity`` holds the config.json identity (algo, env, variant, q, alpha, seed) when it was
    readable, so failed runs can be counted against their method.
    """

    path: str
    reason: str
    identity: dict[str, Any] | None = None


@dataclass(frozen=True)
class RunSet:
    """Everything the report knows about the runs.

    ``data`` is the tidy frame (columns :data:`TIDY_COLUMNS`, one row per logged point), ``runs``
    has one row per loaded run (columns :data:`RUN_COLUMNS`), ``skipped`` lists what was left out.
    """

    data: pd.DataFrame
    runs: pd.DataFrame
    skipped: tuple[Skipped, ...]
    metric: Metric
    root: Path


def runs_root(results: Path) -> Path:
    """``<results>/runs`` when it exists (the contract layout), else ``results`` itself."""
    nested = results / "runs"
    return nested if nested.is_dir() else results


def find_run_dirs(root: Path) -> list[Path]:
    """Every directory under ``root`` holding a contract file, sorted; not searched below one."""
    found: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(root):
        if any(name in filenames for name in CONTRACT_FILES):
            found.append(Path(dirpath))
            dirnames.clear()
        else:
            dirnames.sort()
    return sorted(found)


def _refuse_regression_references(root: Path) -> None:
    """When nothing under ``root`` is a usable run: ``tacbench regress``'s references (a tier's
    ``manifest.json`` beside or below ``root``) hold a run's CSVs without its ``config.json``,
    so they are no run directories to mend."""
    for manifest in sorted(root.glob("**/manifest.json")):
        try:
            tier = read_json(manifest).get("tier")
        except TacbenchError:
            continue
        if isinstance(tier, str):
            raise TacbenchError(
                f"{root} holds `tacbench regress`'s {tier} references "
                f"({manifest.relative_to(root).as_posix()}), not run directories; check runs "
                "against them with `tacbench regress`, and pass --results the --out of a run "
                "or sweep to report on"
            )


def _read_json(path: Path) -> dict[str, Any]:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise Unreadable(f"{path.name} missing") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise Unreadable(f"{path.name} unreadable: {err}") from None
    if not isinstance(value, dict):
        raise Unreadable(f"{path.name} is not a JSON object")
    return value


def _number(value: Any) -> float:
    """A finite float from a JSON number, NaN for null; anything else is unreadable."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise Unreadable(f"config.json: expected a number or null, got {value!r}")
    return float(value)


def _identity(config: dict[str, Any]) -> dict[str, Any]:
    """The run's identity and provenance from ``config.json``."""
    for key in ("algo", "env", "variant"):
        if not isinstance(config.get(key), str) or not config[key]:
            raise Unreadable(f"config.json: '{key}' missing or not a string")
    seed = config.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise Unreadable("config.json: 'seed' missing or not an integer")
    q, alpha = _number(config.get("q")), _number(config.get("alpha"))
    settings = config.get("config")
    population = _population(config) if isinstance(settings, dict) else ""
    if population:
        q = math.nan  # learned (--q auto): config.json's q is where the member started
    elif config["algo"] == "tac" and not q > 0:
        raise Unreadable("config.json: a TAC run needs a number q > 0")
    total = config.get("total_steps")
    if total is not None and (isinstance(total, bool) or not isinstance(total, int) or total < 1):
        raise Unreadable(f"config.json: 'total_steps' is {total!r}, not a step count")
    versions = config.get("versions")
    return {
        "algo": config["algo"],
        "env": config["env"],
        "variant": config["variant"],
        "q": q,
        "alpha": alpha,
        "seed": seed,
        "population": population,
        "total_steps": math.nan if total is None else float(total),
        "command": str(config.get("command", "")),
        "git_commit": str(config.get("git_commit", "")),
        "host": str(config.get("host", "")),
        "created": str(config.get("created", "")),
        "versions": json.dumps(versions, sort_keys=True) if isinstance(versions, dict) else "{}",
    }


def _population(config: dict[str, Any]) -> str:
    """A --q auto member's population, named by its members' seeds (``seeds 0,10,20,30``);
    empty for every other run."""
    if config["algo"] != "tac" or config["config"].get("q_mode") != "auto":
        return ""
    members = config.get("members")
    if not isinstance(members, list) or not all(isinstance(m, dict) for m in members):
        raise Unreadable("config.json: a --q auto run needs its 'members'")
    return "seeds " + ",".join(str(m.get("seed")) for m in members)


def _status(run_dir: Path) -> tuple[str, float, str]:
    """(state, step, reason); a missing status.json reads as state 'unknown'."""
    if not (run_dir / "status.json").exists():
        return "unknown", math.nan, ""
    status = _read_json(run_dir / "status.json")
    state = status.get("state")
    if state not in STATES:
        raise Unreadable(f"status.json: unknown state {state!r}")
    step = status.get("step")
    step_f = (
        float(step) if isinstance(step, int | float) and not isinstance(step, bool) else math.nan
    )
    return str(state), step_f, str(status.get("reason", ""))


def _read_run(run_dir: Path, metric: Metric) -> tuple[dict[str, Any], tuple[np.ndarray, ...]]:
    identity = _identity(_read_json(run_dir / "config.json"))
    state, status_step, reason = _status(run_dir)
    if state == "failed":
        at = "" if math.isnan(status_step) else f" at step {int(status_step)}"
        raise Unreadable(f"run failed{at}: {reason or 'no reason given'}", identity)
    read = read_series(run_dir, metric, state, status_step, identity["env"])
    series = (read.step, read.value, read.wall_s)
    reached = float(np.nanmax([status_step, series[0][-1]]))
    total = identity["total_steps"]
    partial = state != "complete" or (not math.isnan(total) and reached < total)
    row = {**identity, "state": state, "step_reached": reached, "partial": partial}
    row["rows"], row["note"], row["dropped"] = len(series[0]), read.note, read.dropped
    return row, series


def final_return(run_dir: Path, last: int) -> float:
    """A complete run's final return as the report computes it: the mean of its last ``last``
    evaluation returns (``eval.csv``). TacbenchError, with the reason, for a run that is not
    complete or cannot be read."""
    try:
        row, (step, value, _) = _read_run(run_dir, "eval")
    except Unreadable as err:
        raise TacbenchError(f"{run_dir}: {err}") from None
    if row["partial"]:
        raise TacbenchError(f"{run_dir} is not complete (step {row['step_reached']:g}).")
    series = pd.DataFrame({"run": 0, "step": step, "return": value})
    return float(run_scores(series, last)["final"].iloc[0])


def load_runs(results: Path | str, metric: Metric = "eval") -> RunSet:
    """Load every run directory under ``results`` (see :func:`runs_root`) for one metric.

    Raises :class:`TacbenchError` when ``results`` does not exist, holds no run directory, or
    holds no usable one (the message lists the reasons).
    """
    if metric not in METRIC_SOURCES:
        raise TacbenchError(f"unknown metric {metric!r}; use one of {sorted(METRIC_SOURCES)}")
    results = Path(results)
    if not results.is_dir():
        raise TacbenchError(
            f"results directory {results} does not exist; pass --results pointing at the folder "
            "that holds runs/<algo>/<env>/<variant>/seed<k>/"
        )
    root = runs_root(results)
    run_dirs = find_run_dirs(root)
    if not run_dirs:
        _refuse_regression_references(root)
        raise TacbenchError(
            f"no run directories under {root} (looked for folders holding config.json, "
            "status.json, eval.csv or train.csv); train something with `tacbench run` first "
            "or pass --results pointing at copied results"
        )
    rows: list[dict[str, Any]] = []
    series: list[tuple[np.ndarray, ...]] = []
    skipped: list[Skipped] = []
    seen: dict[tuple[str, str, str, int], int] = {}  # a run's identity -> its index in rows
    for run_dir in run_dirs:
        rel = run_dir.relative_to(root).as_posix()
        try:
            row, run_series = _read_run(run_dir, metric)
        except Unreadable as err:
            skipped.append(Skipped(rel, str(err), err.identity))
            continue
        key = (row["algo"], row["env"], row["variant"], row["seed"])
        if key not in seen:
            seen[key] = len(rows)
            rows.append({"run": len(rows), "path": rel, **row})
            series.append(run_series)
            continue
        at = seen[key]
        kept = rows[at]
        if _further(row, kept):  # the one that trained further stays, whatever the path order
            rows[at], series[at] = {"run": at, "path": rel, **row}, run_series
            rel, kept = kept["path"], rows[at]
        skipped.append(Skipped(rel, f"duplicate of {kept['path']} ({_SAME})"))
    skipped = _failed_once(skipped, seen, rows)
    if not rows:
        _refuse_regression_references(root)
        reasons = listing([f"{s.path}: {s.reason}" for s in skipped], sep="; ")
        raise TacbenchError(
            f"none of the {len(skipped)} run directories under {root} could be used ({reasons}"
            "); fix or remove them"
        )
    runs = pd.DataFrame(rows, columns=list(RUN_COLUMNS))
    # a run planned shorter than others of its method is partial beside them: included, and
    # counted in the partial column, as a run stopped early is (the page says so)
    planned = runs.groupby(["algo", "env", "variant"])["total_steps"].transform("max")
    runs["partial"] = runs["partial"] | (runs["total_steps"] < planned)
    return RunSet(_tidy(runs, series), runs, tuple(skipped), metric, root)


def _failed_once(
    skipped: list[Skipped], seen: dict[tuple[str, str, str, int], int], rows: list[dict[str, Any]]
) -> list[Skipped]:
    """``skipped`` with each failed run counted once per identity: one whose identity also has
    a usable run (a rerun that did not fail), or a failed one before it in path order, is a
    duplicate, its failure named but not counted against its method."""
    result: list[Skipped] = []
    failed: dict[tuple[str, str, str, int], str] = {}
    for skip in skipped:
        if skip.identity is None:
            result.append(skip)
            continue
        key = tuple(skip.identity[k] for k in ("algo", "env", "variant", "seed"))
        kept = rows[seen[key]]["path"] if key in seen else failed.get(key)
        if kept is None:
            failed[key] = skip.path
            result.append(skip)
        else:
            result.append(Skipped(skip.path, f"duplicate of {kept} ({_SAME}); {skip.reason}"))
    return result


def _further(row: dict[str, Any], than: dict[str, Any]) -> bool:
    """Whether a run trained further than another of the same identity: complete against
    partial, else more steps reached."""
    return (not row["partial"], row["step_reached"]) > (not than["partial"], than["step_reached"])


def _tidy(runs: pd.DataFrame, series: list[tuple[np.ndarray, ...]]) -> pd.DataFrame:
    counts = np.array([len(s[0]) for s in series])
    index = np.repeat(runs.index.to_numpy(), counts)
    data = runs.loc[index, ["run", "algo", "env", "variant", "q", "alpha", "seed"]]
    data = data.reset_index(drop=True)
    data["step"] = np.concatenate([s[0] for s in series])
    data["return"] = np.concatenate([s[1] for s in series])
    data["wall_s"] = np.concatenate([s[2] for s in series])
    return data
