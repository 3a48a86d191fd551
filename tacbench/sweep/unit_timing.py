"""How one unit of runs is timed for its calibration (:mod:`tacbench.sweep.calibration`): a short
training of the unit itself.

A unit's cost depends on more than its algorithm and task: its networks, its members, its
schedule, its compilation and the CPU. So the unit is timed as it would train, for a few
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
  of :data:`ENV_STEPS` with random actions): an evaluation steps its ten episodes in lockstep,
  so the policy's batched action, shared by them, is left out.

The same random steps give ``random_episode``, the steps per episode ended: a random policy's
episode, the shortest an evaluation's is likely to be (Hopper 22 steps, Ant 286, HalfCheetah its
limit of 1,000), from which :meth:`Calibration.evaluation_episode` prices one.

A stop signal (Ctrl-C, SIGTERM, SIGHUP) during a measurement stops it (:class:`Interrupted`).
"""

from __future__ import annotations

import dataclasses
import datetime
import statistics
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tacbench import envs
from tacbench.errors import TacbenchError
from tacbench.members import resolve_compile

MEMBERS_MEASURED = 10  # a CPU agent's chunk (tac/agent.py): more members cost the same per member
RANDOM_STEPS = 1000
WARMUP_STEPS = 50
LEARN_STEPS = 1500
ON_POLICY_ROLLOUTS = 3
ENV_STEPS = 2000  # environment steps timed for an evaluation step
ON_POLICY = ("ppo", "trpo")
LOG_EVERY = 50  # the loss log's interval while measuring: the updates counted per 50 steps
# 4: evaluation episodes priced from random episodes' length (Calibration.evaluation_episode),
# each unit measured in rounds (calibration.ROUNDS); 3: trainers flush subnormal numbers
# (hardware.flush_denormals), which makes the authors' profiles' units up to 3x faster on the
# Intel Xeon class; 2: updates counted per window; 1 took a window's time per step
METHOD = 4


class Interrupted(KeyboardInterrupt):
    """A stop signal (Ctrl-C, SIGTERM, SIGHUP) during a calibration: its trainer stops the
    measurement cleanly, and :func:`tacbench.sweep.calibration.calibrate` stops with it, storing
    the units measured before."""


@dataclass(frozen=True)
class Calibration:
    """CPU seconds per member-step of one unit, and when and where they were measured."""

    random: float
    learn: float
    eval_step: float
    measured: str  # date
    members: int  # how many members the measurement trained
    rounds: int = 1  # how many measurements' median (calibration.median)
    # steps per episode under random actions (random_steps); None: stored before METHOD 4
    random_episode: float | None = None

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
            + evaluations * episodes * self.evaluation_episode(episode_limit) * self.eval_step
        )

    def evaluation_episode(self, episode_limit: int) -> float:
        """The steps an evaluation episode is priced at: halfway between a random policy's
        episode and the limit, off by at most half their difference where a trained policy's
        episodes lie between them (the limit itself for a task whose episodes do not end
        early, and for a calibration without ``random_episode``)."""
        if self.random_episode is None:
            return float(episode_limit)
        return (min(self.random_episode, episode_limit) + episode_limit) / 2


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
    steps = random_steps(first.env)
    return Calibration(
        random=random,
        learn=learn,
        eval_step=steps.seconds,
        measured=datetime.date.today().isoformat(),
        members=members,
        random_episode=steps.episode,
    )


@dataclass(frozen=True)
class RandomSteps:
    """A task stepped with random actions: the CPU seconds of a step and the mean episode."""

    seconds: float
    episode: float


def random_steps(env_id: str, steps: int | None = None) -> RandomSteps:
    """``steps`` (default :data:`ENV_STEPS`) steps of ``env_id`` with random actions: the median
    step's CPU seconds, resets not counted, and the steps per episode ended, at most the
    episode limit (the limit where none ended)."""
    import numpy as np

    info = envs.env_info(env_id)
    env = envs.make_env(env_id)
    try:
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        low, high = np.asarray(info.low), np.asarray(info.high)
        times, ended = [], 0
        for _ in range(steps or ENV_STEPS):
            action = rng.uniform(low, high)
            start = time.process_time()
            _, _, terminated, truncated, _ = env.step(action)
            times.append(time.process_time() - start)
            if terminated or truncated:
                ended += 1
                env.reset()
    finally:
        env.close()
    limit = float(info.max_episode_steps)
    return RandomSteps(statistics.median(times), min(limit, len(times) / ended) if ended else limit)
