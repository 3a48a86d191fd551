"""``tacbench run``: train TAC or a baseline into run directories.

Every setting's option is generated from its declaration in :mod:`tacbench.config`; the
options written here are those with no single config field behind them (the task, the
algorithm, the repeatable seeds, q and alpha with their per-task defaults, where to write).
"""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any

import click

from tacbench import paper, runs, trainers
from tacbench.cli.common import command_line, report_outcomes
from tacbench.cli.options import NumberOrAuto, ResultsFolder, cli_settings, setting_options
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError, listing
from tacbench.runs.checkpoints import newest_step
from tacbench.runs.planning import check_nothing_to_lose, check_resume_or_force, unfinished
from tacbench.settings import RunSettings, settings_of

_SETTINGS = cli_settings(RunConfig)
_RUN_SETTINGS = set(settings_of(RunSettings))


def _learned_mode(
    ctx: click.Context, name: str, values: tuple[float | str, ...], does: str, tip: str = ""
) -> str:
    """``--<name> auto``: the mode setting ``<name>_mode`` it stands for, refused next to other
    values of the flag or an explicit ``--<name>-mode fixed``."""
    mode = f"{name}_mode"
    explicit = ctx.get_parameter_source(mode) == click.core.ParameterSource.COMMANDLINE
    if len(values) > 1 or (explicit and ctx.params[mode] != "auto"):
        raise TacbenchError(
            f"--{name} auto {does}; it does not mix with other --{name} values or "
            f"--{name}-mode fixed in one command.{tip}"
        )
    return "auto"


@click.command()
@click.option("--env", required=True, help="Gymnasium id (Ant-v4) or paper task name (Ant).")
@click.option(
    "--algo",
    type=click.Choice(trainers.ALGOS),
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
    "qs",
    type=NumberOrAuto(),
    multiple=True,
    help="Entropic index q; repeatable (--q 0.5 --q 1 --q 1.5): every q x alpha x seed trains "
    "as a member of one process; auto: the seeds (at least 4) learn q as a population "
    "(--q-mode auto).  [default: the paper's best q for the task]",
)
@click.option(
    "--alpha",
    "alphas",
    type=NumberOrAuto(),
    multiple=True,
    help="Entropy coefficient; repeatable, like --q; auto: learned per member from the paper's "
    "alpha (--alpha-mode auto; sac-sb3 from SB3's 1.0, or from --alpha with --alpha-mode "
    "auto).  [default: the paper's: 0.2, Humanoid 0.05]",
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
@setting_options(RunConfig, _SETTINGS)
@click.option(
    "--out",
    type=ResultsFolder(),
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
    qs: tuple[float | str, ...],
    alphas: tuple[float | str, ...],
    seeds: tuple[int, ...],
    out: Path,
    resume: bool,
    force: bool,
    quiet: bool,
    **settings: Any,
) -> None:
    """Train Tsallis Actor-Critic (or a baseline: --algo) on one task into a resumable run
    directory.

    Exit status: 0 when every run is complete (or skipped as complete), 1 when one failed (a
    non-finite loss, now or before: skipped) or crashed, 130/143/129 when interrupted
    (Ctrl-C/SIGTERM/SIGHUP; rerun with --resume), 2 for a usage error.
    """
    from tacbench import envs, training  # torch only when this command runs

    env_id = envs.resolve_env_id(env)
    envs.env_info(env_id)  # refuse unusable tasks before printing anything
    settings["device"] = training.resolve_device(settings["device"])
    if algo == "tac":
        if hp:
            raise TacbenchError(
                "--hp sets a baseline's hyperparameters; TAC's have their own flags."
            )
        if "auto" in alphas:
            settings["alpha_mode"] = _learned_mode(
                ctx,
                "alpha",
                alphas,
                "learns every member's alpha from the paper's value",
                " To learn alpha from another start: --alpha-mode auto --alpha 0.1.",
            )
            alphas = ()
        if "auto" in qs:
            settings["q_mode"] = _learned_mode(ctx, "q", qs, "learns q in a population")
            qs = ()
        numbers = [float(a) for a in alphas]
        configs, notes = trainers.make_configs(
            algo,
            env_id,
            paper.paper_task(env_id),
            seeds,
            settings,
            qs=[float(q) for q in qs],
            alphas=numbers,
        )
    else:
        if "auto" in qs:
            raise TacbenchError(f"--q auto is TAC's (a population learning q); not for {algo}.")
        if len(qs) > 1 or len(alphas) > 1:
            raise TacbenchError(
                f"--q and --alpha are repeatable for TAC only; {algo} trains one value per command."
            )
        given = {name: v[0] for name, v in (("q", qs), ("alpha", alphas)) if v}
        given.update(
            (name, value)
            for name, value in settings.items()
            if name not in _RUN_SETTINGS
            and ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE
        )
        run_settings = {k: v for k, v in settings.items() if k in _RUN_SETTINGS}
        configs, notes = trainers.make_configs(
            algo,
            env_id,
            paper.paper_task(env_id),
            seeds,
            run_settings,
            tac_settings_given=given,
            hp=hp,
        )
    check_resume_or_force(resume, force)
    if resume:
        _say_what_starts_afresh(configs, out)
    for note in notes:
        click.echo(note)
    outcomes = trainers.trainer_for(algo).train(
        configs, out, resume=resume, force=force, quiet=quiet, command=command_line(ctx)
    )
    report_outcomes(ctx, outcomes)


def _say_what_starts_afresh(configs: Sequence[Any], out: Path) -> None:
    """Under --resume, refuse a command that never started (no folder of its variant) where the
    task has runs of other settings under --out (a mistyped or left-out setting makes another
    variant: it would start every run afresh, up to a million steps each); and name each run
    that has nothing to resume: no config.json in its directory (a baseline's seed that a stop
    came before is named as such; a first run, or one stopped in its start-up), or no
    checkpoint yet (killed before its first: it trains again from step 0, and the rows it had
    logged are written again, the same ones for its seed). Not for a TAC group that has members
    to resume beside such ones: it is refused, saying what to do."""
    directories = [runs.run_directory(out, c.algo, c.env, c.variant, c.seed) for c in configs]
    # the command's variant folder (its seeds' lock files are there): it started before, if
    # only to be stopped in its start-up, or trained other seeds; else look for the task's runs
    if not any(d.parent.exists() for d in directories):
        task = directories[0].parent.parent
        others = sorted({p.parent.parent.name for p in task.glob("*/seed*/config.json")})
        if others:
            raise TacbenchError(_nothing_to_resume(directories, others))
    checkpointed = [newest_step(d / "checkpoint") is not None for d in directories]
    resuming = [unfinished(d) for d in directories]
    trained = [c for c, u in zip(checkpointed, resuming, strict=True) if u]
    if configs[0].algo == "tac" and any(trained) and not all(trained):
        return
    written = [(d / "config.json").exists() for d in directories]
    # a baseline's seeds train one after another: those its earlier command named had a stop
    # come before them (a TAC group's members start together)
    started = [d for d, w in zip(directories, written, strict=True) if w]
    named = set().union(*map(_seeds_named, started)) if configs[0].algo != "tac" else set()
    for config, directory, has_checkpoint, resumes, exists in zip(
        configs, directories, checkpointed, resuming, written, strict=True
    ):
        if not exists:  # files but no config.json: refused here, not announced as no run
            check_nothing_to_lose(directory)
        if not exists and config.seed in named:
            click.echo(f"seed {config.seed}: not started before the stop; starting it")
        elif not exists:
            click.echo(
                f"seed {config.seed}: nothing to resume at {directory} (no run there); starting "
                "afresh (check --out and the settings if you meant another run)"
            )
        elif not has_checkpoint and resumes:
            # progress that no checkpoint holds (one deleted) is refused, not trained again
            runs.check_checkpoint(directory, runs.read_status(directory)["step"])
            every = config.checkpoint_every
            when = f"due every {every:,} steps" if every else "--checkpoint-every 0: at the end"
            click.echo(
                f"seed {config.seed}: {directory} has no checkpoint yet (it stopped before its "
                f"first, {when}); it trains again from step 0, writing its rows again"
            )


def _nothing_to_resume(directories: Sequence[Path], others: Sequence[str]) -> str:
    """The refusal of a --resume none of whose runs ``directories`` exists, naming the variants
    ``others`` that the task has beside them."""
    none = "none of its runs exists" if len(directories) > 1 else "its run does not exist"
    return (
        f"--resume: nothing to resume: {none} ({directories[0]}), and "
        f"{directories[0].parent.parent} holds the variants {listing(others)}. Repeat the "
        "command that trained the run you mean (its config.json records it), with its settings "
        "and --out, or drop --resume to start this one."
    )


def _seeds_named(directory: Path) -> set[int]:
    """The seeds of the command recorded in the run's config.json (none where unreadable)."""
    try:
        words = shlex.split(str(runs.read_json(directory / "config.json").get("command", "")))
    except (TacbenchError, OSError, ValueError):
        return set()
    return {int(s) for flag, s in pairwise(words) if flag == "--seed" and s.isdigit()}
