"""``tacbench bench``: TAC's speed against stable-baselines3's SAC, side by side."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import click

from tacbench.cli.options import NumberTuple
from tacbench.errors import TacbenchError

if TYPE_CHECKING:
    from tacbench.bench import BenchOptions


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
@click.option(
    "--grid",
    is_flag=True,
    help="Add a row for the paper's q grid of the task in one process (9 q x 10 seeds, compiled).",
)
@click.option(
    "--bf16",
    is_flag=True,
    help="Add each TAC row again with --matmul-precision bf16 (bfloat16 products), where the "
    "CPU has native bfloat16 instructions; with --profile: profile the bf16 update instead.",
)
@click.option("--no-sb3", is_flag=True, help="Leave out stable-baselines3's SAC.")
@click.option("--no-eager", is_flag=True, help="Leave out the rows of TAC uncompiled.")
@click.option(
    "--device", type=click.Choice(["cpu", "cuda", "auto"]), default="cpu", show_default=True
)
@click.option("--threads", type=int, default=1, show_default=True, help="torch CPU threads.")
@click.option(
    "--hidden-sizes",
    type=NumberTuple(int, "400,300"),
    default=None,
    help="Hidden layer widths of every contestant's networks [default: the paper's 300].",
)
@click.option(
    "--profile",
    is_flag=True,
    help="Instead of the race: where one update's time goes (products by shape with their "
    "GFLOP/s against this core's peak, elementwise kernels, Adam, the rest), at 1 and --members "
    "members, compiled unless --no-compile-profile; one thread, so the race's options "
    "(--threads, --rounds, --grid, ...) are refused with it.",
)
@click.option(
    "--no-compile-profile", is_flag=True, help="With --profile: profile the eager update."
)
@click.option(
    "--json",
    "json_arg",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also write every measurement to this JSON file (its folder is made if need be).",
)
@click.pass_context
def bench(
    ctx: click.Context,
    env: str,
    members: int,
    steps: int,
    rounds: int,
    learning_starts: int,
    compile_: bool,
    grid: bool,
    bf16: bool,
    no_sb3: bool,
    no_eager: bool,
    device: str,
    threads: int,
    hidden_sizes: tuple[int, ...] | None,
    profile: bool,
    no_compile_profile: bool,
    json_arg: str | None,
) -> None:
    """TAC (uncompiled and, with --compile, compiled; one and --members members) against
    stable-baselines3's SAC with the paper's settings, side by side in this process: steps/s,
    ratios and where each TAC step's time goes (docs/performance.md)."""

    from tacbench import bench as measure  # torch and SB3 only when this command runs
    from tacbench import envs, training
    from tacbench.hardware import check_matmul_precision
    from tacbench.runs.files import check_writable

    _check_combination(ctx)
    env_id = envs.resolve_env_id(env)
    envs.env_info(env_id)
    options = measure.BenchOptions(
        env=env_id,
        members=members,
        steps=steps,
        rounds=rounds,
        learning_starts=learning_starts,
        compile=compile_,
        grid=grid,
        sb3=not no_sb3,
        eager=not no_eager,
        device=training.resolve_device(device),
        threads=threads,
        hidden_sizes=hidden_sizes,
        bf16=bf16,
    )
    check_matmul_precision(
        "bf16" if bf16 else "float32", options.device, "--bf16", "leave --bf16 out"
    )
    measure.check_sizes(options)
    json_path = None if json_arg is None else _json_file(json_arg)
    if json_path is not None:  # before minutes of measuring, not after
        check_writable(json_path.parent, "--json")
    if profile:
        _profile(options, not no_compile_profile, json_path)
        return
    before = measure.machine()
    results = measure.run_bench(options, report=lambda line: click.echo(line, err=True))
    click.echo(measure.summary(results, options, before))
    if json_path is not None:
        _write_json(json_path, measure.results_json(results, options, before))


# what --profile measures: one update on one thread, so the race's options do not apply to it
_RACE_ONLY = frozenset(
    ("steps", "rounds", "learning_starts", "compile_", "grid", "no_sb3", "no_eager", "threads")
)


def _check_combination(ctx: click.Context) -> None:
    """Refuse options that would be ignored: the race's with --profile, --no-compile-profile
    without it, and rows that leave nothing (or no bf16 row) to measure."""
    p = ctx.params
    given = {
        option.name: option.opts[0]
        for option in ctx.command.params
        if option.name
        and ctx.get_parameter_source(option.name) == click.core.ParameterSource.COMMANDLINE
    }
    if p["profile"]:
        ignored = [flag for name, flag in given.items() if name in _RACE_ONLY]
        if ignored:
            raise TacbenchError(
                f"--profile measures one update on one thread, not the race: leave out "
                f"{', '.join(ignored)}."
            )
        return
    if p["no_compile_profile"]:
        raise TacbenchError("--no-compile-profile applies with --profile only; add --profile.")
    if p["no_sb3"] and p["no_eager"] and not (p["compile_"] or p["grid"]):
        raise TacbenchError(
            "--no-sb3 and --no-eager leave nothing to measure; add --compile or --grid, or drop "
            "one of them."
        )
    if p["bf16"] and p["no_eager"] and not (p["compile_"] or p["grid"]):
        raise TacbenchError(
            "--bf16 repeats each TAC row with bfloat16 products, and --no-eager without "
            "--compile or --grid leaves no TAC row; add --compile or drop --no-eager."
        )


def _json_file(given: str) -> Path:
    """--json's file; a trailing separator names a folder (Path would drop it silently)."""
    path = Path(given)
    if not path.name or given.endswith(("/", os.sep)):
        raise TacbenchError(
            f"--json must name a file, not a folder (got {given!r}); for example "
            f"--json {Path(given, 'bench.json')}."
        )
    return path


def _write_json(path: Path, record: dict[str, object]) -> None:
    import json

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1) + "\n")
    click.echo(f"wrote {path}")


def _profile(options: BenchOptions, compile_: bool, json_path: Path | None) -> None:
    """``--profile``: the update's profile at 1 and ``options.members`` members."""

    from tacbench import bench as measure
    from tacbench.update_profile import profile_table, profile_update

    before = measure.machine()
    results = []
    for members in dict.fromkeys((1, options.members)):
        click.echo(f"profiling the update of {members} member(s) ...", err=True)
        result = profile_update(
            options.env, members, options.networks, compile_, options.bf16, options.device
        )
        results.append(result)
        click.echo(profile_table(result) + "\n")
    if json_path is not None:
        machine = {"at start": before, "at end": measure.machine()}
        _write_json(json_path, {"machine": machine, "profiles": results})
