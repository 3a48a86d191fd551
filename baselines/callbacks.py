"""The SB3 callback and logger that write a baseline's run directory as TAC's loop does.

Where TAC's loop acts, SB3 calls back: ``on_step`` after each environment step, and
``on_rollout_start`` at each *boundary*, the point where every update due for the data so far
has been made (each step for the off-policy baselines, each rollout for PPO/TRPO) and where the
model, its buffers and the environment can be saved and continued exactly. Hence:

- ``train.csv``: a row at each finished training episode (``on_step``).
- ``eval.csv``: the evaluation due at step N evaluates the policy that acts at step N + 1, i.e.
  after the updates made at step N (TAC evaluates after its update at step N too). It runs at
  the first boundary or step after N, whichever comes first; the policy is the same at both.
- ``losses.csv``: at a boundary, the mean of what SB3 logged under ``train/`` since the last row,
  once per ``log_every`` steps.
- checkpoints, the stop check (Ctrl-C, SIGTERM, a sweep's deadline) and the divergence check:
  at boundaries. A stop therefore takes effect at the next rollout end for PPO and TRPO.

Training stops at exactly ``total_steps`` steps: a PPO/TRPO rollout that would run past it is
cut there, and its partial data is not trained on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.type_aliases import TrainFrequencyUnit

from tacbench import runs
from tacbench.progress import Progress


class Interrupted(Exception):
    """Raised at a boundary after the checkpoint when a stop was requested."""


class Diverged(Exception):
    """Raised at a boundary when a loss logged since the last one is NaN or infinite."""


class LossLogger(Logger):
    """SB3's logger with no output, which averages every ``train/<name>`` value SB3 records
    (one per ``train()`` call) until :meth:`pop_row` collects them for losses.csv."""

    def __init__(self, columns: Sequence[str]) -> None:
        super().__init__(folder=None, output_formats=[])
        self.columns = tuple(columns)
        self.sums: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self.unknown: set[str] = set()
        self.non_finite: list[str] = []

    def record(self, key: str, value: Any, exclude: str | tuple[str, ...] | None = None) -> None:
        """SB3's record, plus the running sums of the ``train/`` values."""
        super().record(key, value, exclude)
        if not key.startswith("train/"):
            return
        name = key.removeprefix("train/")
        if name not in self.columns:
            self.unknown.add(name)
            return
        number = float(value)
        if not math.isfinite(number) and ("loss" in name or name == "policy_objective"):
            self.non_finite.append(name)
        if name == "n_updates":  # a running total, not a per-update value
            self.sums[name], self.counts[name] = number, 1
        else:
            self.sums[name] = self.sums.get(name, 0.0) + number
            self.counts[name] = self.counts.get(name, 0) + 1

    def pop_row(self) -> list[float] | None:
        """The means since the last call, in column order (NaN for a column SB3 did not log in
        this window), or None if nothing was logged."""
        if not self.counts:
            return None
        row = [
            self.sums[c] / self.counts[c] if c in self.counts else math.nan for c in self.columns
        ]
        self.sums, self.counts = {}, {}
        return row

    def state(self) -> dict[str, Any]:
        """The partial sums, for a checkpoint."""
        return {"sums": dict(self.sums), "counts": dict(self.counts)}

    def load_state(self, state: dict[str, Any]) -> None:
        """Undo :meth:`state`."""
        self.sums, self.counts = dict(state["sums"]), dict(state["counts"])


class RunCallback(BaseCallback):
    """Drives the run directory from SB3's callback points (module docstring).

    ``evaluate(step)`` runs the evaluation protocol and writes its row, returning the mean
    return; ``checkpoint(step)`` saves everything resume needs; ``stop(step)`` says whether to
    stop; ``wall_s()`` is the run's wall-clock time so far.
    """

    def __init__(
        self,
        *,
        total_steps: int,
        eval_every: int,
        checkpoint_every: int,
        log_every: int,
        on_policy: bool,
        writer: runs.RunWriter,
        progress: Progress,
        losses: LossLogger,
        evaluate: Callable[[int], float],
        checkpoint: Callable[[int], None],
        stop: Callable[[int], bool],
        wall_s: Callable[[], float],
    ) -> None:
        super().__init__()
        self.total_steps, self.eval_every = total_steps, eval_every
        self.checkpoint_every, self.log_every = checkpoint_every, log_every
        self.on_policy = on_policy
        self.writer, self.progress, self.losses = writer, progress, losses
        self._evaluate, self._checkpoint, self._stop, self._wall_s = (
            evaluate,
            checkpoint,
            stop,
            wall_s,
        )
        self.last_boundary = 0
        self.pending_eval: int | None = None
        self.stop_announced = False

    def _on_training_start(self) -> None:
        self.last_boundary = self.num_timesteps

    def _flush_eval(self) -> None:
        if self.pending_eval is not None:
            step, self.pending_eval = self.pending_eval, None
            self.progress.update(step, self._evaluate(step))

    def _on_step(self) -> bool:
        step = self.num_timesteps
        self._flush_eval()
        for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
            if done:
                episode = info["episode"]
                self.writer.train_row(step, self._wall_s(), episode["r"], episode["l"])
        if self.eval_every and (step % self.eval_every == 0 or step == self.total_steps):
            self.pending_eval = step  # the progress line follows with its result
        else:
            self.progress.update(step)
        if not self._every_step() and not self.stop_announced and self._stop(step):
            self.stop_announced = True
            self.progress.message(
                f"stop requested at step {step}: finishing this rollout, then checkpointing"
            )
        if step >= self.total_steps:
            # a rollout that would run past the budget is cut here (its data is not trained on)
            return self._rollout_ends_here()
        return True

    def _every_step(self) -> bool:
        """Whether a rollout is one step (off-policy with ``train_freq`` 1 step, the default):
        then a stop takes effect at once, else at the rollout's end."""
        if self.on_policy:
            return False
        freq = self.locals["train_freq"]
        return bool(freq.unit == TrainFrequencyUnit.STEP and freq.frequency == 1)

    def _rollout_ends_here(self) -> bool:
        """Whether the rollout SB3 is collecting is complete with this step (it trains on it
        next): PPO's and TRPO's after ``n_steps`` steps, an off-policy algorithm's after
        ``train_freq`` steps or episodes (1 step by default: then never cut)."""
        if self.on_policy:
            return bool(self.locals["n_steps"] + 1 >= self.locals["n_rollout_steps"])
        freq = self.locals["train_freq"]
        if freq.unit == TrainFrequencyUnit.STEP:
            return bool(self.locals["num_collected_steps"] >= freq.frequency)
        # SB3 counts this step's episode end only after the callback
        episodes = self.locals["num_collected_episodes"] + int(any(self.locals["dones"]))
        return bool(episodes >= freq.frequency)

    def _on_rollout_start(self) -> None:
        self._boundary(self.model.num_timesteps)

    def _on_training_end(self) -> None:
        self._boundary(self.model.num_timesteps)

    def _boundary(self, step: int) -> None:
        """Evaluate, log, check, checkpoint and poll for a stop: all updates up to ``step`` done."""
        self._flush_eval()
        if self.losses.non_finite:
            names = ", ".join(sorted(set(self.losses.non_finite)))
            raise Diverged(f"non-finite {names} at step {step}")
        previous, self.last_boundary = self.last_boundary, step
        last = step >= self.total_steps
        if step != previous and (step // self.log_every != previous // self.log_every or last):
            row = self.losses.pop_row()
            if row is not None:
                self.writer.losses_row(step, row)
        every = self.checkpoint_every
        due = last or (every and step // every != previous // every and step != previous)
        if due:
            self._checkpoint(step)
        if not last and self._stop(step):
            # nothing to keep at step 0, nor at the step resumed from: its generation is on disk
            if not due and step != previous:
                self._checkpoint(step)
            raise Interrupted(step)
