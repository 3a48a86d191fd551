"""``tacbench sweep``: the paper's grids, locally, on Ray or on Slurm.

The options that replace a preset's settings (``--steps``, ``--critic-target``, ...) are
generated from the settings' declarations, like ``tacbench run``'s: a TAC setting applies to the
preset's TAC runs, a run setting to every run.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

import click

from tacbench import paper, trainers
from tacbench.cli.common import command_line
from tacbench.cli.options import ResultsFolder, cli_settings, setting_options
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.sweep import EXECUTORS, GROUPS
from tacbench.sweep.presets import PRESETS as SWEEP_PRESETS

_OVERRIDES = cli_settings(RunConfig, sweep=True)


def _fixed_q(value: str) -> float:
    """A ``--q`` of the sweep: a number. ``auto`` is a population learning q in one process,
    which a sweep (and --until-decided, one q per method) cannot compare."""
    if str(value).strip().lower() == "auto":
        raise TacbenchError(
            "--q auto trains one population that learns q, in one process: run it with "
            "tacbench run --q auto --seed 0 --seed 10 --seed 20 --seed 30. A sweep, and "
            "--until-decided's comparisons, take fixed q values, one per method."
        )
    try:
        return float(value)
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a number.") from None


@click.command()
@click.option(
    "--preset",
    type=click.Choice(list(SWEEP_PRESETS)),
    required=True,
    help="paper-q-grid (TAC, 9 q x 6 tasks x 10 seeds), paper-comparison (TAC best q, SAC = "
    "TAC q=1, DDPG, TD3, PPO, TRPO, SB3's SAC), smoke (tiny budgets). Sources: docs/sweep.md.",
)
@click.option("--env", "envs", multiple=True, help="Repeatable: keep only these tasks (Ant).")
@click.option(
    "--suite",
    type=click.Choice(list(paper.SUITES)),
    default=paper.DEFAULT_SUITE,
    show_default=True,
    help="The tasks' Gymnasium version: v4 (the studies', closest to the paper's v2) or v5 "
    "(Gymnasium's recommendation for new work; the paper's alpha and best q carried over).",
)
@click.option(
    "--q",
    "qs",
    type=click.UNPROCESSED,
    callback=lambda ctx, param, values: tuple(_fixed_q(v) for v in values),
    multiple=True,
    help="Repeatable: keep only these TAC q.",
)
@click.option(
    "--algo",
    "algos",
    type=click.Choice(trainers.ALGOS),
    multiple=True,
    help="Repeatable: keep only these algorithms.",
)
@click.option("--seed", "seeds", type=int, multiple=True, help="Repeatable: keep only these seeds.")
@setting_options(RunConfig, _OVERRIDES, sweep=True)
@click.option(
    "--executor",
    type=click.Choice(EXECUTORS),
    default="local",
    show_default=True,
    help="Where units train: processes here, a Ray cluster or Slurm jobs (docs/sweep.md).",
)
@click.option(
    "--workers",
    type=int,
    default=None,
    help="Units at once. [default: local: the core count, and at most 1/G with --gpus-per-run "
    "G; ray: what the cluster has room for; "
    "slurm: every unit, as one job array]",
)
@click.option("--address", default=None, help="Ray cluster: auto, HOST:6379 or ray://HOST:10001.")
@click.option(
    "--cpus-per-run", type=float, default=1.0, show_default=True, help="Ray or Slurm request."
)
@click.option(
    "--gpus-per-run",
    type=float,
    default=0.0,
    show_default=True,
    help="> 0: the runs train on cuda. Ray or Slurm: the request; local: each worker's share of "
    "the one GPU (0.2: at most five workers).",
)
@click.option("--partition", default=None, help="Slurm partition.  [default: the cluster's]")
@click.option(
    "--time",
    "time_limit",
    default=None,
    help="Slurm time limit per job, in sbatch's formats (90 and 1:30:00 are 90 minutes, 30:00 "
    "is 30, 2-0 two days); a unit that needs longer checkpoints at the limit and is "
    "requeued; at least 10 minutes.  [default: 4:00:00]",
)
@click.option(
    "--slurm-arg",
    "slurm_args",
    multiple=True,
    help="Repeatable: KEY=VALUE, an sbatch option without its dashes (mem=8G, qos=normal).",
)
@click.option(
    "--scratch",
    type=ResultsFolder("leave --scratch out for each node's temporary folder"),
    default=None,
    help="Ray: run directories and checkpoints on each node.  [default: tacbench-sweep in "
    "each node's temporary folder]",
)
@click.option("--shared-fs", is_flag=True, help="Ray: --out is the same path on every node.")
@click.option(
    "--group",
    type=click.Choice(GROUPS),
    default="task",
    show_default=True,
    help="task: TAC runs of one task that differ only in q, alpha or seed train as members of "
    "one unit (process or Ray task); seeds: only runs that differ in seed; none: one run each.",
)
@click.option(
    "--members",
    type=int,
    default=None,
    help="At most this many members per unit.  [default: what this machine's memory holds with "
    "every worker busy, and small enough that every worker gets a unit; --dry-run shows it]",
)
@click.option("--max-retries", type=int, default=2, show_default=True, help="Per failed run.")
@click.option(
    "--out",
    type=ResultsFolder(),
    default=Path("results"),
    show_default=True,
    help="Results folder: runs/... as `tacbench run`, and sweep/ (state, summary, logs).",
)
@click.option(
    "--until-decided",
    is_flag=True,
    help="Train in interims until AdaStop decides each task's comparisons (docs/sequential.md).",
)
@click.option(
    "--interim-runs",
    type=int,
    default=None,
    help="--until-decided: runs each open method gets per interim (AdaStop's n).  [default: 5]",
)
@click.option(
    "--interims",
    type=int,
    default=None,
    help="--until-decided: at most this many interims (AdaStop's K).  [default: 2, so at most "
    "the paper's ten seeds]",
)
@click.option(
    "--fwer",
    type=float,
    default=None,
    help="--until-decided: family-wise error rate of a task's comparisons (not TAC's --alpha).  "
    "[default: 0.05]",
)
@click.option(
    "--control",
    default=None,
    help="--until-decided: what each method is compared with: a method as the report names it "
    "('SAC (TAC q=1)', 'TD3') or q=1.5, best-q (TAC at the paper's best q), or pairs (every "
    "pair).  [default: best-q when the grid has TAC and baselines, q=1 for TAC alone, pairs for "
    "baselines alone]",
)
@click.option("--dry-run", is_flag=True, help="Print the plan and cost estimate; train nothing.")
@click.option(
    "--calibrate",
    is_flag=True,
    help="With --dry-run: first measure, by a short training of each kind of unit, what the "
    "plan's units cost on this CPU class, and keep it for later dry runs (a few minutes).",
)
@click.option(
    "--recalibrate",
    is_flag=True,
    help="With --dry-run: measure the plan's units again, replacing what this class stored "
    "(the same class on another host or day can run at another speed).",
)
@click.pass_context
def sweep(ctx: click.Context, preset: str, **p: Any) -> None:
    """Train a preset grid of runs (or what is left of it) locally, on Ray or on Slurm; rerun
    the same command to resume after Ctrl-C or a crash (docs/sweep.md).

    Exit status: 0 when every run is complete, 1 when a run failed more than --max-retries
    times, 130/143/129 when interrupted (Ctrl-C/SIGTERM/SIGHUP; rerun to resume), 2 for a usage
    error.
    """
    from tacbench.sweep import driver, dry_run, preflight  # torch only when this command runs

    grid, options = _grid_and_options(ctx, preset, p)
    if warning := options.oversubscribed():
        click.echo(warning, err=True)
    sequential = {k: p[k] for k in ("interim_runs", "interims", "fwer", "control")}
    if p["until_decided"]:
        if p["seeds"]:
            raise click.UsageError(
                "--until-decided takes its seeds from the design (--interim-runs per interim, "
                "the preset's seeds first): leave --seed out."
            )
        if flag := next((f for f in ("calibrate", "recalibrate") if p[f]), None):
            raise click.UsageError(
                f"--{flag} prices a plain sweep's plan: run the same sweep without "
                f"--until-decided with --dry-run --{flag} first; this dry run then prices the "
                "same kinds of unit from the rates it stored."
            )
        _until_decided(ctx, grid, p["out"], options, sequential, p["dry_run"])
        return
    given = [f"--{k.replace('_', '-')}" for k, v in sequential.items() if v is not None]
    if given:
        verb = "applies" if len(given) == 1 else "apply"
        raise click.UsageError(f"{' and '.join(given)} only {verb} with --until-decided.")
    for flag in ("calibrate", "recalibrate"):
        if p[flag] and not p["dry_run"]:
            raise click.UsageError(f"--{flag} prices a plan: give it with --dry-run.")
    if p["dry_run"]:
        from tacbench.runs.files import check_writable

        check_writable(p["out"])  # as the sweep itself would, though the dry run writes nothing
        work, _ = driver.load_plan(grid, p["out"], options, save=False)
        preflight.check_sizes(work, options)
        if p["calibrate"] or p["recalibrate"]:
            from tacbench.sweep import calibration

            calibration.calibrate(
                calibration.unit_configs(work),
                report=lambda line: click.echo(line, err=True),
                again=p["recalibrate"],
            )
        workers = options.worker_count()
        click.echo(dry_run.describe_plan(work, workers, options.group, options.workers_source()))
        return
    result = driver.run_sweep(grid, p["out"], options)
    click.echo(result.text)
    if not result.kept:
        click.echo(f"wrote {p['out'] / 'sweep' / 'summary.json'} and summary.txt")
    ctx.exit(result.exit_code)


def _until_decided(
    ctx: click.Context,
    grid: Any,
    out: Path,
    options: Any,
    given: dict[str, Any],
    dry_run: bool,
) -> None:
    """``--until-decided``: the sequential sweep, or its dry run."""
    from tacbench.sweep import until_decided
    from tacbench.sweep.sequential_design import Design

    fields = {"n": "interim_runs", "K": "interims", "alpha": "fwer", "control": "control"}
    design = Design(
        **{field: given[flag] for field, flag in fields.items() if given[flag] is not None}
    )
    if dry_run:
        click.echo(until_decided.describe_design(grid, out, options, design))
        return
    outcome = until_decided.run_until_decided(grid, out, options, design)
    click.echo(outcome.text)
    click.echo(f"wrote {out / 'sweep' / 'sequential.json'}, summary.json and summary.txt")
    ctx.exit(outcome.exit_code)


def _grid_and_options(ctx: click.Context, preset: str, p: dict[str, Any]) -> tuple[Any, Any]:
    """The sweep's grid (the preset narrowed and its settings replaced) and its options, from
    the parsed flags ``p`` (the settings' flags are taken out of it)."""
    from tacbench.sweep import presets
    from tacbench.sweep.options import Options

    overrides = {name: p.pop(name) for name in _OVERRIDES}
    grid = presets.narrow(
        presets.get_preset(preset),
        presets.Narrowing(
            p["envs"],
            p["qs"],
            p["algos"],
            p["seeds"],
            {name: value for name, value in overrides.items() if value is not None},
            p.pop("suite"),
        ),
    )
    options = Options(
        executor=p["executor"],
        workers=p["workers"],
        address=p["address"],
        cpus_per_run=p["cpus_per_run"],
        gpus_per_run=p["gpus_per_run"],
        scratch=p["scratch"],
        shared_fs=p["shared_fs"],
        group=p["group"],
        members=p["members"],
        max_retries=p["max_retries"],
        command=command_line(ctx),
        partition=p["partition"],
        slurm_args=p["slurm_args"],
        time_limit=p["time_limit"],
    )
    return grid, options


def recorded_sweep(command: str, out: Path) -> tuple[Any, Any]:
    """The grid and options of a recorded ``tacbench sweep ...`` command (a run's config.json,
    a sweep's summary.json), with its results folder replaced by ``out``."""
    args = shlex.split(command)
    if args[:2] != ["tacbench", "sweep"]:
        raise TacbenchError(f"not a tacbench sweep command: {command!r}")
    try:
        with sweep.make_context("sweep", [*args[2:], "--out", str(out)]) as ctx:
            p = dict(ctx.params)
            return _grid_and_options(ctx, p.pop("preset"), p)
    except click.ClickException as err:  # a flag renamed or removed since it was recorded
        raise TacbenchError(
            f"this tacbench does not accept the recorded command: {err.format_message()}"
        ) from None
