"""The TAC training loop for one group of members: warm-up, act, store, update, evaluate, log,
checkpoint, resume.

The members train in lockstep: each step every member acts in its own environment, then
(``step`` schedule) every member makes one gradient update on its own minibatch, all in one
batched computation. Each member writes its own run directory.
"""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path

import numpy as np
import torch

from tacbench import envs, runs
from tacbench.config import RunConfig
from tacbench.interrupts import SecondSignal, StopCheck, resume_command
from tacbench.members import members_label
from tacbench.progress import Progress
from tacbench.runs import CpuShares, Outcome, RunClock, checkpoints
from tacbench.seeding import run_streams
from tacbench.tac import METRICS, Coefficients, ReplayBuffer, TacAgent, coefficients
from tacbench.tac.update import update
from tacbench.training.checkpoint import MemberState, load_replay, read, write_checkpoint
from tacbench.training.loss_window import LossWindow
from tacbench.training.pbt import PBT_COLUMNS, Population, check_whole_on_resume
from tacbench.training.schedule import rounds, updates_due

LOSS_COLUMNS = ("q", "updates", *METRICS)  # with --alpha auto, ALPHA_METRICS follow
# Where a step's time goes (GroupTrainer.phase_seconds, read by tacbench bench). Each phase ends
# at a point that waits for the device (the actions' copy to the host; the losses' finiteness
# check), so on a GPU its kernels are counted in their own phase.
PHASES = ("act", "environments", "sample", "update")


class GroupTrainer:
    """The loop state of one group of members (one config each, equal but for q, alpha and the
    seed)."""

    def __init__(
        self, configs: list[RunConfig], directories: list[Path], command: str, quiet: bool
    ):
        self.config = config = configs[0]
        self.configs = configs
        self.seeds = [c.seed for c in configs]
        self.command = command
        self.info = envs.env_info(config.env)
        k, obs_dim, act_dim = len(configs), self.info.obs_dim, self.info.act_dim
        streams = [run_streams(seed) for seed in self.seeds]
        self.env_seeds = [s.env_seed for s in streams]
        # reference profile: the critics and the buffer see actions times the action bound
        self.action_scale = self.info.high[0] if config.action_scale == "bound" else 1.0
        learns_alpha = config.alpha_mode == "auto"  # one setting, so shared by the members
        self.agent = TacAgent(
            obs_dim,
            act_dim,
            config,
            [s.torch_seed for s in streams],
            torch.device(config.device),
            self.action_scale,
            [c.alpha for c in configs] if learns_alpha else None,
        )
        self.metrics = self.agent.metric_names
        self.buffer = ReplayBuffer(k, obs_dim, act_dim, min(config.buffer_size, config.total_steps))
        self.rngs = [np.random.default_rng(s.numpy) for s in streams]
        evaluated = config.eval_episodes if config.eval_every > 0 else 0
        say = functools.partial(print, file=sys.stderr, flush=True)
        self.envs, self.eval_envs = envs.member_envs(config.env, k, evaluated, say)
        columns = ("q", "updates", *self.metrics)
        qs = [c.q for c in configs]  # --q auto: where the population starts
        self.population = Population(self.seeds, qs, config) if config.q_mode == "auto" else None
        extra = {"pbt": PBT_COLUMNS} if self.population else {}
        self.writers = [runs.RunWriter(d, columns, config.tensorboard, extra) for d in directories]
        self.step = 0
        self.obs = np.zeros((k, obs_dim))
        self.episode_return = np.zeros(k)
        self.episode_length = np.zeros(k, dtype=np.int64)
        self.losses = LossWindow(k, len(self.metrics), self.agent.device)
        self.updates_started = np.zeros(k, dtype=bool)  # training.schedule
        self.alive = list(range(k))  # live members, kept on the host (no device sync to read)
        self.clock_offsets = [(0.0, 0.0)] * k  # each member's checkpoint's: runs.RunClock
        self.phase_seconds = dict.fromkeys(PHASES, 0.0)  # since start, not kept by checkpoints
        self.finished_length = np.zeros(k, dtype=np.int64)  # length of episodes just ended
        self.chunk_added, self.chunk_rows = 0, np.zeros(k, dtype=np.int64)
        self.replay_chunks: list[list[Path]] = [[] for _ in range(k)]  # the last generation's
        self.resume_notes: list[str] = []
        self._coefficients: tuple[tuple[float, ...], Coefficients] | None = None
        self._resume_or_start(directories)
        label = f"TAC {config.env} {members_label(configs)}"
        self.progress = Progress(label, config.total_steps, self.step, config.eval_every, quiet)
        for note in self.resume_notes:
            self.progress.message(f"{note}; resuming from step {self.step}")
        self.cpu_shares = CpuShares(len(self.configs))  # the process's CPU, split by members
        self.clocks = [  # a run begun before the split logs the whole process's (runs.clock)
            RunClock(w, c, self.cpu_shares, i) if self.writers[i].shares_cpu else RunClock(w, c)
            for i, (w, c) in enumerate(self.clock_offsets)
        ]

    # --- start and resume ----------------------------------------------------------------
    def _resume_or_start(self, directories: list[Path]) -> None:
        """Start afresh, or continue from the newest checkpoint generation that every member can
        use (:func:`checkpoints.choose`: a damaged one is passed over, and said so)."""
        folders = [d / "checkpoint" for d in directories]
        step, self.resume_notes = checkpoints.choose(folders)
        if step is not None and self.population is not None:
            self.resume_notes += check_whole_on_resume(directories[0], self.seeds, step)
        pairs = zip(self.writers, self.configs, strict=True)
        members = [{"q": c.q, "alpha": c.alpha, "seed": c.seed} for c in self.configs]
        plans = (  # every member's CSVs are checked before anything is written
            [None] * len(folders)
            if step is None
            else [w.check_resume(step, c.to_dict(), members) for w, c in pairs]
        )
        for folder in folders:  # what a resume abandons: all of a first checkpoint cut short
            checkpoints.discard_after(folder, -1 if step is None else step)
        # each note once: the members share their hardware settings and their group
        self.resume_notes += dict.fromkeys(note for plan in plans if plan for note in plan.notes)
        for writer, config, plan in zip(self.writers, self.configs, plans, strict=True):
            if self.resume_notes:
                writer.note = f"resumed from step {step or 0}: " + "; ".join(self.resume_notes)
            writer.open(
                runs.run_metadata(config, self.command, config.q, members=members)
                if plan is None  # a resumed run keeps its config.json
                else None,
                plan,
            )
        if step is None:
            for k, env in enumerate(self.envs):
                self.obs[k] = env.reset(seed=self.env_seeds[k])[0]
            self.buffer.start_episodes(range(len(self.envs)), self.obs)
            return
        loaded = [read(folder, step) for folder in folders]
        states = [state for state, _ in loaded]
        self.replay_chunks = [chunks for _, chunks in loaded]
        self.step = self.chunk_added = step
        self.agent.load_member_states([s.agent for s in states])
        for k, state in enumerate(states):
            self.buffer.restore_counters(k, state.buffer)
            self.chunk_rows[k] = state.buffer["n_rows"]  # rows added later go to a new chunk
            load_replay(self.buffer, k, self.replay_chunks[k])
            self.rngs[k].bit_generator.state = state.rng
            self.obs[k] = state.obs.numpy()
            self.envs[k].reset(seed=self.env_seeds[k])
            if state.env is not None:
                envs.set_env_state(self.envs[k], state.env)
                self.episode_return[k] = state.episode_return
                self.episode_length[k] = state.episode_length
            else:  # no exact env state (not MuJoCo): continue with a fresh episode
                self.obs[k] = self.envs[k].reset(seed=self.env_seeds[k] + self.step)[0]
                self.buffer.start_episodes([k], self.obs[k : k + 1])
            self.losses.load_member_state(k, state.loss_sum, state.loss_count)
            self.updates_started[k] = state.updates_started
        if self.population is not None:
            self.population.load_member_states([s.pbt or {} for s in states])
        self.clock_offsets = [(s.wall_s, s.cpu_s) for s in states]  # a member's own, in any group

    # --- the loop ---------------------------------------------------------------------------
    def run(self, stop: StopCheck) -> list[Outcome]:
        """Step until done, stopped or every member failed (an error: crashed); then close."""
        outcomes = list[Outcome]()
        try:
            while self.step < self.config.total_steps and self.alive:
                if stop(self.step):
                    if self.step > self.chunk_added:  # new steps since the newest generation
                        self._checkpoint()
                    return outcomes + self._finish("interrupted")
                outcomes += self.advance()
            return outcomes + self._finish("complete")
        except SecondSignal as stopped:
            stopped.resume = resume_command(self.command)
            for k in self.alive:
                self.writers[k].stopped_at_once(self.step, stopped)
            raise
        except Exception as err:
            for k in self.alive:
                self.writers[k].crashed(self.step, err)
            raise
        finally:
            self.close()

    def advance(self) -> list[Outcome]:
        """One step of every live member and what is due after it: updates, evaluation,
        checkpoint, progress. Returns the members that failed in it."""
        config = self.config
        done = self._env_step()
        outcomes = self._learn(done)
        if self.population is not None and self.population.due(self.step):
            self._pbt_round()
        eval_mean = self._maybe_evaluate()
        every = config.checkpoint_every
        if (every and self.step % every == 0) or self.step == config.total_steps:
            self._checkpoint()
        self.progress.update(self.step, eval_mean, learning=bool(self.updates_started.any()))
        return outcomes

    def close(self) -> None:
        """Close the progress display, the writers and the environments."""
        self.progress.close()
        for writer in self.writers:
            writer.close()
        for env in [*self.envs, *(e for group in self.eval_envs for e in group)]:
            env.close()

    def _finish(self, state: str) -> list[Outcome]:
        """Mark every live member complete, or interrupted (with how to resume)."""
        reason = ""
        if state == "interrupted":
            reason = f"interrupted at step {self.step}; resume with: {resume_command(self.command)}"
        outcomes = []
        for k in self.alive:
            writer = self.writers[k]
            writer.status("complete" if state == "complete" else "interrupted", self.step, reason)
            outcomes.append(Outcome(self.seeds[k], writer.directory, state, self.step, reason))
        return outcomes

    def _env_step(self) -> np.ndarray:
        """Act in each live member's env, store the transitions; return which episodes ended."""
        k_all, started = len(self.envs), time.perf_counter()
        if self.step < self.config.learning_starts:  # warm-up: uniform random actions
            draws = [rng.uniform(-1.0, 1.0, self.info.act_dim) for rng in self.rngs]
            actions: np.ndarray = np.stack(draws).astype(np.float32)
        else:
            actions = self.agent.act(self.obs)
        acted = time.perf_counter()
        self.phase_seconds["act"] += acted - started
        env_actions = envs.to_env_action(actions, self.info)
        next_obs, reward = self.obs.copy(), np.zeros(k_all)
        terminated, done = np.zeros(k_all, dtype=bool), np.zeros(k_all, dtype=bool)
        for k in self.alive:
            obs, r, term, trunc, _ = self.envs[k].step(env_actions[k])
            next_obs[k], reward[k], terminated[k], done[k] = obs, r, term, term or trunc
        if self.config.time_limits == "terminal-below-1000":  # the authors' code (docs/tac.md)
            terminated = done & (self.episode_length + 1 != 1000)
        scaled = actions if self.action_scale == 1.0 else actions * self.action_scale
        self.buffer.add(scaled, reward, terminated, next_obs)
        self.step += 1
        self.episode_return += reward
        self.episode_length += 1
        for k in np.flatnonzero(done).tolist():
            episode = float(self.episode_return[k]), int(self.episode_length[k])
            self.writers[k].train_row(self.step, self.clocks[k].wall_s, *episode)
            if self.population is not None:
                self.population.episode_ended(k, float(self.episode_return[k]))
            next_obs[k] = self.envs[k].reset()[0]
            self.buffer.start_episodes([k], next_obs[k : k + 1])
        self.obs = next_obs
        self.finished_length = self.episode_length.copy()
        self.episode_return[done] = 0.0
        self.episode_length[done] = 0
        self.phase_seconds["environments"] += time.perf_counter() - acted
        return done

    def q_of(self, k: int, step: int) -> float:
        """Member k's q at ``step``: its schedule's value, or with --q auto its q now."""
        if self.population is not None:
            return self.population.qs[k]
        return self.configs[k].q_at(step)

    def coefficients_at(self, step: int) -> Coefficients:
        """Each member's q (:meth:`q_of`) and alpha, as tensors; made again only when a q
        changes."""
        qs = tuple(self.q_of(k, step) for k in range(len(self.configs)))
        if self._coefficients is None or self._coefficients[0] != qs:
            alphas = [c.alpha for c in self.configs]
            self._coefficients = (
                qs,
                coefficients(qs, alphas, self.agent.device, self.agent.config.density_cap),
            )
        return self._coefficients[1]

    def _learn(self, done: np.ndarray) -> list[Outcome]:
        """Gradient updates due after this step (training.schedule); log losses; retire members
        whose losses blew up."""
        config, outcomes = self.config, []
        due = updates_due(config, self.step, done, self.finished_length, self.updates_started)
        due[[k for k in range(len(due)) if k not in self.alive]] = 0
        if due.any():
            c = self.coefficients_at(self.step)
            for members in rounds(due):
                subset = members.tolist() if config.per_member_updates else None
                started = time.perf_counter()
                sample = self.buffer.sample(self.rngs, config.batch_size, subset)
                sampled = time.perf_counter()
                metrics = update(self.agent, sample, c, subset)
                self.losses.add(metrics, members, every_member=subset is None)
                finite = torch.isfinite(metrics)
                all_finite = bool(finite.all())  # the common case, in one reduction
                self.phase_seconds["sample"] += sampled - started
                self.phase_seconds["update"] += time.perf_counter() - sampled
                if all_finite:
                    continue
                active = torch.as_tensor(members, device=self.agent.alive.device)
                bad = self.agent.alive & active & ~finite.all(dim=-1)
                if bad.any():
                    outcomes += self._fail(bad, metrics)
                    if not self.alive:
                        break
        if self.step % config.log_every == 0 or self.step == config.total_steps:
            for k, count, means in self.losses.close(self.alive):
                self.writers[k].losses_row(self.step, [self.q_of(k, self.step), count, *means])
        return outcomes

    def _fail(self, bad: torch.Tensor, metrics: torch.Tensor) -> list[Outcome]:
        outcomes, failed = [], torch.nonzero(bad).flatten().tolist()
        for k in failed:
            config = self.configs[k]
            values = dict(zip(self.metrics, metrics[k].tolist(), strict=True))
            names = ", ".join(n for n, v in values.items() if not np.isfinite(v))
            reason = f"non-finite {names} at step {self.step} (mean log pi {values['log_pi']:.4g})"
            if config.lnq == "joint" and self.q_of(k, self.step) > 1:
                reason += (
                    "; ln_q of a large joint density overflows float32 (docs/tac.md, "
                    "Numerics): --lnq per-dim, the reference code's form, stays finite"
                )
            reason += f"; {checkpoints.KEPT if self.chunk_added else checkpoints.NONE_KEPT}"
            self.writers[k].status("failed", self.step, reason)
            self.cpu_shares.stop(k)  # the members still training share its CPU from now
            self.progress.message(f"seed {self.seeds[k]} failed: {reason}")
            outcomes.append(
                Outcome(self.seeds[k], self.writers[k].directory, "failed", self.step, reason)
            )
        self.agent.alive &= ~bad
        self.alive = [k for k in self.alive if k not in failed]
        return outcomes

    def _pbt_round(self) -> None:
        """--q auto: one exploit/explore round (training/pbt.py), each decision in pbt.csv."""
        assert self.population is not None
        alive = [k in self.alive for k in range(len(self.configs))]
        decisions = self.population.round(alive, self.config.q_range)
        for d in decisions:
            if d.source is not None:
                self.agent.copy_member(d.source, d.member)
            self.writers[d.member].extra_row("pbt", self.population.row(self.step, d))
        moves = self.population.moves(decisions)
        if moves:
            self.progress.message(f"step {self.step}: pbt {moves}")

    def _maybe_evaluate(self) -> float | None:
        """Deterministic evaluation (reference protocol) when due; returns the mean over members."""
        every, step = self.config.eval_every, self.step
        alive, n_eps, obs_dim = list(self.alive), self.config.eval_episodes, self.info.obs_dim
        if not every or not alive or (step % every and step != self.config.total_steps):
            return None

        def policy(obs: np.ndarray) -> np.ndarray:
            full = np.zeros((len(self.envs), len(obs) // len(alive), obs_dim))
            full[alive] = obs.reshape(len(alive), -1, obs_dim)
            actions = self.agent.act_deterministic(full)[alive].reshape(len(obs), -1)
            return envs.to_env_action(actions, self.info)

        returns, lengths = envs.evaluate_members(
            policy,
            [self.eval_envs[k] for k in alive],
            [envs.eval_seeds(self.seeds[k], step, n_eps) for k in alive],
        )
        for i, k in enumerate(alive):
            self.writers[k].eval_row(step, self.clocks[k], returns[i].tolist(), lengths[i].tolist())
        return float(returns.mean())

    def _checkpoint(self) -> None:
        """Write every live member's checkpoint generation (new replay chunk, state, manifest),
        then status."""
        for k in self.alive:
            loss_sum, loss_count = self.losses.member_state(k)
            state = MemberState(
                step=self.step,
                agent=self.agent.member_state(k),
                buffer=self.buffer.counters(k),
                rng=self.rngs[k].bit_generator.state,
                env=envs.get_env_state(self.envs[k]),
                obs=torch.from_numpy(self.obs[k].copy()),
                episode_return=float(self.episode_return[k]),
                episode_length=int(self.episode_length[k]),
                loss_sum=loss_sum,
                loss_count=loss_count,
                updates_started=bool(self.updates_started[k]),
                wall_s=self.clocks[k].wall_s,
                cpu_s=self.clocks[k].cpu_s,
                pbt=None if self.population is None else self.population.member_state(k),
            )
            since = (self.chunk_added, int(self.chunk_rows[k]))
            writer = self.writers[k]
            self.replay_chunks[k] = write_checkpoint(
                writer.checkpoint_dir,
                state,
                self.buffer,
                k,
                since,
                self.replay_chunks[k],
                writer.log_digests(),
            )
            self.writers[k].status("running", self.step)
        if self.step > self.chunk_added:  # the next chunk starts where this one ended
            self.chunk_added, self.chunk_rows = self.step, self.buffer.n_rows.copy()
