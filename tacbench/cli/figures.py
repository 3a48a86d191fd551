"""``tacbench figures``: the paper's theory figures and the numbers they plot."""

from __future__ import annotations

from pathlib import Path

import click

from tacbench.cli.options import ResultsFolder


@click.command()
@click.option(
    "--out",
    type=ResultsFolder("the default is results/figures/"),
    default=Path("results/figures"),
    show_default=True,
    help="Directory for the PNGs and CSVs (created if missing).",
)
def figures(out: Path) -> None:
    """Write the paper's theory figures (PNG) and the numbers they plot (CSV)."""
    from tacbench.theory.figures import write_figures  # matplotlib only when this command runs

    for path in write_figures(out):
        click.echo(f"wrote {path}")
