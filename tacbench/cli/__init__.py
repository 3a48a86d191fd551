"""The ``tacbench`` command line: parse flags, build a config, call the library. No logic here.

One module per command (``run``, ``sweep``, ``report``, ``figures``, ``envs``, ``bench``,
``regress``, ``video``, ``study``); ``common`` holds what they share and ``options`` generates
the options of the declared settings.
"""

from __future__ import annotations

import click

from tacbench import __version__
from tacbench.cli.bench import bench
from tacbench.cli.common import Group
from tacbench.cli.envs import envs_command
from tacbench.cli.figures import figures
from tacbench.cli.regress import regress
from tacbench.cli.report import report
from tacbench.cli.run import run
from tacbench.cli.study import study
from tacbench.cli.sweep import sweep
from tacbench.cli.video import video

__all__ = ["cli", "main"]


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="tacbench")
def cli() -> None:
    """tacbench: train, sweep and report Tsallis Actor-Critic and its baselines."""


for command in (figures, report, run, sweep, bench, regress, envs_command, video, study):
    cli.add_command(command)


def main() -> None:
    """Console-script entry point."""
    cli()
