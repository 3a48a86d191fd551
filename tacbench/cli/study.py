"""``tacbench study NAME commands|analyse``: the published studies' commands and tables
(:mod:`tacbench.studies`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import click
import pandas as pd

from tacbench.cli.options import ResultsFolder
from tacbench.studies import parity as parity_study

_RESULTS = click.Path(exists=True, file_okay=False, path_type=Path)
_OUT = ResultsFolder("leave --out out to write no CSV")


def _show(tables: Mapping[str, pd.DataFrame], out: Path | None) -> None:
    """Print each table; with ``out``, also write it there as ``<name>.csv``."""
    with pd.option_context("display.width", 200):
        for name, frame in tables.items():
            text = frame.to_string(index=False, float_format=lambda x: f"{x:.2f}")
            click.echo(f"{name}:\n{text}\n")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        for name, frame in tables.items():
            frame.to_csv(out / f"{name}.csv", index=False)
        click.echo(f"wrote {', '.join(f'{name}.csv' for name in tables)} to {out}")


@click.group()
def study() -> None:
    """The published studies: print a study's commands, or analyse its runs."""


@study.group()
def adaptive() -> None:
    """Learned q and alpha against the fixed values on the same seeds (docs/adaptive.md)."""


@adaptive.command(name="commands")
@click.option("--out", default="results/adaptive", show_default=True, help="Results folder.")
def adaptive_commands(out: str) -> None:
    """Print the study's tacbench run commands."""
    from tacbench.studies import adaptive as adaptive_study

    click.echo("\n".join(adaptive_study.commands(out)))


@adaptive.command(name="analyse")
@click.option("--results", type=_RESULTS, required=True, help="The study's results folder.")
@click.option("--out", type=_OUT, help="Also write each table here as CSV.")
def adaptive_analyse(results: Path, out: Path | None) -> None:
    """Print the study's tables: the populations, alpha, each member's final q."""
    from tacbench.studies import adaptive as adaptive_study

    _show(adaptive_study.analyse(results), out)


@study.group()
def parity() -> None:
    """TAC at q = 1 against stable-baselines3's SAC (docs/parity.md)."""


@parity.command(name="commands")
@click.option("--env", "envs", multiple=True, help="Repeatable.  [default: the study's]")
@click.option("--seed", "seeds", type=int, multiple=True, help="Repeatable.  [default: 0-40]")
@click.option("--steps", type=int, default=parity_study.STEPS, show_default=True)
@click.option("--out", default="results/parity", show_default=True, help="Results folder.")
def parity_commands(envs: tuple[str, ...], seeds: tuple[int, ...], steps: int, out: str) -> None:
    """Print the study's tacbench run commands."""
    lines = parity_study.commands(
        envs or parity_study.ENVS, seeds or parity_study.SEEDS, steps, out
    )
    click.echo("\n".join(lines))


@parity.command(name="analyse")
@click.option("--results", type=_RESULTS, default=Path("results/parity"), show_default=True)
@click.option("--out", type=_OUT, help="Also write each table here as CSV, and curves.png.")
@click.option("--reps", type=click.IntRange(min=1), default=parity_study.REPS, show_default=True)
@click.option(
    "--fraction",
    type=float,
    default=parity_study.FRACTION,
    show_default=True,
    help="Final return: the evaluations in this last fraction of the steps.",
)
@click.option("--by-variant", is_flag=True, help="Name TAC runs by variant (an ablation).")
@click.option(
    "--finals",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    multiple=True,
    help="Repeatable: a CSV of final returns recorded by an earlier study (env, method, seed, "
    "return).",
)
def parity_analyse(
    results: Path,
    out: Path | None,
    reps: int,
    fraction: float,
    by_variant: bool,
    finals: tuple[Path, ...],
) -> None:
    """Print the learning curves, the final returns and their differences to SB3."""
    tables = parity_study.analyse(
        results, by_variant=by_variant, fraction=fraction, finals=finals, reps=reps
    )
    _show(tables, out)
    if out is not None:
        click.echo(f"wrote {parity_study.figure(tables, out)}")


@study.group()
def sequential() -> None:
    """AdaStop's sequential comparisons, checked: the paper-q-grid study replayed, and the error
    rate and power on synthetic grids (docs/sequential.md)."""


@sequential.command(name="commands")
def sequential_commands() -> None:
    """Print the command that makes docs/sequential.md's tables."""
    from tacbench.studies import sequential as sequential_study

    click.echo("\n".join(sequential_study.commands()))


@sequential.command(name="analyse")
@click.option(
    "--results",
    type=_RESULTS,
    default=Path("results/studies/paper-q-grid-100k"),
    show_default=True,
    help="The q-grid study to replay.",
)
@click.option("--reps", type=click.IntRange(min=1), default=500, show_default=True)
@click.option("--out", type=_OUT, help="Also write each table here as CSV.")
def sequential_analyse(results: Path, reps: int, out: Path | None) -> None:
    """Print the replay tables, and each design's error rate and power over REPS grids."""
    from tacbench.studies import sequential as sequential_study

    _show(sequential_study.analyse(results, reps), out)
