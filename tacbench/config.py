"""Run configuration: one frozen, JSON-serialisable :class:`RunConfig` and the paper's presets.

Every default names its source next to the value:

- "paper, Hyperparameter Settings table": the first table of the appendix "Implementation Detail"
  (``tsallis-rl-paper.tex`` lines 2040-2054);
- "paper, per-task table": the second table of that appendix (lines 2057-2068), which gives the
  entropy coefficient alpha and the best entropic index q for each task;
- "reference code": the authors' TensorFlow implementation, as summarised in
  ``shared/REFERENCE.md``;
- "issue 3": the issue that specified ``tacbench run``.

A config is validated once, when it is built (``__post_init__``); everything downstream trusts it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from tacbench.errors import TacbenchError

# --- paper and reference-code defaults ------------------------------------------------------

TOTAL_STEPS = 1_000_000  # reference code: 200 epochs x 5,000 steps; paper figures span 1M steps
LEARNING_STARTS = 10_000  # reference code (uniform random actions); the paper table says 1e5
HIDDEN_SIZES = (300,)  # paper, Hyperparameter Settings table: 1 hidden layer of 300 ReLU units
LEARNING_RATE = 1e-3  # paper, Hyperparameter Settings table (Adam)
BATCH_SIZE = 100  # paper, Hyperparameter Settings table
BUFFER_SIZE = 1_000_000  # paper, Hyperparameter Settings table
GAMMA = 0.99  # paper, Hyperparameter Settings table
TAU = 0.005  # paper, Hyperparameter Settings table ("moving average ratio")
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # reference code: tanh head rescaled to [-20, 2]
EVAL_EVERY = 5_000  # reference code: one evaluation per 5,000-step epoch
EVAL_EPISODES = 10  # reference code: 10 deterministic test episodes
Q_SCHEDULE_START, Q_SCHEDULE_END = 0.1, 0.9  # reference code ("TAC with curricula"): 10%..90%
CHECKPOINT_EVERY = 50_000  # issue 3
LOG_EVERY = 1_000  # ours: one losses.csv row (mean over the updates since the last) per 1,000 steps
PAPER_SEEDS = (0, 10, 20, 30, 40, 50, 60, 70, 80, 90)  # paper, Hyperparameter Settings table

# paper, per-task table (lines 2059-2067): alpha 0.05 for Humanoid, 0.2 for every other task.
PAPER_ALPHA: dict[str, float] = {
    "HalfCheetah": 0.2,
    "Ant": 0.2,
    "Hopper": 0.2,
    "Swimmer": 0.2,
    "Pusher": 0.2,
    "Humanoid": 0.05,
}
DEFAULT_ALPHA = 0.2  # for tasks outside the paper: the paper's value for all but Humanoid

# paper, per-task table, column "(Best) Entropic Index" (lines 2059-2067). Section 7.1 (line 822)
# agrees for HalfCheetah/Ant (1.5) and Humanoid (1.2); Hopper, Swimmer and Pusher are marked
# "slightly better" there, i.e. the differences between q values were small.
PAPER_BEST_Q: dict[str, float] = {
    "HalfCheetah": 1.5,
    "Ant": 1.5,
    "Hopper": 2.0,
    "Swimmer": 2.0,
    "Pusher": 1.2,
    "Humanoid": 1.2,
}
DEFAULT_Q = 1.0  # tasks the paper did not run have no best q: q = 1 (Shannon entropy, i.e. SAC)

UPDATE_SCHEDULES = ("step", "episode")
IMPLS = ("fused", "eager")  # issue 7: fused (fast, default) or eager (autograd: the reference)
LNQ_MODES = ("joint", "per-dim")
CRITIC_TARGETS = ("v", "twin-q")
Q_SCHEDULES = ("constant", "linear")

# Fields that cannot change any number a run writes; a resumed run may differ in these.
RESULT_NEUTRAL_FIELDS = ("device", "threads", "checkpoint_every")


@dataclass(frozen=True)
class RunConfig:
    """Everything that determines one TAC run; built once (CLI or sweep), then read-only."""

    env: str
    q: float
    alpha: float
    seed: int = 0
    algo: str = "tac"
    total_steps: int = TOTAL_STEPS
    learning_starts: int = LEARNING_STARTS
    update_schedule: str = "step"  # issue 3: one update per step; "episode" is paper Algorithm 1
    # reference code: sum of per-dimension ln_q, what produced the paper's curves; "joint" (the
    # appendix's formula) overflows on Ant, Humanoid, Pusher at their paper q (docs/tac.md)
    lnq: str = "per-dim"
    # paper eqn:q_obj and reference code (SAC v1): the Q target bootstraps from a target V;
    # "twin-q" (SAC v2, as stable-baselines3): from target Q1, Q2 at a' ~ pi(.|s'), no V
    # (docs/parity.md says why it is offered)
    critic_target: str = "v"
    q_schedule: str = "constant"  # paper; "linear": 1 -> q between the two fractions below
    q_schedule_start: float = Q_SCHEDULE_START
    q_schedule_end: float = Q_SCHEDULE_END
    hidden_sizes: tuple[int, ...] = field(default=HIDDEN_SIZES)
    learning_rate: float = LEARNING_RATE
    batch_size: int = BATCH_SIZE
    buffer_size: int = BUFFER_SIZE
    gamma: float = GAMMA
    tau: float = TAU
    log_std_min: float = LOG_STD_MIN
    log_std_max: float = LOG_STD_MAX
    eval_every: int = EVAL_EVERY
    eval_episodes: int = EVAL_EPISODES
    checkpoint_every: int = CHECKPOINT_EVERY
    log_every: int = LOG_EVERY
    device: str = "cpu"
    threads: int = 1
    # issue 7: how the update is computed; the same maths either way (docs/performance.md), but
    # not the same rounding, so a run keeps its choice (resume refuses another)
    impl: str = "fused"
    compile: bool = False  # torch.compile the fused update (docs/performance.md)

    def __post_init__(self) -> None:
        from tacbench.tsallis import check_alpha, check_q  # imports torch: not at CLI start-up

        object.__setattr__(self, "q", check_q(self.q))
        object.__setattr__(self, "alpha", check_alpha(self.alpha))
        object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))
        _check_choice("--update-schedule", self.update_schedule, UPDATE_SCHEDULES)
        _check_choice("--lnq", self.lnq, LNQ_MODES)
        _check_choice("--critic-target", self.critic_target, CRITIC_TARGETS)
        _check_choice("--q-schedule", self.q_schedule, Q_SCHEDULES)
        _check_choice("--device", self.device, ("cpu", "cuda"))
        _check_choice("--impl", self.impl, IMPLS)
        if not isinstance(self.compile, bool):
            raise TacbenchError(f"compile must be true or false (got {self.compile!r}).")
        if self.compile and self.impl != "fused":
            raise TacbenchError("--compile compiles the fused update: use it with --impl fused.")
        if self.algo != "tac":
            raise TacbenchError(f"RunConfig is TAC's config; got algo={self.algo!r}.")
        check_integers(
            self,
            total_steps=1,
            learning_starts=0,
            batch_size=1,
            buffer_size=1,
            eval_every=0,
            eval_episodes=1,
            checkpoint_every=0,
            log_every=1,
            threads=1,
            seed=0,
        )
        if not self.hidden_sizes or min(self.hidden_sizes) < 1:
            raise TacbenchError(
                f"hidden_sizes must be positive layer widths (got {self.hidden_sizes})."
            )
        if not 0.0 < self.gamma <= 1.0 or not 0.0 < self.tau <= 1.0 or self.learning_rate <= 0:
            raise TacbenchError("need 0 < gamma <= 1, 0 < tau <= 1 and learning_rate > 0.")
        if not self.log_std_min < self.log_std_max:
            raise TacbenchError("log_std_min must be smaller than log_std_max.")
        if not 0.0 <= self.q_schedule_start < self.q_schedule_end <= 1.0:
            raise TacbenchError(
                "need 0 <= q_schedule_start < q_schedule_end <= 1 (fractions of steps)."
            )

    @property
    def variant(self) -> str:
        """The run directory's variant: ``q1.5-a0.2`` plus a suffix for each non-default choice
        that changes training (``-joint``, ``-episode``, ``-qlinear``, ``-ls100000``, ...)."""
        name = f"q{self.q:g}-a{self.alpha:g}"
        defaults = RunConfig(env=self.env, q=self.q, alpha=self.alpha)
        short = {
            "lnq": "joint",
            "critic_target": "twinq",
            "update_schedule": "episode",
            "q_schedule": "qlinear",
        }
        for key in _TRAINING_FIELDS:
            value = getattr(self, key)
            if value == getattr(defaults, key):
                continue
            if key in short:
                name += f"-{short[key]}"
            elif key == "hidden_sizes":
                name += "-h" + "x".join(str(h) for h in value)
            else:
                text = f"{value:g}" if isinstance(value, float) else str(value)
                name += f"-{_ABBREVIATIONS.get(key, key)}{text}"
        return name

    def q_at(self, step: int) -> float:
        """The entropic index in force at ``step``: constant, or the linear curriculum from 1 to q
        between ``q_schedule_start`` and ``q_schedule_end`` of ``total_steps`` (reference code)."""
        if self.q_schedule == "constant":
            return self.q
        frac = step / self.total_steps
        ramp = (frac - self.q_schedule_start) / (self.q_schedule_end - self.q_schedule_start)
        return 1.0 + (self.q - 1.0) * min(1.0, max(0.0, ramp))

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of every field (tuples become lists)."""
        data = dataclasses.asdict(self)
        data["hidden_sizes"] = list(self.hidden_sizes)
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunConfig:
        """Rebuild a config from :meth:`to_dict` output (unknown keys are an error)."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise TacbenchError(
                f"unknown RunConfig fields {unknown}; was it written by a newer tacbench?"
            )
        kwargs: dict[str, Any] = {
            k: tuple(v) if k == "hidden_sizes" else v for k, v in data.items()
        }
        return cls(**kwargs)


# Fields that change what is learned (the variant names their non-default values). Not here:
# env and seed (their own path components), total_steps, evaluation, logging and hardware.
_TRAINING_FIELDS = (
    "lnq",
    "critic_target",
    "update_schedule",
    "q_schedule",
    "q_schedule_start",
    "q_schedule_end",
    "learning_starts",
    "hidden_sizes",
    "learning_rate",
    "batch_size",
    "buffer_size",
    "gamma",
    "tau",
    "log_std_min",
    "log_std_max",
)
_ABBREVIATIONS = {
    "learning_starts": "ls",
    "learning_rate": "lr",
    "batch_size": "bs",
    "buffer_size": "buf",
    "q_schedule_start": "qstart",
    "q_schedule_end": "qend",
}


def check_integers(config: object, **minimums: int) -> None:
    """Each named field of ``config`` is an integer (not a bool) at least its minimum; else a
    TacbenchError names the flag."""
    for name, minimum in minimums.items():
        value = getattr(config, name)
        if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
            flag = "--" + name.replace("_", "-")
            raise TacbenchError(f"{name} must be an integer >= {minimum} (got {value!r}); {flag}.")


def _check_choice(flag: str, value: str, choices: Sequence[str]) -> None:
    if value not in choices:
        raise TacbenchError(f"{flag} must be one of {', '.join(choices)} (got {value!r}).")


def paper_defaults(task: str | None) -> tuple[float, float, str, str]:
    """(q, alpha, where q comes from, where alpha comes from) for a paper task name (None: a
    task the paper did not run)."""
    if task is None:
        return (
            DEFAULT_Q,
            DEFAULT_ALPHA,
            "the paper reports no best q for this task; q = 1 is Shannon entropy, i.e. SAC",
            "the paper's alpha for every task but Humanoid",
        )
    return (
        PAPER_BEST_Q[task],
        PAPER_ALPHA[task],
        f"the paper's best q for {task} (appendix, per-task table)",
        f"the paper's alpha for {task} (appendix, per-task table)",
    )


def make_run_configs(
    env: str,
    task: str | None,
    seeds: Sequence[int],
    q: float | None = None,
    alpha: float | None = None,
    **overrides: Any,
) -> tuple[list[RunConfig], list[str]]:
    """One config per seed (the members of one process) and notes on the defaults chosen.

    ``task`` is the paper's name for ``env`` (None if the paper did not run it); ``q`` and
    ``alpha`` left as None take the paper's values for that task.
    """
    if not seeds:
        raise TacbenchError("give at least one --seed.")
    if len(set(seeds)) != len(seeds):
        raise TacbenchError(f"--seed values must differ (got {list(seeds)}).")
    paper_q, paper_alpha, q_source, alpha_source = paper_defaults(task)
    notes = []
    if q is None:
        notes.append(f"q = {paper_q:g}: {q_source}")
    if alpha is None:
        notes.append(f"alpha = {paper_alpha:g}: {alpha_source}")
    configs = [
        RunConfig(
            env=env,
            q=paper_q if q is None else q,
            alpha=paper_alpha if alpha is None else alpha,
            seed=seed,
            **overrides,
        )
        for seed in seeds
    ]
    if configs[0].update_schedule == "episode" and len(configs) > 1:
        raise TacbenchError(
            "--update-schedule episode updates at each member's own episode ends, so the members "
            "cannot run in lockstep: train one --seed per process (or use --update-schedule step)."
        )
    if configs[0].q >= 2:
        cap = 10 ** (8 / (configs[0].q - 1))
        notes.append(f"q >= 2: the policy density is capped at {cap:.3g} (paper, Numerical Issue)")
    return configs, notes
