"""``tacbench study NAME commands|analyse``: the published studies' commands and tables, and
``tacbench study bills``: what their sweeps took against the dry run's price
(:mod:`tacbench.studies`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from tacbench.cli.options import ResultsFolder
from tacbench.errors import TacbenchError, plural
from tacbench.studies import parity as parity_study

if TYPE_CHECKING:
    import pandas as pd

_RESULTS = click.Path(exists=True, file_okay=False, path_type=Path)
_OUT = ResultsFolder("leave --out out to write no CSV")
F = TypeVar("F", bound=Callable[..., Any])


def _commands_out(default: str) -> Callable[[F], F]:
    """A study's ``commands --out``: the results folder its printed commands write to."""
    return click.option(
        "--out",
        type=ResultsFolder(f"the default is {default}"),
        default=default,
        show_default=True,
        help="Results folder.",
    )


def _check_out(out: Path | None, files: Sequence[str], inputs: Sequence[Path] = ()) -> None:
    """Before any work: ``out`` can be written, no folder stands where one of ``files`` goes,
    and none of them is an input file of the analysis (``inputs``), which it would replace."""
    if out is None:
        return
    from tacbench.runs import check_writable

    check_writable(out)
    given = {path.resolve(): path for path in inputs}
    for name in files:
        target = out / name
        if target.is_dir():
            raise TacbenchError(
                f"{target} is a folder, where this writes its {name}; move it away, or choose "
                "another --out."
            )
        if target.resolve() in given:
            raise TacbenchError(
                f"--out {out} would replace the input {given[target.resolve()]} with its own "
                f"{name}; choose another --out."
            )


def _show(tables: Mapping[str, pd.DataFrame], out: Path | None) -> None:
    """Print each table (a ``cautions`` table as ``caution:`` lines on stderr); with ``out``,
    also write it there as ``<name>.csv``."""
    import pandas as pd

    with pd.option_context("display.width", 200):
        for name, frame in tables.items():
            if name == "cautions":
                continue
            text = frame.to_string(index=False, float_format=lambda x: f"{x:.2f}")
            click.echo(f"{name}:\n{text}\n")
    for caution in tables.get("cautions", pd.DataFrame({"caution": []}))["caution"]:
        click.echo(f"caution: {caution}", err=True)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        for name, frame in tables.items():
            frame.to_csv(out / f"{name}.csv", index=False)
        click.echo(f"wrote {', '.join(f'{name}.csv' for name in tables)} to {out}")


@click.group()
def study() -> None:
    """The published studies: print a study's commands, analyse its runs, or price its sweeps."""


@study.group()
def adaptive() -> None:
    """Learned q and alpha against the fixed values on the same seeds (docs/adaptive.md)."""


@adaptive.command(name="commands")
@_commands_out("results/adaptive")
def adaptive_commands(out: Path) -> None:
    """Print the study's tacbench run commands."""
    from tacbench.studies import adaptive as adaptive_study

    click.echo("\n".join(adaptive_study.commands(str(out))))


@adaptive.command(name="analyse")
@click.option("--results", type=_RESULTS, required=True, help="The study's results folder.")
@click.option("--out", type=_OUT, help="Also write each table here as CSV.")
def adaptive_analyse(results: Path, out: Path | None) -> None:
    """Print the study's tables: the populations, alpha, each member's final q."""
    from tacbench.studies import adaptive as adaptive_study

    _check_out(out, [f"{name}.csv" for name in adaptive_study.TABLES])
    _show(adaptive_study.analyse(results), out)


@study.group()
def parity() -> None:
    """TAC at q = 1 against stable-baselines3's SAC (docs/parity.md)."""


@parity.command(name="commands")
@click.option("--env", "envs", multiple=True, help="Repeatable.  [default: the study's]")
@click.option(
    "--seed",
    "seeds",
    type=click.IntRange(min=0),
    multiple=True,
    help="Repeatable.  [default: 0-40]",
)
@click.option("--steps", type=click.IntRange(min=1), default=parity_study.STEPS, show_default=True)
@_commands_out("results/parity")
def parity_commands(envs: tuple[str, ...], seeds: tuple[int, ...], steps: int, out: Path) -> None:
    """Print the study's tacbench run commands."""
    from tacbench.envs import resolve_env_id

    # each once (hopper and Hopper-v4 are one task; tacbench run refuses a seed given twice);
    # a bad name says so now
    tasks = list(dict.fromkeys(resolve_env_id(env) for env in envs)) or parity_study.ENVS
    once = list(dict.fromkeys(seeds)) or parity_study.SEEDS
    lines = parity_study.commands(tasks, once, steps, str(out))
    click.echo("\n".join(lines))


@parity.command(name="analyse")
@click.option(
    "--results",
    type=_RESULTS,
    multiple=True,
    default=[Path("results/parity")],
    show_default=True,
    help="Repeatable: the runs of several folders, each run in one of them.",
)
@click.option("--out", type=_OUT, help="Also write each table here as CSV, and curves.png.")
@click.option(
    "--reps",
    type=click.IntRange(min=100),  # as tacbench report: fewer make no interval worth reading
    default=parity_study.REPS,
    show_default=True,
)
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
    results: tuple[Path, ...],
    out: Path | None,
    reps: int,
    fraction: float,
    by_variant: bool,
    finals: tuple[Path, ...],
) -> None:
    """Print the learning curves, the final returns and their differences to SB3."""
    files = [*(f"{name}.csv" for name in parity_study.TABLES), parity_study.FIGURE]
    _check_out(out, files, finals)
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

    _check_out(out, [f"{name}.csv" for name in sequential_study.TABLES])
    _show(sequential_study.analyse(results, reps), out)


@study.command(name="bills")
@click.argument("results", nargs=-1, required=True, type=_RESULTS)
@click.option(
    "--calibrate",
    is_flag=True,
    help="First calibrate, on this CPU class, the units it has not calibrated (a few minutes "
    "per kind of unit), as `tacbench sweep --dry-run --calibrate` does; only of the sweeps "
    "that can test their price.",
)
@click.option(
    "--recalibrate",
    is_flag=True,
    help="First measure every unit again (of the sweeps that can test their price), replacing "
    "this class's calibrations, as `tacbench sweep --dry-run --recalibrate` does.",
)
def bills(results: tuple[Path, ...], calibrate: bool, recalibrate: bool) -> None:
    """What each sweep that trained the runs under RESULTS took, against what the dry run
    prices its command at on this CPU class (docs/sweep.md, "The price and the bill")."""
    from tacbench.cli.sweep import recorded_sweep
    from tacbench.hardware import cpu_class
    from tacbench.progress import duration
    from tacbench.sweep import bills as sweep_bills
    from tacbench.sweep.summary import load_note

    here = cpu_class()
    found = sweep_bills.sweeps(*results)
    if not found:
        raise TacbenchError(
            f"no run under {', '.join(map(str, results))} was trained by a tacbench sweep; "
            "name the folders of a sweep's runs (tacbench run's are not priced)."
        )
    priceable = []
    for took in found:
        try:
            grid, options = recorded_sweep(took.command, Path("unused"))
        except TacbenchError as err:  # one sweep that cannot be priced does not hide the others
            click.echo(f"{took.command}\n  cannot be priced here: {err}")
            continue
        if took.workers is not None:  # what it ran on, whatever the command left to the machine
            options = dataclasses.replace(options, workers=took.workers)
        priceable.append((took, sweep_bills.fresh_plan(grid, options), options))
    if calibrate or recalibrate:  # each kind of unit once, of the sweeps that test the price
        from tacbench.sweep import calibration

        calibration.calibrate(
            [
                unit
                for took, work, _ in priceable
                if not sweep_bills.not_comparable(took, work)
                for unit in calibration.unit_configs(work)
            ],
            report=lambda line: click.echo(line, err=True),
            again=recalibrate,
        )
    for took, work, options in priceable:
        priced = sweep_bills.reprice(work, options)
        runs = plural(took.runs, "run")
        named = len(took.keys & {p.run.key for p in work.runs})
        part = named == took.runs < priced.runs  # a study that keeps part of its sweep
        if part:
            runs += f" of the {priced.runs} its command plans"
        ran_on = took.cpu_class or "CPU class not recorded"
        line = f"  took {duration(took.wall_s)} ({took.source}; {ran_on}"
        if took.priced_at_start_s is not None:
            line += f"; priced at its start {duration(took.priced_at_start_s)}"
        line += "); priced here "
        workers = plural(priced.workers, "worker")
        if took.workers is None and "--workers" not in took.command.split():
            workers += " (this machine's: the command left them to it)"
        line += f"{duration(priced.wall_s)} on {workers} ({here}, "
        why_not = sweep_bills.not_comparable(took, work)
        if named != took.runs:
            runs += f", of which the command's plan names {named}"
        elif took.unfinished:
            runs += ", of which " + ", ".join(
                f"{n} {state}" for state, n in took.unfinished.items()
            )
        if why_not:
            line += f"not comparable: {why_not})"
        elif not priced.calibrated:
            line += "not calibrated: give --calibrate)"
        else:
            ratio = took.wall_s / priced.wall_s
            verdict = "within" if sweep_bills.within(took.wall_s, priced.wall_s) else "outside"
            line += f"calibrated): took {ratio:.2f}x the price, the price {verdict} 25 % of it"
            if took.cpu_class not in (None, here):
                line += " (another class: not the test)"
            if took.cpu_s is not None and not part:  # every run's CPU seconds, not a part's
                core_s = priced.core_hours * 3600
                line += (
                    f"\n  its runs' CPU time (eval.csv cpu_s): {duration(took.cpu_s)} of one core, "
                    f"{took.cpu_s / core_s:.2f}x the price's {duration(core_s)}"
                )
        load = load_note(took.load_average, took.cores, took.workers or 0)  # a bill's, or ""
        if load:
            line += f"\n  while it ran, {load}"
        click.echo(f"{took.command}\n  {runs}\n{line}")
