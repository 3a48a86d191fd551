"""``tacbench bench`` (speed against SB3) and ``tacbench regress`` (reference results)."""

from __future__ import annotations

from pathlib import Path

import click

from tacbench.errors import TacbenchError


@click.command()
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


@click.command()
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
