"""TAC's run configuration: a frozen, JSON-serialisable config whose fields are the settings,
declared once (:func:`tacbench.settings.setting`).

:class:`RunConfig` is TAC's config; it extends :class:`tacbench.settings.RunSettings`, what every
trainer's run has (steps, evaluation, checkpoints, logging, hardware), as
``baselines.config.BaselineConfig`` does.
Every default names its source next to the value:

- "paper, Hyperparameter Settings table": the first table of the appendix "Implementation Detail"
  (``tsallis-rl-paper.tex`` lines 2040-2054);
- "paper, per-task table": the second table of that appendix (lines 2057-2068), which gives the
  entropy coefficient alpha and the best entropic index q for each task;
- "reference code": the authors' TensorFlow implementation, as summarised in
  ``shared/REFERENCE.md``;
- "ours": a choice of this project, with its reason.

The paper's values themselves live in :mod:`tacbench.paper`.

A config is validated once, when it is built (``__post_init__``); everything downstream trusts
it. Error messages name the command-line flag of the offending setting.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from tacbench import config_checks as checks
from tacbench import paper
from tacbench.errors import TacbenchError
from tacbench.settings import (
    RunSettings,
    check_choice,
    check_integers,
    neutral_fields,
    setting,
    settings_of,
)

ON_OFF = ("on", "off")
# --compile auto compiles runs with at least this many learning steps: the compilation pays for
# itself after about 8,000 (docs/performance.md, "--compile auto and its break-even"); 20,000
# leaves a margin for slower compilers
COMPILE_AUTO_LEARNING_STEPS = 20_000
# the variant part of --matmul-precision bf16, by which a report tells such runs apart
BF16_VARIANT_PART = "bf16"


def has_bf16_products(variant: str) -> bool:
    """Whether a run of this variant name trained with ``--matmul-precision bf16``."""
    return BF16_VARIANT_PART in variant.split("-")


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
        "terminal, actions scaled by the bound; docs/tac.md, Profiles); authors-DATE: their "
        "code as it stood then (docs/authors-versions.md). Each is its own setting.",
        source="ours: the paper's table is the default",
        choices=tuple(paper.PROFILES),
        variant=paper.PROFILE_VARIANTS,
    )
    lnq: str = setting(
        None,
        "per-dim: sum of per-dimension ln_q (the authors' final code); joint: ln_q of the joint "
        "density (paper appendix; overflows in high action dimensions, docs/tac.md); "
        "joint-batch-max: ln_q of the joint density over the minibatch's largest (the authors' "
        "code of 2019-01-07, docs/authors-versions.md).",
        source="reference code and the authors' earlier versions",
        choices=("joint", "per-dim", "joint-batch-max"),
        variant={"joint": "joint", "per-dim": "perdim", "joint-batch-max": "jointbm"},
        profile=True,
    )
    density_floor: float = setting(
        None,
        "Smallest density that ln_q sees: each dimension's (--lnq per-dim) or the normalised "
        "joint one (joint-batch-max); --lnq joint has none.",
        source="the authors' code: 1e-6 from 2019-01-22 (7a7e754), 1e-8 before",
        variant="floor",
        metavar="FLOAT",
        profile=True,
    )
    density_cap: str = setting(
        None,
        "Where the density cap 10^(8/(q-1)) applies: paper: for q >= 2 (its Numerical Issue; "
        "the authors' final code); every-q: for every q != 1; off: never.",
        source="paper appendix; the authors' code: every q on 2019-01-16 (7b0308a), none before",
        choices=paper.DENSITY_CAP_RULES,
        variant={"paper": "cappaper", "every-q": "capeveryq", "off": "capoff"},
        profile=True,
    )
    jacobian_clip: float = setting(
        None,
        "Raise each 1 - tanh(z)^2 of the density's Jacobian to at least this before its "
        "+ 1e-6, passing the gradient through (0: no change).",
        source="the authors' code: 1e-3 on 2019-01-07 (3c5cf2b), 0 otherwise",
        variant="jclip",
        metavar="FLOAT",
        profile=True,
    )
    gaussian_eps: float = setting(
        None,
        "Standardise the policy's noise by sigma + this in its log-density, as Spinning Up's "
        "gaussian_likelihood does (0: the exact Gaussian).",
        source="the authors' code: 1e-8 in every version (Spinning Up)",
        variant="geps",
        metavar="FLOAT",
        profile=True,
    )
    critic_target: str = setting(
        "v",
        "v: the Q target bootstraps from a target V (SAC v1); twin-q: from target Q1, Q2 at "
        "a' ~ pi(s') without V (SAC v2, as stable-baselines3; docs/parity.md).",
        source="paper eqn:q_obj and reference code",
        choices=("v", "twin-q"),
        variant={"twin-q": "twinq"},
    )
    alpha_mode: str = setting(
        "fixed",
        "fixed: alpha stays --alpha; auto (also --alpha auto): each member learns its alpha, "
        "starting from --alpha, to hold its E[-ln_q pi] at --target-entropy (SAC v2's rule "
        "with ln_q; docs/tac.md).",
        source="paper: fixed per task; auto: after SAC v2 (Haarnoja et al. 2018b)",
        choices=("fixed", "auto"),
    )  # in the variant's alpha part: q1.5-aauto0.2 (learned, from 0.2)
    target_entropy: float | None = setting(
        None,
        "--alpha auto: the target of E[-ln_q pi]; the default is -A at q = 1, as SAC v2 and "
        "stable-baselines3.",
        source="ours: the per-dimension density that SAC's target implies",
        variant="te",
        metavar="FLOAT",
        shown_default="-A ln_q(e) (--lnq per-dim) or -ln_q(e^A) (joint), A the action size",
    )
    update_schedule: str = setting(
        None,
        "step: one update per env step; episode: at each episode end, one update per step of "
        "that episode (paper Algorithm 1; each member at its own episode ends).",
        source="ours: tacbench's first specification (step); episode is paper Algorithm 1 and "
        "the reference code (tac.py's main loop)",
        choices=("step", "episode"),
        variant={"episode": "episode", "step": "step"},
        profile=True,
    )
    warmup_updates: str = setting(
        None,
        "on: updates start at each member's first episode end, during the random warm-up, as "
        "the authors' code did; off: at --learning-starts.",
        source="paper: its table's minimum samples; reference: tac.py's main loop",
        choices=ON_OFF,
        variant={"on": "wu", "off": "nowu"},
        profile=True,
    )
    time_limits: str = setting(
        None,
        "not-terminal: a time-limit end bootstraps; terminal-below-1000: only an episode of "
        "1,000 steps does (the authors' code: Pusher's 100-step limit is stored as terminal).",
        source="paper: as SB3 and CleanRL; reference: tac.py",
        choices=("not-terminal", "terminal-below-1000"),
        variant={"terminal-below-1000": "tl1000", "not-terminal": "tlnever"},
        profile=True,
    )
    action_scale: str = setting(
        None,
        "unit: the critics and the replay buffer see actions in [-1, 1]; bound: scaled by the "
        "action bound first (the authors' code; Humanoid's 0.4, Pusher's 2). The policy's "
        "density is that of the unscaled action either way.",
        source="paper: the policy's range; reference: core.py",
        choices=("unit", "bound"),
        variant={"bound": "abound", "unit": "aunit"},
        profile=True,
    )
    q_mode: str = setting(
        "fixed",
        "fixed: each member keeps its --q; auto (also --q auto): the members (at least 4 seeds) "
        "are a population that learns q by population-based training: every --pbt-every steps "
        "the bottom quarter by recent training return copy a top-quarter member and perturb its "
        "q within --q-range (tacbench/training/pbt.py, docs/tac.md).",
        source="paper: a grid search (its future work: learn q); auto: after Jaderberg et al. 2017",
        choices=("fixed", "auto"),
        sweep=False,  # a population is one process's members: tacbench run
    )  # in the variant's q part: qauto
    pbt_every: int = setting(
        10_000,
        "--q auto: steps between exploit/explore rounds, counted from --learning-starts.",
        source="ours: 8 rounds in a 100,000-step run (at 20,000, ..., 90,000)",
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
        choices=("constant", "linear"),
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
        "Steps of uniform random actions before learning (the paper's table says "
        f"{paper.HYPERPARAMETERS.min_samples:,}).",
        source="reference code",
        variant="ls",
    )
    hidden_sizes: tuple[int, ...] = setting(
        None,
        "Hidden layer widths of every network, comma-separated (400,300).",
        source="paper: Hyperparameter Settings table; reference: core.py's default",
        variant="h",
        metavar="W1,W2,...",
        profile=True,
    )
    learning_rate: float = setting(
        paper.HYPERPARAMETERS.learning_rate,
        "Adam's learning rate.",
        source="paper, Hyperparameter Settings table",
        variant="lr",
    )
    batch_size: int = setting(
        paper.HYPERPARAMETERS.batch_size,
        "Minibatch size.",
        source="paper, Hyperparameter Settings table",
        variant="bs",
    )
    buffer_size: int = setting(
        paper.HYPERPARAMETERS.buffer_size,
        "Replay buffer capacity (transitions).",
        source="paper, Hyperparameter Settings table",
        variant="buf",
    )
    gamma: float = setting(
        paper.HYPERPARAMETERS.gamma,
        "Discount factor.",
        source="paper, Hyperparameter Settings table",
        variant="gamma",
    )
    tau: float = setting(
        paper.HYPERPARAMETERS.tau,
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
        source="ours: the break-even measured in docs/performance.md",
        choices=("auto", "on", "off"),
    )
    matmul_precision: str = setting(
        "float32",
        "The update's matrix products: float32, or bf16 (inputs rounded to bfloat16, float32 "
        "accumulation, outputs back to float32) where the device has native bfloat16 "
        "instructions (a CPU's AVX512-BF16 or AMX, a GPU's bf16); everything else stays "
        "float32. Changes the rounding, so bf16 runs are a variant of their own "
        "(docs/performance.md, 'Reduced precision').",
        source="float32: the paper's TensorFlow code; bf16: ours, opt-in with its learning check",
        choices=("float32", "bf16"),
        variant={"bf16": BF16_VARIANT_PART},
    )

    def __post_init__(self) -> None:
        from tacbench.theory.tsallis import (  # imports torch: not at CLI start-up
            check_alpha,
            check_q,
        )

        check_choice(self, "profile")
        for name, value in paper.PROFILES[self.profile].items():  # unset: the profile's value
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        super().__post_init__()
        object.__setattr__(self, "q", check_q(self.q))
        object.__setattr__(self, "alpha", check_alpha(self.alpha))
        object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))
        if self.algo != "tac":
            raise TacbenchError(f"RunConfig is TAC's config; got algo={self.algo!r}.")
        check_integers(self, learning_starts=0, batch_size=1, buffer_size=1)
        checks.check_numbers(self)
        checks.check_density(self)
        checks.check_q_schedule(self)
        checks.check_pbt(self)

    @property
    def per_member_updates(self) -> bool:
        """Whether members update at their own times (the episode schedule, or updates during
        warm-up from each member's first episode end), not all at every step."""
        return self.update_schedule == "episode" or self.warmup_updates == "on"

    @property
    def learning_steps(self) -> int:
        """Environment steps after the random warm-up."""
        return max(0, self.total_steps - self.learning_starts)

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
            default = paper.PROFILES[self.profile].get(key, declared.default)
            if (
                part is None
                or value == default
                or (key in checks.PBT_FIELDS and self.q_mode != "auto")
            ):
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
    """The config fields in which a resumed run may differ (the other fields must be equal):
    they change no number a run writes, or only the rounding (the hardware,
    :data:`tacbench.settings.REROUNDING_FIELDS`)."""
    return neutral_fields(RunConfig, RunSettings)


RESULT_NEUTRAL_FIELDS = result_neutral_fields()
