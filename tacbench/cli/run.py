"""``tacbench run``: train TAC or a baseline into run directories."""

from __future__ import annotations

from pathlib import Path

import click

from baselines import ALGOS as BASELINES
from tacbench import config
from tacbench.cli.common import command_line, report_outcomes
from tacbench.errors import TacbenchError


@click.command()
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
    "--critic-target",
    type=click.Choice(config.CRITIC_TARGETS),
    default="v",
    show_default=True,
    help="v: the Q target bootstraps from a target V (paper, reference code: SAC v1); twin-q: "
    "from target Q1, Q2 at a' ~ pi(s') without V (SAC v2, as stable-baselines3; docs/parity.md).",
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
    critic_target: str,
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
        critic_target=critic_target,
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
        configs, out, resume=resume, force=force, quiet=quiet, command=command_line(ctx)
    )
    report_outcomes(ctx, outcomes)


_TAC_ONLY = (
    "q",
    "alpha",
    "learning_starts",
    "update_schedule",
    "lnq",
    "critic_target",
    "q_schedule",
)


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
        command=command_line(ctx),
    )
    report_outcomes(ctx, outcomes)
