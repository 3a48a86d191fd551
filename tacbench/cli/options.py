"""Click options generated from the declared settings (:mod:`tacbench.settings`).

``tacbench run`` offers every setting of TAC's config with its default; ``tacbench sweep``
offers the same settings as overrides of its preset, defaulting to the preset's value. Each
option's help names the default's source. The option's destination is the config field's name,
so a command passes its options to the config as they are.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

import click

from tacbench.paper import PROFILES
from tacbench.settings import Setting, settings_of

F = TypeVar("F", bound=Callable[..., Any])


class ResultsFolder(click.Path):
    """A results folder to write to or read from: not a file, and not an empty string (which
    would write into, or read everything under, the current folder)."""

    def __init__(self, hint: str = "the default is results/") -> None:
        super().__init__(file_okay=False, path_type=Path)
        self.hint = hint

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and not value.strip():
            self.fail(f"must name a folder (got an empty string); {self.hint}.")
        return super().convert(value, param, ctx)


class NumberTuple(click.ParamType):
    """Comma-separated numbers of one kind: ``400,300`` -> ``(400, 300)`` (int), ``0.5,5`` ->
    ``(0.5, 5.0)`` (float)."""

    def __init__(self, kind: type[int] | type[float], example: str) -> None:
        self.kind, self.example = kind, example
        self.name = "integers" if kind is int else "numbers"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, tuple):
            return value
        try:
            return tuple(self.kind(part) for part in str(value).split(","))
        except ValueError:
            self.fail(
                f"{value!r} is not a comma-separated list of {self.name} ({self.example})",
                param,
                ctx,
            )


class NumberOrAuto(click.ParamType):
    """A number, or ``auto`` (learned: --q auto, --alpha auto)."""

    name = "float|auto"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if value == "auto" or isinstance(value, float):
            return value
        try:
            return float(value)
        except ValueError:
            self.fail(f"{value!r} is neither a number nor 'auto'", param, ctx)


def _shown(value: Any) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def default_text(declared: Setting) -> str:
    """A setting's default as ``--help`` shows it: its value, the profiles' values where the
    profile sets it (``paper: 300; reference, authors-*: 400,300``: profiles grouped by
    value), or how a computed default is computed."""
    info = declared.info
    if info.profile:
        groups: dict[str, list[str]] = {}
        for name, values in PROFILES.items():
            groups.setdefault(_shown(values[declared.name]), []).append(name)
        authors = [name for name in PROFILES if name.startswith("authors-")]
        shown = []
        for value, names in groups.items():
            if set(authors) <= set(names):  # every dated version alike: one word for them all
                names = [n for n in names if n not in authors] + ["authors-*"]
            shown.append(f"{', '.join(names)}: {value}")
        return "; ".join(shown)
    if info.shown_default:
        return info.shown_default
    return _shown(declared.default)


def _option(declared: Setting, *, sweep: bool) -> Callable[[F], F]:
    info = declared.info
    shown = "the preset's" if sweep else f"{default_text(declared)} ({info.source})"
    kwargs: dict[str, Any] = {
        "help": f"{info.help}  [default: {shown}]",
        "default": None if sweep else declared.default,
    }
    if declared.type is bool:  # --name/--no-name
        return click.option(f"{declared.flag}/--no-{declared.flag[2:]}", declared.name, **kwargs)
    if info.choices:
        kwargs["type"] = click.Choice(info.choices)
    elif declared.type in (tuple[int, ...], tuple[int, ...] | None):
        kwargs["type"] = NumberTuple(int, "400,300")
    elif declared.type == tuple[float, ...]:
        kwargs["type"] = NumberTuple(float, "0.5,5")
    elif declared.type == float | None:
        kwargs["type"] = float
    else:
        kwargs["type"] = declared.type
    if info.metavar:
        kwargs["metavar"] = info.metavar
    return click.option(declared.flag, declared.name, **kwargs)


def setting_options(cls: type, names: Iterable[str], *, sweep: bool = False) -> Callable[[F], F]:
    """A decorator adding the options of settings ``names`` of config class ``cls``, in order;
    with ``sweep`` each defaults to None (the preset's value)."""
    declared = settings_of(cls)
    decorators = [_option(declared[name], sweep=sweep) for name in names]

    def decorate(function: F) -> F:
        for decorator in reversed(decorators):
            function = decorator(function)
        return function

    return decorate


def cli_settings(cls: type, *, sweep: bool = False) -> list[str]:
    """The names of ``cls``'s settings offered on the command line (by ``sweep``)."""
    return [
        name
        for name, declared in settings_of(cls).items()
        if declared.info.cli and (declared.info.sweep or not sweep)
    ]
