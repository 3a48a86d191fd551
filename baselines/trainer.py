"""Train baselines into TAC's run directories: plan, start or resume, learn, end cleanly.

:func:`train` is the baselines' counterpart of :func:`tacbench.training.train`, with the same
interface and outcomes: it plans every seed's run directory first (start, resume, skip, refuse;
:func:`tacbench.runs.planned_runs`, which also locks them), then trains the seeds one after
another (SB3 trains one model per process), each through
:class:`baselines.callbacks.RunCallback`. The evaluation protocol is TAC's own function
(:func:`tacbench.envs.evaluate` with :func:`tacbench.envs.eval_seeds`): deterministic actions,
one episode on each of ``eval_episodes`` separate env instances.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecNormalize

from baselines import algos, checkpoint, hyperparams
from baselines.callbacks import Diverged, Interrupted, LossLogger, RunCallback
from baselines.config import SB3_N_STEPS, BaselineConfig
from tacbench import envs, memory, paper, runs
from tacbench.errors import TacbenchError
from tacbench.hardware import configure_process
from tacbench.interrupts import SecondSignal, StopCheck, resume_command, stop_signals
from tacbench.progress import Progress
from tacbench.runs import Outcome, RunClock, checkpoints, planned_runs, read_status
from tacbench.runs.checkpoints import disk_errors


def metadata(config: BaselineConfig, command: str) -> dict[str, Any]:
    """config.json's content for ``config``; ``hp_overrides`` lists where its hyperparameters
    differ from the table's values for its environment."""
    table, _ = hyperparams.resolve(config.algo, config.env, paper.paper_task(config.env))
    overrides = {k: v for k, v in config.hyperparams.items() if table.get(k) != v}
    return runs.run_metadata(
        config,
        command,
        None,
        hp_overrides=overrides,
        hyperparams_file=f"baselines/hyperparams/{config.algo}.yaml",
    )


def train(
    configs: Sequence[BaselineConfig],
    out: Path,
    *,
    resume: bool = False,
    force: bool = False,
    quiet: bool = False,
    command: str = "",
    stop: StopCheck | None = None,
) -> list[Outcome]:
    """:meth:`tacbench.trainers.Trainer.train` for a baseline: the seeds train one after the
    other; ``stop`` is polled at every boundary (each step off-policy, each rollout for
    PPO/TRPO), and after an interruption later seeds are not started."""
    if not configs or len({c.seed for c in configs}) != len(configs):
        raise TacbenchError("give each baseline run a different seed.")
    info = envs.env_info(configs[0].env)  # an unusable task fails before any directory is touched
    for config in configs:
        check_sizes(config, info)
    with (
        disk_errors("the run's files"),
        stop_signals() as received,
        planned_runs(configs, out, resume=resume, force=force) as (outcomes, active),
    ):
        for k, (config, directory) in enumerate(active):
            configure_process(config.threads)
            run = _Run(config, directory, command, quiet)
            try:
                outcome = run.learn(
                    lambda step: bool(received) or (stop is not None and stop(step))
                )
            except SecondSignal as stopped:
                stopped.resume = resume_command(command)
                run.writer.stopped_at_once(run.model.num_timesteps, stopped)
                raise
            except Exception as err:
                run.writer.crashed(run.model.num_timesteps, err)
                raise
            outcomes.append(outcome)
            if outcome.state == "interrupted":
                outcomes += [  # named, so that the stop's report covers every seed
                    Outcome(later.seed, path, "interrupted", _step(path), _NOT_REACHED)
                    for later, path in active[k + 1 :]
                ]
                break
    return sorted(outcomes, key=lambda o: o.seed)


_NOT_REACHED = "the stop came before this seed's turn; the resume command trains it"


def _step(directory: Path) -> int:
    """Where a run not reached stands: its status.json's step, 0 if it has not started."""
    return int(read_status(directory)["step"]) if (directory / "config.json").exists() else 0


def check_sizes(config: BaselineConfig, info: envs.EnvInfo) -> None:
    """Refuse, before anything is written, a run whose networks, minibatches and buffer (SB3's
    replay buffer, allocated whole, of float32 observations (:mod:`baselines.algos` casts
    them) with each transition's s' stored apart; or the on-policy rollout) would not
    fit this machine's memory, or more threads than it has cores (:mod:`tacbench.memory`)."""
    memory.check_threads(config.threads)
    hp = config.hyperparams  # where a table leaves a size out, SB3's default stands in
    arch = hp.get("net_arch") or [64, 64]
    widths = [
        int(w) for part in (arch.values() if isinstance(arch, dict) else [arch]) for w in part
    ]
    needs = memory.actor_critic_bytes(
        info.obs_dim, info.act_dim, widths, int(hp.get("batch_size", 256)), value_network=False
    )
    obs, act = info.obs_dim * memory.FLOAT32, info.act_dim * memory.FLOAT32
    if config.off_policy:
        rows = min(int(hp.get("buffer_size", 1_000_000)), config.total_steps)  # as built
        # s, s', the action, and the reward, done and timeout flags (float32 each)
        needs["the replay buffer"] = rows * (2 * obs + act + 3 * memory.FLOAT32)
    else:
        needs["the rollout"] = int(hp.get("n_steps", SB3_N_STEPS)) * (
            obs + act + 6 * memory.FLOAT32
        )
    if config.eval_every > 0:  # --eval-every 0 evaluates nothing
        needs["an evaluation"] = memory.evaluation_bytes(config.eval_episodes)
    memory.check_fits(
        needs, "--hp net_arch, batch_size, buffer_size or n_steps, or --eval-episodes"
    )


class _Run:
    """One baseline run: its model, environments, writer and checkpoints."""

    def __init__(
        self,
        config: BaselineConfig,
        directory: Path,
        command: str,
        quiet: bool,
    ) -> None:
        self.config, self.command = config, command
        self.writer = runs.RunWriter(directory, algos.loss_columns(config), config.tensorboard)
        self.losses = LossLogger(algos.loss_columns(config))
        self.dummy, self.venv = algos.make_training_env(config)
        self.eval_envs = [
            envs.make_env(config.env)
            for _ in range(envs.eval_pool_size(config.eval_episodes) if config.eval_every else 0)
        ]
        folder = directory / "checkpoint"
        state, self.chunks, notes = checkpoint.load(folder)
        if state is None:  # SB3 refuses some settings as it builds: before anything is written
            self.model = algos.build_model(config, self.venv)
            self.writer.open(metadata(config, command), None)
            self.step, offsets = 0, (0.0, 0.0)
        else:
            step = int(state["step"])
            plan = self.writer.check_resume(step, config.to_dict())
            checkpoints.discard_after(folder, step)  # only once the CSVs can continue
            notes += plan.notes
            if notes:
                self.writer.note = f"resumed from step {step}: " + "; ".join(notes)
            self.writer.open(None, plan)
            self.model = checkpoint.restore(
                config,
                self.writer.checkpoint_dir,
                state,
                self.chunks,
                self.dummy,
                self.venv,
                self.losses,
            )
            self.step = int(state["step"])
            offsets = float(state["wall_s"]), float(state.get("cpu_s", 0.0))
        self.model.set_logger(self.losses)
        self.checkpoint_step = self.step
        label = f"{algos.DISPLAY_NAMES[config.algo]} {config.env} seed {config.seed}"
        self.progress = Progress(label, config.total_steps, self.step, config.eval_every, quiet)
        for note in notes:
            self.progress.message(f"{note}; resuming from step {self.step}")
        self.clock = RunClock(*offsets)  # a checkpoint without cpu_s predates the CPU clock

    def evaluate(self, step: int) -> float:
        """TAC's evaluation protocol on the current policy; writes the eval.csv row."""
        normalizer = self.venv if isinstance(self.venv, VecNormalize) else None

        def policy(obs: np.ndarray) -> np.ndarray:
            if normalizer is not None:
                normalized = normalizer.normalize_obs(obs)
                assert isinstance(normalized, np.ndarray)
                obs = normalized
            actions, _ = self.model.predict(obs, deterministic=True)
            return np.asarray(actions, dtype=np.float64)

        seeds = envs.eval_seeds(self.config.seed, step, self.config.eval_episodes)
        [returns], [lengths] = envs.evaluate_members(policy, [self.eval_envs], [seeds])
        self.writer.eval_row(step, self.clock, returns.tolist(), lengths.tolist())
        return float(returns.mean())

    def save(self, step: int) -> None:
        """Checkpoint at ``step`` (a boundary) and record it in status.json."""
        self.chunks = checkpoint.save(
            self.writer.checkpoint_dir,
            step,
            self.checkpoint_step,
            self.model,
            self.dummy,
            self.venv,
            self.losses,
            self.clock,
            self.chunks,
            self.writer.log_digests(),
        )
        self.checkpoint_step = step
        self.writer.status("running", step)

    def learn(self, stop: StopCheck) -> Outcome:
        """Train to ``total_steps`` or until stopped or diverged; close everything."""
        config, directory = self.config, self.writer.directory
        callback = RunCallback(
            total_steps=config.total_steps,
            eval_every=config.eval_every,
            checkpoint_every=config.checkpoint_every,
            log_every=config.log_every,
            on_policy=not config.off_policy,
            writer=self.writer,
            progress=self.progress,
            losses=self.losses,
            evaluate=self.evaluate,
            checkpoint=self.save,
            stop=stop,
            wall_s=lambda: self.clock.wall_s,
        )
        try:
            self.model.learn(
                total_timesteps=config.total_steps - self.step,
                callback=callback,
                reset_num_timesteps=self.step == 0,
            )
        except Interrupted as stopped:
            step = int(stopped.args[0])
            reason = f"interrupted at step {step}; resume with: {resume_command(self.command)}"
            self.writer.status("interrupted", step, reason)
            return Outcome(config.seed, directory, "interrupted", step, reason)
        except (Diverged, ValueError) as err:
            if isinstance(err, ValueError) and "invalid values" not in str(err):
                raise
            step = self.model.num_timesteps
            kept = checkpoints.newest_step(self.writer.checkpoint_dir) is not None
            left = checkpoints.KEPT if kept else checkpoints.NONE_KEPT
            reason = f"{_divergence(err, step)}; {left}"
            self.writer.status("failed", step, reason)
            self.progress.message(f"seed {config.seed} failed: {reason}")
            return Outcome(config.seed, directory, "failed", step, reason)
        finally:
            self._close()
        self.writer.status("complete", config.total_steps)
        return Outcome(config.seed, directory, "complete", config.total_steps)

    def _close(self) -> None:
        self.progress.close()
        self.writer.close()
        self.venv.close()
        for env in self.eval_envs:
            env.close()


def _divergence(err: Exception, step: int) -> str:
    if isinstance(err, Diverged):
        return str(err)
    # torch.distributions refuses NaN parameters: the policy's weights are no longer finite
    return f"non-finite policy output at step {step} ({str(err).splitlines()[0][:120]})"


def policy(
    config_data: dict[str, Any], folder: Path, state: dict[str, Any]
) -> Callable[[np.ndarray], np.ndarray]:
    """:meth:`tacbench.trainers.Trainer.policy` for a baseline: SB3's deterministic
    ``predict``, one observation at a time, with the run's observation normaliser."""
    config = BaselineConfig(**{**config_data, "device": "cpu"})
    model = algos.ALGORITHMS[config.algo].load(folder / state["model"], device="cpu")
    _, venv = algos.make_training_env(config)  # only its observation normaliser is used
    checkpoint.set_normalizer_state(venv, state["normalize"])

    def act(obs: np.ndarray) -> np.ndarray:
        observation = obs[None]  # as the evaluation does
        if isinstance(venv, VecNormalize):
            observation = np.asarray(venv.normalize_obs(observation))
        actions, _ = model.predict(observation, deterministic=True)
        return np.asarray(actions, dtype=np.float64)[0]

    return act
