"""What a unit of runs costs on this CPU class, measured by a short training of the unit itself
(``tacbench sweep --dry-run --calibrate``; :mod:`tacbench.sweep.unit_timing` says how), stored
per class, and priced.

A run of T steps that updates from step L and evaluates E episodes every V steps is priced at
``L x random + (T - L) x learn + (T / V) x E x D x eval_step`` per member. D, an evaluation
episode's steps, is halfway between a random policy's episode R and the task's episode limit H,
``(R + H) / 2`` (:meth:`~tacbench.sweep.unit_timing.Calibration.evaluation_episode`): H for
tasks whose episodes do not end early; for those that do, a trained policy's episodes usually
lie between the two, and then the halfway point is off by at most half the difference.
Priced at H, a TAC grid of nine Hopper runs at 100,000 steps (episodes of 135 steps on average)
cost 1.15-1.75x its CPU time (docs/notes/performance-history.md). A TAC run that updates during
warm-up (``--warmup-updates on``, the authors' code) starts at its first episode end, priced at
H. The compilation of the first update (seconds; the measurement's window starts after it) and
the checkpoints are left out.

Each unit is measured :data:`ROUNDS` times, the units in turn, and the median of each time is
kept: the project's virtual machines change speed by 1.3-1.6x over minutes, and against two
sweeps' own CPU time the medians of three rounds spread 1.35x where single measurements spread
1.5x (docs/notes/performance-history.md, "A host's speed from minute to minute").

A stop signal (Ctrl-C, SIGTERM, SIGHUP) during a measurement stops the calibration
(:class:`~tacbench.sweep.unit_timing.Interrupted`): the units measured before it are stored, and
the command exits with the signal's status.

Calibrations are kept per CPU class (:func:`tacbench.hardware.cpu_class`) in
``$TACBENCH_CALIBRATION`` or ``~/.cache/tacbench/calibration/<class>.json``, keyed by what
decides a unit's cost (:func:`unit_key`) and by :data:`~tacbench.sweep.unit_timing.METHOD`, so
that a calibration measured another way is measured again.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from tacbench import envs, runs
from tacbench.errors import TacbenchError
from tacbench.hardware import cpu_class
from tacbench.members import resolve_compile
from tacbench.sweep.unit_timing import MEMBERS_MEASURED, METHOD, Calibration, Interrupted, measure

ROUNDS = 3  # measurements of each unit, the units in turn, whose median is kept (module doc)
# config fields that do not change what a step costs (the budget, the evaluation's schedule,
# priced separately, and the member's identity)
_FREE_FIELDS = (
    "seed",
    "q",
    "alpha",
    "total_steps",
    "eval_every",
    "eval_episodes",
    "checkpoint_every",
    "log_every",
    "tensorboard",
    "variant",
)


def store_path(cpu: str | None = None) -> Path:
    """Where this class's calibrations are kept."""
    root = os.environ.get("TACBENCH_CALIBRATION")
    folder = Path(root) if root else Path.home() / ".cache" / "tacbench" / "calibration"
    return folder / f"{cpu or cpu_class()}.json"


def load(cpu: str | None = None) -> dict[str, Calibration]:
    """This class's calibrations by :func:`unit_key` (none yet: empty)."""
    path = store_path(cpu)
    if not path.exists():
        return {}
    try:
        units = json.loads(path.read_text())["units"]
        return {key: Calibration(**value) for key, value in units.items()}
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError):
        raise TacbenchError(
            f"{path} is not a readable calibration store; delete it (or point "
            "TACBENCH_CALIBRATION elsewhere), then calibrate again with tacbench sweep ... "
            "--dry-run --calibrate."
        ) from None


def save(calibrations: dict[str, Calibration], cpu: str | None = None) -> Path:
    """Write this class's calibrations (atomically), merged with those already stored."""
    path = store_path(cpu)
    merged = {**load(cpu), **calibrations}
    record = {
        "cpu_class": cpu or cpu_class(),
        "units": {key: dataclasses.asdict(c) for key, c in sorted(merged.items())},
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    runs.atomic_write_json(path, record)
    return path


def unit_key(configs: Sequence[Any]) -> str:
    """What decides a unit's cost per member-step: its algorithm, task, every setting but the
    member's identity, the budget and the evaluation schedule, and its members (up to
    :data:`MEMBERS_MEASURED`). ``--compile auto`` counts as what it resolves to here."""
    first = configs[0]
    data = (resolve_compile(first) if first.algo == "tac" else first).to_dict()
    shared = {k: v for k, v in data.items() if k not in _FREE_FIELDS}
    members = min(len(configs), MEMBERS_MEASURED)
    settings = json.dumps(shared, sort_keys=True)
    return f"m{METHOD} {data['algo']} {data['env']} K={members} {settings}"


def run_pricing(config: Any) -> tuple[int, int, int, int]:
    """(the step its updates start, evaluation interval, evaluation episodes, episode limit) of
    a run. Updates during warm-up start at the first episode end, whatever learning_starts,
    priced at the episode limit."""
    limit = envs.env_info(config.env).max_episode_steps
    warmup = config.algo == "tac" and config.warmup_updates == "on"
    starts = limit if warmup else int(config.learning_starts)
    return starts, int(config.eval_every), int(config.eval_episodes), limit


def calibrate(
    units: Sequence[Sequence[Any]],
    report: Callable[[str], None] = print,
    *,
    again: bool = False,
    rounds: int = ROUNDS,
) -> dict[str, Calibration]:
    """Measure every unit (a sequence of its configs) whose key this class has not calibrated
    (``again``: every unit, replacing what was stored: the same class on another host, or on a
    busier day, can run at another speed) ``rounds`` times, the units in turn, store each unit's
    median (:func:`median`) and return all of this class's calibrations. A unit that cannot be
    measured (every member failed before the timed window) is reported and measured no more, a
    calibration stored before it kept if no round measured it; the others are stored."""
    known = load()
    todo: dict[str, Sequence[Any]] = {}
    for configs in units:
        key = unit_key(configs)
        if (again or key not in known) and key not in todo:
            todo[key] = configs
    if todo:  # before minutes of measuring whose results would have nowhere to go
        runs.check_writable(store_path().parent, "TACBENCH_CALIBRATION")
    measured: dict[str, list[Calibration]] = {key: [] for key in todo}
    failed: set[str] = set()
    for round_, (index, (key, configs)) in itertools.product(
        range(1, rounds + 1), enumerate(todo.items(), start=1)
    ):
        if key in failed:
            continue
        c = configs[0]
        report(
            f"calibrating {index}/{len(todo)}{f', round {round_}/{rounds}' if rounds > 1 else ''}"
            f": {c.algo} {c.env}, {min(len(configs), MEMBERS_MEASURED)} member(s) ..."
        )
        start = time.perf_counter()
        try:
            measured[key].append(measure(configs))
        except TacbenchError as err:  # the other units' measurements are still stored
            failed.add(key)
            if measured[key]:
                report(f"  not measured again: {err}; the rounds measured before are kept")
                continue
            kept = f"; the calibration of {known[key].measured} is kept" if key in known else ""
            report(f"  not calibrated: {err}{kept}")
            continue
        except KeyboardInterrupt:  # a stop signal, or a second one: keep what was measured
            new = _medians(measured)
            kept = f"the units measured before it are stored in {save(new)}" if new else ""
            report(f"  calibration interrupted; {kept or 'nothing was stored'}")
            raise Interrupted from None
        report(
            f"  {measured[key][-1].learn * 1e3:.2f} ms per member-step learning, "
            f"{measured[key][-1].random * 1e3:.2f} before ({time.perf_counter() - start:.0f} s)"
        )
    new = _medians(measured)
    for key, found in measured.items():
        if len(found) > 1:
            c, learn = todo[key][0], sorted(f.learn for f in found)
            report(
                f"{c.algo} {c.env}: {', '.join(f'{v * 1e3:.2f}' for v in learn)} ms per "
                f"member-step learning in {len(found)} rounds ({learn[-1] / learn[0]:.2f}x apart)"
                f"; stored the median, {new[key].learn * 1e3:.2f}"
            )
    if new:
        report(f"wrote {save(new)}")
    return {**known, **new}


def median(rounds: Sequence[Calibration]) -> Calibration:
    """One calibration from a unit's ``rounds``: the median of each time, the last date."""
    return dataclasses.replace(
        rounds[-1],
        random=statistics.median(c.random for c in rounds),
        learn=statistics.median(c.learn for c in rounds),
        eval_step=statistics.median(c.eval_step for c in rounds),
        rounds=len(rounds),
    )


def _medians(measured: dict[str, list[Calibration]]) -> dict[str, Calibration]:
    """Each measured unit's :func:`median` (a unit without a round left out)."""
    return {unit: median(found) for unit, found in measured.items() if found}


def unit_configs(plan: Any) -> list[list[Any]]:
    """The configs of each unit of a sweep plan."""
    return [[run.config for run in unit.runs] for unit in plan.units]


def price(plan: Any, calibrations: dict[str, Calibration]) -> dict[tuple[str, str], float]:
    """CPU seconds left per (cost algorithm, task) of ``plan``, for the groups whose every unit
    to train is calibrated (:func:`tacbench.sweep.cost.cost_algo` names the algorithm)."""
    from tacbench.sweep.cost import cost_algo

    planned = {p.run.key: p for p in plan.runs}
    seconds: dict[tuple[str, str], float] = {}
    missing: set[tuple[str, str]] = set()
    for unit in plan.units:
        configs = [run.config for run in unit.runs]
        first = configs[0]
        group = (cost_algo(first.algo, getattr(first, "profile", None)), first.env)
        found = calibrations.get(unit_key(configs))
        if found is None:
            missing.add(group)
            continue
        pricing = run_pricing(first)  # the unit's runs differ only in seed, q and alpha
        for run in unit.runs:
            left = planned[run.key].steps_left
            seconds[group] = seconds.get(group, 0.0) + found.seconds(
                run.total_steps, *pricing, steps_left=left
            )
    return {group: s for group, s in seconds.items() if group not in missing}
