"""Hyperparameter tables (``baselines/hyperparams/<algo>.yaml``), ``--hp`` overrides, variants.

A table has a ``default`` section and optional sections named by a Gymnasium id (``Hopper-v4``)
or by the paper's task name (``Humanoid``, every version); for an environment the task-name
section applies on top of ``default`` and the id section on top of that. Every value in the
files carries a comment naming its source.

Each algorithm accepts a fixed set of keys (:data:`ALGO_KEYS`), each with a kind and range
(:data:`SPECS`). A value from a table or from ``--hp key=value`` is checked against them here, so
a mistake is reported with the valid keys or the expected type before anything is trained.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from typing import Any

import yaml

from tacbench import paper
from tacbench.config_checks import FLOAT32_TINY, check_normal
from tacbench.errors import TacbenchError

ALGOS = ("ddpg", "td3", "sac-sb3", "ppo", "trpo")
OFF_POLICY = ("ddpg", "td3", "sac-sb3")


@dataclass(frozen=True)
class Spec:
    """What a hyperparameter accepts and where it goes.

    ``kind``: ``float``, ``int``, ``bool``, ``layers`` (list of positive ints), ``choice``,
    ``optional-float`` (a float or null), ``float-or-auto`` (SAC's ent_coef / target_entropy),
    ``train-freq`` (an int, or ``[n, "step"|"episode"]``). ``target``: ``model`` (an argument of
    the SB3 constructor), ``policy`` (of ``policy_kwargs``) or ``adapter`` (used by tacbench).
    """

    kind: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple[str, ...] = ()
    target: str = "model"

    def describe(self) -> str:
        """The accepted values in words."""
        if self.kind == "choice":
            return "one of " + ", ".join(self.choices)
        if self.kind == "layers":
            return "a list of layer widths, e.g. [400,300]"
        if self.kind == "train-freq":
            return 'an integer >= 1, or [n,"step"] / [n,"episode"]'
        if self.kind == "ent-coef":  # the bound is the constant's; a learned one starts above 0
            return (
                'a number >= 0, "auto" or "auto_<initial value>" with an initial value of at '
                "least float32's smallest normal number, 1.175e-38, written without _"
            )
        text = {
            "float": "a number",
            "int": "an integer",
            "bool": "true or false",
            "optional-float": "a number or null",
            "float-or-auto": 'a number or "auto"',
        }[self.kind]
        if self.low is not None:
            text += f" {'>' if self.low_open else '>='} {self.low:g}"
        if self.high is not None:
            text += f" and <= {self.high:g}"
        return text


def _positive(kind: str = "float") -> Spec:
    return Spec(kind, low=0.0, low_open=True)


def _fraction() -> Spec:
    return Spec("float", low=0.0, high=1.0, low_open=True)


SPECS: dict[str, Spec] = {
    # networks (policy_kwargs)
    "net_arch": Spec("layers", target="policy"),
    "activation_fn": Spec("choice", choices=("relu", "tanh", "elu", "leaky_relu"), target="policy"),
    "log_std_init": Spec("float", target="policy"),
    "ortho_init": Spec("bool", target="policy"),
    # shared by several algorithms
    "learning_rate": _positive(),
    "gamma": _fraction(),
    "batch_size": Spec("int", low=1),
    # off-policy
    "buffer_size": Spec("int", low=1),
    "learning_starts": Spec("int", low=0),
    "tau": _fraction(),
    "train_freq": Spec("train-freq"),
    "gradient_steps": Spec("int", low=-1),
    "noise_type": Spec("choice", choices=("normal", "none"), target="adapter"),
    "noise_std": Spec("float", low=0.0, target="adapter"),
    "policy_delay": Spec("int", low=1),
    "target_policy_noise": Spec("float", low=0.0),
    "target_noise_clip": Spec("float", low=0.0),
    "target_update_interval": Spec("int", low=1),
    "target_entropy": Spec("float-or-auto"),
    # on-policy
    "normalize": Spec("bool", target="adapter"),
    "n_steps": Spec("int", low=2),
    "n_epochs": Spec("int", low=1),
    "gae_lambda": Spec("float", low=0.0, high=1.0),
    "clip_range": _positive(),
    "clip_range_vf": _positive("optional-float"),
    "normalize_advantage": Spec("bool"),
    "vf_coef": Spec("float", low=0.0),
    "max_grad_norm": _positive(),
    "cg_max_steps": Spec("int", low=1),
    "cg_damping": Spec("float", low=0.0),
    "line_search_shrinking_factor": Spec("float", low=0.0, high=1.0, low_open=True),
    "line_search_max_iter": Spec("int", low=1),
    "n_critic_updates": Spec("int", low=1),
    "sub_sampling_factor": Spec("int", low=1),
}
# Keys whose kind differs by algorithm: ent_coef a constant for PPO, a constant or "auto" for
# SAC; target_kl null (no limit) or a number for PPO, a number for TRPO (its line search's step)
_BY_ALGO = {
    "ent_coef": {"ppo": Spec("float", low=0.0), "sac-sb3": Spec("ent-coef", low=0.0)},
    "target_kl": {"ppo": _positive("optional-float"), "trpo": _positive()},
}

_OFF_POLICY_KEYS = (
    "net_arch",
    "activation_fn",
    "learning_rate",
    "buffer_size",
    "learning_starts",
    "batch_size",
    "tau",
    "gamma",
    "train_freq",
    "gradient_steps",
)
_ON_POLICY_KEYS = (
    "net_arch",
    "activation_fn",
    "log_std_init",
    "ortho_init",
    "normalize",
    "learning_rate",
    "n_steps",
    "batch_size",
    "gamma",
    "gae_lambda",
    "normalize_advantage",
    "target_kl",
)
ALGO_KEYS: dict[str, tuple[str, ...]] = {
    "ddpg": (*_OFF_POLICY_KEYS, "noise_type", "noise_std"),
    "td3": (
        *_OFF_POLICY_KEYS,
        "policy_delay",
        "target_policy_noise",
        "target_noise_clip",
        "noise_type",
        "noise_std",
    ),
    "sac-sb3": (*_OFF_POLICY_KEYS, "ent_coef", "target_update_interval", "target_entropy"),
    "ppo": (
        *_ON_POLICY_KEYS,
        "n_epochs",
        "clip_range",
        "clip_range_vf",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
    ),
    "trpo": (
        *_ON_POLICY_KEYS,
        "cg_max_steps",
        "cg_damping",
        "line_search_shrinking_factor",
        "line_search_max_iter",
        "n_critic_updates",
        "sub_sampling_factor",
    ),
}


def spec(algo: str, key: str) -> Spec:
    """The :class:`Spec` of ``key`` for ``algo`` (TacbenchError naming the valid keys if none)."""
    check_algo(algo)
    if key not in ALGO_KEYS[algo]:
        close = [k for k in ALGO_KEYS[algo] if key in k or k in key]
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        raise TacbenchError(
            f"unknown hyperparameter {key!r} for {algo}.{hint} Valid keys: "
            f"{', '.join(sorted(ALGO_KEYS[algo]))}."
        )
    return _BY_ALGO[key][algo] if key in _BY_ALGO else SPECS[key]


def check_algo(algo: str) -> None:
    """Refuse an algorithm name that is not a baseline."""
    if algo not in ALGOS:
        raise TacbenchError(f"unknown baseline {algo!r}; choose one of {', '.join(ALGOS)}.")


def _number(value: Any) -> float | None:
    """``value`` as a float if it is a number or a numeric string (YAML reads ``1e-3`` as text)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return None
    return None


def _in_range(number: float, rule: Spec) -> bool:
    if not math.isfinite(number):
        return False
    if rule.low is not None and (number <= rule.low if rule.low_open else number < rule.low):
        return False
    return rule.high is None or number <= rule.high


def coerce(algo: str, key: str, value: Any, given: str = "") -> Any:
    """Check ``value`` for ``key`` and return it in canonical form (JSON-ready); an error names
    it as ``given`` (a TAC flag, ``--learning-starts -5``), else as ``--hp key=value``."""
    rule = spec(algo, key)
    given = given or f"--hp {key}={_text(value)}"
    bad = TacbenchError(f"{given}: {key} for {algo} must be {rule.describe()}.")
    kind = rule.kind
    if kind == "bool":
        if isinstance(value, bool):
            return value
        raise bad
    if kind == "choice":
        if isinstance(value, str) and value.lower() in rule.choices:
            return value.lower()
        raise bad
    if kind == "layers":
        if (
            isinstance(value, list)
            and value
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value)
        ):
            return list(value)
        raise bad
    if kind == "train-freq":  # SB3 reads n as [n, "step"]: one spelling, one variant folder
        if isinstance(value, list) and len(value) == 2 and value[1] in ("step", "episode"):
            count = _integer(value[0], 1, bad)
            return count if value[1] == "step" else [count, "episode"]
        return _integer(value, 1, bad)
    if kind == "optional-float" and value is None:
        return None
    if (
        kind in ("float-or-auto", "ent-coef")
        and isinstance(value, str)
        and value.startswith("auto")
    ):
        initial = kind == "ent-coef" and value.startswith("auto_")  # the learned value's start
        # SB3 reads the start as the text up to a second "_": auto_1_0 would start at 1, not 10
        start = _number(value[5:]) if initial and "_" not in value[5:] else None
        if value == "auto":
            return value
        if start is not None and FLOAT32_TINY <= start < math.inf:  # SB3's "auto" starts at 1
            return "auto" if start == 1 else f"auto_{start!r}"  # auto_1e-3 is auto_0.001
        raise bad
    number = _number(value)
    if number is None or not _in_range(number, rule):
        raise bad
    check_normal(number, given)
    if kind == "int":
        return _integer(value, rule.low, bad)
    return number


def _integer(value: Any, low: float | None, error: TacbenchError) -> int:
    """An integer from an int or an integral number (``1e4``), at least ``low``."""
    number = _number(value)
    if number is None or not number.is_integer() or (low is not None and number < low):
        raise error
    return int(number)


def _text(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value, default=str)


YAML_ONLY_NUMBER = re.compile(r"(?<![\w.])0[0-9xob]|\d:\d|\d_\d", re.IGNORECASE)
"""Numbers YAML 1.1 reads otherwise than they are written: octal 010 (8), hex 0x10, binary
0b10, base 60 (1:30 is 90) and digit groups (1_000)."""


def _plain(value: Any) -> bool:
    """Whether ``value`` is made of JSON's types only (YAML also reads dates and bytes)."""
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    return value is None or isinstance(value, str | int | float | bool)


def parse_overrides(algo: str, items: Sequence[str]) -> dict[str, Any]:
    """``["learning_rate=3e-4", "net_arch=[64,64]"]`` -> checked values (YAML syntax)."""
    overrides: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise TacbenchError(
                f"--hp {item!r}: write key=value, e.g. --hp learning_rate=3e-4. Valid keys for "
                f"{algo}: {', '.join(sorted(ALGO_KEYS[algo]))}."
            )
        if key in overrides:
            raise TacbenchError(f"--hp {key} is given twice.")
        try:
            value = yaml.safe_load(raw) if raw.strip() else None
        except yaml.YAMLError:
            value = raw
        if not _plain(value) or YAML_ONLY_NUMBER.search(raw):
            value = raw  # a date, bytes or a YAML 1.1 number (12:30 is 750): as written
        overrides[key] = coerce(algo, key, value)
    return overrides


def load_table(algo: str) -> dict[str, dict[str, Any]]:
    """The raw sections of ``baselines/hyperparams/<algo>.yaml``."""
    check_algo(algo)
    text = resources.files("baselines").joinpath("hyperparams", f"{algo}.yaml").read_text()
    table = yaml.safe_load(text)
    if not isinstance(table, dict) or not isinstance(table.get("default"), dict):
        raise TacbenchError(f"baselines/hyperparams/{algo}.yaml needs a `default` section.")
    return table


def resolve(algo: str, env_id: str, task: str | None) -> tuple[dict[str, Any], list[str]]:
    """The table's values for ``env_id`` (paper task name ``task``) and the sections used.

    Another version of a paper task (``Hopper-v5``) with no section of its own takes the section
    of the task's id in the default suite (``Hopper-v4``, where RL Zoo tuned it), and says so."""
    table = load_table(algo)
    suite_id = paper.ENV_IDS.get(task or "")
    by_id = env_id
    if env_id not in table and suite_id and suite_id != env_id and suite_id in table:
        by_id = suite_id
    names = ["default", *(name for name in (task, by_id) if name and name in table)]
    values: dict[str, Any] = {}
    for name in names:
        for key, value in table[name].items():
            values[key] = coerce(algo, key, value)
    sections = [
        f"{name} (carried over to {env_id})" if name != env_id and name == by_id else name
        for name in names
    ]
    missing = sorted(set(ALGO_KEYS[algo]) - set(values))
    if missing:
        raise TacbenchError(f"baselines/hyperparams/{algo}.yaml sets no value for {missing}.")
    return values, sections


def variant(defaults: Mapping[str, Any], effective: Mapping[str, Any]) -> str:
    """``default`` when ``effective`` equals the table's values, else a slug of the differences
    plus a hash of them (``learning_rate0.0003-net_arch64x64-1a2b3c4d``), so runs with different
    overrides never share a directory. Values keep their signs and exponents
    (``log_std_init-2``, ``learning_rate1e-05``), as TAC's variants do (``-log_std_min-5``)."""
    changed = {k: effective[k] for k in sorted(effective) if effective[k] != defaults.get(k)}
    if not changed:
        return "default"
    slug = "-".join(
        key + re.sub(r"[^A-Za-z0-9.+-]", "", _short(value)) for key, value in changed.items()
    )
    digest = hashlib.sha1(json.dumps(changed, sort_keys=True).encode()).hexdigest()[:8]
    return f"{slug[:48]}-{digest}"


def _short(value: Any) -> str:
    if isinstance(value, list):
        return "x".join(_short(v) for v in value)
    if isinstance(value, float):
        return f"{value:g}"
    return "null" if value is None else str(value)
