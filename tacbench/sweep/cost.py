"""How long the steps left will take (seconds per environment step for each (algo, env)), and
how much memory a unit of TAC members needs.

Measured, where possible, from run directories already under ``--out`` of the plan's kind
(:func:`rates`): a run's ``eval.csv`` ``cpu_s`` (its share of the CPU seconds of its process's
threads in training, evaluation and checkpoints, summed over sessions) over its second half of
evaluations; for a run begun before eval.csv logged ``cpu_s``, its ``wall_s`` times its torch
threads divided by its members (K seeds sharing one process share its wall clock), which other
work on the machine stretches. The median over the runs of an (algo, env) is used. Where no run
has two evaluations yet, the defaults below are used, and the plan says so.
"""

from __future__ import annotations

import csv
import heapq
import json
import math
import statistics
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tacbench import runs
from tacbench.errors import TacbenchError
from tacbench.members import resolve_compile
from tacbench.paper import ENV_IDS, HYPERPARAMETERS, PROFILES, paper_task
from tacbench.runs.clock import shares_cpu

# CPU seconds per member-step with the paper's settings, one torch thread, measured with
# :func:`measure`: learning from step 1,000, CPU time (time.process_time, not inflated by other
# jobs) from step 1,001 to 3,000, 4 evaluation episodes every 1,000 steps (the paper's ratio, 10
# per 5,000; early episodes are short on Hopper, Ant and Humanoid, so later evaluations cost
# more). TAC: as the paper's grid trains by default, compiled, in units of as
# many members as tacbench sweep --dry-run planned on the development machine then (2 cores,
# 23 GiB: 45 members, Ant 30, Humanoid 5; it now plans 45 for Ant), AMD EPYC class, torch 2.13
# CPU, 2026-12-02. The baselines: one
# run per process (K = 1), 2026-11-22. TD3's table uses a (400, 300) network, DDPG's one of 300.
DEFAULT_SECONDS_PER_STEP: dict[tuple[str, str], float] = {
    # tac, grouped and compiled (members per unit: DEFAULT_TAC_MEMBERS below)
    ("tac", "HalfCheetah-v4"): 0.62e-3,
    ("tac", "Ant-v4"): 1.29e-3,
    ("tac", "Hopper-v4"): 0.55e-3,
    ("tac", "Swimmer-v4"): 0.57e-3,
    ("tac", "Pusher-v5"): 0.70e-3,
    ("tac", "Humanoid-v4"): 6.12e-3,
    # ddpg
    ("ddpg", "HalfCheetah-v4"): 4.19e-3,
    ("ddpg", "Ant-v4"): 6.27e-3,
    ("ddpg", "Hopper-v4"): 3.63e-3,
    ("ddpg", "Swimmer-v4"): 4.59e-3,
    ("ddpg", "Pusher-v5"): 4.93e-3,
    ("ddpg", "Humanoid-v4"): 14.28e-3,
    # td3
    ("td3", "HalfCheetah-v4"): 18.63e-3,
    ("td3", "Ant-v4"): 18.31e-3,
    ("td3", "Hopper-v4"): 16.96e-3,
    ("td3", "Swimmer-v4"): 16.94e-3,
    ("td3", "Pusher-v5"): 16.87e-3,
    ("td3", "Humanoid-v4"): 29.06e-3,
    # ppo
    ("ppo", "HalfCheetah-v4"): 1.53e-3,
    ("ppo", "Ant-v4"): 2.29e-3,
    ("ppo", "Hopper-v4"): 1.16e-3,
    ("ppo", "Swimmer-v4"): 1.48e-3,
    ("ppo", "Pusher-v5"): 1.23e-3,
    ("ppo", "Humanoid-v4"): 1.21e-3,
    # trpo
    ("trpo", "HalfCheetah-v4"): 1.09e-3,
    ("trpo", "Ant-v4"): 1.90e-3,
    ("trpo", "Hopper-v4"): 0.88e-3,
    ("trpo", "Swimmer-v4"): 1.05e-3,
    ("trpo", "Pusher-v5"): 0.75e-3,
    ("trpo", "Humanoid-v4"): 0.92e-3,
    # sac-sb3 (the paper's (300,) networks, batch 100): measured 2026-12-04 on the AMD EPYC AVX2
    # class (x86_64-AuthenticAMD-25-1-AVX2) beside two training processes, where DDPG's Hopper
    # measured 6.34e-3 and TD3's 21.39e-3 (1.7x and 1.3x the rows above)
    ("sac-sb3", "HalfCheetah-v4"): 10.19e-3,
    ("sac-sb3", "Ant-v4"): 11.90e-3,
    ("sac-sb3", "Hopper-v4"): 11.55e-3,
    ("sac-sb3", "Swimmer-v4"): 11.04e-3,
    ("sac-sb3", "Pusher-v5"): 11.37e-3,
    ("sac-sb3", "Humanoid-v4"): 19.82e-3,
}
# TAC in --profile reference ((400, 300) networks, updates during warm-up, episode bursts), a
# cost of its own: 5 members of one process, compiled, 100,000 steps, wall time (eval.csv) of the
# second half with the other core busy, AMD EPYC class, 2026-12-02 (docs/parity.md). Other tasks
# get the mean of these.
REFERENCE_TAC = "tac-ref"
DEFAULT_SECONDS_PER_STEP |= {
    (REFERENCE_TAC, "HalfCheetah-v4"): 7.94e-3,
    (REFERENCE_TAC, "Hopper-v4"): 8.73e-3,
}
DEFAULT_SOURCE = "default*"  # the plan explains the asterisk
# the members per unit in which the TAC defaults above were measured
DEFAULT_TAC_MEMBERS = {"Ant-v4": 30, "Humanoid-v4": 5}
DEFAULT_TAC_MEMBERS_ELSEWHERE = 45
REFERENCE_TAC_MEMBERS = 5  # and the members per unit of the tac-ref defaults (networks (400, 300))


@dataclass(frozen=True)
class TacBasis:
    """The compiled units in which a TAC default rate was measured: members and networks."""

    members: int
    hidden_sizes: tuple[int, ...]


def default_tac_basis(algo: str, env: str) -> TacBasis:
    """The units that TAC's default rate on ``env`` was measured in, ``algo`` as
    :func:`cost_algo` names it: the paper's (300,) networks, or the reference profile's
    (400, 300) for :data:`REFERENCE_TAC`."""
    if algo == REFERENCE_TAC:
        return TacBasis(REFERENCE_TAC_MEMBERS, PROFILES["reference"]["hidden_sizes"])
    members = DEFAULT_TAC_MEMBERS.get(env, DEFAULT_TAC_MEMBERS_ELSEWHERE)
    return TacBasis(members, HYPERPARAMETERS.hidden_sizes)


def cost_algo(algo: str, profile: str | None) -> str:
    """The name a run's cost is kept under: its algorithm, or :data:`REFERENCE_TAC` for TAC in
    the reference profile or a dated version of the authors' code (``authors-*``, the same
    networks and schedule), which cost several times the paper profile per step."""
    authors_code = profile is not None and profile != "paper"
    return REFERENCE_TAC if algo == "tac" and authors_code else algo


@dataclass(frozen=True)
class Rate:
    """Seconds of one core per environment step, and where the number comes from."""

    seconds_per_step: float
    source: str


def run_seconds_per_step(directory: Path) -> float | None:
    """Core-seconds per step of the run in ``directory`` from its eval.csv (None: fewer than two
    evaluations, or no config.json)."""
    eval_csv, config_json = directory / "eval.csv", directory / "config.json"
    if not eval_csv.exists() or not config_json.exists():
        return None
    measured = _seconds_per_step(eval_csv, runs.read_json(config_json))
    return None if measured is None else measured[0]


def _seconds_per_step(eval_csv: Path, metadata: dict[str, Any]) -> tuple[float, str] | None:
    """:func:`run_seconds_per_step` from the run's eval.csv and its config.json's contents, and
    the clock it read: ``cpu_s`` over the window where both ends record it (the run's share of
    every thread's CPU seconds), else ``wall_s`` times the threads over the members that
    config.json lists (the run's first group: a run resumed in a group of another size is
    priced as if in that one). None also when eval.csv or config.json is damaged, and when the
    window starts before the run learns, its random warm-up being many times faster: a price
    does without that rate, and the run's own resume check says what is wrong with it."""
    try:
        with eval_csv.open(newline="") as handle:
            rows = [
                (int(r["step"]), float(r["wall_s"]), float(r.get("cpu_s") or "nan"))
                for r in csv.DictReader(handle)
            ]
        settings = metadata["config"]
        threads = int(settings.get("threads", 1))
        members = len(metadata.get("members", [0])) or 1
        start = int(
            settings.get(
                "learning_starts", settings.get("hyperparams", {}).get("learning_starts", 0)
            )
        )
    except (OSError, csv.Error, AttributeError, KeyError, TypeError, ValueError):
        return None  # ValueError: undecodable, or a step, time or thread count not a number
    if len(rows) < 2:
        return None
    (step_a, wall_a, cpu_a), (step_b, wall_b, cpu_b) = rows[(len(rows) - 1) // 2], rows[-1]
    if step_b <= step_a or wall_b <= wall_a or step_a < start:
        return None
    if cpu_b > cpu_a:  # both recorded (NaN where not: the comparison is False)
        shared = 1 if shares_cpu(metadata) else members  # else it logged the whole process's
        return (cpu_b - cpu_a) / (step_b - step_a) / shared, "cpu_s"
    return (wall_b - wall_a) / (step_b - step_a) * threads / members, "wall_s"


PRICED_ALIKE = ("seed", "q", "alpha", "total_steps", "variant")
"""Settings in which a measured run may differ from the plan's runs it prices: a member's
identity and the run's length (the variant names q and alpha). Any other difference (the
network, the schedule, compilation, threads) is another kind of run, priced otherwise."""


def _kind(settings: Mapping[str, Any]) -> Any:
    """A run's settings without :data:`PRICED_ALIKE`, as JSON reads them (lists, not tuples)."""
    return json.loads(json.dumps({k: v for k, v in settings.items() if k not in PRICED_ALIKE}))


def rates(
    out: Path, planned: Mapping[tuple[str, str], Sequence[Any]]
) -> dict[tuple[str, str], Rate]:
    """A :class:`Rate` for each (algo, env) of ``planned`` (algo as :func:`cost_algo` names it;
    the plan's configs of that pair): measured under ``out`` where a run there of the same kind
    (the settings of one of those configs but for :data:`PRICED_ALIKE`) has two evaluations
    after its warm-up, else the default (None-free: an unmeasured pair gets the mean default of
    its algorithm, or of everything). A run of another kind or with a damaged config.json
    prices nothing."""
    kinds = {  # a run records the compile that --compile auto resolved to: compare with that
        pair: [_kind((resolve_compile(c) if c.algo == "tac" else c).to_dict()) for c in configs]
        for pair, configs in planned.items()
    }
    measured: dict[tuple[str, str], list[tuple[float, str]]] = defaultdict(list)
    for config_json in Path(out).glob("runs/*/*/*/seed*/config.json"):
        eval_csv = config_json.parent / "eval.csv"
        if not eval_csv.exists():
            continue
        try:
            metadata = runs.read_json(config_json)  # once: the rate's divisors and the kind
        except TacbenchError:
            continue
        stored = metadata.get("config") if isinstance(metadata, dict) else None
        if not isinstance(stored, dict):
            continue
        pair = cost_algo(config_json.parts[-5], stored.get("profile")), config_json.parts[-4]
        if (
            pair not in planned
            or _kind(runs.as_read_now(stored, planned[pair][0])) not in kinds[pair]
        ):
            continue
        value = _seconds_per_step(eval_csv, metadata)
        if value is not None:
            measured[pair].append(value)
    result = {}
    for pair in planned:
        if measured.get(pair):
            n, by_wall = len(measured[pair]), sum(c == "wall_s" for _, c in measured[pair])
            result[pair] = Rate(
                statistics.median(value for value, _ in measured[pair]),
                f"measured: {n} run{'s' if n > 1 else ''} under {out}"
                + (f", {by_wall} by wall_s (no cpu_s over the window)" if by_wall else ""),
            )
        else:
            result[pair] = Rate(_default(*pair), DEFAULT_SOURCE)
    return result


def _default(algo: str, env: str) -> float:
    """The default rate of (algo, env): its own, or the mean of :func:`default_stand_ins`."""
    if (algo, env) in DEFAULT_SECONDS_PER_STEP:
        return DEFAULT_SECONDS_PER_STEP[(algo, env)]
    return statistics.fmean(DEFAULT_SECONDS_PER_STEP[pair] for pair in default_stand_ins(algo, env))


def default_stand_ins(algo: str, env: str) -> list[tuple[str, str]]:
    """The (algo, env) pairs whose defaults' mean prices a pair without a default of its own:
    the same paper task in the suite the defaults were measured in (``Hopper-v5`` by
    ``Hopper-v4``), else the algorithm's pairs (``tac-ref`` on the tasks other than HalfCheetah
    and Hopper, a task outside the paper's), or every pair's for an algorithm with none. Empty
    for a pair with its own."""
    if (algo, env) in DEFAULT_SECONDS_PER_STEP:
        return []
    task = paper_task(env)
    if task is not None and (algo, ENV_IDS[task]) in DEFAULT_SECONDS_PER_STEP:
        return [(algo, ENV_IDS[task])]
    same_algo = sorted(pair for pair in DEFAULT_SECONDS_PER_STEP if pair[0] == algo)
    return same_algo or sorted(DEFAULT_SECONDS_PER_STEP)


def measure(
    out: Path, pairs: Iterable[tuple[str, str]], *, members: int = 1, compile: str = "off"
) -> dict[tuple[str, str], float]:
    """CPU seconds per member-step of each (algo, env) as :data:`DEFAULT_SECONDS_PER_STEP` was
    measured: 3,000 steps, learning from step 1,000, 4 evaluation episodes every 1,000 steps,
    one thread, each run trained afresh into ``out``; the CPU time from step 1,000 to the last
    (after the first update, so a compilation is not counted) is divided by the steps and the
    members. TAC runs at q = 1.5 (q hardly changes the cost), ``members`` seeds as members of one
    process, ``compile`` as ``--compile``. About 10 minutes for the paper's 30 pairs at K = 1."""
    import time

    from tacbench import trainers

    settings = {"total_steps": 3000, "eval_every": 1000, "eval_episodes": 4}
    result = {}
    for algo, env in pairs:
        marks: dict[str, tuple[int, float]] = {}

        def stop(step: int, marks: dict[str, tuple[int, float]] = marks) -> bool:
            if step > 1000:
                marks.setdefault("first", (step, time.process_time()))
                marks["last"] = (step, time.process_time())
            return False

        warm_up = {"learning_starts": 1000}
        tac = {**warm_up, "compile": compile} if algo == "tac" else {}
        configs, _ = trainers.make_configs(
            algo,
            env,
            paper_task(env),
            list(range(members)) if algo == "tac" else [0],
            {**settings, **tac},
            qs=[1.5] if algo == "tac" else (),
            tac_settings_given=warm_up if algo in ("ddpg", "td3", "sac-sb3") else {},
        )
        trainers.trainer_for(configs[0].algo).train(configs, out, quiet=True, force=True, stop=stop)
        (s0, t0), (s1, t1) = marks["first"], marks["last"]
        result[(algo, env)] = (t1 - t0) / (s1 - s0) / len(configs)
    return result


# A TAC member's memory besides its replay buffer: its share of the networks, gradients and Adam
# moments and its training and 10 evaluation environments: 12.4 MiB measured for 90 HalfCheetah
# members (resident memory after construction, 2026-12-02), rounded up for larger models
MEMBER_OVERHEAD_BYTES = 20 << 20
# the buffer's row ring commits about 1 + 1/L rows per step for episodes of mean length L;
# L = 20 is short for the paper's tasks (Humanoid's early episodes), so the estimate is generous
_ROWS_PER_STEP = 1.0 + 1.0 / 20
MEMORY_SHARE = 0.75  # of this machine's memory, split between the workers, for replay buffers


def member_bytes(obs_dim: int, act_dim: int, transitions: int) -> int:
    """Memory of one TAC member with a replay buffer of ``transitions`` transitions: two int64
    row indices, the action, reward and terminal flag (float32) per transition, and the float32
    observation rows (tacbench/tac/buffer.py), plus :data:`MEMBER_OVERHEAD_BYTES`."""
    per_step = 16 + 4 * act_dim + 8 + 4 * obs_dim * _ROWS_PER_STEP
    return int(per_step * transitions) + MEMBER_OVERHEAD_BYTES


def members_per_unit(
    group_size: int,
    bytes_per_member: int,
    *,
    workers: int,
    groups: int,
    memory: int,
    limit: int | None = None,
) -> int:
    """How many of a group's ``group_size`` runs one unit trains: at most ``limit`` (--members),
    no more than fit this machine's memory when every worker holds a unit (``MEMORY_SHARE`` of
    ``memory`` split between ``workers``), and split so that ``groups`` groups give every worker
    a unit."""
    fits = max(1, int(MEMORY_SHARE * memory / workers) // bytes_per_member)
    units_for_workers = max(1, math.ceil(workers / max(1, groups)))
    spread = math.ceil(group_size / units_for_workers)
    return max(1, min(fits, spread, limit or group_size))


def makespan(seconds: Sequence[float], workers: int) -> float:
    """The wall time of units taking ``seconds`` each on ``workers`` workers, each unit started,
    in this order, on the first worker to be free (as the local executor starts them): never
    less than the longest unit, whatever the total divided by the workers."""
    free = [0.0] * max(1, workers)
    for duration in seconds:
        start = heapq.heappop(free)
        heapq.heappush(free, start + duration)
    return max(free)
