"""What the tests share: tiny configs of every learner, training them quietly, comparing run
directories, running ``tacbench`` in a child process that a signal can interrupt, small TAC
agents and random minibatches for them, and waiting for a condition on a child process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import torch

from tacbench import trainers
from tacbench.config import RunConfig
from tacbench.paper import paper_task
from tacbench.regress.manifest import without_clocks
from tacbench.runs import Outcome
from tacbench.tac.agent import TacAgent
from tacbench.tac.maths import Batch

if TYPE_CHECKING:
    from tacbench.trainers import AnyConfig

STUDIES = Path(__file__).resolve().parents[1] / "results" / "studies"
"""The published studies."""
Q_GRID_STUDIES = {
    "HalfCheetah-v4": "paper-q-grid-100k",
    "Hopper-v4": "paper-q-grid-100k",
    "Ant-v4": "paper-q-grid-100k-ant",
    "Swimmer-v4": "paper-q-grid-100k-swimmer",
    "Pusher-v5": "paper-q-grid-100k-pusher",
    "Humanoid-v4": "paper-q-grid-100k-humanoid",
}
"""Each task's q-grid study under :data:`STUDIES`, in the paper's panel order; the comparison
study copies its TAC runs from these."""

RESULT_CSVS = ("eval.csv", "train.csv", "losses.csv")

# Tiny budgets: 1,500 steps, evaluation (2 episodes) and a checkpoint every 500, losses every
# 250; TAC and the off-policy baselines learn from step 1,000 with minibatches of 32; PPO and
# TRPO roll out 512 steps, so the third rollout is cut short by the budget (not trained on).
TINY_RUN = {
    "total_steps": 1500,
    "eval_every": 500,
    "eval_episodes": 2,
    "checkpoint_every": 500,
    "log_every": 250,
}
TINY_TAC = {"learning_starts": 1000, "batch_size": 32}
TINY_HP = {
    "ddpg": ("learning_starts=1000", "batch_size=32"),
    # TD3's table networks, (400, 300), made its tiny runs the suite's slowest; the exact
    # regression tier and tests/test_baselines_models.py train and check the table's size
    "td3": ("learning_starts=1000", "batch_size=32", "net_arch=[64, 64]"),
    "sac-sb3": ("learning_starts=1000", "batch_size=32"),
    # ent_coef: with the table's 0 (RL Zoo's MuJoCo default since 2026-12-04) a PPO run stopped
    # at 1,234 steps and resumed logs its second policy_gradient_loss 1 float32 ulp away from
    # the uninterrupted run's (2.3e-10), unless MKL_CBWR=AUTO makes MKL's products independent
    # of the operands' alignment (docs/notes/open-questions.md)
    "ppo": ("n_steps=512", "batch_size=64", "n_epochs=2", "ent_coef=0.00229519"),
    "trpo": ("n_steps=512", "batch_size=64", "n_critic_updates=2"),
}
# every learner: TAC (both critic targets) and each baseline, as (algo, TAC settings) ids
LEARNERS = ("tac", "tac-twinq", "ddpg", "td3", "sac-sb3", "ppo", "trpo")


def tac_agent(
    obs: int,
    act: int,
    seeds: Sequence[int],
    *,
    env: str = "Hopper-v4",
    q: float = 1.5,
    alpha: float = 0.2,
    hidden_sizes: tuple[int, ...] | None = (16,),
    initial_alphas: Sequence[float] | None = None,
    **settings: Any,
) -> TacAgent:
    """A TAC agent with a member per seed of ``seeds``, for ``obs``-dimensional observations and
    ``act``-dimensional actions: ``env``'s config at ``q`` and ``alpha``, with networks of
    ``hidden_sizes`` (None: the config's default), not compiled, and ``settings`` (RunConfig
    fields) on top; on the config's device (the CPU unless ``settings`` name another)."""
    sizes = {} if hidden_sizes is None else {"hidden_sizes": hidden_sizes}
    config = RunConfig(env=env, q=q, alpha=alpha, **{"compile": "off", **sizes, **settings})
    device = torch.device(config.device)
    return TacAgent(obs, act, config, list(seeds), device, initial_alphas=initial_alphas)


def random_batch(
    k: int,
    b: int,
    obs: int,
    act: int,
    *,
    seed: int = 0,
    terminal: float = 0.0,
    obs_scale: float = 1.0,
    noise_scale: float = 1.0,
) -> tuple[Batch, torch.Tensor]:
    """A minibatch ``(k, b, ...)`` of normal observations (standard deviation ``obs_scale``) and
    standard-normal rewards, uniform actions in [-1, 1] and a ``terminal`` fraction of terminal
    transitions, and normal reparameterisation noise ``(k, b, act)`` (standard deviation
    ``noise_scale``), all from one generator seeded with ``seed``."""
    g = torch.Generator().manual_seed(seed)
    batch = Batch(
        obs=torch.randn(k, b, obs, generator=g) * obs_scale,
        action=torch.rand(k, b, act, generator=g) * 2 - 1,
        reward=torch.randn(k, b, generator=g),
        next_obs=torch.randn(k, b, obs, generator=g) * obs_scale,
        terminated=(torch.rand(k, b, generator=g) < terminal).float()
        if terminal
        else torch.zeros(k, b),
    )
    return batch, torch.randn(k, b, act, generator=g) * noise_scale


def random_minibatch(
    k: int, b: int, obs: int, act: int, *, seed: int = 0, terminal: float = 0.0
) -> dict[str, np.ndarray]:
    """The minibatch of :func:`random_batch` as the replay buffer hands one to ``update``: a
    float32 NumPy array per field."""
    batch, _ = random_batch(k, b, obs, act, seed=seed, terminal=terminal)
    return {name: getattr(batch, name).numpy() for name in Batch._fields}


def assert_close_per_member(
    ours: torch.Tensor, reference: torch.Tensor, rtol: float, name: str
) -> None:
    """Equal, member by member (the leading dimension), up to ``rtol`` of that member's largest
    finite magnitude in the reference (float32 rounding), and non-finite where the reference
    overflowed (the joint ln_q's float32 overflow below q = 2, docs/tac.md, may give inf in one
    path and nan in the other). Each member has its own scale: a q = 3 member's values reach
    1e14, which would leave a q = 1 member's unchecked under one shared scale."""
    finite = torch.isfinite(reference)
    assert torch.equal(torch.isfinite(ours), finite), (name, "overflows in one path only")
    for k in range(reference.shape[0]):
        if not finite[k].any():
            continue
        scale = reference[k][finite[k]].abs().max().item()
        error = (ours[k][finite[k]] - reference[k][finite[k]]).abs().max().item()
        assert error <= rtol * max(scale, 1e-12), (name, k, error, scale)


def tiny_configs(
    learner: str,
    env: str = "Hopper-v4",
    seeds: Sequence[int] = (0,),
    *,
    q: float | None = 1.5,
    alpha: float | None = 0.2,
    qs: Sequence[float] = (),
    **settings: Any,
) -> list[AnyConfig]:
    """Tiny-budget configs of ``learner`` (one of :data:`LEARNERS`) on ``env``, one per seed;
    ``settings`` replace the tiny ones; q (or several, ``qs``), alpha and TAC settings apply to
    TAC only (None: the paper's q or alpha for the task)."""
    algo = "tac" if learner.startswith("tac") else learner
    run = {k: v for k, v in {**TINY_RUN, **settings}.items() if k not in TINY_TAC}
    if algo == "tac":
        tac = {**TINY_TAC, **settings}
        if learner == "tac-twinq":
            tac["critic_target"] = "twin-q"
        configs, _ = trainers.make_configs(
            algo,
            env,
            paper_task(env),
            seeds,
            {**run, **tac},
            qs=qs or ([] if q is None else [q]),
            alphas=() if alpha is None else [alpha],
        )
    else:
        configs, _ = trainers.make_configs(algo, env, paper_task(env), seeds, run, hp=TINY_HP[algo])
    return configs


def train(out: Path, configs: Sequence[AnyConfig], **kwargs: Any) -> list[Outcome]:
    """Train ``configs`` into ``out`` without a progress display."""
    trainer = trainers.trainer_for(configs[0].algo)
    return trainer.train(list(configs), out, quiet=True, **kwargs)


def results_of(run: Path) -> dict[str, str]:
    """A run directory's CSVs as text without their clock columns (wall_s, cpu_s)."""
    return {name: without_clocks((run / name).read_text()) for name in RESULT_CSVS}


def assert_same_results(a: Path, b: Path) -> None:
    """Two run directories wrote the same CSVs, apart from their clocks."""
    ours, theirs = results_of(a), results_of(b)
    for name in RESULT_CSVS:
        assert ours[name] == theirs[name], name


def start_cli(
    args: Sequence[str], *, env: Mapping[str, str] | None = None, session: bool = False
) -> subprocess.Popen[str]:
    """``tacbench ARGS`` started in a child process (``env`` added to the environment), its
    output and errors in one unbuffered text pipe; ``session``: in a process group of its own,
    so that ``os.killpg`` reaches it and its workers."""
    return subprocess.Popen(
        [sys.executable, "-m", "tacbench", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
        start_new_session=session,
        preexec_fn=_hangup_as_default,
    )


def _hangup_as_default() -> None:
    """In the child, before tacbench starts: SIGHUP's default action. Tests run under nohup
    pass their ignored SIGHUP on, which tacbench then keeps ignored (as nohup asks), so the
    hangup tests failed there."""
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def interrupt_cli(
    args: Sequence[str],
    when: str,
    *,
    signals: Sequence[int] = (signal.SIGINT,),
    gap: float = 0.0,
    env: Mapping[str, str] | None = None,
    timeout: float = 60.0,
) -> tuple[int, str]:
    """Run ``tacbench ARGS`` in a child process (``env`` added to the environment), send it
    ``signals`` one after the other (``gap`` seconds apart) once a line of its output contains
    ``when``; its exit status and everything it printed."""
    proc = start_cli(args, env=env)
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if when in line:
            for number, sig in enumerate(signals):
                if number:
                    time.sleep(gap)
                proc.send_signal(sig)
            break
    seen.append(proc.stdout.read())
    return proc.wait(timeout=timeout), "".join(seen)


def wait_for(
    condition: Callable[[], bool],
    *,
    timeout: float,
    proc: subprocess.Popen[str] | None = None,
    poll: float = 0.02,
    what: str = "the condition",
) -> None:
    """Return once ``condition()`` holds, checking every ``poll`` seconds; fail the test after
    ``timeout`` seconds, or as soon as ``proc`` (when given) has ended first."""
    deadline = time.monotonic() + timeout
    while not condition():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the process ended before {what} held")
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(poll)


def run_status(run: Path) -> dict[str, Any]:
    """A run directory's status.json, or {} while it is missing or being replaced."""
    try:
        return dict(json.loads((run / "status.json").read_text()))
    except (OSError, json.JSONDecodeError):
        return {}


def last_logged_step(csv: Path) -> int:
    """The step of a CSV's last row (-1 before its first row, or while it cannot be read)."""
    try:
        lines = csv.read_text().splitlines()
        return int(lines[-1].split(",")[0]) if len(lines) > 1 else -1
    except (OSError, ValueError):
        return -1


def past_checkpoint(run: Path, at_least: int) -> Callable[[], bool]:
    """For :func:`wait_for`: true once ``run`` checkpointed at ``at_least`` or later and logged
    a losses row after it (rows that a resumed run must cut away)."""

    def check() -> bool:
        step = run_status(run).get("step", 0)
        return bool(step >= at_least and last_logged_step(run / "losses.csv") > step)

    return check


def run_cli(args: Sequence[str]) -> subprocess.CompletedProcess[str]:
    """Run ``tacbench ARGS`` in a child process to the end."""
    command = [sys.executable, "-m", "tacbench", *args]
    return subprocess.run(command, capture_output=True, text=True, check=False)


def checkpoint_state(run: Path) -> dict[str, Any]:
    """The state (``state-<step>.pt``) of run directory ``run``'s newest checkpoint."""
    folder = run / "checkpoint"
    step = max(int(p.stem.split("-")[1]) for p in folder.glob("manifest-*.json"))
    state: dict[str, Any] = torch.load(folder / f"state-{step:012d}.pt", weights_only=True)
    return state


def assert_tensorboard_matches_csvs(run: Path) -> None:
    """Run directory ``run``'s TensorBoard events, as TensorBoard reads them (purged points
    left out), hold exactly the rows of its CSVs: one point per row and column, no step twice."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    board = EventAccumulator(str(run / "tensorboard"), size_guidance={"scalars": 0})
    board.Reload()
    columns = {
        "eval": {"return_mean": "return", "return_std": "return_std", "length_mean": "length"},
        "train": {"return": "episode_return", "length": "episode_length"},
    }
    for group in ("eval", "train", "losses"):
        # pandas' default parser may miss a value's last bit, which can move it across a
        # float32 rounding boundary: the round-trip parser reads back exactly what was written
        rows = pd.read_csv(run / f"{group}.csv", float_precision="round_trip")
        names = columns.get(group, {c: c for c in rows.columns if c != "step"})
        for column, tag in names.items():
            points = board.Scalars(f"{group}/{tag}") if len(rows) else []
            assert [p.step for p in points] == rows["step"].tolist(), f"{group}/{tag}"
            expected = rows[column].to_numpy(dtype=np.float32)
            got = np.array([p.value for p in points], dtype=np.float32)
            np.testing.assert_array_equal(got, expected, err_msg=f"{group}/{tag}")


def smoke_tac_unit() -> list[Any]:
    """The configs of the smoke preset's TAC unit (Hopper, q = 1 and 2, seeds 0 and 10), as
    ``tacbench sweep --preset smoke --algo tac --workers 1`` plans it."""
    from tacbench.members import make_run_configs

    configs, _ = make_run_configs(
        "Hopper-v4",
        "Hopper",
        [0, 10],
        qs=[1.0, 2.0],
        total_steps=1000,
        learning_starts=500,
        batch_size=32,
        eval_every=500,
        eval_episodes=2,
        log_every=250,
        checkpoint_every=500,
    )
    return list(configs)
