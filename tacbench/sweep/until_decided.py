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

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import IO, Any

from tacbench import paper, runs
from tacbench.errors import TacbenchError
from tacbench.report.load import final_return
from tacbench.report.methods import BASELINE_NAMES, tac_label
from tacbench.report.tables import DEFAULT_LAST
from tacbench.sequential import (
    DEFAULT_ALPHA,
    DEFAULT_B,
    RECORD_FILE,
    Interim,
    Pair,
    SequentialComparison,
    SequentialResult,
    decision_table,
    decision_text,
    run_sequential,
)
from tacbench.sweep import driver, plan, state, summary
from tacbench.sweep.options import Options
from tacbench.sweep.presets import Entry, Preset

# the paper's seeds are 0, 10, ..., 90 (line 2054); further seeds continue that spacing
SEED_SPACING = 10
PAIRS = "pairs"  # --control pairs: every pair of methods
BEST_Q = "best-q"  # --control best-q: TAC at the paper's best q of each task
Train = Callable[[Preset, Path, Options, IO[str] | None], driver.SweepResult]


@dataclass(frozen=True)
class Design:
    """The sequential design: ``n`` runs per method per interim, at most ``K`` interims,
    family-wise error rate ``alpha`` per task, the ``control`` each method is compared with
    (a method label, ``best-q`` or ``pairs``), AdaStop's ``B`` permutations and its ``seed``."""

    n: int = 5  # two interims of five: at most the paper's ten seeds (line 2054)
    K: int = 2
    alpha: float = DEFAULT_ALPHA
    control: str = ""  # "": the preset's (default_control)
    B: int = DEFAULT_B
    seed: int = 0

    def __post_init__(self) -> None:
        if self.n < 1 or self.K < 1:
            raise TacbenchError(
                f"--interim-runs and --interims must be at least 1 (got {self.n}, {self.K})."
            )
        if not 0.0 < self.alpha < 1.0:
            raise TacbenchError(f"--fwer must lie between 0 and 1 (got {self.alpha!r}).")


@dataclass(frozen=True)
class Method:
    """One method of a task: a preset entry narrowed to the task (and to one q for TAC)."""

    label: str
    entry: Entry

    def first(self, count: int) -> Entry:
        """Its entry narrowed to its first ``count`` seeds (:func:`seed_order`)."""
        return replace(self.entry, seeds=seed_order(self.entry.seeds, count))

    def runs(self, count: int) -> list[plan.Run]:
        """Its first ``count`` runs, in seed order."""
        return plan.build_runs(Preset("", "", (self.first(count),)))


def seed_order(seeds: Sequence[int], count: int) -> tuple[int, ...]:
    """The first ``count`` seeds: ``seeds`` in order, then ``SEED_SPACING`` apart after the
    largest."""
    order = list(seeds[:count])
    while len(order) < count:
        order.append(max([*seeds, *order]) + SEED_SPACING)
    return tuple(order)


def default_control(preset: Preset) -> str:
    """TAC at the paper's best q for a grid that holds baselines (the comparison study), SAC
    (TAC q = 1, the paper's question: does a q other than 1 help?) for TAC alone, and every
    pair for baselines alone (no TAC to compare them with)."""
    algos = {e.algo for e in preset.entries}
    if "tac" not in algos:
        return PAIRS
    return BEST_Q if algos != {"tac"} else tac_label(1.0)


def methods_of(preset: Preset) -> dict[str, list[Method]]:
    """Each task's methods (by Gymnasium id), labelled as the report labels them: TAC by q
    (``SAC (TAC q=1)``, ``TAC q=1.5``), a baseline by name. A method listed twice (the
    comparison's TAC at a best q of 1 and its SAC) is kept once."""
    tasks: dict[str, list[Method]] = {}
    for entry in preset.entries:
        for task in entry.tasks:
            for q in entry.q_values(task) or (math.nan,):
                label = BASELINE_NAMES.get(entry.algo, entry.algo.upper())
                narrowed = replace(entry, tasks=(task,))
                if entry.algo == "tac":
                    label, narrowed = tac_label(q), replace(narrowed, q=(q,))
                methods = tasks.setdefault(entry.env_id(task), [])
                if label not in [m.label for m in methods]:
                    methods.append(Method(label, narrowed))
    return tasks


def control_of(design: Design, env: str, methods: Sequence[Method]) -> str | None:
    """The label of ``env``'s control (None: every pair), or TacbenchError naming the choices
    (also for a task with a single method: nothing to compare)."""
    labels = [m.label for m in methods]
    if len(labels) < 2:
        raise TacbenchError(
            f"--until-decided compares the methods of a task, and {env} has one ("
            f"{', '.join(labels)}); keep more of the preset's q values or algorithms."
        )
    wanted = design.control
    if wanted.lower() == PAIRS:
        return None
    if wanted.lower() == BEST_Q:
        facts = paper.TASK_FACTS[paper.task_name(env)]
        wanted = tac_label(facts.best_q)
    found = [label for label in labels if label.lower() == wanted.lower()]
    q = wanted.lower().removeprefix("q=")
    if q != wanted.lower() and q.replace(".", "", 1).isdigit():  # q=1.5: TAC q=1.5 (q=1: SAC)
        found = [label for label in labels if label == tac_label(float(q))]
    if not found:
        raise TacbenchError(
            f"--control {design.control}: {env} has no such method; choose one of "
            f"{', '.join(labels)}, {BEST_Q} or {PAIRS}."
        )
    return found[0]


@functools.cache
def earliest_decision(design: Design, methods: int, paired: bool) -> int | None:
    """The first interim at which the design can decide a comparison at all: when every run of
    one method beats every run of the other (None: never, whatever the runs give). Cached:
    tasks with as many methods share the answer, and AdaStop takes seconds to give it."""
    names = [f"m{i}" for i in range(methods)]
    scores = {m: [1e6 * i + j for j in range(design.n * design.K)] for i, m in enumerate(names)}
    control = None if paired else names[0]
    result = run_sequential(scores, design.n, design.K, design.alpha, control, design.B)
    decided = [result.decided_at(p) for p in result.comparisons]
    return min((d for d in decided if d is not None), default=None)


def check_decidable(design: Design, tasks: dict[str, list[Method]]) -> None:
    """Refuse a design that can never decide a comparison of some task, saying what can."""
    for env, methods in tasks.items():
        paired = design.control == PAIRS
        if earliest_decision(design, len(methods), paired) is not None:
            continue
        larger = next(
            (
                n
                for n in range(design.n + 1, 11)
                if earliest_decision(replace(design, n=n), len(methods), paired) is not None
            ),
            None,
        )
        hint = f"--interim-runs {larger} can" if larger else "raise --interim-runs or --fwer"
        raise TacbenchError(
            f"with --interim-runs {design.n}, --interims {design.K} and --fwer {design.alpha:g} "
            f"no comparison of the {len(methods)} methods on {env} can ever be decided, even if "
            f"every run of one method beats every run of another: too few runs for the "
            f"permutation test to reach its share of the error rate; {hint}."
        )


class Record:
    """``<out>/sweep/sequential.json``: the design, and each task's interims with their seeds,
    final returns and decisions."""

    def __init__(self, out: Path, design: Design, tasks: dict[str, list[Method]]) -> None:
        self.path = state.sweep_dir(out) / RECORD_FILE
        self.design = design
        self.methods = {env: [m.label for m in methods] for env, methods in tasks.items()}
        self.interims: dict[str, list[dict[str, Any]]] = {env: [] for env in tasks}
        if not self.path.exists():
            return
        stored = runs.read_json(self.path)
        same = _same_design(stored.get("design"), design, tasks)
        if stored.get("methods") != self.methods or not same:
            raise TacbenchError(
                f"{self.path} records another sequential design or other methods "
                f"({stored.get('design')}, {stored.get('methods')}); rerun with the flags it "
                "records, or use another --out."
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
        data = {"design": asdict(self.design), "methods": self.methods, "interims": self.interims}
        runs.atomic_write_json(self.path, data)


def _same_design(stored: Any, design: Design, tasks: dict[str, list[Method]]) -> bool:
    """Whether a recorded design is ``design``, its control compared as resolved on each task
    (``q=1`` is ``SAC (TAC q=1)``, ``BEST-Q`` is ``best-q``), not as spelled."""
    try:
        before = Design(**stored)
        resolved = [
            {env: control_of(d, env, methods) for env, methods in tasks.items()}
            for d in (before, design)
        ]
    except (TypeError, TacbenchError):  # not a design, or a control these tasks do not have
        return False
    return replace(before, control="") == replace(design, control="") and resolved[0] == resolved[1]


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
    design = replace(design, control=design.control or default_control(preset))
    tasks = methods_of(preset)
    controls = {env: control_of(design, env, methods) for env, methods in tasks.items()}
    record = Record(out, design, tasks)
    if not any(record.interims.values()):
        check_decidable(design, tasks)
    compared = comparisons(record, controls)
    runs.ensure_writable(out)
    last: driver.SweepResult | None = None
    while needed := {env: c.runs_needed() for env, c in compared.items() if not c.finished}:
        chosen = [(m, needed[env][m.label]) for env in needed for m in tasks[env]]
        k = max(len(compared[env].interims) for env in needed) + 1
        _echo(stream, f"interim {k} of {design.K}: {_plan_line(needed, compared)}")
        last = train(_grid(preset, chosen), out, options, stream)
        if last.exit_code:
            why = "stopped" if last.interrupted else "could not train every run"
            text = f"{last.text}\ninterim {k} {why}; rerun the same command to continue it."
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
    first interim at which a decision is possible at all."""
    design = replace(design, control=design.control or default_control(preset))
    tasks = methods_of(preset)
    controls = {env: control_of(design, env, methods) for env, methods in tasks.items()}
    record = Record(out, design, tasks)
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
    lines.append(
        f"at most {len(work.runs)} runs (a fixed design of {design.n} x {design.K} seeds: "
        f"{fixed}); fewer as comparisons are decided. The most it can still cost:"
    )
    workers, source = options.worker_count(), options.workers_source()
    lines.append(summary.describe_plan(work, workers, options.group, source))
    return "\n".join(lines)
