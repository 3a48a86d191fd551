"""The checks of a TAC run's settings beyond each one's own range (which
:mod:`tacbench.settings` checks): numbers that must be finite, settings that only mean something
together, and population-based training's. :class:`tacbench.config.RunConfig` runs them when it
is made; each error names the flag and says what to do."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from tacbench import paper
from tacbench.errors import TacbenchError
from tacbench.settings import flag_of, settings_of

FLOAT32_TINY = 2.0**-126  # float32's smallest normal number; below it the CPU may flush to 0


def check_normal(value: float, named: str) -> None:
    """Refuse a nonzero ``value`` (``named`` as the user gave it: ``--alpha 1e-40``) below
    :data:`FLOAT32_TINY`: the runs flush such numbers to zero, so it would train as 0."""
    if 0 < abs(value) < FLOAT32_TINY:
        raise TacbenchError(
            f"{named} is below float32's smallest normal number, {FLOAT32_TINY:.4g}, which "
            "training reads as 0."
        )


if TYPE_CHECKING:
    from tacbench.config import RunConfig

PBT_FIELDS = ("pbt_every", "q_range")  # in the variant only with --q auto
# the largest q a run trains; q -> infinity is plain RL (paper, section 3), and at q = 1,000
# the density cap 10^(8/(q-1)) is 1.02, so ln_q is one constant for nearly every density, while
# without the cap (--density-cap off) ln_q overflows float32 from a density of about 1.1
MAX_TRAINING_Q = 1_000.0
ABOVE_MAX_TRAINING_Q = (
    "the density cap (below 1.02) makes ln_q flat and, with --density-cap off, ln_q overflows "
    "float32"
)
FLOAT32_MAX = 3.4028234663852886e38


def check_numbers(config: RunConfig) -> None:
    """The layer widths, q, gamma, tau, the learning rate, the log-std bounds and the target
    entropy."""
    if not config.hidden_sizes or min(config.hidden_sizes) < 1:
        raise TacbenchError(
            f"hidden_sizes must be positive layer widths (got {config.hidden_sizes}); "
            "--hidden-sizes 400,300 for example."
        )
    if config.q_mode == "fixed" and config.q > MAX_TRAINING_Q:
        raise TacbenchError(
            f"--q {config.q:g} is above {MAX_TRAINING_Q:g}, where {ABOVE_MAX_TRAINING_Q}; "
            "q -> infinity is plain RL (the paper's grid ends at 5)."
        )
    for name, low, high in (("gamma", 0.0, 1.0), ("tau", 0.0, 1.0)):
        if not low < getattr(config, name) <= high:
            raise TacbenchError(
                f"{flag_of(type(config), name)} must lie in ({low:g}, {high:g}] "
                f"(got {getattr(config, name)!r})."
            )
    if not (math.isfinite(config.learning_rate) and config.learning_rate > 0):
        raise TacbenchError(
            f"--learning-rate must be a finite number > 0 (got {config.learning_rate!r})."
        )
    for name in ("alpha", "gamma", "tau", "learning_rate"):  # > 0 above, or in RunConfig
        value = getattr(config, name)
        check_normal(value, f"{flag_of(type(config), name)} {value:g}")
        if not _float32(value):  # float32's inf: a non-finite loss at the first update
            raise TacbenchError(
                f"{flag_of(type(config), name)} {value:g} is above float32's largest number, "
                f"{FLOAT32_MAX:.4g}, which the update's tensors hold."
            )
    bounds = (config.log_std_min, config.log_std_max)
    if not all(_float32(b) for b in bounds) or not bounds[0] < bounds[1]:
        raise TacbenchError(
            f"--log-std-min and --log-std-max must be finite float32 numbers with min < max "
            f"(got {bounds})."
        )
    if config.target_entropy is not None and not _float32(config.target_entropy):
        raise TacbenchError(
            "--target-entropy must be a finite number a float32 holds, |x| < 3.4e38 (got "
            f"{config.target_entropy!r}); the usual target is minus the action dimension."
        )
    if config.target_entropy is not None and config.alpha_mode != "auto":
        raise TacbenchError(
            "--target-entropy is the target of a learned alpha; add --alpha auto "
            "(or --alpha-mode auto)."
        )


def _float32(value: float) -> bool:
    """Whether ``value`` is finite and within float32's range (the update's tensors)."""
    return math.isfinite(value) and abs(value) <= FLOAT32_MAX


def check_q_schedule(config: RunConfig) -> None:
    """The linear q schedule's fractions, and none without that schedule."""
    if not 0.0 <= config.q_schedule_start < config.q_schedule_end <= 1.0:
        raise TacbenchError(
            "need 0 <= q_schedule_start < q_schedule_end <= 1 (fractions of steps)."
        )
    ramp = _changed_flags(config, ("q_schedule_start", "q_schedule_end"))
    if config.q_schedule != "linear" and ramp:
        verb = "shape" if " and " in ramp else "shapes"
        raise TacbenchError(f"{ramp} {verb} the linear q schedule; add --q-schedule linear.")


def check_density(config: RunConfig) -> None:
    """The density settings (the authors' versions): in range, and meaningful together."""
    if not FLOAT32_TINY <= config.density_floor < 1.0:  # a floor float32 reads as 0 is none
        raise TacbenchError(
            f"--density-floor must lie in [{FLOAT32_TINY:.4g}, 1), float32's normal numbers "
            f"(got {config.density_floor:g}); the authors' code used 1e-6 and 1e-8."
        )
    if (
        config.lnq == "joint"
        and config.density_floor != paper.PROFILES[config.profile]["density_floor"]
    ):
        raise TacbenchError(
            "--density-floor applies to --lnq per-dim and joint-batch-max; joint has none."
        )
    if not 0.0 <= config.jacobian_clip < 1.0:
        raise TacbenchError(f"--jacobian-clip must lie in [0, 1) (got {config.jacobian_clip:g}).")
    if not 0.0 <= config.gaussian_eps < 1.0:
        raise TacbenchError(f"--gaussian-eps must lie in [0, 1) (got {config.gaussian_eps:g}).")
    if config.lnq == "joint-batch-max" and config.alpha_mode == "auto":
        raise TacbenchError(
            "--lnq joint-batch-max depends on the minibatch, so it has no entropy to hold; "
            "--alpha auto needs --lnq per-dim or joint."
        )


def check_alpha_target(config: RunConfig, act_dim: int) -> None:
    """Refuse ``--alpha auto`` with the default target where the density cap binds at the
    target's own density (log-density 1 per action dimension): the target is then the largest
    value the capped ln_q takes, E[ln_q pi] never exceeds it, and alpha could only fall. That is
    per-dim above q = 1 + 8 ln 10 (19.4), joint where act_dim (q - 1) >= 8 ln 10 (HalfCheetah at
    q = 5); with --q auto at the top of its --q-range."""
    if config.alpha_mode != "auto" or config.target_entropy is not None:
        return
    q = max(config.q_range) if config.q_mode == "auto" else config.q
    if config.lnq == "joint-batch-max":
        return
    _check_target_is_finite(config, q, act_dim)
    at_target = 1.0 if config.lnq == "per-dim" else float(act_dim)
    if at_target < paper.density_log_cap(q, config.density_cap):
        return
    remedies = [
        "give --target-entropy",
        "narrow --q-range" if config.q_mode == "auto" else "use a smaller q",
        *(["use --lnq per-dim"] if config.lnq == "joint" else []),
    ]
    raise TacbenchError(
        f"--alpha auto: at q = {q:g} with --lnq {config.lnq} on {act_dim} action dimensions "
        "the default target of E[ln_q pi] lies at the density cap (--density-cap "
        f"{config.density_cap}: 10^(8/(q-1)) per density), the largest value the capped ln_q "
        f"takes, so alpha could only fall; {', '.join(remedies[:-1])} or {remedies[-1]}."
    )


def _check_target_is_finite(config: RunConfig, q: float, act_dim: int) -> None:
    """Without a density cap the default target's ln_q grows as e^((q-1) x) / (q-1) (x: the
    target's log-density, 1 per dimension) and past float32's range it is inf: the temperature
    loss would be inf and alpha NaN from the first update (--density-cap off with a large q)."""
    import torch  # only where a run is about to train

    from tacbench.tac.maths import coefficients, default_lnq_target

    c = coefficients([q], [1.0], torch.device("cpu"), config.density_cap)
    if bool(torch.isfinite(default_lnq_target(c, act_dim, config.lnq)).all()):
        return
    raise TacbenchError(
        f"--alpha auto: at q = {q:g} with --lnq {config.lnq} on {act_dim} action dimensions and "
        f"--density-cap {config.density_cap} the default target of E[ln_q pi] overflows "
        "float32 (inf), so the temperature loss would be inf from the first update; give "
        "--target-entropy, use a smaller q or leave the density cap on."
    )


def check_pbt(config: RunConfig) -> None:
    """Population-based training's settings, only with --q auto; stores ``q_range`` as
    (LOW, HIGH) first, so that it compares equal to its default."""
    low_high = check_q_range(config.q_range)
    object.__setattr__(config, "q_range", low_high)
    if config.pbt_every < 1:
        raise TacbenchError(f"--pbt-every must be at least 1 step (got {config.pbt_every}).")
    changed = _changed_flags(config, PBT_FIELDS)
    if config.q_mode != "auto" and changed:
        raise TacbenchError(f"{changed} set population-based training of q; add --q auto.")
    if config.q_mode == "auto" and config.q_schedule != "constant":
        raise TacbenchError("--q auto learns q; it does not combine with --q-schedule linear.")
    if config.q_mode == "auto" and not low_high[0] <= config.q <= low_high[1]:
        raise TacbenchError(f"--q auto: a member's q {config.q:g} lies outside --q-range.")


def _changed_flags(config: RunConfig, fields: Sequence[str]) -> str:
    """The flags of ``fields`` that differ from their declared defaults, joined by "and"
    ("" if none): settings that only mean something in a mode the config may not be in."""
    declared = settings_of(type(config))
    changed = [f for f in fields if getattr(config, f) != declared[f].default]
    return " and ".join(flag_of(type(config), f) for f in changed)


def check_q_range(values: Sequence[float]) -> tuple[float, float]:
    """``--q-range`` as (LOW, HIGH), or a TacbenchError unless 0 < LOW < HIGH <=
    :data:`MAX_TRAINING_Q` (a learned q goes anywhere in it)."""
    low_high = tuple(float(v) for v in values)
    if len(low_high) != 2 or not 0 < low_high[0] < low_high[1] <= MAX_TRAINING_Q:
        raise TacbenchError(
            f"--q-range must be LOW,HIGH with 0 < LOW < HIGH <= {MAX_TRAINING_Q:g} (got "
            f"{low_high}): above {MAX_TRAINING_Q:g} {ABOVE_MAX_TRAINING_Q}; the paper's grid "
            "is 0.5,5."
        )
    return low_high[0], low_high[1]
