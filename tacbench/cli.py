"""The ``tacbench`` command line: parse flags, build a config, call the library. No logic here."""

from __future__ import annotations

from typing import Any

import click

from tacbench import __version__
from tacbench.errors import TacbenchError


class _UserError(click.ClickException):
    """A :class:`TacbenchError` as click shows it: ``Error: <message>``, exit status 2."""

    exit_code = 2


class _Group(click.Group):
    """A click group that turns :class:`TacbenchError` into a clean message and exit status 2."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except TacbenchError as err:
            raise _UserError(str(err)) from None


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="tacbench")
def cli() -> None:
    """tacbench: train, sweep and report Tsallis Actor-Critic and its baselines."""


def main() -> None:
    """Console-script entry point."""
    cli()
