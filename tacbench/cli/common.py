"""What the command modules share: errors as click shows them, and the command line as recorded."""

from __future__ import annotations

import shlex
import signal
from collections import Counter
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import click

from tacbench.errors import TacbenchError
from tacbench.interrupts import SecondSignal, exit_status
from tacbench.runs.checkpoints import FULL_ERRNOS

if TYPE_CHECKING:
    from tacbench.runs import Outcome


class UserError(click.ClickException):
    """A :class:`TacbenchError` as click shows it: ``Error: <message>``, exit status 2."""

    exit_code = 2


class Group(click.Group):
    """A click group that turns :class:`TacbenchError` into a clean message and exit status 2,
    as it does a full disk under a command that has no words of its own for it (``figures``,
    ``report``, ``bench --json``: ``run`` and ``sweep`` say how to resume), and a Ctrl-C that
    no command handles (while one starts, say) into exit status 130."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except TacbenchError as err:
            raise UserError(str(err)) from None
        except OSError as err:
            if err.errno not in FULL_ERRNOS:
                raise
            what = err.filename or "the command's files"  # matplotlib's errors name none
            raise UserError(
                f"cannot write {what}: the disk is full; free some space, then run the command "
                "again."
            ) from None
        except SecondSignal as stopped:
            resume = stopped.resume or "the same command (with --resume for tacbench run)"
            click.echo(
                f"stopped at once by a second {stopped}: every run keeps its last checkpoint; "
                f"resume with: {resume}",
                err=True,
            )
            ctx.exit(stopped.exit_status)
        except KeyboardInterrupt as stopped:  # outside the commands' own handling of signals
            # (a regress whose reference run a signal stopped says which signal by its status)
            status = getattr(stopped, "exit_status", 0) or exit_status()
            name = "Ctrl-C" if status == 128 + signal.SIGINT else signal.Signals(status - 128).name
            click.echo(f"interrupted by {name}", err=True)
            ctx.exit(status)


def command_line(ctx: click.Context) -> str:
    """The flags the user gave, in canonical form (defaults left out): recorded in config.json."""
    parts = ["tacbench", ctx.info_name or "run"]
    for param in ctx.command.params:
        name = param.name or ""
        if ctx.get_parameter_source(name) != click.core.ParameterSource.COMMANDLINE:
            continue
        flag, value = param.opts[0], ctx.params[name]
        if isinstance(param, click.Option) and param.is_flag:
            parts.append(flag if value else (param.secondary_opts or [flag])[0])
        elif param.multiple:
            for item in value:
                parts += [flag, str(item)]
        else:
            parts += [flag, ",".join(map(str, value)) if isinstance(value, tuple) else str(value)]
    return shlex.join(parts)


def report_outcomes(ctx: click.Context, outcomes: Sequence[Outcome]) -> None:
    """One line per run, and a message that several runs share (a stopped group's resume
    command) once after them, with how many share it; exit status 128 + the stop signal's
    number if interrupted (:func:`tacbench.interrupts.exit_status`), 1 if a run failed."""
    sharing = Counter(outcome.message for outcome in outcomes if outcome.message)
    for outcome in outcomes:
        alone = outcome.message and sharing[outcome.message] == 1
        detail = f" ({outcome.message})" if alone else ""
        click.echo(f"seed {outcome.seed}: {outcome.state}, {outcome.directory}{detail}")
    for message, runs in sharing.items():
        if runs > 1:
            click.echo(f"{runs} runs: {message}")
    states = {outcome.state for outcome in outcomes}
    if "interrupted" in states:
        ctx.exit(exit_status())
    if "failed" in states:
        ctx.exit(1)
