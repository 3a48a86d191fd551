"""What each sweep that trained a results folder's runs took, and what the dry run prices its
command at on this CPU class: the test of the price (docs/sweep.md, "The price and the bill").

A sweep records what it took in its summary's ``bill`` (CPU class, workers, wall time), which
stands for the sweep when that sweep created every run (a sweep that resumed runs another had
started billed only its part). Otherwise, and for runs trained before sweeps kept a bill, the
runs' records give it: each run's command, when it was created (config.json) and when it last
wrote its status (status.json). A sweep's wall time is then from its first run's creation to its
last run's status, a pause included, and its CPU class is not recorded (docs/results.md names
it in words).

A sweep with a run that did not reach its budget (failed, interrupted or still running) is not
compared with its price: the price trains every run to its budget.

The runs' own CPU seconds (``eval.csv``'s ``cpu_s`` at their last evaluation, each run's share
of its process's) add up to the core-hours the sweep spent, where every run records them: other
work on the machine stretches them much less than the wall time, so they test the price's rates
also for a sweep that shared the machine.

Repricing a command plans it into an empty folder, so that runs already trained do not price
it, and prices that plan as the dry run does (:func:`tacbench.sweep.dry_run.price`), with the
calibrations stored for this class.
"""

from __future__ import annotations

import csv
import datetime
import io
import tempfile
from collections import Counter, defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tacbench import runs
from tacbench.errors import TacbenchError
from tacbench.runs.clock import members_sharing
from tacbench.sweep import driver, dry_run
from tacbench.sweep.options import Options
from tacbench.sweep.plan import SweepPlan
from tacbench.sweep.presets import Preset

BILL = "bill"
RUN_RECORDS = "run records"
TOLERANCE = 0.25  # the price within 25 % of the wall time (the speed issue's target)
CLOCK_SLACK = datetime.timedelta(seconds=5)  # the bill's start is the summary's end less its wall
ADVICE = "restore it from the study's copy, or name folders without it"


@dataclass(frozen=True)
class Took:
    """What one sweep took: its command, its runs, its wall time, the CPU class it ran on
    (None: not recorded) and where the figures come from (:data:`BILL` or :data:`RUN_RECORDS`)."""

    command: str
    keys: frozenset[str]  # the runs' directories, ``runs/<algo>/<env>/<variant>/seed<k>``
    wall_s: float
    cpu_class: str | None
    source: str
    priced_at_start_s: float | None = None  # a bill's: the dry run's price when it started
    workers: int | None = None  # a bill's: the workers it ran on
    unfinished: Mapping[str, int] = field(default_factory=dict)  # state -> runs, if not complete
    load_average: float | None = None  # a local sweep's bill: the machine's mean load meanwhile
    cores: int | None = None  # and its cores
    cpu_s: float | None = None  # the runs' CPU seconds (eval.csv); None if one does not record it

    @property
    def comparable(self) -> bool:
        """Whether the price is a test of its wall time: every run trained to its budget."""
        return not self.unfinished

    @property
    def runs(self) -> int:
        """How many of the sweep's runs lie under the results folder."""
        return len(self.keys)


def sweeps(*folders: Path) -> list[Took]:
    """Every sweep that trained runs under ``folders``, in the order they started, each once
    with all of its runs found there (a study may keep a copy of part of another's sweep: a run
    found twice counts once). Runs of ``tacbench run`` commands are left out."""
    created: dict[str, list[datetime.datetime]] = defaultdict(list)
    updated: dict[str, list[datetime.datetime]] = defaultdict(list)
    keys: dict[str, set[str]] = defaultdict(set)
    states: dict[str, dict[str, str]] = defaultdict(dict)  # by run key, as the CPU seconds
    cpu: dict[str, dict[str, float | None]] = defaultdict(dict)
    named = dict.fromkeys(folder.resolve() for folder in folders)
    folders = tuple(f for f in named if not any(p in named for p in f.parents))  # each read once
    config_paths = sorted(path for folder in folders for path in folder.rglob("config.json"))
    for config_path in config_paths:
        status_path = config_path.with_name("status.json")
        if not status_path.exists():
            continue
        config = runs.read_json(config_path, ADVICE)
        command = config.get("command", "")
        if not isinstance(command, str) or not command.startswith("tacbench sweep "):
            continue
        created[command].append(_time(config, "created", config_path))
        key = _key(config_path.parent)
        keys[command].add(key)
        status = runs.read_json(status_path, ADVICE)
        seconds = _cpu_seconds(config_path.with_name("eval.csv"), status)
        cpu[command][key] = None if seconds is None else seconds / members_sharing(config)
        updated[command].append(_time(status, "updated", status_path))
        states[command][key] = str(status.get("state"))
    bills = {command: bill for folder in folders for command, bill in _bills(folder).items()}
    took = []
    for command in sorted(created, key=lambda c: min(created[c])):
        bill, found = bills.get(command), frozenset(keys[command])
        left = dict(sorted(Counter(s for s in states[command].values() if s != "complete").items()))
        recorded = [s for s in cpu[command].values() if s is not None]
        cpu_s = sum(recorded) if len(recorded) == len(cpu[command]) else None
        if bill is not None and _created_every_run(bill, min(created[command])):
            took.append(
                Took(
                    command,
                    found,
                    bill["wall_s"],
                    bill["cpu_class"],
                    BILL,
                    bill["priced_wall_s"],
                    bill["workers"],
                    left,
                    bill.get("load_average"),
                    bill.get("cores"),
                    cpu_s,
                )
            )
        else:  # no bill, or one of a sweep that resumed runs another had started
            wall = (max(updated[command]) - min(created[command])).total_seconds()
            took.append(Took(command, found, wall, None, RUN_RECORDS, unfinished=left, cpu_s=cpu_s))
    return took


def _cpu_seconds(eval_csv: Path, status: Mapping[str, Any]) -> float | None:
    """The run's CPU seconds at its last evaluation, or None: no eval.csv, no row, or a run
    begun before eval.csv logged ``cpu_s``. A file that cannot be read, ends in a torn line, or
    (of a complete run) ends before the step its ``status`` records is a TacbenchError: its last
    row would be an earlier step's CPU time."""
    if not eval_csv.exists():
        return None
    try:
        text = eval_csv.read_text()
        rows = list(csv.DictReader(io.StringIO(text, newline="")))
        if text and not text.endswith("\n"):
            raise ValueError("its last line is torn")
        reached = status.get("step") if status.get("state") == "complete" else None
        if rows and isinstance(reached, int) and int(rows[-1]["step"]) != reached:
            raise ValueError(
                f"it ends at step {rows[-1]['step']}, where the complete run reached {reached}"
            )
        return float(rows[-1]["cpu_s"]) if rows and rows[-1].get("cpu_s") else None
    except (OSError, UnicodeDecodeError, csv.Error, ValueError, TypeError, KeyError) as err:
        raise TacbenchError(f"{eval_csv} cannot be read ({err}); {ADVICE}.") from None


def _time(record: Mapping[str, Any], name: str, path: Path) -> datetime.datetime:
    """The ISO 8601 time ``record[name]`` read from ``path``; a TacbenchError if it is not one."""
    value = record.get(name)
    try:
        time = datetime.datetime.fromisoformat(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise TacbenchError(
            f"{path}: {name!r} is {value!r}, not an ISO 8601 time; {ADVICE}."
        ) from None
    if time.tzinfo is None:  # compared with the other records' times, which have one
        raise TacbenchError(
            f"{path}: {name!r} is {value!r}, a time without its UTC offset; {ADVICE}."
        )
    return time


def _created_every_run(bill: dict[str, Any], first_created: datetime.datetime) -> bool:
    """Whether the sweep of ``bill`` started before its first run was created: a sweep that
    resumed runs (after a stop) billed only its own part."""
    started = datetime.datetime.fromisoformat(bill["finished"]) - datetime.timedelta(
        seconds=bill["wall_s"]
    )
    return bill["priced_wall_s"] > 0 and first_created >= started - CLOCK_SLACK


def _not_a(value: Any, kind: type | tuple[type, ...]) -> bool:
    return isinstance(value, bool) or not isinstance(value, kind)


def _key(directory: Path) -> str:
    """A run directory's key in a sweep's plan: its path from the last ``runs`` folder on."""
    parts = directory.parts
    if "runs" not in parts:
        return directory.as_posix()
    start = len(parts) - 1 - parts[::-1].index("runs")
    return "/".join(parts[start:])


def _bills(results: Path) -> dict[str, dict[str, Any]]:
    """The bills of the whole sweeps whose summaries lie under ``results`` (a study keeps a
    sweep's summary.json under a name of its own), by command."""
    found = {}
    for path in sorted(results.rglob("*summary.json")):
        record = runs.read_json(path, ADVICE)
        bill = record.get(BILL)
        if not bill or record.get("interrupted"):
            continue
        number = (int, float)
        kinds: dict[str, type | tuple[type, ...]] = {
            "wall_s": number,
            "cpu_class": str,
            "priced_wall_s": number,
            "workers": int,
        }
        optional: dict[str, type | tuple[type, ...]] = {"load_average": number, "cores": int}
        if (
            not isinstance(bill, dict)
            or any(_not_a(bill.get(f), kind) for f, kind in kinds.items())
            or any(f in bill and _not_a(bill[f], kind) for f, kind in optional.items())
            or bill["workers"] < 1
        ):
            raise TacbenchError(
                f"{path}: its bill lacks one of {list(kinds)} or holds one of another type "
                f"(seconds, load and at least one worker as numbers, the class as text); "
                f"{ADVICE}."
            )
        if not isinstance(record.get("command"), str):
            raise TacbenchError(f"{path} records no sweep command; {ADVICE}.")
        _time(record, "finished", path)  # checked: compared with the runs' times
        found[record["command"]] = {**bill, "finished": record["finished"]}
    return found


@dataclass(frozen=True)
class Repriced:
    """The dry run's price of a sweep's whole plan on this class, and whether every group of
    its runs was priced from a calibration of this class (otherwise from the defaults)."""

    wall_s: float
    core_hours: float
    calibrated: bool
    workers: int
    runs: int


def fresh_plan(grid: Preset, options: Options) -> SweepPlan:
    """``grid``'s plan with ``options`` as it stood before the first run trained: planned into an
    empty folder, gone when this returns (pricing the plan finds no runs there, as in the empty
    folder)."""
    with tempfile.TemporaryDirectory(prefix="tacbench-reprice-") as empty:
        return driver.load_plan(grid, Path(empty), options, save=False)[0]


def reprice(work: SweepPlan, options: Options) -> Repriced:
    """The price of a :func:`fresh_plan` on ``options``' workers, as the dry run gives it before
    the first run trains, from this class's calibrations (``--calibrate`` measures the plan's
    units: :func:`tacbench.sweep.calibration.unit_configs`)."""
    workers = options.worker_count()
    price = dry_run.price(work, workers)
    return Repriced(
        price.wall_seconds,
        price.core_seconds / 3600,
        all(g.source == dry_run.CALIBRATED for g in price.groups),
        workers,
        len(work.runs),
    )


def not_comparable(took: Took, work: SweepPlan) -> str:
    """Why what ``took`` took cannot test the price of ``work`` (its command's
    :func:`fresh_plan`), or "" where it can."""
    named = len(took.keys & {p.run.key for p in work.runs})
    if named != took.runs:
        return "the plan differs from the runs"
    if named < len(work.runs) and took.source != BILL:
        return (
            "only part of the sweep lies here, and its runs' records span whatever else the "
            "sweep trained meanwhile"
        )
    if not took.comparable:
        return "a run that stopped before its budget did not train what the price trains"
    return ""


def within(took_s: float, priced_s: float, tolerance: float = TOLERANCE) -> bool:
    """Whether the price is within ``tolerance`` of the wall time it took."""
    return abs(priced_s - took_s) <= tolerance * took_s
