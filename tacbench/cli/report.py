"""``tacbench report``: figures, tables and statistics from run directories."""

from __future__ import annotations

from pathlib import Path

import click

from tacbench.cli.options import ResultsFolder


@click.command()
@click.option(
    "--results",
    type=ResultsFolder("the default is results/"),
    default=Path("results"),
    show_default=True,
    help="Folder holding runs/<algo>/<env>/<variant>/seed<k>/ (or the run folders themselves).",
)
@click.option(
    "--out",
    type=ResultsFolder("the default is results/report/"),
    default=Path("results/report"),
    show_default=True,
    help="Folder for index.html, report.md, the figures and the CSV tables (created if missing).",
)
@click.option(
    "--metric",
    type=click.Choice(["eval", "train"]),
    default="eval",
    show_default=True,
    help="eval: evaluation returns (eval.csv); train: training-episode returns (train.csv).",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["png", "svg", "pdf"]),
    default="png",
    show_default=True,
    help="File format of the figures.",
)
@click.option(
    "--reps",
    type=int,
    default=2000,
    show_default=True,
    help="Bootstrap replications for every confidence interval.",
)
@click.option(
    "--last",
    type=int,
    default=10,
    show_default=True,
    help="Final return = mean of each run's last N logged returns.",
)
@click.option(
    "--grid-points",
    type=int,
    default=200,
    show_default=True,
    help="At most this many points on the common step grid the curves are put on, per task.",
)
def report(
    results: Path, out: Path, metric: str, fmt: str, reps: int, last: int, grid_points: int
) -> None:
    """Figures, tables and rliable statistics from the run directories under --results."""
    from tacbench.errors import listing, plural
    from tacbench.report import ReportOptions, analyse, write_report  # pandas etc. only here
    from tacbench.report.write import check_out, leftovers
    from tacbench.runs.files import check_writable

    check_writable(out)  # before the analysis, which can take minutes
    check_out(out)

    options = ReportOptions(
        results=results,
        out=out,
        metric=metric,
        fmt=fmt,
        reps=reps,
        last=last,
        grid_points=grid_points,
    )
    analysed = analyse(options)
    written = write_report(analysed)
    runs, skipped = analysed.runset.runs, analysed.runset.skipped
    for caution in analysed.cautions:
        click.echo(f"caution: {caution}", err=True)
    older = leftovers(out, written)
    if older:
        click.echo(
            f"caution: {out} also holds {listing(older)}"
            ", which this report did not write (an earlier one's?); delete them, or use an "
            "empty --out",
            err=True,
        )
    click.echo(
        f"{plural(len(runs), 'run')} loaded ({int(runs['partial'].sum())} partial), "
        f"{len(skipped)} skipped"
        f"{' (see skipped.csv)' if skipped else ''}; wrote {out / 'index.html'} and "
        f"{out / 'report.md'}"
    )
