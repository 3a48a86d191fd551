"""``tacbench bench``: TAC's training loop against stable-baselines3's SAC, side by side.

Every contestant trains on the same task with the paper's networks (one hidden layer of 300 ReLU
units, or ``--hidden-sizes``) and update rate (batch 100, Adam lr 1e-3, one update per
environment step, a 1M replay buffer) in this one process, under the same thread count and heap
setting (:func:`tacbench.hardware.configure_process`). After ``learning_starts`` steps of random
actions (not timed) and a few updates of warm-up (where ``torch.compile`` compiles), the
contestants take turns: each round, each one trains ``steps / rounds`` more steps while its
time is measured. Taking turns spreads a shared machine's load over all of them, so the
ratios are fairer than the absolute rates; both are reported, with the load average.

The TAC contestants run :func:`tacbench.training.stepper`, the real training loop (run
directories in a temporary folder, evaluation and checkpoints off). SB3's SAC is SAC v2 (no V
network), with a constant entropy coefficient equal to TAC's alpha.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import platform
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from tacbench import envs, paper, training
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.hardware import configure_process, cpu_class, cpu_name
from tacbench.members import make_run_configs

Advance = Callable[[int], int]
PhaseClock = Callable[[], dict[str, float]]  # seconds so far in each of training.PHASES
WARMUP_UPDATES = 50  # untimed updates after learning starts (compilation happens here)


@dataclass(frozen=True)
class Contestant:
    """One row of the table: a learner and how many members it trains at once."""

    name: str
    members: int
    tac: bool = False  # TAC, or SB3's SAC
    compile: bool = False
    qs: tuple[float, ...] = ()  # the members' q values (empty: the task's paper q for all)
    bf16: bool = False  # --matmul-precision bf16


@dataclass
class BenchResult:
    """A contestant's measured rounds: steps and seconds, one pair per round."""

    contestant: Contestant
    steps: list[int] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    phase_seconds: dict[str, float] = field(default_factory=dict)  # TAC rows: training.PHASES

    @property
    def rate(self) -> float:
        """Lockstep environment steps per second over all rounds."""
        return sum(self.steps) / sum(self.seconds)

    @property
    def member_rate(self) -> float:
        """Member-steps per second: every member takes one step per lockstep step."""
        return self.rate * self.contestant.members

    @property
    def spread(self) -> tuple[float, float]:
        """The slowest and fastest round's steps per second."""
        rates = [s / t for s, t in zip(self.steps, self.seconds, strict=True)]
        return min(rates), max(rates)

    @property
    def phase_shares(self) -> dict[str, float]:
        """Each phase's share of the measured time, then ``rest`` (empty for SB3's SAC)."""
        if not self.phase_seconds:
            return {}
        total = sum(self.seconds)
        shares = {name: seconds / total for name, seconds in self.phase_seconds.items()}
        return {**shares, "rest": 1.0 - sum(shares.values())}


@dataclass(frozen=True)
class BenchOptions:
    """What ``tacbench bench`` measures."""

    env: str = "HalfCheetah-v4"
    members: int = 10
    steps: int = 1500
    rounds: int = 5
    learning_starts: int = 1000
    compile: bool = False
    grid: bool = False
    sb3: bool = True
    eager: bool = True
    device: str = "cpu"
    threads: int = 1
    hidden_sizes: tuple[int, ...] | None = None  # None: the paper's (one layer of 300)
    bf16: bool = False  # also each TAC row with --matmul-precision bf16

    @property
    def networks(self) -> tuple[int, ...]:
        """The hidden layer widths every contestant trains with."""
        return self.hidden_sizes or paper.HYPERPARAMETERS.hidden_sizes

    def __post_init__(self) -> None:
        for name in ("members", "rounds", "threads"):
            if getattr(self, name) < 1:
                raise TacbenchError(f"--{name} must be at least 1.")
        if self.hidden_sizes is not None and (not self.hidden_sizes or min(self.hidden_sizes) < 1):
            raise TacbenchError(
                f"--hidden-sizes must be positive layer widths (got {self.hidden_sizes}); "
                "--hidden-sizes 400,300 for example."
            )
        if self.steps < self.rounds:
            raise TacbenchError("--steps must be at least --rounds (steps are split into rounds).")
        if self.steps % self.rounds:  # the remainder was dropped unsaid
            whole = self.steps - self.steps % self.rounds
            raise TacbenchError(
                f"--steps {self.steps} does not split into {self.rounds} rounds of equal steps; "
                f"give a multiple of --rounds, --steps {whole} for example."
            )
        if self.learning_starts < 1:
            raise TacbenchError("--learning-starts must be at least 1.")


def contestants(options: BenchOptions) -> list[Contestant]:
    """SB3's SAC, then TAC at K = 1 and K = ``members``: uncompiled (unless not ``eager``) and,
    with ``compile``, compiled; with ``grid``, the q grid; with ``bf16``, each TAC row (the
    grid's too) also with bfloat16 products."""
    rows = [Contestant("SB3 SAC", 1)] if options.sb3 else []
    paths = [("TAC", False)] if options.eager else []
    paths += [("TAC compiled", True)] if options.compile else []
    for k in dict.fromkeys((1, options.members)):
        for name, compiled in paths:
            rows.append(Contestant(name, k, tac=True, compile=compiled))
            if options.bf16:
                rows.append(Contestant(f"{name} bf16", k, tac=True, compile=compiled, bf16=True))
    if options.grid:  # the paper's q grid of one task in one process: 9 q x 10 seeds
        members = len(paper.Q_GRID) * len(paper.SEEDS)
        rows.append(Contestant("TAC q grid compiled", members, True, True, paper.Q_GRID))
        if options.bf16:
            rows.append(
                Contestant("TAC q grid compiled bf16", members, True, True, paper.Q_GRID, True)
            )
    return rows


def check_sizes(options: BenchOptions) -> None:
    """Refuse, before anything is built, what ``tacbench run`` refuses: more threads than
    cores, and the largest TAC group of the bench (or of ``--profile``) too big for this
    machine's memory (:func:`tacbench.training.check_sizes`), counting the replay rows the
    bench fills (its buffers reserve more, committed only as rows are written)."""
    largest = max((c.members for c in contestants(options) if c.tac), default=options.members)
    rows = options.learning_starts + WARMUP_UPDATES + options.steps
    # the members differ only in seed and q, not in what is sized: one config stands for all
    # (building each of --members 100000 took 20 s before the refusal)
    (config,) = _tac_configs(options, Contestant("TAC", 1, tac=True))
    group = [replace(config, total_steps=rows)] * largest
    flags = "--hidden-sizes or --members" + (" (or leave out --grid)" if options.grid else "")
    training.check_sizes(group, envs.env_info(options.env), flags)


def _tac_configs(options: BenchOptions, contestant: Contestant) -> list[RunConfig]:
    n_seeds = contestant.members // max(1, len(contestant.qs))
    configs, _ = make_run_configs(
        options.env,
        paper.paper_task(options.env),
        list(range(0, 10 * n_seeds, 10)),  # the paper's seeds 0, 10, 20, ...
        contestant.qs,
        learning_starts=options.learning_starts,
        eval_every=0,
        checkpoint_every=0,
        compile="on" if contestant.compile else "off",
        matmul_precision="bf16" if contestant.bf16 else "float32",
        device=options.device,
        threads=options.threads,
        **_network_overrides(options),
    )
    return configs


def _network_overrides(options: BenchOptions) -> dict[str, Any]:
    """The config override of ``--hidden-sizes``, if given (else the paper's networks)."""
    return {} if options.hidden_sizes is None else {"hidden_sizes": options.hidden_sizes}


@contextlib.contextmanager
def _sb3_sac(options: BenchOptions) -> Iterator[Advance]:
    """SB3's SAC with TAC's paper settings; advance(n) trains n more steps."""
    import warnings

    from stable_baselines3 import SAC
    from stable_baselines3.common.logger import Logger

    q_alpha = make_run_configs(
        options.env, paper.paper_task(options.env), [0], **_network_overrides(options)
    )[0][0]
    env = envs.make_env(options.env)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SB3's notes on the env wrapper and on v4 tasks
        model = SAC(
            "MlpPolicy",
            env,
            learning_rate=q_alpha.learning_rate,
            buffer_size=q_alpha.buffer_size,
            learning_starts=options.learning_starts,
            batch_size=q_alpha.batch_size,
            tau=q_alpha.tau,
            gamma=q_alpha.gamma,
            train_freq=1,
            gradient_steps=1,
            ent_coef=q_alpha.alpha,
            policy_kwargs={"net_arch": list(q_alpha.hidden_sizes)},
            seed=0,
            device=options.device,
            verbose=0,
        )

    model.set_logger(Logger(folder=None, output_formats=[]))  # not a /tmp folder per learn()

    def advance(n: int) -> int:
        model.learn(n, reset_num_timesteps=False, progress_bar=False)
        return int(model.num_timesteps)

    try:
        yield advance
    finally:
        env.close()


@contextlib.contextmanager
def _learner(
    options: BenchOptions, contestant: Contestant, out: Path
) -> Iterator[tuple[Advance, PhaseClock]]:
    if not contestant.tac:
        with _sb3_sac(options) as advance:
            yield advance, dict
        return
    directory = out / f"{contestant.name.replace(' ', '_')}-{contestant.members}"
    with training.stepper(_tac_configs(options, contestant), directory) as stepper:
        yield stepper, lambda: stepper.phase_seconds


def run_bench(options: BenchOptions, report: Callable[[str], None] = print) -> list[BenchResult]:
    """Measure every contestant in turns (see the module docstring); ``report`` gets progress
    lines. Returns one :class:`BenchResult` per contestant, in :func:`contestants` order."""
    configure_process(options.threads)
    results = [BenchResult(c) for c in contestants(options)]
    chunk = options.steps // options.rounds
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        learners = []
        for result in results:
            name = f"{result.contestant.name} K={result.contestant.members}"
            report(f"warming up {name} ...")
            advance, clock = stack.enter_context(_learner(options, result.contestant, Path(tmp)))
            advance(options.learning_starts + WARMUP_UPDATES)
            learners.append((advance, clock))
        for round_index in range(options.rounds):
            report(f"round {round_index + 1}/{options.rounds}")
            for result, (advance, clock) in zip(results, learners, strict=True):
                start, phases, t0 = advance(0), clock(), time.perf_counter()
                reached = advance(chunk)
                result.seconds.append(time.perf_counter() - t0)
                result.steps.append(reached - start)
                for phase, seconds in clock().items():
                    spent = seconds - phases[phase]
                    result.phase_seconds[phase] = result.phase_seconds.get(phase, 0.0) + spent
    return results


def machine() -> dict[str, Any]:
    """Where and when the numbers were taken."""
    return {
        "date": datetime.date.today().isoformat(),
        "cpu": cpu_name(),
        "cpu_class": cpu_class(),
        "cores": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "torch": torch.__version__,
        "python": platform.python_version(),
    }


def table(results: list[BenchResult]) -> str:
    """The side-by-side table: steps/s, member-steps/s and the ratio to SB3's SAC."""
    sb3 = next((r for r in results if not r.contestant.tac), None)
    lines = [
        "| learner | members | steps/s | member-steps/s | vs SB3 SAC | rounds (steps/s) |",
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        ratio = f"{r.member_rate / sb3.rate:.2f}x" if sb3 else "-"
        low, high = r.spread
        lines.append(
            f"| {r.contestant.name} | {r.contestant.members} | {r.rate:.0f} | "
            f"{r.member_rate:.0f} | {ratio} | {low:.0f}-{high:.0f} |"
        )
    return "\n".join(lines)


def phase_table(results: list[BenchResult]) -> str:
    """Where each TAC row's measured time went, phase by phase (training.PHASES)."""
    rows = [r for r in results if r.phase_shares]
    if not rows:
        return ""
    names = list(rows[0].phase_shares)
    lines = [
        "Where a TAC step's time goes (act: the policy's forward pass and the actions' copy to "
        "the host; environments: stepping them and storing the transitions; sample: drawing "
        "the minibatches; update: the gradient step, waited for; rest: logging, progress, "
        "Python):",
        "",
        "| learner | members | ms/step | " + " | ".join(names) + " |",
        "|---|---|---|" + "---|" * len(names),
    ]
    for r in rows:
        shares = " | ".join(f"{r.phase_shares[name]:.0%}" for name in names)
        lines.append(
            f"| {r.contestant.name} | {r.contestant.members} | {1e3 / r.rate:.2f} | {shares} |"
        )
    return "\n".join(lines)


def summary(results: list[BenchResult], options: BenchOptions, before: dict[str, Any]) -> str:
    """The table with a header that says what was measured, where and under what load."""
    after = machine()
    widths = ", ".join(str(w) for w in options.networks)
    head = (
        f"{options.env}, batch 100, ReLU hidden layers ({widths}), one update per step, "
        f"{options.threads} torch thread(s), device {options.device}; {options.rounds} rounds of "
        f"{options.steps // options.rounds} steps after {options.learning_starts} "
        f"random steps and {WARMUP_UPDATES} warm-up updates.\n"
        f"{after['date']}, {after['cpu']}, {after['cores']} cores; load average "
        f"{before['load_average']} at start, {after['load_average']} at end "
        "(a load above the thread count means other work shared the cores)."
    )
    phases = phase_table(results)
    return f"{head}\n\n{table(results)}" + (f"\n\n{phases}" if phases else "")


def results_json(
    results: list[BenchResult], options: BenchOptions, before: dict[str, Any]
) -> dict[str, Any]:
    """Everything measured, for the record: the options (with the networks trained), and the
    machine at the start (``before``, from :func:`machine`) and at the end."""
    return {
        "options": {**asdict(options), "networks": list(options.networks)},
        "machine": {"at start": before, "at end": machine()},
        "results": [
            {
                **asdict(r.contestant),
                "steps": r.steps,
                "seconds": r.seconds,
                "steps_per_s": r.rate,
                "member_steps_per_s": r.member_rate,
                "phase_seconds": r.phase_seconds,
            }
            for r in results
        ],
    }
