"""The TAC training loop: warm-up, act, store, update, evaluate, log, checkpoint, resume.

:func:`train` takes the configs of K members (one per seed, otherwise equal), plans each run
directory (start, resume, skip; runs.plan_run), and trains the members in lockstep: each step
every member acts in its own environment, then (``step`` schedule) every member makes one
gradient update on its own minibatch, all in one batched computation.

Each member's checkpoint (``checkpoint/state.pt`` and ``checkpoint/replay/*.npz``) holds
everything its continuation depends on: weights, Adam moments, generators, the env's exact
state (MuJoCo), the episode in progress, the partial losses window and the replay buffer, the
latter written incrementally (only what was added since the previous checkpoint).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tacbench import envs, runs
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.launch import Outcome, StopCheck, plan_runs, stop_signals
from tacbench.progress import Progress
from tacbench.tac.agent import METRICS, TacAgent
from tacbench.tac.buffer import ReplayBuffer
from tacbench.tac.speed import reuse_freed_memory

LOSS_COLUMNS = ("q", "updates", *METRICS)
_STATE_FILE = "state.pt"


def resolve_device(name: str) -> str:
    """``cpu``, ``cuda`` or ``auto`` (cuda when available) -> a usable device name."""
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise TacbenchError("--device cuda: no CUDA device is visible here; use --device cpu.")
    return name


def train(
    configs: Sequence[RunConfig],
    out: Path,
    *,
    resume: bool = False,
    force: bool = False,
    quiet: bool = False,
    command: str = "",
    stop: StopCheck | None = None,
) -> list[Outcome]:
    """Train the members ``configs`` (equal but for the seed) into their run directories.

    ``stop`` is polled before every step with the step count; when it (or Ctrl-C / SIGTERM)
    says stop, every member is checkpointed and left "running", to be continued with
    ``resume=True``. Complete and failed runs are skipped unless ``force``.
    """
    shared = [{k: v for k, v in c.to_dict().items() if k != "seed"} for c in configs]
    if (
        not configs
        or len({c.seed for c in configs}) != len(configs)
        or shared.count(shared[0]) != len(shared)
    ):
        raise TacbenchError("members must share every setting but the seed, and differ in seed.")
    envs.env_info(configs[0].env)  # an unusable task fails before any directory is touched
    outcomes, active = plan_runs(configs, out, resume=resume, force=force)
    if active:
        torch.set_num_threads(active[0][0].threads)
        reuse_freed_memory()
        trainer = _Trainer([c for c, _ in active], [d for _, d in active], command, quiet)
        with stop_signals() as received:
            outcomes += trainer.run(
                lambda step: bool(received) or (stop is not None and stop(step))
            )
    return sorted(outcomes, key=lambda o: o.seed)


@contextmanager
def stepper(configs: Sequence[RunConfig], out: Path) -> Iterator[Callable[[int], int]]:
    """For benchmarks and profiles: fresh members ``configs`` (run directories under ``out``)
    and a function that advances them by n steps (fewer at the end or when all have failed)
    and returns the step reached. No signal handling; everything is closed on exit."""
    directories = [runs.run_directory(out, c.algo, c.env, c.variant, c.seed) for c in configs]
    torch.set_num_threads(configs[0].threads)
    reuse_freed_memory()
    trainer = _Trainer(list(configs), directories, "", quiet=True)

    def advance(n: int) -> int:
        for _ in range(n):
            if trainer.step >= trainer.config.total_steps or not trainer.alive:
                break
            trainer.advance()
        return trainer.step

    try:
        yield advance
    finally:
        trainer.close()


class _Trainer:
    """The loop state for one group of members; see :func:`train`."""

    def __init__(
        self, configs: list[RunConfig], directories: list[Path], command: str, quiet: bool
    ):
        self.config = config = configs[0]
        self.seeds = [c.seed for c in configs]
        self.command = command
        self.info = envs.env_info(config.env)
        k, obs_dim, act_dim = len(configs), self.info.obs_dim, self.info.act_dim
        self.agent = TacAgent(obs_dim, act_dim, config, self.seeds, torch.device(config.device))
        self.buffer = ReplayBuffer(k, obs_dim, act_dim, min(config.buffer_size, config.total_steps))
        self.rngs = [np.random.default_rng(seed) for seed in self.seeds]
        self.envs = [envs.make_env(config.env) for _ in range(k)]
        self.eval_envs = [
            [envs.make_env(config.env) for _ in range(config.eval_episodes)]
            for _ in range(k if config.eval_every > 0 else 0)
        ]
        self.writers = [runs.RunWriter(d, LOSS_COLUMNS) for d in directories]
        self.step = 0
        self.obs = np.zeros((k, obs_dim))
        self.episode_return = np.zeros(k)
        self.episode_length = np.zeros(k, dtype=np.int64)
        self.loss_sum = torch.zeros(k, len(METRICS), device=self.agent.device)
        self.loss_count = 0
        self.alive = list(range(k))  # live members, kept on the host (no device sync to read)
        self.wall_offset = 0.0
        self.finished_length = np.zeros(k, dtype=np.int64)  # length of episodes just ended
        self.chunk_added, self.chunk_rows = 0, np.zeros(k, dtype=np.int64)
        self._resume_or_start(configs, directories)
        seeds = ",".join(map(str, self.seeds))
        label = f"TAC {config.env} q={config.q:g} seed{'s' if k > 1 else ''} {seeds}"
        self.progress = Progress(label, config.total_steps, self.step, config.eval_every, quiet)
        self._t0 = time.perf_counter()

    # --- start and resume ----------------------------------------------------------------

    def _resume_or_start(self, configs: list[RunConfig], directories: list[Path]) -> None:
        paths = [d / "checkpoint" / _STATE_FILE for d in directories]
        states = [torch.load(p, weights_only=True) if p.exists() else None for p in paths]
        steps = {s["step"] if s else 0 for s in states}
        if len(steps) > 1:
            detail = ", ".join(
                f"seed {c.seed}: {s['step'] if s else 0}"
                for c, s in zip(configs, states, strict=True)
            )
            raise TacbenchError(
                f"these members stopped at different steps ({detail}); "
                "resume them one --seed at a time."
            )
        for writer, config, state in zip(self.writers, configs, states, strict=True):
            metadata = None if state else self._metadata(config)
            writer.open(metadata, state["step"] if state else None)
        if any(s is None for s in states):
            for k, env in enumerate(self.envs):
                self.obs[k] = env.reset(seed=self.seeds[k])[0]
            self.buffer.start_episodes(range(len(self.envs)), self.obs)
            return
        assert all(s is not None for s in states)
        full = [s for s in states if s is not None]
        self.step = self.chunk_added = full[0]["step"]
        self.agent.load_member_states([s["agent"] for s in full])
        for k, (state, writer) in enumerate(zip(full, self.writers, strict=True)):
            self.buffer.restore_counters(k, state["buffer"])
            self.chunk_rows[k] = state["buffer"]["n_rows"]  # rows added later go to a new chunk
            replay = writer.checkpoint_dir / "replay"
            for chunk in sorted(replay.glob("*.npz")):
                if int(chunk.stem.split("-")[1]) > self.step:
                    chunk.unlink()  # written after the state we resume from
                else:
                    self.buffer.load_chunk(k, chunk)
            self.rngs[k].bit_generator.state = state["rng"]
            self.obs[k] = state["obs"].numpy()
            self.envs[k].reset(seed=self.seeds[k])
            if state["env"] is not None:
                envs.set_env_state(self.envs[k], state["env"])
                self.episode_return[k], self.episode_length[k] = (
                    state["episode_return"],
                    state["episode_length"],
                )
            else:  # no exact env state (not MuJoCo): continue with a fresh episode
                self.obs[k] = self.envs[k].reset(seed=self.seeds[k] + self.step)[0]
                self.buffer.start_episodes([k], self.obs[k : k + 1])
            self.loss_sum[k] = state["loss_sum"].to(self.loss_sum.device)
        self.loss_count = full[0]["loss_count"]
        self.wall_offset = full[0]["wall_s"]

    def _metadata(self, config: RunConfig) -> dict[str, Any]:
        return runs.run_metadata(
            config.to_dict(),
            self.command,
            algo=config.algo,
            env=config.env,
            variant=config.variant,
            seed=config.seed,
            q=config.q,
            alpha=config.alpha,
            total_steps=config.total_steps,
            members=self.seeds,
        )

    # --- the loop ---------------------------------------------------------------------------

    @property
    def wall_s(self) -> float:
        return self.wall_offset + time.perf_counter() - self._t0

    def _alive(self) -> list[int]:
        return list(self.alive)

    def run(self, stop: StopCheck) -> list[Outcome]:
        """Step until done, stopped or every member failed; then close everything."""
        config, outcomes = self.config, list[Outcome]()
        try:
            while self.step < config.total_steps and self._alive():
                if stop(self.step):
                    if self.step:  # at step 0 there is nothing to keep: resume starts afresh
                        self._checkpoint()
                    return outcomes + self._finish("interrupted")
                outcomes += self.advance()
            return outcomes + self._finish("complete")
        finally:
            self.close()

    def advance(self) -> list[Outcome]:
        """One step of every live member and what is due after it: updates, evaluation,
        checkpoint, progress. Returns the members that failed in it."""
        config = self.config
        done = self._env_step()
        outcomes = self._learn(done)
        eval_mean = self._maybe_evaluate()
        every = config.checkpoint_every
        if (every and self.step % every == 0) or self.step == config.total_steps:
            self._checkpoint()
        self.progress.update(self.step, eval_mean)
        return outcomes

    def close(self) -> None:
        """Close the progress display, the writers and the environments."""
        self.progress.close()
        for writer in self.writers:
            writer.close()
        for env in [*self.envs, *(e for group in self.eval_envs for e in group)]:
            env.close()

    def _finish(self, state: str) -> list[Outcome]:
        """Mark every live member complete, or interrupted (status "running", how to resume)."""
        reason = ""
        if state == "interrupted":
            command = self.command or "train(..., resume=True)"
            resume = command if "--resume" in command.split() else f"{command} --resume"
            reason = f"interrupted at step {self.step}; resume with: {resume}"
        outcomes = []
        for k in self._alive():
            writer = self.writers[k]
            writer.status("complete" if state == "complete" else "running", self.step, reason)
            outcomes.append(Outcome(self.seeds[k], writer.directory, state, self.step, reason))
        return outcomes

    def _env_step(self) -> np.ndarray:
        """Act in each live member's env, store the transitions; return which episodes ended."""
        k_all, alive = len(self.envs), self._alive()
        if self.step < self.config.learning_starts:  # warm-up: uniform random actions
            draws = [rng.uniform(-1.0, 1.0, self.info.act_dim) for rng in self.rngs]
            actions: np.ndarray = np.stack(draws).astype(np.float32)
        else:
            actions = self.agent.act(self.obs)
        env_actions = envs.to_env_action(actions, self.info)
        next_obs, reward = self.obs.copy(), np.zeros(k_all)
        terminated, done = np.zeros(k_all, dtype=bool), np.zeros(k_all, dtype=bool)
        for k in alive:
            obs, r, term, trunc, _ = self.envs[k].step(env_actions[k])
            next_obs[k], reward[k], terminated[k], done[k] = obs, r, term, term or trunc
        self.buffer.add(actions, reward, terminated, next_obs)  # a time-limit end is not terminal
        self.step += 1
        self.episode_return += reward
        self.episode_length += 1
        for k in np.flatnonzero(done).tolist():
            self.writers[k].train_row(
                self.step, self.wall_s, float(self.episode_return[k]), int(self.episode_length[k])
            )
            next_obs[k] = self.envs[k].reset()[0]
            self.buffer.start_episodes([k], next_obs[k : k + 1])
        self.obs = next_obs
        self.finished_length = self.episode_length.copy()
        self.episode_return[done] = 0.0
        self.episode_length[done] = 0
        return done

    def _learn(self, done: np.ndarray) -> list[Outcome]:
        """Gradient updates due after this step; log losses; retire members whose losses blew up."""
        config, outcomes = self.config, []
        if self.step >= config.learning_starts:
            if config.update_schedule == "step":
                n_updates = 1
            else:  # paper Algorithm 1: at an episode end, one update per step of that episode
                n_updates = int(self.finished_length[0]) if done[0] else 0
            q = config.q_at(self.step)
            for _ in range(n_updates):
                metrics = self.agent.update(self.buffer.sample(self.rngs, config.batch_size), q)
                self.loss_sum += metrics
                self.loss_count += 1
                finite = torch.isfinite(metrics)
                if bool(finite.all()):  # the common case, in one reduction
                    continue
                bad = self.agent.alive & ~finite.all(dim=-1)
                if bad.any():
                    outcomes += self._fail(bad, metrics)
                    if not self.alive:
                        break
        if self.loss_count and (
            self.step % config.log_every == 0 or self.step == config.total_steps
        ):
            mean = (self.loss_sum / self.loss_count).cpu().tolist()
            for k in self._alive():
                self.writers[k].losses_row(
                    self.step, [config.q_at(self.step), self.loss_count, *mean[k]]
                )
            self.loss_sum.zero_()
            self.loss_count = 0
        return outcomes

    def _fail(self, bad: torch.Tensor, metrics: torch.Tensor) -> list[Outcome]:
        outcomes, failed = [], torch.nonzero(bad).flatten().tolist()
        for k in failed:
            values = dict(zip(METRICS, metrics[k].tolist(), strict=True))
            names = ", ".join(n for n, v in values.items() if not np.isfinite(v))
            reason = f"non-finite {names} at step {self.step} (mean log pi {values['log_pi']:.4g})"
            if self.config.lnq == "joint" and self.config.q_at(self.step) > 1:
                reason += (
                    "; ln_q of a large joint density overflows float32 (docs/tac.md, "
                    "Numerics): --lnq per-dim, the reference code's form, stays finite"
                )
            reason += "; the last checkpoint is kept"
            self.writers[k].status("failed", self.step, reason)
            self.progress.message(f"seed {self.seeds[k]} failed: {reason}")
            outcomes.append(
                Outcome(self.seeds[k], self.writers[k].directory, "failed", self.step, reason)
            )
        self.agent.alive &= ~bad
        self.alive = [k for k in self.alive if k not in failed]
        return outcomes

    def _maybe_evaluate(self) -> float | None:
        """Deterministic evaluation (reference protocol) when due; returns the mean over members."""
        every, step = self.config.eval_every, self.step
        alive, n_eps, obs_dim = self._alive(), self.config.eval_episodes, self.info.obs_dim
        if not every or not alive or (step % every and step != self.config.total_steps):
            return None

        def policy(obs: np.ndarray) -> np.ndarray:
            full = np.zeros((len(self.envs), n_eps, obs_dim))
            full[alive] = obs.reshape(len(alive), n_eps, obs_dim)
            actions = self.agent.act_deterministic(full)[alive].reshape(len(obs), -1)
            return envs.to_env_action(actions, self.info)

        returns, lengths = envs.evaluate(
            policy,
            [env for k in alive for env in self.eval_envs[k]],
            [s for k in alive for s in envs.eval_seeds(self.seeds[k], step, n_eps)],
        )
        returns, lengths = returns.reshape(len(alive), n_eps), lengths.reshape(len(alive), n_eps)
        for i, k in enumerate(alive):
            self.writers[k].eval_row(step, self.wall_s, returns[i].tolist(), lengths[i].tolist())
        return float(returns.mean())

    def _checkpoint(self) -> None:
        """Write every live member's checkpoint: new replay chunk, then state.pt, then status."""
        for k in self._alive():
            directory = self.writers[k].checkpoint_dir
            replay = directory / "replay"
            replay.mkdir(exist_ok=True)
            if self.step > self.chunk_added:
                chunk = replay / f"{self.chunk_added:012d}-{self.step:012d}.npz"
                self.buffer.save_chunk(k, chunk, self.chunk_added, int(self.chunk_rows[k]))
            state = {
                "step": self.step,
                "agent": self.agent.member_state(k),
                "buffer": self.buffer.counters(k),
                "rng": self.rngs[k].bit_generator.state,
                "env": envs.get_env_state(self.envs[k]),
                "obs": torch.from_numpy(self.obs[k].copy()),
                "episode_return": float(self.episode_return[k]),
                "episode_length": int(self.episode_length[k]),
                "loss_sum": self.loss_sum[k].cpu().clone(),
                "loss_count": self.loss_count,
                "wall_s": self.wall_s,
            }
            tmp = directory / (_STATE_FILE + ".tmp")
            torch.save(state, tmp)
            tmp.replace(directory / _STATE_FILE)
            for old in replay.glob("*.npz"):  # chunks whose transitions have all been overwritten
                if int(old.stem.split("-")[1]) < self.step - self.buffer.capacity:
                    old.unlink()
            self.writers[k].status("running", self.step)
        if self.step > self.chunk_added:  # the next chunk starts where this one ended
            self.chunk_added, self.chunk_rows = self.step, self.buffer.n_rows.copy()
