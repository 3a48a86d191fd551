"""The ``tacbench`` command line: parse flags, build a config, call the library. No logic here."""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from baselines import ALGOS as BASELINES
from tacbench import __version__, config
from tacbench.errors import TacbenchError
from tacbench.sweep.presets import PRESETS as SWEEP_PRESETS

if TYPE_CHECKING:
    from tacbench.training import Outcome


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


@cli.command()
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("results/figures"),
    show_default=True,
    help="Directory for the PNGs and CSVs (created if missing).",
)
def figures(out: Path) -> None:
    """Write the paper's theory figures (PNG) and the numbers they plot (CSV)."""
    from tacbench.figures import write_figures  # matplotlib only when this command runs

    for path in write_figures(out):
        click.echo(f"wrote {path}")


@cli.command()
@click.option(
    "--results",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("results"),
    show_default=True,
    help="Folder holding runs/<algo>/<env>/<variant>/seed<k>/ (or the run folders themselves).",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
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
    from tacbench.report import ReportOptions, analyse, write_report  # pandas etc. only here

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
    write_report(analysed)
    runs, skipped = analysed.runset.runs, analysed.runset.skipped
    click.echo(
        f"{len(runs)} runs loaded ({int(runs['partial'].sum())} partial), {len(skipped)} skipped"
        f"{' (see skipped.csv)' if skipped else ''}; wrote {out / 'index.html'} and "
        f"{out / 'report.md'}"
    )


def _command_line(ctx: click.Context) -> str:
    """The flags the user gave, in canonical form (defaults left out): recorded in config.json."""
    parts = ["tacbench", ctx.info_name or "run"]
    for param in ctx.command.params:
        name = param.name or ""
        if ctx.get_parameter_source(name) != click.core.ParameterSource.COMMANDLINE:
            continue
        flag, value = param.opts[0], ctx.params[name]
        if isinstance(param, click.Option) and param.is_flag:
            parts.append(flag)
        else:
            for item in value if isinstance(value, tuple) else (value,):
                parts += [flag, str(item)]
    return shlex.join(parts)


@cli.command()
@click.option("--env", required=True, help="Gymnasium id (Ant-v4) or paper task name (Ant).")
@click.option(
    "--algo",
    type=click.Choice(["tac", *BASELINES]),
    default="tac",
    show_default=True,
    help="TAC, or a baseline from stable-baselines3 / sb3-contrib (docs/baselines.md).",
)
@click.option(
    "--hp",
    multiple=True,
    metavar="KEY=VALUE",
    help="Repeatable: override a baseline hyperparameter (baselines/hyperparams/<algo>.yaml).",
)
@click.option(
    "--q",
    type=float,
    default=None,
    help="Entropic index q.  [default: the paper's best q for the task]",
)
@click.option(
    "--alpha",
    type=float,
    default=None,
    help="Entropy coefficient.  [default: the paper's: 0.2, Humanoid 0.05]",
)
@click.option(
    "--seed",
    "seeds",
    type=int,
    multiple=True,
    default=(0,),
    show_default=True,
    help="Repeatable (--seed 0 --seed 10): the seeds train as members of one process.",
)
@click.option("--steps", type=int, default=config.TOTAL_STEPS, show_default=True)
@click.option(
    "--learning-starts",
    type=int,
    default=config.LEARNING_STARTS,
    show_default=True,
    help="Steps of uniform random actions before learning (the paper's table says 100000).",
)
@click.option(
    "--eval-every",
    type=int,
    default=config.EVAL_EVERY,
    show_default=True,
    help="Steps between evaluations; 0 disables evaluation.",
)
@click.option("--eval-episodes", type=int, default=config.EVAL_EPISODES, show_default=True)
@click.option(
    "--update-schedule",
    type=click.Choice(config.UPDATE_SCHEDULES),
    default="step",
    show_default=True,
    help="step: one update per env step; episode: paper Algorithm 1 (one --seed only).",
)
@click.option(
    "--lnq",
    type=click.Choice(config.LNQ_MODES),
    default="per-dim",
    show_default=True,
    help="per-dim: sum of per-dimension ln_q (reference code, which produced the paper's "
    "curves); joint: ln_q of the joint density (paper appendix; overflows in high action "
    "dimensions, see docs/tac.md).",
)
@click.option(
    "--q-schedule",
    type=click.Choice(config.Q_SCHEDULES),
    default="constant",
    show_default=True,
    help="linear: q goes from 1 to --q between 10% and 90% of --steps.",
)
@click.option("--checkpoint-every", type=int, default=config.CHECKPOINT_EVERY, show_default=True)
@click.option(
    "--device", type=click.Choice(["cpu", "cuda", "auto"]), default="cpu", show_default=True
)
@click.option("--threads", type=int, default=1, show_default=True, help="torch CPU threads.")
@click.option(
    "--impl",
    type=click.Choice(config.IMPLS),
    default="fused",
    show_default=True,
    help="TAC's update: fused (hand-written gradients, fast) or eager (autograd, the reference); "
    "the same maths (docs/performance.md).",
)
@click.option(
    "--compile",
    "compile_",
    is_flag=True,
    help="torch.compile TAC's fused update (a CPU needs a C++ compiler; falls back without).",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("results"),
    show_default=True,
    help="Results folder; runs go to <out>/runs/<algo>/<env>/<variant>/seed<k>/.",
)
@click.option("--resume", is_flag=True, help="Continue an interrupted run from its checkpoint.")
@click.option("--force", is_flag=True, help="Delete an existing run directory and start over.")
@click.option("--quiet", is_flag=True, help="Plain progress lines instead of a progress bar.")
@click.pass_context
def run(
    ctx: click.Context,
    env: str,
    algo: str,
    hp: tuple[str, ...],
    q: float | None,
    alpha: float | None,
    seeds: tuple[int, ...],
    steps: int,
    learning_starts: int,
    eval_every: int,
    eval_episodes: int,
    update_schedule: str,
    lnq: str,
    q_schedule: str,
    checkpoint_every: int,
    device: str,
    threads: int,
    impl: str,
    compile_: bool,
    out: Path,
    resume: bool,
    force: bool,
    quiet: bool,
) -> None:
    """Train Tsallis Actor-Critic (or a baseline: --algo) on one task into a resumable run
    directory.

    Exit status: 0 when every run is complete (or skipped), 1 when one failed (NaN/inf),
    130 when interrupted (Ctrl-C or SIGTERM; rerun with --resume), 2 for a usage error.
    """
    from tacbench import envs, training  # torch only when this command runs

    env_id = envs.resolve_env_id(env)
    envs.env_info(env_id)  # refuse unusable tasks before printing anything
    if algo != "tac":
        _run_baseline(ctx, algo, env_id, hp)
        return
    if hp:
        raise TacbenchError("--hp sets a baseline's hyperparameters; TAC's have their own flags.")
    configs, notes = config.make_run_configs(
        env_id,
        envs.paper_task(env_id),
        seeds,
        q=q,
        alpha=alpha,
        total_steps=steps,
        learning_starts=learning_starts,
        eval_every=eval_every,
        eval_episodes=eval_episodes,
        update_schedule=update_schedule,
        lnq=lnq,
        q_schedule=q_schedule,
        checkpoint_every=checkpoint_every,
        device=training.resolve_device(device),
        threads=threads,
        impl=impl,
        compile=compile_,
    )
    for note in notes:
        click.echo(note)
    outcomes = training.train(
        configs, out, resume=resume, force=force, quiet=quiet, command=_command_line(ctx)
    )
    _report_outcomes(ctx, outcomes)


_TAC_ONLY = ("q", "alpha", "learning_starts", "update_schedule", "lnq", "q_schedule")


def _run_baseline(ctx: click.Context, algo: str, env_id: str, hp: tuple[str, ...]) -> None:
    """`tacbench run --algo <baseline>`: the same run settings, the baseline's trainer."""
    from baselines import config as baseline_config  # torch and SB3 only when this runs
    from baselines import trainer
    from tacbench import envs, training

    p = ctx.params
    given = {
        name: p[name]
        for name in _TAC_ONLY
        if ctx.get_parameter_source(name) != click.core.ParameterSource.DEFAULT
    }
    configs, _, notes = baseline_config.make_configs(
        algo,
        env_id,
        envs.paper_task(env_id),
        p["seeds"],
        [*baseline_config.flags_as_overrides(algo, given), *hp],
        total_steps=p["steps"],
        eval_every=p["eval_every"],
        eval_episodes=p["eval_episodes"],
        checkpoint_every=p["checkpoint_every"],
        device=training.resolve_device(p["device"]),
        threads=p["threads"],
    )
    for note in notes:
        click.echo(note)
    outcomes = trainer.train(
        configs,
        p["out"],
        resume=p["resume"],
        force=p["force"],
        quiet=p["quiet"],
        command=_command_line(ctx),
    )
    _report_outcomes(ctx, outcomes)


def _report_outcomes(ctx: click.Context, outcomes: Sequence[Outcome]) -> None:
    """One line per seed; exit status 130 if interrupted, 1 if a run failed."""
    for outcome in outcomes:
        detail = f" ({outcome.message})" if outcome.message else ""
        click.echo(f"seed {outcome.seed}: {outcome.state}, {outcome.directory}{detail}")
    states = {outcome.state for outcome in outcomes}
    if "interrupted" in states:
        ctx.exit(130)
    if "failed" in states:
        ctx.exit(1)


@cli.command()
@click.option(
    "--preset",
    type=click.Choice(list(SWEEP_PRESETS)),
    required=True,
    help="paper-q-grid (TAC, 9 q x 6 tasks x 10 seeds), paper-comparison (TAC best q, SAC = "
    "TAC q=1, DDPG, TD3, PPO, TRPO), smoke (tiny budgets). Sources: docs/sweep.md.",
)
@click.option("--env", "envs", multiple=True, help="Repeatable: keep only these tasks (Ant).")
@click.option("--q", "qs", type=float, multiple=True, help="Repeatable: keep only these TAC q.")
@click.option(
    "--algo",
    "algos",
    type=click.Choice(["tac", *BASELINES]),
    multiple=True,
    help="Repeatable: keep only these algorithms.",
)
@click.option("--seed", "seeds", type=int, multiple=True, help="Repeatable: keep only these seeds.")
@click.option("--steps", type=int, default=None, help="Environment steps per run (budget).")
@click.option("--checkpoint-every", type=int, default=None, help="Steps between checkpoints.")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local", show_default=True)
@click.option(
    "--workers",
    type=int,
    default=None,
    help="Units at once. [default: local: the core count; ray: what the cluster has room for]",
)
@click.option("--address", default=None, help="Ray cluster: auto, HOST:6379 or ray://HOST:10001.")
@click.option("--cpus-per-run", type=float, default=1.0, show_default=True, help="Ray request.")
@click.option("--gpus-per-run", type=float, default=0.0, show_default=True, help="Ray; > 0: cuda.")
@click.option(
    "--scratch",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Ray: run directories and checkpoints on each node.  [default: $TMPDIR/tacbench-sweep]",
)
@click.option("--shared-fs", is_flag=True, help="Ray: --out is the same path on every node.")
@click.option("--group-seeds", is_flag=True, help="TAC runs differing in seed share a process.")
@click.option("--max-retries", type=int, default=2, show_default=True, help="Per failed run.")
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("results"),
    show_default=True,
    help="Results folder: runs/... as `tacbench run`, and sweep/ (state, summary, logs).",
)
@click.option("--dry-run", is_flag=True, help="Print the plan and cost estimate; train nothing.")
@click.pass_context
def sweep(ctx: click.Context, preset: str, **p: Any) -> None:
    """Train a preset grid of runs (or what is left of it) locally or on Ray; rerun the same
    command to resume after Ctrl-C or a crash (docs/sweep.md).

    Exit status: 0 when every run is complete, 1 when a run failed more than --max-retries
    times, 130 when interrupted (rerun to resume), 2 for a usage error.
    """
    from tacbench.sweep import driver, presets, summary  # torch only when this command runs

    grid = presets.narrow(
        presets.get_preset(preset),
        presets.Narrowing(
            p["envs"], p["qs"], p["algos"], p["seeds"], p["steps"], p["checkpoint_every"]
        ),
    )
    options = driver.Options(
        executor=p["executor"],
        workers=p["workers"],
        address=p["address"],
        cpus_per_run=p["cpus_per_run"],
        gpus_per_run=p["gpus_per_run"],
        scratch=p["scratch"],
        shared_fs=p["shared_fs"],
        group_seeds=p["group_seeds"],
        max_retries=p["max_retries"],
        command=_command_line(ctx),
    )
    if p["dry_run"]:
        work, _ = driver.load_plan(grid, p["out"], options, save=False)
        click.echo(summary.describe_plan(work, options.worker_count(), options.group_seeds))
        return
    result = driver.run_sweep(grid, p["out"], options)
    click.echo(result.text)
    click.echo(f"wrote {p['out'] / 'sweep' / 'summary.json'} and summary.txt")
    ctx.exit(result.exit_code)


@cli.command()
@click.option("--env", default="HalfCheetah-v4", show_default=True, help="Task to train on.")
@click.option(
    "--members", type=int, default=10, show_default=True, help="K of the multi-member rows."
)
@click.option(
    "--steps",
    type=int,
    default=1500,
    show_default=True,
    help="Timed steps per learner, split into --rounds turns.",
)
@click.option("--rounds", type=int, default=5, show_default=True, help="Turns per learner.")
@click.option(
    "--learning-starts",
    type=int,
    default=1000,
    show_default=True,
    help="Untimed random steps before learning starts.",
)
@click.option("--compile", "compile_", is_flag=True, help="Add rows for TAC under torch.compile.")
@click.option("--no-sb3", is_flag=True, help="Leave out stable-baselines3's SAC.")
@click.option("--no-eager", is_flag=True, help="Leave out TAC's eager (reference) update.")
@click.option(
    "--device", type=click.Choice(["cpu", "cuda", "auto"]), default="cpu", show_default=True
)
@click.option("--threads", type=int, default=1, show_default=True, help="torch CPU threads.")
@click.option(
    "--json",
    "json_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also write every measurement to this JSON file.",
)
def bench(
    env: str,
    members: int,
    steps: int,
    rounds: int,
    learning_starts: int,
    compile_: bool,
    no_sb3: bool,
    no_eager: bool,
    device: str,
    threads: int,
    json_path: Path | None,
) -> None:
    """TAC (eager and fused; one and --members members) against stable-baselines3's SAC with
    the paper's settings, side by side in this process: steps/s and ratios (docs/performance.md).
    """
    import json

    from tacbench import bench as measure  # torch and SB3 only when this command runs
    from tacbench import envs, training

    env_id = envs.resolve_env_id(env)
    envs.env_info(env_id)
    options = measure.BenchOptions(
        env=env_id,
        members=members,
        steps=steps,
        rounds=rounds,
        learning_starts=learning_starts,
        compile=compile_,
        sb3=not no_sb3,
        eager=not no_eager,
        device=training.resolve_device(device),
        threads=threads,
    )
    before = measure.machine()
    results = measure.run_bench(options, report=lambda line: click.echo(line, err=True))
    click.echo(measure.summary(results, options, before))
    if json_path is not None:
        json_path.write_text(json.dumps(measure.results_json(results, options), indent=1) + "\n")
        click.echo(f"wrote {json_path}")


@cli.command()
@click.option(
    "--against",
    type=click.Path(file_okay=False, path_type=Path),
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
    type=click.Path(file_okay=False, path_type=Path),
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

    Prints what matched, what drifted and by how much. Exit status: 0 when nothing regressed
    (a tier skipped for other library versions says why), 1 on a regression, 2 for a usage
    error.
    """
    from tacbench import regress as checks  # torch only when this command runs

    if update:
        if only:
            raise TacbenchError("--only selects what to check; --update regenerates a whole tier.")
        for path in checks.update(against, tier, work, log=click.echo):
            click.echo(f"wrote {path}")
        return
    results = checks.check(against, tier, work, only, log=click.echo)
    for result in results:
        click.echo(checks.format_result(result))
    if any(result.regressions for result in results):
        ctx.exit(1)


@cli.command(name="envs")
def envs_command() -> None:
    """List the paper's task suite with its Gymnasium ids and the paper's alpha and best q."""
    from tacbench.envs import suite_table

    header = (
        f"{'task':<12} {'env':<16} {'obs':>4} {'act':>4} {'limit':>6} {'alpha':>6} {'best q':>7}"
    )
    click.echo(header + "  loads")
    for row in suite_table():
        click.echo(
            f"{row['task']:<12} {row['env']:<16} {row['obs']!s:>4} {row['act']!s:>4} "
            f"{row['limit']!s:>6} {config.PAPER_ALPHA[row['task']]:>6g} "
            f"{config.PAPER_BEST_Q[row['task']]:>7g}  {row['ok']}"
        )
    click.echo(
        "alpha and best q: paper appendix, per-task table. Any other registered Gymnasium id "
        "with continuous actions also works with --env (default q = 1, alpha = 0.2)."
    )


def main() -> None:
    """Console-script entry point."""
    cli()
