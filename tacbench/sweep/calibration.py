"""What a unit of runs costs on this CPU class, measured by a short training of the unit itself
(``tacbench sweep --dry-run --calibrate``), stored per class, and priced.

A unit's cost depends on more than its algorithm and task: its networks, its members, its
schedule, its compilation and the CPU. So the unit is calibrated as it would train, for a few
thousand steps, in a temporary folder: its own configs (at most :data:`MEMBERS_MEASURED`
members, as many as one chunk of a CPU agent), with only the budget, the evaluation, the
checkpoints and the loss log's interval changed. Three CPU times per member-step come out
(``time.process_time``, so other work on the machine does not inflate them, one torch thread):

* ``random``: a step without an update, the median step over up to :data:`RANDOM_STEPS` steps
  before learning starts (random actions);
* ``learn``: a step with its one update, over at least :data:`LEARN_STEPS` steps after
  :data:`WARMUP_STEPS` (where ``torch.compile`` compiles), or for PPO and TRPO over at least three
  rollouts and their updates. A TAC unit in the episode schedule updates in bursts at episode
  ends (a HalfCheetah window of 1,500 steps holds one burst of 1,000 updates), so its updates
  are counted (losses.csv's ``updates``) and the window's time is shared out as ``random`` per
  step plus the rest per update;
* ``eval_step``: one step of an evaluation episode, taken as one environment step (the median
  of :data:`ENV_STEPS`): an evaluation steps its ten episodes in lockstep, so the policy's
  batched action, shared by them, is left out.

A run of T steps that updates from step L and evaluates E episodes every V steps is then priced
at ``L x random + (T - L) x learn + (T / V) x E x H x eval_step`` per member, H the task's
episode limit: evaluation episodes are priced at full length, an upper bound for tasks whose
episodes end early. A TAC run that updates during warm-up (``--warmup-updates on``, the authors'
code) starts at its first episode end, priced at H. The compilation of the first update
(seconds; the measurement's window starts after it) and the checkpoints are left out.

A stop signal (Ctrl-C, SIGTERM, SIGHUP) during a measurement stops the calibration
(:class:`Interrupted`): the units measured before it are stored, and the command exits with the
signal's status.

Calibrations are kept per CPU class (:func:`tacbench.hardware.cpu_class`) in
``$TACBENCH_CALIBRATION`` or ``~/.cache/tacbench/calibration/<class>.json``, keyed by what
decides a unit's cost (:func:`unit_key`) and by :data:`METHOD`, so that a calibration measured
another way is measured again.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tacbench import envs, runs
from tacbench.errors import TacbenchError
from tacbench.hardware import cpu_class
from tacbench.members import resolve_compile

MEMBERS_MEASURED = 10  # a CPU agent's chunk (tac/agent.py): more members cost the same per member
RANDOM_STEPS = 1000
WARMUP_STEPS = 50
LEARN_STEPS = 1500
ON_POLICY_ROLLOUTS = 3
ENV_STEPS = 2000  # environment steps timed for an evaluation step
ON_POLICY = ("ppo", "trpo")
LOG_EVERY = 50  # the loss log's interval while measuring: the updates counted per 50 steps
# 3: trainers flush subnormal numbers (hardware.flush_denormals), which makes the authors'
# profiles' units up to 3x faster on the Intel Xeon class; 2: updates counted per window; 1 took
# a window's time per step, whatever it held
METHOD = 3
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


class Interrupted(KeyboardInterrupt):
    """A stop signal (Ctrl-C, SIGTERM, SIGHUP) during a calibration: its trainer stops the
    measurement cleanly, and :func:`calibrate` stops with it, storing the units measured
    before."""


@dataclass(frozen=True)
class Calibration:
    """CPU seconds per member-step of one unit, and when and where they were measured."""

    random: float
    learn: float
    eval_step: float
    measured: str  # date
    members: int  # how many members the measurement trained

    def seconds(
        self,
        total_steps: int,
        learning_starts: int,
        eval_every: int,
        episodes: int,
        episode_limit: int,
        *,
        steps_left: int,
    ) -> float:
        """CPU seconds per member for the last ``steps_left`` of a ``total_steps`` run."""
        start = total_steps - steps_left
        random_left = min(steps_left, max(0, learning_starts - start))
        learn_left = steps_left - random_left  # none where learning would start after the end
        evaluations = total_steps // eval_every - start // eval_every if eval_every else 0
        return (
            random_left * self.random
            + learn_left * self.learn
            + evaluations * episodes * episode_limit * self.eval_step
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


def _for_measurement(configs: Sequence[Any], total: int, starts: int) -> list[Any]:
    """The unit's first members, set to train ``total`` steps, learning from ``starts``, with
    no evaluation or checkpoint inside them."""
    changed: list[Any] = []
    for config in configs[:MEMBERS_MEASURED]:
        settings: dict[str, Any] = {"total_steps": total, "eval_every": 0, "checkpoint_every": 0}
        if config.algo == "tac":  # timed as the real run would train here, compiled or not
            config = resolve_compile(config)
            settings["learning_starts"] = starts
            settings["log_every"] = LOG_EVERY
        elif config.algo not in ON_POLICY:
            settings["hyperparams"] = {**config.hyperparams, "learning_starts": starts}
        changed.append(dataclasses.replace(config, **settings))
    return changed


def measure(configs: Sequence[Any]) -> Calibration:
    """Train the unit of ``configs`` briefly in a temporary folder and time it (module
    docstring)."""
    from tacbench import trainers

    first = configs[0]
    tac = first.algo == "tac"
    if first.algo in ON_POLICY:
        rollout = int(first.hyperparams["n_steps"])
        starts, total = 0, max(LEARN_STEPS, ON_POLICY_ROLLOUTS * rollout) + rollout
    else:  # a window longer than an episode holds at least one episode end's updates
        starts = min(int(first.learning_starts), RANDOM_STEPS)
        limit = envs.env_info(first.env).max_episode_steps
        total = starts + WARMUP_STEPS + max(LEARN_STEPS, limit + LOG_EVERY)
        total = -(-total // LOG_EVERY) * LOG_EVERY  # the last step of a loss-log window
    # TAC trains one step more, so that the window ends before the final checkpoint
    measured = _for_measurement(configs, total + 1 if tac else total, starts)
    marks: list[tuple[int, float]] = []

    def stop(step: int) -> bool:
        marks.append((step, time.process_time()))
        return False

    with tempfile.TemporaryDirectory() as tmp:
        outcomes = trainers.trainer_for(first.algo).train(
            measured, Path(tmp), quiet=True, stop=stop
        )
        if any(outcome.state == "interrupted" for outcome in outcomes):
            raise Interrupted
        updates = _LoggedUpdates.read(Path(tmp)) if tac else None
    members = len(measured)

    def rate(low: int, high: int) -> float:
        inside = [(s, t) for s, t in marks if low <= s <= high]
        (s0, t0), (s1, t1) = inside[0], inside[-1]
        return (t1 - t0) / max(1, s1 - s0) / members

    if first.algo in ON_POLICY:  # from the end of the first rollout: rollouts and updates
        learn = rate(int(first.hyperparams["n_steps"]), total)
        return _calibration(first, random=learn, learn=learn, members=members)
    # from a tenth of the way in: the first steps also pay for setting the unit up
    low, high = (starts // 10 + 1, starts - 1) if starts > 10 else (starts, starts + WARMUP_STEPS)
    if updates is None:
        random_rate = rate(low, high)
        learn = rate(starts + WARMUP_STEPS, total)
        return _calibration(first, random=random_rate, learn=learn, members=members)
    # TAC: the loop calls stop(step) once every step, with the CPU time of steps 1 .. step
    seconds = dict(marks)
    random_rate = statistics.median(
        (seconds[s + 1] - seconds[s]) / members for s in range(low, high)
    )  # the median: a burst of updates at an episode end inside the random steps is left out
    # the window starts after the first update (where torch.compile compiles), which in the
    # episode schedule waits for an episode end after the random steps
    begin = max(-(-(starts + WARMUP_STEPS) // LOG_EVERY) * LOG_EVERY, updates.first_step())
    done = updates.between(begin, total)
    if total not in seconds or not done:
        raise TacbenchError(
            f"calibrating {first.algo} {first.env}: no update between steps {begin} and "
            f"{total} to time (members failed, or no episode ended); the dry run prices "
            f"every {first.algo} {first.env} run from runs under --out, or from the defaults "
            "(its table says which)."
        )
    cpu = (seconds[total] - seconds[begin]) / members
    learn = random_rate + (cpu - (total - begin) * random_rate) / done
    return _calibration(first, random=random_rate, learn=learn, members=members)


@dataclass(frozen=True)
class _LoggedUpdates:
    """The updates in the loss logs of a measurement (one per member), logged every
    :data:`LOG_EVERY` steps and at the last step."""

    logs: tuple[Any, ...]

    @classmethod
    def read(cls, folder: Path) -> _LoggedUpdates:
        import pandas as pd

        return cls(tuple(pd.read_csv(path) for path in sorted(folder.rglob("losses.csv"))))

    def between(self, low: int, high: int) -> float:
        """Updates per member in steps low+1 .. high (logged steps)."""
        rows = [log[(log["step"] > low) & (log["step"] <= high)] for log in self.logs]
        return float(sum(row["updates"].sum() for row in rows)) / len(self.logs)

    def first_step(self) -> int:
        """The first logged step whose window holds an update of any member (0: none; a member
        that failed at its first update logged no row)."""
        steps = [log.loc[log["updates"] > 0, "step"] for log in self.logs]
        found = [int(step.min()) for step in steps if len(step)]
        return min(found) if found else 0


def _calibration(first: Any, *, random: float, learn: float, members: int) -> Calibration:
    return Calibration(
        random=random,
        learn=learn,
        eval_step=env_step_seconds(first.env),
        measured=datetime.date.today().isoformat(),
        members=members,
    )


def env_step_seconds(env_id: str, steps: int | None = None) -> float:
    """CPU seconds of one step of ``env_id``: the median of ``steps`` (default
    :data:`ENV_STEPS`) steps with random actions, resets not counted."""
    import numpy as np

    env = envs.make_env(env_id)
    try:
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        info = envs.env_info(env_id)
        low, high = np.asarray(info.low), np.asarray(info.high)
        times = []
        for _ in range(steps or ENV_STEPS):
            action = rng.uniform(low, high)
            start = time.process_time()
            _, _, terminated, truncated, _ = env.step(action)
            times.append(time.process_time() - start)
            if terminated or truncated:
                env.reset()
    finally:
        env.close()
    return statistics.median(times)


def calibrate(
    units: Sequence[Sequence[Any]], report: Callable[[str], None] = print, *, again: bool = False
) -> dict[str, Calibration]:
    """Measure every unit (a sequence of its configs) whose key this class has not calibrated
    (``again``: every unit, replacing what was stored: the same class on another host, or on a
    busier day, can run at another speed), store the results and return all of this class's
    calibrations. A unit that cannot be measured (every member failed before the timed window)
    is reported and left out, a calibration stored before it kept; the others are stored."""
    known = load()
    todo: dict[str, Sequence[Any]] = {}
    for configs in units:
        key = unit_key(configs)
        if (again or key not in known) and key not in todo:
            todo[key] = configs
    if todo:  # before minutes of measuring whose results would have nowhere to go
        runs.check_writable(store_path().parent, "TACBENCH_CALIBRATION")
    new: dict[str, Calibration] = {}
    for index, (key, configs) in enumerate(todo.items(), start=1):
        c = configs[0]
        report(
            f"calibrating {index}/{len(todo)}: {c.algo} {c.env}, "
            f"{min(len(configs), MEMBERS_MEASURED)} member(s) ..."
        )
        start = time.perf_counter()
        try:
            new[key] = measure(configs)
        except TacbenchError as err:  # the other units' measurements are still stored
            kept = f"; the calibration of {known[key].measured} is kept" if key in known else ""
            report(f"  not calibrated: {err}{kept}")
            continue
        except KeyboardInterrupt:  # a stop signal, or a second one: keep what was measured
            kept = f"the units measured before it are stored in {save(new)}" if new else ""
            report(f"  calibration interrupted; {kept or 'nothing was stored'}")
            raise Interrupted from None
        report(
            f"  {new[key].learn * 1e3:.2f} ms per member-step learning, "
            f"{new[key].random * 1e3:.2f} before ({time.perf_counter() - start:.0f} s)"
        )
    if new:
        report(f"wrote {save(new)}")
    return {**known, **new}


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
            left = run.total_steps - planned[run.key].status.step
            seconds[group] = seconds.get(group, 0.0) + found.seconds(
                run.total_steps, *pricing, steps_left=left
            )
    return {group: s for group, s in seconds.items() if group not in missing}
