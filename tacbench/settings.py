"""One declaration per setting: a config field that carries its flag, help text and source.

A setting is a dataclass field made by :func:`setting`; its metadata (:class:`SettingInfo`)
says how the command line spells it, what it means, where its default comes from and how it
enters a run's variant name. ``tacbench run`` and ``tacbench sweep`` generate their options
from these declarations (:mod:`tacbench.cli.options`), and the configs validate with the same
flag names, so adding a TAC option is one field in :class:`tacbench.config.RunConfig` plus its
use. :class:`RunSettings` declares what every trainer's run has (steps, evaluation,
checkpoints, logging, hardware). No click and no torch here: the configs import this at CLI
start-up.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any, ClassVar

from tacbench import paper
from tacbench.errors import TacbenchError

_KEY = "tacbench"


@dataclass(frozen=True)
class SettingInfo:
    """How a setting appears on the command line and in a run's name.

    ``variant``: how a non-default value enters the run directory's variant name: a prefix to
    which the value is appended (``"ls"`` -> ``-ls100000``), or for a choice a word per value
    (``{"joint": "joint"}`` -> ``-joint``); None: never (the field cannot change what is
    learned, or has its own path component). ``neutral``: a resumed run may differ in it: it
    changes no number a run writes, or (:data:`REROUNDING_FIELDS`, the hardware) only their
    rounding, which the resume then notes. ``cli``: offered by ``tacbench run`` (and
    ``sweep``, unless ``sweep`` is False). ``profile``: the default, None, stands for the value
    that the config's profile sets. ``shown_default``: how a computed default (None) is
    computed, for ``--help``.
    """

    help: str
    source: str
    flag: str = ""
    choices: tuple[str, ...] = ()
    variant: str | Mapping[str, str] | None = None
    neutral: bool = False
    cli: bool = True
    sweep: bool = True
    metavar: str | None = None
    profile: bool = False  # the default (None) is the value of the config's --profile
    shown_default: str = ""


def setting(
    default: Any,
    help: str,
    *,
    source: str,
    flag: str = "",
    choices: Sequence[str] = (),
    variant: str | Mapping[str, str] | None = None,
    neutral: bool = False,
    cli: bool = True,
    sweep: bool = True,
    metavar: str | None = None,
    profile: bool = False,
    shown_default: str = "",
) -> Any:
    """A dataclass field with a default and its :class:`SettingInfo` (see there)."""
    info = SettingInfo(
        help,
        source,
        flag,
        tuple(choices),
        variant,
        neutral,
        cli,
        sweep,
        metavar,
        profile,
        shown_default,
    )
    return field(default=default, metadata={_KEY: info})


@dataclass(frozen=True)
class Setting:
    """A declared setting of a config class: its field name, type, default and info."""

    name: str
    type: Any
    default: Any
    info: SettingInfo

    @property
    def flag(self) -> str:
        """The command-line flag, ``--name-with-dashes`` unless declared otherwise."""
        return self.info.flag or "--" + self.name.replace("_", "-")


def settings_of(cls: type) -> dict[str, Setting]:
    """Every declared setting of config class ``cls`` (and its bases), in field order."""
    return dict(_declared(cls))


@cache
def _declared(cls: type) -> tuple[tuple[str, Setting], ...]:
    """:func:`settings_of`, read once per class: resolving the type hints is slow, and every
    config validates with it."""
    hints = typing.get_type_hints(cls)
    return tuple(
        (f.name, Setting(f.name, hints[f.name], f.default, f.metadata[_KEY]))
        for f in dataclasses.fields(cls)
        if _KEY in f.metadata
    )


def flag_of(cls: type, name: str) -> str:
    """The flag of setting ``name`` of ``cls`` (``--name`` for an undeclared field)."""
    declared = settings_of(cls).get(name)
    return declared.flag if declared else "--" + name.replace("_", "-")


# the neutral settings that change the rounding of what a run writes (the hardware it runs on):
# a run may resume on other hardware, and the resume notes the change in status.json
REROUNDING_FIELDS = ("device", "threads")


def neutral_fields(*classes: type) -> tuple[str, ...]:
    """The fields of ``classes`` in which a resumed run may differ (``neutral``)."""
    return tuple(
        dict.fromkeys(n for cls in classes for n, s in settings_of(cls).items() if s.info.neutral)
    )


def check_integers(config: object, **minimums: int) -> None:
    """Each named field of ``config`` is an integer (not a bool) at least its minimum; else a
    TacbenchError names the flag."""
    for name, minimum in minimums.items():
        value = getattr(config, name)
        if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
            flag = flag_of(type(config), name)
            raise TacbenchError(f"{name} must be an integer >= {minimum} (got {value!r}); {flag}.")


def check_choice(config: object, name: str) -> None:
    """Field ``name`` of ``config`` is one of its declared choices; else a TacbenchError names
    the flag and the choices."""
    choices = settings_of(type(config))[name].info.choices
    value = getattr(config, name)
    if value not in choices:
        flag = flag_of(type(config), name)
        raise TacbenchError(f"{flag} must be one of {', '.join(choices)} (got {value!r}).")


def check_choices(config: object) -> None:
    """Every setting of ``config`` that declares choices holds one of them."""
    for name, declared in settings_of(type(config)).items():
        if declared.info.choices:
            check_choice(config, name)


class RunWarning(str):
    """A warning among the notes a run prints that is about the run's own settings (its budget,
    its schedule), not this machine: a sweep of such runs repeats it (tacbench.sweep.plan), where
    the compile note's warning, which describes the machine that plans, is left out."""


def never_updated(
    learning_starts: str, starts: int, total_steps: int, *, first_update_at_start: bool = False
) -> list[str]:
    """A warning, for the notes a run prints, when random steps (``learning_starts``, as the
    user set it) fill the whole run, so that its networks are never updated; else none.
    ``first_update_at_start``: the first update follows step ``starts`` itself (TAC's loop;
    SB3's follows the next one), so at ``starts == total_steps`` there is one, after the last
    step."""
    if starts < total_steps:
        return []
    once = first_update_at_start and starts == total_steps
    return [
        RunWarning(
            f"WARNING: {learning_starts} {starts:,} is not below --steps {total_steps:,}: every "
            "step takes a random action and the networks are "
            + ("updated once, after the last step" if once else "never updated")
        )
    ]


@dataclass(frozen=True, kw_only=True)
class RunSettings:
    """What every trainer's run has: its seed, length, evaluation, checkpoints, logging and
    hardware. The seed is repeatable on the command line (``--seed``), so it has no generated
    option."""

    seed: int = setting(0, "Random seed.", source="ours", cli=False)
    total_steps: int = setting(
        paper.TOTAL_STEPS,
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
        source="ours: a 1M-step run checkpoints 20 times",
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
        source="ours",
        neutral=True,
    )
    device: str = setting(
        "cpu",
        "Where the networks run (auto: cuda when available).",
        source="ours",
        choices=("cpu", "cuda", "auto"),
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
        check_choices(self)
