"""One frozen, JSON-serialisable :class:`BaselineConfig` per baseline run, and how to build them.

The run settings (steps, evaluation, checkpoints, logging, hardware) are TAC's own
(:class:`tacbench.settings.RunSettings`, declared once); the algorithm's settings are
the resolved hyperparameter table (``baselines/hyperparams/<algo>.yaml``) with the ``--hp``
overrides applied.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from baselines import hyperparams
from tacbench.errors import TacbenchError
from tacbench.settings import RunSettings, RunWarning, never_updated


@dataclass(frozen=True, kw_only=True)
class BaselineConfig(RunSettings):
    """Everything that determines one baseline run; built once, then read-only. The run
    settings are TAC's (:class:`tacbench.settings.RunSettings`)."""

    algo: str
    env: str
    hyperparams: Mapping[str, Any] = field(default_factory=dict)
    variant: str = "default"

    def __post_init__(self) -> None:
        hyperparams.check_algo(self.algo)
        super().__post_init__()
        missing = sorted(set(hyperparams.ALGO_KEYS[self.algo]) - set(self.hyperparams))
        if missing:
            raise TacbenchError(f"{self.algo} config lacks hyperparameters {missing}.")
        for key, value in self.hyperparams.items():
            hyperparams.coerce(self.algo, key, value)

    @property
    def off_policy(self) -> bool:
        """Whether the algorithm learns from a replay buffer."""
        return self.algo in hyperparams.OFF_POLICY

    @property
    def learning_starts(self) -> int:
        """The step from which the algorithm learns: its table's ``learning_starts`` off-policy,
        0 for PPO and TRPO, which have no random phase (as TAC's config field of that name)."""
        return int(self.hyperparams["learning_starts"]) if self.off_policy else 0

    @property
    def learning_steps(self) -> int:
        """Environment steps after the random warm-up."""
        return max(0, self.total_steps - self.learning_starts)

    @property
    def alpha(self) -> float | None:
        """The entropy coefficient when it is a constant (sac-sb3), else None."""
        value = self.hyperparams.get("ent_coef") if self.algo == "sac-sb3" else None
        return float(value) if isinstance(value, int | float) else None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of every field."""
        data = dataclasses.asdict(self)
        data["hyperparams"] = dict(self.hyperparams)
        return data


def make_configs(
    algo: str,
    env: str,
    task: str | None,
    seeds: Sequence[int],
    hp: Sequence[str] = (),
    **settings: Any,
) -> tuple[list[BaselineConfig], dict[str, Any], list[str]]:
    """One config per seed, the overrides that differ from the table, and notes for the user.

    ``env`` is a Gymnasium id, ``task`` its paper name (None outside the suite); ``hp`` holds
    ``key=value`` overrides; ``settings`` are run settings (``total_steps``, ``eval_every``...).
    """
    hyperparams.check_algo(algo)
    if not seeds:
        raise TacbenchError("give at least one --seed.")
    if len(set(seeds)) != len(seeds):
        raise TacbenchError(f"--seed values must differ (got {list(seeds)}).")
    table, sections = hyperparams.resolve(algo, env, task)
    overrides = hyperparams.parse_overrides(algo, hp)
    effective = {**table, **overrides}
    name = hyperparams.variant(table, effective)
    configs = [
        BaselineConfig(
            algo=algo, env=env, seed=seed, hyperparams=effective, variant=name, **settings
        )
        for seed in seeds
    ]
    changed = {k: v for k, v in overrides.items() if table.get(k) != v}
    notes = [
        f"{algo} hyperparameters: baselines/hyperparams/{algo}.yaml, sections "
        f"{' + '.join(sections)}" + (f"; overridden: {changed}" if changed else "")
    ]
    _check_combination(algo, effective)
    if effective.get("noise_type") == "none" and "noise_std" in overrides:
        raise TacbenchError(
            f"--hp noise_std={overrides['noise_std']}: with noise_type=none {algo} adds no "
            "exploration noise, so its scale would only rename the run; leave noise_std out, "
            "or give noise_type=normal."
        )
    total = configs[0].total_steps
    starts = effective.get("learning_starts")
    if configs[0].off_policy and starts is not None:
        notes += never_updated(f"{algo}'s learning_starts", int(starts), total)
    if configs[0].off_policy:
        notes += _never_trained(algo, effective.get("train_freq"), total)
    rollout = int(effective.get("n_steps", SB3_N_STEPS))
    if not configs[0].off_policy and rollout > total:
        notes.append(
            RunWarning(
                f"WARNING: {algo}'s n_steps {rollout:,} is above --steps {total:,}: the run ends "
                "before its first rollout is complete, and the networks are never updated"
            )
        )
    return configs, changed, notes


SB3_N_STEPS = 2048  # SB3's PPO and TRPO default rollout length, where a table leaves it out


def _never_trained(algo: str, train_freq: Any, total: int) -> list[str]:
    """A warning where an off-policy baseline's ``train_freq`` in steps is above ``--steps``:
    SB3 trains after each ``train_freq`` steps collected, so never."""
    in_steps = isinstance(train_freq, list) and train_freq[1] == "step"
    steps = train_freq[0] if in_steps else train_freq
    if not isinstance(steps, int) or steps <= total:
        return []
    return [
        RunWarning(
            f"WARNING: {algo}'s train_freq {steps:,} steps is above --steps {total:,}: the run "
            "ends before its first training, and the networks are never updated"
        )
    ]


def _check_combination(algo: str, effective: Mapping[str, Any]) -> None:
    """Refuse hyperparameters that SB3 would refuse only once the run is built."""
    learned = str(effective.get("ent_coef", "")).startswith("auto")
    if algo == "sac-sb3" and effective.get("target_entropy", "auto") != "auto" and not learned:
        raise TacbenchError(
            f"target_entropy={effective['target_entropy']} (--target-entropy) is what a learned "
            f"alpha aims at, and sac-sb3's alpha is fixed here (ent_coef={effective['ent_coef']}); "
            "add --alpha auto (or --alpha-mode auto), or leave the target entropy out."
        )
    if int(effective.get("gradient_steps", 1)) == 0:  # SB3 trains only for a count above 0
        raise TacbenchError(
            f"--hp gradient_steps=0: {algo} would make no gradient step, and its networks would "
            "never be updated; give a count of at least 1, or -1 (one per step collected)."
        )
    normalised = algo == "ppo" and effective.get("normalize_advantage", True)
    if normalised and int(effective.get("batch_size", 64)) < 2:  # SB3's PPO default: 64
        raise TacbenchError(
            "--hp batch_size=1: PPO normalises the advantages over each minibatch, which "
            "needs at least 2 samples; give batch_size of 2 or more (or "
            "normalize_advantage=false)."
        )
    if algo == "trpo" and effective.get("normalize_advantage", True):
        n_steps = int(effective.get("n_steps", SB3_N_STEPS))
        factor = int(effective.get("sub_sampling_factor", 1))
        if factor >= n_steps:  # its policy step takes every factor-th sample of the rollout
            raise TacbenchError(
                f"--hp sub_sampling_factor={factor}: TRPO's policy step would take 1 sample of "
                f"its {n_steps}-step rollout, and normalising the advantages needs at least 2; "
                f"give a factor below n_steps ({n_steps}), or normalize_advantage=false."
            )


# TAC's `tacbench run` flags that a baseline understands, as the hyperparameter they set.
# --alpha auto is SB3's ent_coef=auto, and --target-entropy its target_entropy
_FLAG_KEYS = {("sac-sb3", "alpha"): "ent_coef", ("sac-sb3", "target_entropy"): "target_entropy"}
_FLAG_KEYS.update({(algo, "learning_starts"): "learning_starts" for algo in hyperparams.OFF_POLICY})


_IN_A_SWEEP = "in tacbench sweep, --algo tac keeps TAC's runs only"


def flag_key(algo: str, name: str) -> str | None:
    """The hyperparameter of ``algo`` that the ``tacbench run`` setting ``name`` sets
    (``alpha_mode`` too sets sac-sb3's ent_coef); None if it sets none."""
    if (algo, name) == ("sac-sb3", "alpha_mode"):
        return "ent_coef"
    return _FLAG_KEYS.get((algo, name))


def flags_as_overrides(algo: str, given: Mapping[str, Any]) -> list[str]:
    """TAC flags given on the command line (``{"alpha": 0.1}``) as ``--hp`` items for ``algo``
    (``ent_coef=0.1`` for sac-sb3); a flag the baseline has no use for is refused. For sac-sb3
    ``--alpha-mode auto`` is ``--alpha auto``, learning from ``--alpha`` where one is given
    (SB3's ``ent_coef=auto_0.1``), as TAC's ``--alpha-mode auto --alpha 0.1`` does."""
    given, shown = dict(given), {}  # shown: how an error names a flag, where not as given
    if algo == "sac-sb3" and "alpha_mode" in given:
        start = given.get("alpha", "auto")
        if given.pop("alpha_mode") == "auto":
            given["alpha"] = "auto" if start == "auto" else f"auto_{float(start)!r}"
            shown["alpha"] = f"--alpha-mode auto --alpha {start}"
        elif given.get("alpha") == "auto":
            raise TacbenchError(
                "--alpha auto learns alpha; it does not mix with --alpha-mode fixed in one command."
            )
    items = []
    for name, value in given.items():
        key, flag = _FLAG_KEYS.get((algo, name)), f"--{name.replace('_', '-')}"
        if key is None and name in hyperparams.ALGO_KEYS[algo]:  # TAC's, not the baseline's
            raise TacbenchError(
                f"{flag} sets TAC's {name}; {algo}'s is set with tacbench run --algo {algo} --hp "
                f"{name}={value} ({_IN_A_SWEEP})."
            )
        if key is None:
            raise TacbenchError(
                f"{flag} is a TAC option that {algo} does not use; leave it out for {algo} "
                f"({_IN_A_SWEEP}) and set {algo}'s hyperparameters with tacbench run --algo "
                f"{algo} --hp KEY=VALUE, KEY one of "
                f"{', '.join(sorted(hyperparams.ALGO_KEYS[algo]))}."
            )
        hyperparams.coerce(algo, key, value, shown.get(name, f"{flag} {value}"))  # not as --hp
        items.append(f"{key}={value}")
    return items
