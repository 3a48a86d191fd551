"""Run configuration: frozen, JSON-serialisable configs whose fields are the settings, declared
once (:func:`tacbench.settings.setting`), and the paper's presets.

:class:`RunSettings` holds what every trainer's run has (steps, evaluation, checkpoints,
logging, hardware); :class:`RunConfig` (TAC) and ``baselines.config.BaselineConfig`` extend it.
Every default names its source next to the value:

- "paper, Hyperparameter Settings table": the first table of the appendix "Implementation Detail"
  (``tsallis-rl-paper.tex`` lines 2040-2054);
- "paper, per-task table": the second table of that appendix (lines 2057-2068), which gives the
  entropy coefficient alpha and the best entropic index q for each task;
- "reference code": the authors' TensorFlow implementation, as summarised in
  ``shared/REFERENCE.md``;
- "issue N": the issue that specified it; "ours": a choice of this project, with its reason.

A config is validated once, when it is built (``__post_init__``); everything downstream trusts
it. Error messages name the command-line flag of the offending setting.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from tacbench.errors import TacbenchError
from tacbench.settings import flag_of, neutral_fields, setting, settings_of

TOTAL_STEPS = 1_000_000  # reference code: 200 epochs x 5,000 steps; paper figures span 1M steps
PAPER_SEEDS = (0, 10, 20, 30, 40, 50, 60, 70, 80, 90)  # paper, Hyperparameter Settings table
PAPER_Q_GRID = (0.5, 0.7, 1.0, 1.2, 1.5, 1.7, 2.0, 3.0, 5.0)  # paper, section 7.1 (tex line 797)

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
LNQ_MODES = ("joint", "per-dim")
CRITIC_TARGETS = ("v", "twin-q")
Q_SCHEDULES = ("constant", "linear")
DEVICES = ("cpu", "cuda")
COMPILE_CHOICES = ("auto", "on", "off")
PROFILES = ("paper", "reference")
TIME_LIMITS = ("not-terminal", "terminal-below-1000")
ACTION_SCALES = ("unit", "bound")
ON_OFF = ("on", "off")
ALPHA_MODES = ("fixed", "auto")
Q_MODES = ("fixed", "auto")
PBT_FIELDS = ("pbt_every", "q_range")  # in the variant only with --q auto
# --profile: the settings where the authors' code (REFERENCE.md; docs/tac.md, "Profiles") did
# otherwise than the paper's table; each is also a setting of its own, for ablations
PROFILE_VALUES: dict[str, dict[str, Any]] = {
    "paper": {
        "update_schedule": "step",  # issue 3: one update per step
        "warmup_updates": "off",  # the paper's table: no updates before learning starts
        "hidden_sizes": (300,),  # paper, Hyperparameter Settings table
        "time_limits": "not-terminal",  # a time-limit end is never terminal (SB3, CleanRL)
        "action_scale": "unit",  # the critics and the buffer see actions in [-1, 1]
    },
    "reference": {
        "update_schedule": "episode",  # tac.py main loop: bursts at episode ends (Algorithm 1)
        "warmup_updates": "on",  # tac.py: updates from the first episode end, during warm-up
        "hidden_sizes": (400, 300),  # core.py's default, never overridden by the run scripts
        "time_limits": "terminal-below-1000",  # tac.py: d = False only if ep_len == 1000
        "action_scale": "bound",  # core.py: tanh output times action_space.high[0]
    },
}
# --compile auto compiles runs with at least this many learning steps: compiling TAC's update
# took 18-23 s with a cold cache and saved 2.8 ms per step at K = 1 (5.8 ms at K = 10), so it
# pays after about 8,000 steps; 20,000 leaves a margin (docs/performance.md, AMD EPYC class)
COMPILE_AUTO_LEARNING_STEPS = 20_000


@dataclass(frozen=True, kw_only=True)
class RunSettings:
    """What every trainer's run has: its seed, length, evaluation, checkpoints, logging and
    hardware. The seed is repeatable on the command line (``--seed``), so it has no generated
    option."""

    seed: int = setting(0, "Random seed.", source="ours", cli=False)
    total_steps: int = setting(
        TOTAL_STEPS,
        "Environment steps per run.",
        source="reference code: 200 epochs x 5,000 steps",
        flag="--steps",
    )
    eval_every: int = setting(
        5_000,
        "Steps between evaluations; 0 disables evaluation.",
        source="reference code: one evaluation per 5,000-step epoch",
    )
    eval_episodes: int = setting(
        10, "Deterministic episodes per evaluation.", source="reference code"
    )
    checkpoint_every: int = setting(
        50_000,
        "Steps between checkpoints (also at the end and on Ctrl-C); 0: only then.",
        source="issue 3",
        neutral=True,
    )
    log_every: int = setting(
        1_000,
        "Steps between losses.csv rows, each the mean over the updates since the last.",
        source="ours",
    )
    tensorboard: bool = setting(
        True,
        "Also write TensorBoard event files (<run>/tensorboard/) of the rows the CSVs get.",
        source="issue 20",
        neutral=True,
    )
    device: str = setting(
        "cpu",
        "Where the networks run (auto: cuda when available).",
        source="ours",
        choices=(*DEVICES, "auto"),
        neutral=True,
        sweep=False,
    )
    threads: int = setting(1, "torch CPU threads.", source="ours", neutral=True, sweep=False)

    _MINIMUMS: ClassVar[dict[str, int]] = {
        "seed": 0,
        "total_steps": 1,
        "eval_every": 0,
        "eval_episodes": 1,
        "checkpoint_every": 0,
        "log_every": 1,
        "threads": 1,
    }

    def __post_init__(self) -> None:
        check_integers(self, **self._MINIMUMS)
        _check_choice(self, "device", self.device, DEVICES)


@dataclass(frozen=True, kw_only=True)
class RunConfig(RunSettings):
    """Everything that determines one TAC run; built once (CLI or sweep), then read-only."""

    env: str
    q: float
    alpha: float
    algo: str = "tac"
    profile: str = setting(
        "paper",
        "paper: the paper's table; reference: everything the authors' code did otherwise "
        "(updates during warm-up, episode bursts, 400x300 networks, Pusher's time limit "
        "terminal, actions scaled by the bound; docs/tac.md, Profiles). Each is its own setting.",
        source="issue 21",
        choices=PROFILES,
        variant={"reference": "ref"},
    )
    lnq: str = setting(
        "per-dim",
        "per-dim: sum of per-dimension ln_q (what produced the paper's curves); joint: ln_q of "
        "the joint density (paper appendix; overflows in high action dimensions, docs/tac.md).",
        source="reference code",
        choices=LNQ_MODES,
        variant={"joint": "joint"},
    )
    critic_target: str = setting(
        "v",
        "v: the Q target bootstraps from a target V (SAC v1); twin-q: from target Q1, Q2 at "
        "a' ~ pi(s') without V (SAC v2, as stable-baselines3; docs/parity.md).",
        source="paper eqn:q_obj and reference code",
        choices=CRITIC_TARGETS,
        variant={"twin-q": "twinq"},
    )
    alpha_mode: str = setting(
        "fixed",
        "fixed: alpha stays --alpha; auto (also --alpha auto): each member learns its alpha, "
        "starting from --alpha, to hold its E[-ln_q pi] at --target-entropy (SAC v2's rule "
        "with ln_q; docs/tac.md).",
        source="paper: fixed per task; auto: issue 18, after SAC v2 (Haarnoja et al. 2018b)",
        choices=ALPHA_MODES,
    )  # in the variant's alpha part: q1.5-aauto0.2 (learned, from 0.2)
    target_entropy: float | None = setting(
        None,
        "--alpha auto: the target of E[-ln_q pi]. Default: -A ln_q(e) (--lnq per-dim) or "
        "-ln_q(e^A) (joint), A the action size; -A at q = 1, as SAC v2 and stable-baselines3.",
        source="issue 18: the per-dimension density that SAC's target implies",
        variant="te",
        metavar="FLOAT",
    )
    update_schedule: str = setting(
        None,
        "step: one update per env step; episode: at each episode end, one update per step of "
        "that episode (paper Algorithm 1; each member at its own episode ends).",
        source="paper: step (issue 3); reference: episode (the authors' code)",
        choices=UPDATE_SCHEDULES,
        variant={"episode": "episode", "step": "step"},
        profile=True,
    )
    warmup_updates: str = setting(
        None,
        "on: updates start at each member's first episode end, during the random warm-up, as "
        "the authors' code did; off: at --learning-starts.",
        source="paper: off (its table); reference: on (tac.py's main loop)",
        choices=ON_OFF,
        variant={"on": "wu", "off": "nowu"},
        profile=True,
    )
    time_limits: str = setting(
        None,
        "not-terminal: a time-limit end bootstraps; terminal-below-1000: only an episode of "
        "1,000 steps does (the authors' code: Pusher's 100-step limit is stored as terminal).",
        source="paper: not-terminal; reference: terminal-below-1000 (tac.py)",
        choices=TIME_LIMITS,
        variant={"terminal-below-1000": "tl1000", "not-terminal": "tlnever"},
        profile=True,
    )
    action_scale: str = setting(
        None,
        "unit: the critics and the replay buffer see actions in [-1, 1]; bound: scaled by the "
        "action bound first (the authors' code; Humanoid's 0.4, Pusher's 2). The policy's "
        "density is that of the unscaled action either way.",
        source="paper: unit; reference: bound (core.py)",
        choices=ACTION_SCALES,
        variant={"bound": "abound", "unit": "aunit"},
        profile=True,
    )
    q_mode: str = setting(
        "fixed",
        "fixed: each member keeps its --q; auto (also --q auto): the members (at least 4 seeds) "
        "are a population that learns q by population-based training: every --pbt-every steps "
        "the bottom quarter by recent training return copy a top-quarter member and perturb its "
        "q within --q-range (tacbench/training/pbt.py, docs/tac.md).",
        source="paper: a grid search (its future work: learn q); auto: issue 18, after "
        "Jaderberg et al. 2017",
        choices=Q_MODES,
        sweep=False,  # a population is one process's members: tacbench run
    )  # in the variant's q part: qauto
    pbt_every: int = setting(
        10_000,
        "--q auto: steps between exploit/explore rounds, counted from --learning-starts.",
        source="ours (issue 18): 8 rounds in a 100,000-step run (at 20,000, ..., 90,000)",
        variant="pbt",
        sweep=False,
    )
    q_range: tuple[float, ...] = setting(
        (0.5, 5.0),
        "--q auto: the range q starts in (log-spaced over the members) and explores, LOW,HIGH.",
        source="the paper's grid, 0.5 to 5",
        variant="qr",
        metavar="LOW,HIGH",
        sweep=False,
    )
    q_schedule: str = setting(
        "constant",
        "linear: q goes from 1 to --q between --q-schedule-start and --q-schedule-end.",
        source="paper; linear: the authors' later curricula code",
        choices=Q_SCHEDULES,
        variant={"linear": "qlinear"},
    )
    q_schedule_start: float = setting(
        0.1,
        "Fraction of --steps where the linear q schedule starts.",
        source="reference code (TAC with curricula)",
        variant="qstart",
    )
    q_schedule_end: float = setting(
        0.9,
        "Fraction of --steps where the linear q schedule reaches --q.",
        source="reference code (TAC with curricula)",
        variant="qend",
    )
    learning_starts: int = setting(
        10_000,
        "Steps of uniform random actions before learning (the paper's table says 100000).",
        source="reference code",
        variant="ls",
    )
    hidden_sizes: tuple[int, ...] = setting(
        None,
        "Hidden layer widths of every network, comma-separated (400,300).",
        source="paper: 300 (Hyperparameter Settings table: 1 hidden layer of 300 ReLU units); "
        "reference: 400,300 (core.py's default)",
        variant="h",
        metavar="W1,W2,...",
        profile=True,
    )
    learning_rate: float = setting(
        1e-3, "Adam's learning rate.", source="paper, Hyperparameter Settings table", variant="lr"
    )
    batch_size: int = setting(
        100, "Minibatch size.", source="paper, Hyperparameter Settings table", variant="bs"
    )
    buffer_size: int = setting(
        1_000_000,
        "Replay buffer capacity (transitions).",
        source="paper, Hyperparameter Settings table",
        variant="buf",
    )
    gamma: float = setting(
        0.99, "Discount factor.", source="paper, Hyperparameter Settings table", variant="gamma"
    )
    tau: float = setting(
        0.005,
        "Polyak rate of the target networks.",
        source="paper, Hyperparameter Settings table (moving average ratio)",
        variant="tau",
    )
    log_std_min: float = setting(
        -20.0,
        "Lower bound of the policy's log std.",
        source="reference code",
        variant="log_std_min",
    )
    log_std_max: float = setting(
        2.0, "Upper bound of the policy's log std.", source="reference code", variant="log_std_max"
    )
    compile: str = setting(
        "auto",
        "torch.compile TAC's update: the same maths, 3-4x faster on a CPU, after a compilation "
        "of 10-25 s (a CPU needs a C++ compiler). auto: on when the run has at least "
        f"{COMPILE_AUTO_LEARNING_STEPS:,} learning steps and a C++ compiler is found.",
        source="issue 17: the break-even measured in docs/performance.md",
        choices=COMPILE_CHOICES,
    )

    def __post_init__(self) -> None:
        from tacbench.tsallis import check_alpha, check_q  # imports torch: not at CLI start-up

        super().__post_init__()
        _check_choice(self, "profile", self.profile, PROFILES)
        for name, value in PROFILE_VALUES[self.profile].items():  # unset: the profile's value
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        object.__setattr__(self, "q", check_q(self.q))
        object.__setattr__(self, "alpha", check_alpha(self.alpha))
        object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))
        for name, choices in (
            ("update_schedule", UPDATE_SCHEDULES),
            ("lnq", LNQ_MODES),
            ("critic_target", CRITIC_TARGETS),
            ("q_schedule", Q_SCHEDULES),
            ("warmup_updates", ON_OFF),
            ("time_limits", TIME_LIMITS),
            ("action_scale", ACTION_SCALES),
            ("alpha_mode", ALPHA_MODES),
        ):
            _check_choice(self, name, getattr(self, name), choices)
        _check_choice(self, "compile", self.compile, COMPILE_CHOICES)
        if self.compile == "auto":  # what is used is recorded: a resumed run keeps it
            object.__setattr__(self, "compile", self._auto_compile())
        if self.algo != "tac":
            raise TacbenchError(f"RunConfig is TAC's config; got algo={self.algo!r}.")
        check_integers(self, learning_starts=0, batch_size=1, buffer_size=1)
        if not self.hidden_sizes or min(self.hidden_sizes) < 1:
            raise TacbenchError(
                f"hidden_sizes must be positive layer widths (got {self.hidden_sizes}); "
                "--hidden-sizes 400,300 for example."
            )
        if not 0.0 < self.gamma <= 1.0 or not 0.0 < self.tau <= 1.0 or self.learning_rate <= 0:
            raise TacbenchError("need 0 < gamma <= 1, 0 < tau <= 1 and learning_rate > 0.")
        if not self.log_std_min < self.log_std_max:
            raise TacbenchError("log_std_min must be smaller than log_std_max.")
        if self.target_entropy is not None and self.alpha_mode != "auto":
            raise TacbenchError(
                "--target-entropy is the target of a learned alpha; add --alpha auto "
                "(or --alpha-mode auto)."
            )
        if not 0.0 <= self.q_schedule_start < self.q_schedule_end <= 1.0:
            raise TacbenchError(
                "need 0 <= q_schedule_start < q_schedule_end <= 1 (fractions of steps)."
            )
        self._check_pbt()

    def _check_pbt(self) -> None:
        _check_choice(self, "q_mode", self.q_mode, Q_MODES)
        low_high = check_q_range(self.q_range)
        object.__setattr__(self, "q_range", low_high)
        if self.pbt_every < 1:
            raise TacbenchError(f"--pbt-every must be at least 1 step (got {self.pbt_every}).")
        declared = settings_of(RunConfig)
        changed = [f for f in PBT_FIELDS if getattr(self, f) != declared[f].default]
        if self.q_mode != "auto" and changed:
            flags = " and ".join(flag_of(RunConfig, f) for f in changed)
            raise TacbenchError(f"{flags} set population-based training of q; add --q auto.")
        if self.q_mode == "auto" and self.q_schedule != "constant":
            raise TacbenchError("--q auto learns q; it does not combine with --q-schedule linear.")
        if self.q_mode == "auto" and not low_high[0] <= self.q <= low_high[1]:
            raise TacbenchError(f"--q auto: a member's q {self.q:g} lies outside --q-range.")

    @property
    def per_member_updates(self) -> bool:
        """Whether members update at their own times (the episode schedule, or updates during
        warm-up from each member's first episode end), not all at every step."""
        return self.update_schedule == "episode" or self.warmup_updates == "on"

    @property
    def learning_steps(self) -> int:
        """Environment steps after the random warm-up."""
        return max(0, self.total_steps - self.learning_starts)

    def _auto_compile(self) -> str:
        """``--compile auto``: on for a run long enough to repay the compilation, where a C++
        compiler is found (the note of :func:`compile_note` says which applied)."""
        from tacbench.hardware import cpp_compiler  # torch's Inductor: only when it matters

        long_enough = self.learning_steps >= COMPILE_AUTO_LEARNING_STEPS
        return "on" if long_enough and cpp_compiler() is not None else "off"

    @property
    def variant(self) -> str:
        """The run directory's variant: ``q1.5-a0.2`` (``q1.5-aauto0.2``: alpha learned from 0.2)
        plus ``-ref`` for the reference profile and
        a suffix for each choice that changes training and differs from its default or its
        profile's value (``-joint``, ``-episode``, ``-qlinear``, ``-ls100000``, ...)."""
        learned = "auto" if self.alpha_mode == "auto" else ""
        q_part = "auto" if self.q_mode == "auto" else f"{self.q:g}"
        name = f"q{q_part}-a{learned}{self.alpha:g}"
        for key, declared in settings_of(RunConfig).items():
            part, value = declared.info.variant, getattr(self, key)
            default = PROFILE_VALUES[self.profile].get(key, declared.default)
            if part is None or value == default or (key in PBT_FIELDS and self.q_mode != "auto"):
                continue
            if isinstance(part, Mapping):
                name += f"-{part[value]}"
            elif isinstance(value, tuple):
                name += f"-{part}" + "x".join(f"{v:g}" for v in value)
            else:
                name += f"-{part}" + (f"{value:g}" if isinstance(value, float) else str(value))
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
        data["q_range"] = list(self.q_range)
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


def result_neutral_fields() -> tuple[str, ...]:
    """The config fields that cannot change any number a run writes: a resumed run may differ
    in these (the other fields must be equal)."""
    return neutral_fields(RunConfig, RunSettings)


RESULT_NEUTRAL_FIELDS = result_neutral_fields()


def check_integers(config: object, **minimums: int) -> None:
    """Each named field of ``config`` is an integer (not a bool) at least its minimum; else a
    TacbenchError names the flag."""
    for name, minimum in minimums.items():
        value = getattr(config, name)
        if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
            flag = flag_of(type(config), name)
            raise TacbenchError(f"{name} must be an integer >= {minimum} (got {value!r}); {flag}.")


def _check_choice(config: object, name: str, value: str, choices: Sequence[str]) -> None:
    if value not in choices:
        flag = flag_of(type(config), name)
        raise TacbenchError(f"{flag} must be one of {', '.join(choices)} (got {value!r}).")


def check_q_range(values: Sequence[float]) -> tuple[float, float]:
    """``--q-range`` as (LOW, HIGH), or a TacbenchError unless 0 < LOW < HIGH < inf."""
    low_high = tuple(float(v) for v in values)
    if len(low_high) != 2 or not 0 < low_high[0] < low_high[1] < math.inf:
        raise TacbenchError(
            f"--q-range must be LOW,HIGH with 0 < LOW < HIGH < inf (got {low_high}); "
            "the paper's grid is 0.5,5."
        )
    return low_high[0], low_high[1]
