"""``tacbench regress``: reproduce the committed reference results (docs/regression.md)."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import click

from tacbench.cli.options import ResultsFolder
from tacbench.errors import TacbenchError

if TYPE_CHECKING:
    from tacbench.regress.manifest import CommandResult, Runner


def in_process(group: click.Group) -> Runner:
    """A :data:`~tacbench.regress.manifest.Runner` that runs ``tacbench run ARGS --out OUT`` in
    this process through ``group`` (the ``tacbench`` command group), its output captured. A
    command this tacbench refuses (a flag renamed since it was recorded) ends with exit status 2
    and the error as the last line of its output, as on the command line."""
    from tacbench.regress.manifest import finished

    def run(args: Sequence[str], out: Path) -> CommandResult:
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
            try:
                code = group.main(
                    ["run", *args, "--out", str(out)], prog_name="tacbench", standalone_mode=False
                )
            except click.ClickException as err:
                print(f"Error: {err.format_message()}")
                code = err.exit_code
        return finished(int(code or 0), buffer.getvalue(), out)

    return run


@click.command()
@click.option(
    "--against",
    type=ResultsFolder("the default is results/reference"),
    default=Path("results/reference"),
    show_default=True,
    help="Folder of the committed references (exact/, theory/, stat/).",
)
@click.option(
    "--tier",
    type=click.Choice(["exact", "theory", "stat"]),
    default="exact",
    show_default=True,
    help="exact: short runs reproduced to the last digit, plus the theory CSVs (minutes); "
    "theory: the CSVs alone; stat: longer runs on fresh seeds, tested for a drop in return.",
)
@click.option(
    "--update",
    is_flag=True,
    help="Regenerate the tier's references on purpose (records commands, versions, date).",
)
@click.option(
    "--only",
    multiple=True,
    metavar="NAME",
    help="Repeatable: check only these exact runs or statistical groups (names in the manifest).",
)
@click.option(
    "--work",
    type=ResultsFolder("leave --work out for a temporary folder"),
    default=None,
    help="Empty folder to keep the fresh runs in.  [default: a temporary folder, deleted]",
)
@click.pass_context
def regress(
    ctx: click.Context,
    against: Path,
    tier: str,
    update: bool,
    only: tuple[str, ...],
    work: Path | None,
) -> None:
    """Compare fresh results with the committed references (docs/regression.md).

    Prints what matched, what drifted and by how much. Exit status: 0 when nothing regressed,
    1 on a regression, 2 for a usage error, 3 when a tier compared nothing here (no references
    for this CPU class, or other library versions: the message gives the command that records
    them).
    """
    from tacbench import regress as checks  # torch only when this command runs

    root = ctx.find_root().command
    assert isinstance(root, click.Group)
    runner = in_process(root)

    if update:
        if only:
            raise TacbenchError("--only selects what to check; --update regenerates a whole tier.")
        for path in checks.update(against, tier, work, log=click.echo, runner=runner):
            click.echo(f"wrote {path}")
        return
    results = checks.check(against, tier, work, only, log=click.echo, runner=runner)
    for result in results:
        click.echo(checks.format_result(result))
    if any(result.regressions for result in results):
        ctx.exit(1)
    if any(result.skipped for result in results):
        ctx.exit(3)
