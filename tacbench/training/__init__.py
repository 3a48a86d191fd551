"""Train TAC into run directories: :func:`train` (what ``tacbench run`` and the sweep call) and
:func:`stepper` (for benchmarks and profiles).

:func:`train` takes the configs of K members, plans each run directory (start, resume, skip;
:func:`tacbench.runs.planned_runs`), and trains the members in lockstep as one group
(:class:`loop.GroupTrainer`). Each member's checkpoint (:mod:`checkpoint`) holds everything its
continuation depends on: weights, Adam moments, generators, the env's exact state (MuJoCo), the
episode in progress, the partial losses window and the replay buffer, the latter written
incrementally (only what was added since the previous checkpoint).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from tacbench import envs, memory, runs
from tacbench.config import RunConfig
from tacbench.config_checks import check_alpha_target
from tacbench.errors import TacbenchError
from tacbench.hardware import check_matmul_precision, configure_process
from tacbench.interrupts import StopCheck, stop_signals
from tacbench.members import resolve_compile
from tacbench.runs import Outcome, planned_runs
from tacbench.runs.checkpoints import disk_errors, recorded_members
from tacbench.training.loop import LOSS_COLUMNS, PHASES, GroupTrainer

__all__ = ["LOSS_COLUMNS", "PHASES", "Stepper", "policy", "resolve_device", "stepper", "train"]


def resolve_device(name: str) -> str:
    """``cpu``, ``cuda`` or ``auto`` (cuda when available) -> a usable device name."""
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise TacbenchError("--device cuda: no CUDA device is visible here; use --device cpu.")
    return name


MEMBER_FIELDS = ("q", "alpha", "seed")  # what the members of one group may differ in


def check_members(configs: Sequence[RunConfig]) -> None:
    """The members of one group share every setting but q, alpha and the seed, and no two are
    the same run; else a TacbenchError names what differs."""
    if not configs:
        raise TacbenchError("give at least one member to train.")
    first = configs[0].to_dict()
    for config in configs[1:]:
        differing = runs.differing_fields(first, config.to_dict(), MEMBER_FIELDS)
        if differing:
            raise TacbenchError(
                "the members of one process may differ only in q, alpha and the seed; these "
                f"differ: {'; '.join(differing)}. Train them in separate commands."
            )
    identities = [(c.q, c.alpha, c.seed) for c in configs]
    if len(set(identities)) != len(identities):
        raise TacbenchError("two members are the same run (same q, alpha and seed).")
    places: dict[tuple[str, int], RunConfig] = {}
    for config in configs:  # the variant names q and alpha to 6 significant digits
        other = places.setdefault((config.variant, config.seed), config)
        if other is not config:
            raise TacbenchError(
                f"two members would share the run directory {config.variant}/seed{config.seed}: "
                f"q {other.q!r} and {config.q!r}, alpha {other.alpha!r} and {config.alpha!r} "
                "differ only beyond the 6 significant digits its name keeps; give values that "
                "differ within them."
            )


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
    """:meth:`tacbench.trainers.Trainer.train` for TAC: the members ``configs`` (equal but for
    q, alpha and the seed) train in lockstep as one group; ``stop`` is polled before every
    step."""
    configs = _in_recorded_order(out, configs) if resume else list(configs)
    recorded = [_recorded_compile(out, c) for c in configs] if resume else []
    started = next((value for value in recorded if value is not None), None)
    configs = [resolve_compile(c, started) for c in configs]  # a group shares one value
    check_members(configs)
    info = envs.env_info(configs[0].env)  # an unusable task fails before any directory is touched
    check_sizes(configs, info)
    for config in configs:
        check_alpha_target(config, info.act_dim)
    check_matmul_precision(configs[0].matmul_precision, resolve_device(configs[0].device))
    with (
        disk_errors("the run's files"),
        planned_runs(configs, out, resume=resume, force=force) as (outcomes, active),
    ):
        if active:
            configure_process(active[0][0].threads)
            trainer = GroupTrainer([c for c, _ in active], [d for _, d in active], command, quiet)
            with stop_signals() as received:
                outcomes += trainer.run(
                    lambda step: bool(received) or (stop is not None and stop(step))
                )
    return sorted(outcomes, key=lambda o: o.seed)


def _in_recorded_order(out: Path, configs: Sequence[RunConfig]) -> list[RunConfig]:
    """The members in the order their config.json records, where it lists these members: the
    order of a group's members is part of its rounding, so the same members given in another
    order resume as they trained (another group keeps the command's order, and its resume says
    that the group changed). A ``--q auto`` member resumes at the q it started from, which its
    place among the first command's seeds set (another order, or a seed left out, gave each
    member another q: a refusal naming a q the user never gave)."""
    for config in configs:
        path = runs.run_directory(out, config.algo, config.env, config.variant, config.seed)
        recorded = recorded_members(path)
        if recorded is None:
            continue  # none yet, or unreadable: planning says what to do about the latter
        if not all(isinstance(m, dict) for m in recorded):
            return list(configs)
        members = list(configs)
        if members[0].q_mode == "auto":  # a member starts at the q of its place among --seed
            start = {m.get("seed"): m.get("q") for m in recorded}
            members = [
                dataclasses.replace(c, q=float(start[c.seed]))
                if isinstance(start.get(c.seed), int | float)
                else c
                for c in members
            ]
        order = [(m.get("q"), m.get("alpha"), m.get("seed")) for m in recorded]
        if len(order) != len(members) or set(order) != {(c.q, c.alpha, c.seed) for c in members}:
            return members
        return sorted(members, key=lambda c: order.index((c.q, c.alpha, c.seed)))
    return list(configs)


def _recorded_compile(out: Path, config: RunConfig) -> str | None:
    """The ``compile`` a run directory's ``config.json`` recorded, if it has one."""
    path = runs.run_directory(out, config.algo, config.env, config.variant, config.seed)
    path = path / "config.json"
    if not path.exists():
        return None
    try:
        recorded = runs.read_json(path).get("config", {}).get("compile")
    except (OSError, ValueError, AttributeError):
        return None  # planning reports an unreadable config.json with what to do
    return recorded if isinstance(recorded, str) else None


def check_sizes(
    configs: Sequence[RunConfig],
    info: envs.EnvInfo,
    flags: str = "--hidden-sizes, --batch-size, --buffer-size or --eval-episodes (or the members)",
) -> None:
    """Refuse, before anything is written, a group whose networks, minibatches and replay
    buffer would not fit this machine's memory, or that asks for more threads than it has
    cores (:mod:`tacbench.memory`); the refusal names ``flags`` as what to make smaller."""
    config = configs[0]
    memory.check_threads(config.threads)
    needs = memory.actor_critic_bytes(
        info.obs_dim, info.act_dim, config.hidden_sizes, config.batch_size, len(configs)
    )
    rows = min(config.buffer_size, config.total_steps)
    row_bytes = (info.obs_dim + info.act_dim + 2) * memory.FLOAT32 + 16  # + the (s, s') index
    needs["the replay buffer"] = len(configs) * rows * row_bytes
    if config.eval_every > 0:  # --eval-every 0 builds no evaluation envs
        needs["an evaluation"] = memory.evaluation_bytes(config.eval_episodes, len(configs))
    memory.check_fits(needs, flags)


class Stepper:
    """What :func:`stepper` yields: ``stepper(n)`` advances the members by n steps (fewer at the
    end or when all have failed) and returns the step reached."""

    def __init__(self, trainer: GroupTrainer):
        self._trainer = trainer

    def __call__(self, n: int) -> int:
        trainer = self._trainer
        for _ in range(n):
            if trainer.step >= trainer.config.total_steps or not trainer.alive:
                break
            trainer.advance()
        return trainer.step

    @property
    def phase_seconds(self) -> dict[str, float]:
        """Seconds spent so far in each of :data:`loop.PHASES` (a copy)."""
        return dict(self._trainer.phase_seconds)


@contextmanager
def stepper(configs: Sequence[RunConfig], out: Path) -> Iterator[Stepper]:
    """For benchmarks and profiles: fresh members ``configs`` (run directories under ``out``),
    advanced by the :class:`Stepper` it yields. No signal handling; everything is closed on
    exit."""
    configs = [resolve_compile(c) for c in configs]
    check_matmul_precision(configs[0].matmul_precision, resolve_device(configs[0].device))
    directories = [runs.run_directory(out, c.algo, c.env, c.variant, c.seed) for c in configs]
    configure_process(configs[0].threads)
    trainer = GroupTrainer(list(configs), directories, "", quiet=True)
    try:
        yield Stepper(trainer)
    finally:
        trainer.close()


def policy(
    config_data: dict[str, Any], folder: Path, state: dict[str, Any]
) -> Callable[[np.ndarray], np.ndarray]:
    """:meth:`tacbench.trainers.Trainer.policy` for TAC: the member's deterministic action
    tanh(mu), one observation at a time, on the CPU."""
    import torch

    from tacbench.tac.agent import TacAgent

    config = RunConfig.from_dict({**config_data, "compile": "off"})  # one forward per frame
    info = envs.env_info(config.env)
    scale = info.high[0] if config.action_scale == "bound" else 1.0
    agent = TacAgent(info.obs_dim, info.act_dim, config, [config.seed], torch.device("cpu"), scale)
    agent.load_member_states([state["agent"]])

    def act(obs: np.ndarray) -> np.ndarray:
        return envs.to_env_action(agent.act_deterministic(obs[None, None])[0, 0], info)

    return act
