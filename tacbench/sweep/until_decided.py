"""``tacbench sweep --until-decided``: a grid trained in interims until AdaStop decides it.

Each interim trains ``n`` more seeds of every method still in an undecided comparison of a task
(the preset's seeds first, in order, then further ones at the same spacing), through the same
driver, executors and member grouping as any sweep (:func:`tacbench.sweep.driver.run_sweep`);
then :class:`tacbench.sequential.SequentialComparison` decides each comparison of the task from
the runs' final returns, the family-wise error rate ``alpha`` shared by the task's comparisons,
for at most ``K`` interims (docs/sequential.md).

What it decided is kept in ``<out>/sweep/sequential.json``, written atomically after each
interim: the design, the methods and comparisons of each task, and per interim the seeds and
final returns of every method and each comparison's state. The comparator is seeded, so a sweep
run again rebuilds it from the recorded scores (and checks that it reaches the recorded
decisions), then continues with the interim that was cut off; its runs resume like any sweep's.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path, PurePosixPath
from typing import IO, Any, Protocol

from tacbench import runs
from tacbench.errors import TacbenchError
from tacbench.report.load import final_return
from tacbench.report.tables import DEFAULT_LAST
from tacbench.sequential import (
    Interim,
    Pair,
    SequentialComparison,
    SequentialResult,
    decision_table,
    decision_text,
)
from tacbench.sequential_record import RECORD_FILE, read_record
from tacbench.sweep import driver, dry_run, preflight, state, summary
from tacbench.sweep.options import Options
from tacbench.sweep.presets import Preset
from tacbench.sweep.sequential_design import (
    Design,
    Method,
    check_decidable,
    check_evaluated,
    earliest_decision,
    methods_of,
    same_design,
    seed_order,
    with_controls,
)


class Train(Protocol):
    """What trains one interim's grid: :func:`driver.run_sweep` (tests pass their own)."""

    def __call__(
        self,
        preset: Preset,
        out: Path,
        options: Options,
        stream: IO[str] | None,
        /,
        *,
        told: Collection[str],
    ) -> driver.SweepResult: ...


class Record:
    """``<out>/sweep/sequential.json``: the design, and each task's interims with their seeds,
    final returns and decisions."""

    def __init__(self, out: Path, design: Design, tasks: dict[str, list[Method]]) -> None:
        self.path = state.sweep_dir(out) / RECORD_FILE
        self.design = design
        self.methods = {env: [m.label for m in methods] for env, methods in tasks.items()}
        # where each method's runs are: their settings, which the labels alone do not name
        self.folders = {
            env: {m.label: str(PurePosixPath(m.runs(1)[0].key).parent) for m in methods}
            for env, methods in tasks.items()
        }
        self.interims: dict[str, list[dict[str, Any]]] = {env: [] for env in tasks}
        if not self.path.exists():
            return
        stored = read_record(self.path)
        same = same_design(stored.get("design"), design, tasks)
        if stored.get("methods") != self.methods or not same:
            raise TacbenchError(
                f"{self.path} records another sequential design or other methods "
                f"({stored.get('design')}, {stored.get('methods')}); rerun with the flags it "
                "records, or use another --out."
            )
        if stored.get("folders", self.folders) != self.folders:  # a record without: not checked
            raise TacbenchError(
                f"{self.path} records interims of runs with other settings "
                f"({stored.get('folders')}, where this command trains {self.folders}); its "
                "scores would be mixed with these runs'. Rerun with the settings it records, or "
                "use another --out."
            )
        self.interims = stored["interims"]

    def add(
        self,
        env: str,
        interim: Interim,
        seeds: dict[str, list[int]],
        scores: dict[str, list[float]],
    ) -> None:
        """Record one interim of ``env`` and save."""
        self.interims[env].append(
            {
                "number": interim.number,
                "seeds": {m: seeds[m][: interim.runs[m]] for m in seeds},
                "scores": {m: scores[m][: interim.runs[m]] for m in scores},
                "decisions": _decision_list(interim.decisions),
            }
        )
        self.save()

    def save(self) -> None:
        """Write the file atomically."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = {
            "design": asdict(self.design),
            "methods": self.methods,
            "folders": self.folders,
            "interims": self.interims,
        }
        runs.atomic_write_json(self.path, data)


def comparisons(record: Record, controls: dict[str, str | None]) -> dict[str, SequentialComparison]:
    """Each task's comparator rebuilt from the recorded interims; TacbenchError if it does not
    reach the recorded decisions (the file was edited, or the package changed)."""
    d = record.design
    rebuilt = {}
    for env, labels in record.methods.items():
        comparison = SequentialComparison(labels, d.n, d.K, d.alpha, controls[env], d.B, d.seed)
        for recorded in record.interims[env]:
            interim = comparison.add(recorded["scores"])
            decided = _decision_list(interim.decisions)
            if decided != recorded["decisions"]:
                raise TacbenchError(
                    f"{record.path}: interim {recorded['number']} of {env} replays to "
                    f"{decided}, not the recorded {recorded['decisions']}; move the file away "
                    "to decide again from the runs."
                )
        rebuilt[env] = comparison
    return rebuilt


@dataclass(frozen=True)
class Outcome:
    """How a sequential sweep ended: each task's result, the last sweep's, and its text."""

    results: dict[str, SequentialResult]
    sweep: driver.SweepResult | None
    text: str

    @property
    def exit_code(self) -> int:
        """The last interim sweep's (interrupted, a run given up on), else 0."""
        return self.sweep.exit_code if self.sweep is not None else 0


def run_until_decided(
    preset: Preset,
    out: Path,
    options: Options,
    design: Design,
    stream: IO[str] | None = None,
    train: Train = driver.run_sweep,
) -> Outcome:
    """Train ``preset`` into ``out`` interim by interim until every task's comparisons are
    decided or ``design.K`` interims are done (the module doc). ``train`` trains one interim's
    grid (a sweep; tests pass their own)."""
    tasks = methods_of(preset)
    design, controls = with_controls(design, preset, tasks)
    check_evaluated(tasks)
    record = Record(out, design, tasks)
    if not any(record.interims.values()):
        check_decidable(design, tasks)
    compared = comparisons(record, controls)
    runs.ensure_writable(out)
    last: driver.SweepResult | None = None
    told: set[str] = set()  # the plan's warnings, printed at this command's first interim
    while needed := {env: c.runs_needed() for env, c in compared.items() if not c.finished}:
        chosen = [(m, needed[env][m.label]) for env in needed for m in tasks[env]]
        k = max(len(compared[env].interims) for env in needed) + 1
        _echo(stream, f"interim {k} of {design.K}: {_plan_line(needed, compared)}")
        last = train(_grid(preset, chosen), out, options, stream, told=frozenset(told))
        told.update(last.warnings)
        if last.exit_code:
            counts = last.summary["counts"]
            given_up = 0 if last.interrupted else counts["given_up"]
            why = (
                "stopped; rerun the same command to continue it"
                if last.interrupted
                else f"gave up on {given_up} run{'s' if given_up != 1 else ''} after too many "
                "failures; see why above, then rerun it with a larger --max-retries to continue"
                if given_up
                else "could not resume every run from its files; see why above, fix them, then "
                "rerun the same command to continue it"
                if counts["cannot_resume"]
                else "could not train every run; rerun the same command to continue it"
            )
            text = f"{last.text}\ninterim {k} {why}."
            return Outcome({e: c.result() for e, c in compared.items()}, last, text)
        for env in needed:
            trained = {m.label: m.runs(needed[env][m.label]) for m in tasks[env]}
            scores = {
                label: [final_return(out / r.key, DEFAULT_LAST) for r in method_runs]
                for label, method_runs in trained.items()
            }
            seeds = {label: [r.config.seed for r in rs] for label, rs in trained.items()}
            interim = compared[env].add(scores)
            record.add(env, interim, seeds, scores)
            _echo(stream, f"{env}, interim {k}: " + _decisions(interim.decisions))
    results = {env: c.result() for env, c in compared.items()}
    text = decision_text(results)
    spent = [(m, results[env].interims[-1].runs[m.label]) for env in tasks for m in tasks[env]]
    final, history = driver.load_plan(_grid(preset, spent), out, options, save=False)
    written = summary.summarize(final, history, command=options.command, interrupted=False)
    written["sequential"] = decision_table(results).to_dict("records")
    summary.write_summary(
        out, written, summary.summary_text(written, options.command) + "\n" + text
    )
    return Outcome(results, last, text)


def _grid(preset: Preset, chosen: Sequence[tuple[Method, int]]) -> Preset:
    """``preset`` holding exactly the first ``count`` runs of each chosen method."""
    return replace(preset, entries=tuple(m.first(count) for m, count in chosen if count))


def _decision_list(decisions: dict[Pair, str]) -> list[dict[str, str]]:
    return [{"method": a, "against": b, "decision": d} for (a, b), d in decisions.items()]


def _echo(stream: IO[str] | None, line: str) -> None:
    print(line, file=stream, flush=True)


def _plan_line(needed: dict[str, dict[str, int]], compared: dict[str, SequentialComparison]) -> str:
    parts = []
    for env, counts in needed.items():
        open_methods = sorted({m for pair in compared[env].open_pairs() for m in pair})
        parts.append(f"{env}: {', '.join(f'{m} to {counts[m]} runs' for m in open_methods)}")
    return "; ".join(parts)


def _decisions(decisions: dict[Pair, str]) -> str:
    return "; ".join(f"{a} vs {b}: {d}" for (a, b), d in decisions.items())


def describe_design(preset: Preset, out: Path, options: Options, design: Design) -> str:
    """The dry run: each task's methods and comparisons, what the record holds (its decisions),
    the most runs and core-hours the design can still take (every open comparison to the last
    interim; a method no longer in one keeps the runs it has), the fixed design's runs, and the
    first interim at which a decision is possible at all. A design that can never decide is
    refused, as the sweep refuses it (:func:`check_decidable`)."""
    tasks = methods_of(preset)
    design, controls = with_controls(design, preset, tasks)
    check_evaluated(tasks)
    record = Record(out, design, tasks)
    if not any(record.interims.values()):
        check_decidable(design, tasks)
    compared = comparisons(record, controls)
    lines = [
        f"sequential design: interims of {design.n} runs per open method, at most "
        f"{design.K}; family-wise error rate {design.alpha:g} per task; control: "
        f"{design.control}"
    ]
    most: list[tuple[Method, int]] = []
    full = design.n * design.K
    for env, methods in tasks.items():
        control, comparison = controls[env], compared[env]
        paired = control is None
        first = earliest_decision(design, len(methods), paired)
        done = len(record.interims[env])
        lines.append(
            f"  {env}: {len(methods)} methods "
            f"({'every pair' if paired else f'each against {control}'}); "
            f"{done} interim{'s' if done != 1 else ''} recorded; earliest possible decision: "
            + (f"interim {first}" if first else "never (raise --interim-runs)")
        )
        if comparison.interims:
            lines.append(f"    decisions so far: {_decisions(comparison.interims[-1].decisions)}")
        given = comparison.interims[-1].runs if comparison.interims else {}
        still = set() if comparison.finished else {m for p in comparison.open_pairs() for m in p}
        most += [(m, full if m.label in still else given.get(m.label, 0)) for m in methods]
    fixed = full * sum(len(methods) for methods in tasks.values())
    work, _ = driver.load_plan(_grid(preset, most), out, options, save=False)
    preflight.check_sizes(work, options)
    lines.append(
        f"at most {len(work.runs)} runs (a fixed design of {design.n} x {design.K} seeds: "
        f"{fixed}); fewer as comparisons are decided. The most it can still cost:"
    )
    workers, source = options.worker_count(), options.workers_source()
    interims = [
        driver.load_plan(g, out, options, save=False)[0] for g in _interims(preset, most, design.n)
    ]
    lines.append(dry_run.describe_plan(work, workers, options.group, source, interims))
    return "\n".join(lines)


def _interims(preset: Preset, chosen: Sequence[tuple[Method, int]], n: int) -> list[Preset]:
    """The grids of :func:`_grid` ``(preset, chosen)`` trained interim by interim: the k-th
    holds each method's runs (k - 1) n + 1 to k n, in seed order."""
    grids = []
    for start in range(0, max((count for _, count in chosen), default=0), n):
        slices = [(m, seed_order(m.entry.seeds, count)[start : start + n]) for m, count in chosen]
        entries = tuple(replace(m.entry, seeds=seeds) for m, seeds in slices if seeds)
        grids.append(replace(preset, entries=entries))
    return grids
