"""What ``--dry-run`` prints, and what every sweep prices at its start: the plan (counts by
state, the units with their members and memory, steps left) and its price on the sweep's
workers, from the runs under ``--out``, this CPU class's calibration or the defaults."""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from tacbench import envs, memory
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError, plural
from tacbench.hardware import cpu_class
from tacbench.members import repays_compilation
from tacbench.progress import duration
from tacbench.sweep import calibration, cost
from tacbench.sweep.plan import PlannedRun, SweepPlan
from tacbench.sweep.summary import counts, shown_state

CALIBRATED = "calibrated**"

GROUPING = {
    "task": "TAC runs of a task that differ only in q, alpha or seed train as members of one unit",
    "seeds": "TAC runs that differ only in seed train as members of one unit",
    "none": "one run per unit",
}


@dataclass(frozen=True)
class GroupPrice:
    """What the runs of one (algo, env) still cost: their steps left and core-seconds, and
    where the rate comes from (runs measured under --out, a calibration or the defaults)."""

    algo: str
    env: str
    runs: int
    states: Counter[str]
    steps: int
    seconds: float
    source: str


@dataclass(frozen=True)
class Price:
    """What a plan still costs: core-seconds in all and the wall time on its workers."""

    groups: tuple[GroupPrice, ...]
    core_seconds: float
    wall_seconds: float


def price(plan: SweepPlan, workers: int, *, training: bool = False) -> Price:
    """The plan's price on ``workers`` workers (:func:`wall_seconds`), group by group. A
    damaged calibration store stops a dry run; a sweep that is ``training`` warns (in the
    plan's warnings) and prices without it: a price is no reason not to train."""
    groups: dict[tuple[str, str], list[PlannedRun]] = defaultdict(list)
    for p in plan.runs:
        groups[_priced_as(p.run.config)].append(p)
    rates = cost.rates(
        plan.out, {pair: [p.run.config for p in group] for pair, group in groups.items()}
    )
    calibrated = calibration.price(plan, _calibrations(plan, training))
    priced = []
    for (algo, env), members in groups.items():
        steps = sum(p.steps_left for p in members if p.action in ("train", "retry"))
        rate = rates[(algo, env)]
        seconds, source = steps * rate.seconds_per_step, rate.source
        if rate.source == cost.DEFAULT_SOURCE and (algo, env) in calibrated:
            seconds, source = calibrated[(algo, env)], CALIBRATED
        states = Counter[str](shown_state(p) for p in members)
        priced.append(GroupPrice(algo, env, len(members), states, steps, seconds, source))
    per_step = {(g.algo, g.env): g.seconds / max(1, g.steps) for g in priced}
    return Price(
        tuple(priced), sum(g.seconds for g in priced), wall_seconds(plan, per_step, workers)
    )


def _calibrations(plan: SweepPlan, training: bool) -> dict[str, calibration.Calibration]:
    try:
        return calibration.load()
    except TacbenchError as err:
        if not training:
            raise
        plan.warnings.append(f"{err} This sweep trains all the same, priced without it.")
        return {}


def describe_plan(
    plan: SweepPlan,
    workers: int,
    group: str,
    workers_from: str = "",
    in_turn: Sequence[SweepPlan] = (),
) -> str:
    """The dry-run report: counts by state, the units with their members and memory, steps left
    and the cost estimate; where ``plan`` trains as the sweeps ``in_turn`` (the interims of
    ``--until-decided``), one after another, its wall time is the sum of theirs."""
    c = counts(plan)
    total = sum(p.run.total_steps for p in plan.runs)
    left = plan.steps_left()
    budgets = " or ".join(f"{b:,}" for b in sorted({p.run.total_steps for p in plan.runs}))
    lines = [
        f"preset {plan.preset.name}, before the command's options: {plan.preset.description}",
        *plan.warnings,
        f"{plural(c['runs'], 'run')}: {c['complete']} complete, {c['partial']} partial, "
        f"{c['failed']} failed ({c['to_retry']} to retry, {c['given_up']} given up after too "
        f"many failures), {c['new']} not started",
        f"{plural(len(plan.units), 'unit')} to train (one process or Ray task each; --group "
        f"{group}: {GROUPING[group]})",
        *_units(plan),
        f"environment steps left: {left:,} of {total:,} ({budgets} per run)",
        "",
        f"{'algo':<8} {'env':<15} {'runs':>5} {'done':>5} {'part':>5} {'fail':>5} {'new':>5} "
        f"{'steps left':>14} {'ms/step':>8}  throughput",
    ]
    priced = price(plan, workers)
    for g in priced.groups:
        lines.append(
            f"{g.algo:<8} {g.env:<15} {g.runs:>5} {g.states['complete']:>5} "
            f"{g.states['partial']:>5} {g.states['failed']:>5} {g.states['new']:>5} "
            f"{g.steps:>14,} {g.seconds / max(1, g.steps) * 1e3:>8.2f}  {g.source}"
        )
    sources = {g.source for g in priced.groups}
    wall = sum(price(p, workers).wall_seconds for p in in_turn) if in_turn else priced.wall_seconds
    lines += [
        "",
        f"cost estimate: {priced.core_seconds / 3600:,.1f} core-hours; with "
        f"{plural(workers, 'worker')}{f' ({workers_from})' if workers_from else ''} about "
        f"{duration(wall)} "
        "(one core per worker; each unit on one worker, started in plan order"
        + (f"; {plural(len(in_turn), 'interim')} one after another)" if in_turn else ")"),
    ]
    if CALIBRATED in sources:
        lines.append(
            f"** calibrated: measured on this CPU class ({cpu_class()}) by --calibrate, stored "
            f"in {calibration.store_path()}; evaluation episodes priced halfway between a "
            "random policy's and the task's limit (docs/sweep.md)."
        )
    if cost.DEFAULT_SOURCE in sources:
        lines.append(
            "* CPU time per step measured on tacbench's development machine, not here "
            "(tacbench/sweep/cost.py); runs of the plan's kind under --out with two evaluations "
            "replace it, and --dry-run --calibrate measures the units on this CPU class (a few "
            "minutes)."
        )
        lines += _without_a_default_of_its_own(priced)
        lines += _unlike_the_tac_default(plan, priced)
    if any(p.run.config.device != "cpu" for p in plan.runs):
        lines.append(
            "The runs train on a GPU (--gpus-per-run), and every figure above prices CPU cores: "
            "measure the GPU's speed with `tacbench bench --device cuda` (docs/performance.md)."
        )
    return "\n".join(lines)


def wall_seconds(plan: SweepPlan, per_step: dict[tuple[str, str], float], workers: int) -> float:
    """How long the units take on ``workers`` workers, each unit priced at its (algo, env)'s
    seconds per member-step times its members' steps left (:func:`cost.makespan`)."""
    left = {p.run.key: p.steps_left for p in plan.runs}
    seconds = []
    for unit in plan.units:
        rate = per_step[_priced_as(unit.runs[0].config)]
        seconds.append(rate * sum(left[run.key] for run in unit.runs))
    return cost.makespan(seconds, workers)


def _priced_as(config: Any) -> tuple[str, str]:
    """The (algo, env) whose rate prices a run: TAC's reference-code profiles have their own."""
    return cost.cost_algo(config.algo, getattr(config, "profile", None)), config.env


def _without_a_default_of_its_own(priced: Price) -> list[str]:
    """A line for each (algo, env) priced at other pairs' defaults (:func:`cost.default_stand_ins`):
    a task's own cost can be far from them (the paper profile's TAC on Humanoid costs 10x
    HalfCheetah's)."""
    lines = []
    for g in sorted(priced.groups, key=lambda g: (g.algo, g.env)):
        stand_ins = cost.default_stand_ins(g.algo, g.env)
        if g.source != cost.DEFAULT_SOURCE or not stand_ins:
            continue
        whose = (
            f"{'' if len(stand_ins) == 1 else 'the mean of '}{g.algo}'s on "
            + ", ".join(env for _, env in stand_ins)
            if all(algo == g.algo for algo, _ in stand_ins)
            else "the mean of every algorithm's defaults"
        )
        lines.append(
            f"  {g.algo} {g.env}: no default of its own, priced at {whose}; "
            "--calibrate measures it."
        )
    return lines


def _unlike_the_tac_default(plan: SweepPlan, priced: Price) -> list[str]:
    """A line for each TAC task whose units the default prices but which differ from the units
    it was measured in (:func:`cost.default_tac_basis`). Smaller units and uncompiled ones cost
    more per member-step (AMD EPYC AVX2 class: the smoke preset's one eager Hopper member 4.1 ms
    a step when calibrated, 7.5x the default; one compiled HalfCheetah member 1.9 ms in tacbench
    bench, 3x), wider networks more, narrower ones less. Not the reference profile's unit size:
    its (400, 300) products take most of a step, and batching members hardly speeds them (one
    compiled member 1.1-1.2x five's member-step in tacbench bench; uncompiled 1.75x)."""
    defaulted = {
        (g.algo, g.env)
        for g in priced.groups
        if g.algo in ("tac", cost.REFERENCE_TAC) and g.source == cost.DEFAULT_SOURCE
    }
    lines = []
    for algo, env in sorted(defaulted):
        units = [
            (len(u.runs), config)
            for u in plan.units
            if isinstance(config := u.runs[0].config, RunConfig)
            and _priced_as(config) == (algo, env)
        ]
        if not units:
            continue
        basis = cost.default_tac_basis(algo, env)
        smallest = min(size for size, _ in units)
        fewer = algo == "tac" and smallest < basis.members
        eager = any(_never_compiled(config) for _, config in units)
        obs_dim = envs.env_info(env).obs_dim  # the hidden layers' parameters: their products
        measured = memory.mlp_parameters((obs_dim, *basis.hidden_sizes))
        networks = sorted({config.hidden_sizes for _, config in units} - {basis.hidden_sizes})
        wider = any(memory.mlp_parameters((obs_dim, *h)) > measured for h in networks)
        narrower = any(memory.mlp_parameters((obs_dim, *h)) < measured for h in networks)
        costlier = fewer or eager or wider
        if not (costlier or narrower):
            continue
        held = [
            *([f"of {plural(smallest, 'member')}"] if fewer else []),
            *(["not compiled"] if eager else []),
            *(f"with hidden layers {h}" for h in networks),
        ]
        verdict = (
            "the estimate may be off either way"
            if costlier and narrower
            else f"each member-step costs {'more' if costlier else 'less'} than it says, so the "
            f"estimate is {'low' if costlier else 'high'}"
        )
        lines.append(
            f"  {algo} {env}: units {', '.join(held)}, where the default was measured in "
            f"compiled units of {basis.members} with hidden layers {basis.hidden_sizes}: "
            f"{verdict}; --calibrate measures these units."
        )
    return lines


def _never_compiled(config: RunConfig) -> bool:
    """Whether ``config`` trains uncompiled wherever it runs: ``--compile off``, or ``auto`` for
    too few learning steps (``auto`` for more is decided by the worker's C++ compiler, which the
    machine that plans cannot see)."""
    return config.compile == "off" or (config.compile == "auto" and not repays_compilation(config))


def _units(plan: SweepPlan) -> list[str]:
    """One line per (algo, env): its units, their members and the memory each needs."""
    by_task: dict[tuple[str, str], list[int]] = defaultdict(list)
    memory: dict[tuple[str, str], int] = {}
    for unit in plan.units:
        config = unit.runs[0].config
        key = (config.algo, config.env)
        by_task[key].append(len(unit.runs))
        if config.algo == "tac":
            info = envs.env_info(config.env)
            transitions = min(getattr(config, "buffer_size", 0), config.total_steps)
            per_member = cost.member_bytes(info.obs_dim, info.act_dim, transitions)
            memory[key] = max(memory.get(key, 0), per_member * len(unit.runs))
    lines = []
    for (algo, env), sizes in by_task.items():
        members = f"{min(sizes)}" if min(sizes) == max(sizes) else f"{min(sizes)}-{max(sizes)}"
        need = memory.get((algo, env))
        lines.append(
            f"  {algo} {env}: {plural(len(sizes), 'unit')} of {members} "
            f"member{'s' if max(sizes) != 1 else ''}"
            + (
                f", up to {need / (1 << 30):.1f} GiB each (replay buffers and networks)"
                if need
                else ""
            )
        )
    return lines
