"""The CLI: a TacbenchError prints its message, no traceback, exit status 2; the options of
`run` and `sweep` are generated from the declared settings."""

from __future__ import annotations

import errno
import json
import shlex
import subprocess
import sys
from pathlib import Path
from unittest import mock

import click
import pytest
from click.testing import CliRunner

from tacbench import __version__
from tacbench.cli import cli
from tacbench.cli.common import Group
from tacbench.cli.run import run
from tacbench.cli.sweep import sweep
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.settings import settings_of
from tacbench.sweep import presets

pytestmark = pytest.mark.unit


def test_user_error_exits_with_status_two_and_no_traceback() -> None:
    @click.group(cls=Group)
    def group() -> None:
        pass

    @group.command()
    def broken() -> None:
        raise TacbenchError("q must be > 0; pass --q 1.5 for example.")

    result = CliRunner().invoke(group, ["broken"])
    assert result.exit_code == 2
    assert "Error: q must be > 0; pass --q 1.5 for example." in result.output
    assert "Traceback" not in result.output


def test_a_ctrl_c_no_command_handles_exits_130_without_a_traceback() -> None:
    """Click's own answer is "Aborted!" and exit status 1, which the sweep keeps for a run
    given up on."""

    @click.group(cls=Group)
    def group() -> None:
        pass

    @group.command()
    def starting() -> None:
        raise KeyboardInterrupt

    result = CliRunner().invoke(group, ["starting"])
    assert result.exit_code == 130
    assert result.output == "interrupted by Ctrl-C\n"


def test_other_exceptions_are_not_swallowed() -> None:
    @click.group(cls=Group)
    def group() -> None:
        pass

    @group.command()
    def bug() -> None:
        raise RuntimeError("a real bug")

    result = CliRunner().invoke(group, ["bug"])
    assert result.exit_code == 1
    assert isinstance(result.exception, RuntimeError)


def test_a_full_disk_is_a_user_error_and_other_os_errors_stay_bugs() -> None:
    @click.group(cls=Group)
    def group() -> None:
        pass

    @group.command()
    def full() -> None:
        raise OSError(errno.ENOSPC, "No space left on device", "/out/bounds.png")

    @group.command()
    def missing() -> None:
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", "/in/eval.csv")

    result = CliRunner().invoke(group, ["full"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert result.output == (
        "Error: cannot write /out/bounds.png: the disk is full; free some space, then run the "
        "command again.\n"
    )
    result = CliRunner().invoke(group, ["missing"])
    assert result.exit_code == 1 and isinstance(result.exception, FileNotFoundError)


def test_version() -> None:
    result = CliRunner().invoke(cli, ["--version"])
    assert result.exit_code == 0 and __version__ in result.output


def test_run_offers_every_declared_setting_with_its_default_and_source() -> None:
    options = {opt for p in run.params for opt in p.opts}
    for name, declared in settings_of(RunConfig).items():
        if not declared.info.cli:
            continue
        assert declared.flag in options, name
        param = next(p for p in run.params if p.name == name)
        assert isinstance(param, click.Option) and param.help is not None
        assert declared.info.source in param.help, name
        assert param.default == declared.default, name
        if declared.type is bool:
            assert param.secondary_opts == ["--no-" + declared.flag[2:]], name


def test_sweep_overrides_default_to_the_presets_value() -> None:
    names = {p.name: p for p in sweep.params}
    for name, declared in settings_of(RunConfig).items():
        offered = declared.info.cli and declared.info.sweep
        assert (name in names) == offered, name
        if offered:
            assert names[name].default is None, name


@pytest.mark.parametrize(
    ("args", "settings"),
    [
        ([], {}),
        (["--compile", "on"], {"compile": "on"}),
        (["--compile", "off", "--steps", "300"], {"compile": "off", "total_steps": 300}),
        (["--hidden-sizes", "400,300"], {"hidden_sizes": (400, 300)}),
        (["--no-tensorboard"], {"tensorboard": False}),
        (["--alpha-mode", "auto"], {"alpha_mode": "auto"}),
        (["--tensorboard"], {"tensorboard": True}),
    ],
)
def test_sweep_passes_only_the_settings_given(args: list[str], settings: dict) -> None:
    seen: dict = {}

    def narrow(preset: object, by: presets.Narrowing) -> object:
        seen.update(by.settings)
        raise SystemExit(0)

    with mock.patch.object(presets, "narrow", narrow):
        result = CliRunner().invoke(cli, ["sweep", "--preset", "smoke", "--dry-run", *args])
    assert result.exit_code == 0, result.output
    assert seen == settings


def test_a_bad_list_of_layer_widths_is_a_usage_error(tmp_path: Path) -> None:
    args = ["run", "--env", "Hopper-v4", "--hidden-sizes", "400,x", "--out", str(tmp_path)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2
    assert "'400,x' is not a comma-separated list of integers" in result.output


@pytest.mark.parametrize(
    ("command", "option"),
    [
        (["run", "--env", "Hopper-v4"], "--out"),
        (["sweep", "--preset", "smoke"], "--out"),
        (["sweep", "--preset", "smoke", "--executor", "ray"], "--scratch"),
        (["report", "--results", "."], "--out"),
        (["figures"], "--out"),
        (["study", "adaptive", "analyse", "--results", "."], "--out"),
        (["study", "parity", "analyse", "--results", "."], "--out"),
        (["regress", "--tier", "theory"], "--against"),
        (["regress", "--tier", "theory"], "--work"),
        (["study", "adaptive", "commands"], "--out"),  # printed commands that run refused
        (["study", "parity", "commands"], "--out"),
    ],
)
def test_an_empty_folder_is_refused_rather_than_taken_for_the_current_one(
    command: list[str], option: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, [*command, option, ""])
    assert result.exit_code == 2
    assert f"Invalid value for '{option}': must name a folder" in result.output
    assert not any(tmp_path.iterdir())


def test_the_command_line_loads_without_the_heavy_libraries() -> None:
    """`tacbench --help` and every command's start stay quick: torch, rliable (with arch's
    bootstrap, about a second), matplotlib and gymnasium load in the commands that use them."""
    heavy = ("torch", "rliable", "arch", "matplotlib", "gymnasium")
    code = f"import sys, tacbench.cli; print([m for m in {heavy!r} if m in sys.modules])"
    loaded = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert loaded.stdout.strip() == "[]"


def test_resume_names_each_run_that_has_nothing_to_resume(tmp_path: Path) -> None:
    """--resume with a mistyped setting or --out would train from step 0 in silence: the runs
    without a directory to resume are named before training starts."""
    kept = tmp_path / "runs" / "tac" / "Hopper-v4" / "q1.5-a0.2" / "seed0"
    kept.mkdir(parents=True)
    (kept / "config.json").write_text("{}")
    args = ["--env", "Hopper-v4", "--q", "1.5", "--alpha", "0.2", "--seed", "0", "--seed", "10"]
    with mock.patch("tacbench.trainers.trainer_for") as trainer_for:
        trainer_for.return_value.train.return_value = []
        result = CliRunner().invoke(run, [*args, "--out", str(tmp_path), "--resume"])
        assert result.exit_code == 0, result.output
        fresh = [line for line in result.output.splitlines() if "nothing to resume" in line]
        assert fresh == [
            f"seed 10: nothing to resume at {kept.parent / 'seed10'} (no run there); starting "
            "afresh (check --out and the settings if you meant another run)"
        ]
        result = CliRunner().invoke(run, [*args, "--out", str(tmp_path)])
        assert "nothing to resume" not in result.output  # without --resume, nothing to say
        # a run whose config.json was lost was announced as "nothing to resume ... starting
        # afresh", then refused: it is refused alone
        lost = kept.parent / "seed10"
        lost.mkdir()
        (lost / "eval.csv").write_text("step\n")
        result = CliRunner().invoke(run, [*args, "--out", str(tmp_path), "--resume"])
        assert "eval.csv but no config.json" in str(result.exception)  # exit 2 under tacbench
        assert "nothing to resume" not in result.output


def test_resume_with_no_run_of_the_command_is_refused(tmp_path: Path) -> None:
    """--resume whose settings name no existing run beside runs of other settings would start
    every run afresh (a million steps by default): it is refused, naming the variants the task
    has there."""
    other = tmp_path / "runs" / "tac" / "Hopper-v4" / "q1.5-a0.2-ls300" / "seed0"
    other.mkdir(parents=True)
    (other / "config.json").write_text("{}")
    args = [
        "--env",
        "Hopper-v4",
        "--q",
        "1.5",
        "--seed",
        "0",
        "--seed",
        "10",
        "--out",
        str(tmp_path),
    ]
    with mock.patch("tacbench.trainers.trainer_for") as trainer_for:
        result = CliRunner().invoke(cli, ["run", *args, "--resume"])
        assert result.exit_code == 2, result.output
        assert result.output.startswith(
            "Error: --resume: nothing to resume: none of its runs exists "
            f"({other.parent.parent / 'q1.5-a0.2' / 'seed0'}), and {other.parent.parent} holds "
            "the variants q1.5-a0.2-ls300."
        )
        result = CliRunner().invoke(cli, ["run", *args, "--resume", "--force"])
        assert result.output.startswith("Error: --resume continues a run and --force deletes it")
        trainer_for.assert_not_called()
        # with no run of the task there (a first run) it starts, and so it does where the
        # command's variant folder exists: its start-up was stopped (a lock file is left), or
        # its other seeds trained
        trainer_for.return_value.train.return_value = []
        for out in (tmp_path / "elsewhere", tmp_path):
            if out == tmp_path:
                lock = other.parent.parent / "q1.5-a0.2" / ".seed0.lock"
                lock.parent.mkdir()
                lock.touch()
            result = CliRunner().invoke(cli, ["run", *args[:-1], str(out), "--resume"])
            assert result.exit_code == 0 and "seed 10: nothing to resume" in result.output


def test_resume_says_a_baseline_seed_after_a_stop_was_not_started(tmp_path: Path) -> None:
    """A baseline trains its seeds one after another: a seed a Ctrl-C came before has no run
    yet, which is no reason to check --out and the settings, as the resume used to say."""
    variant = "learning_starts200-faeb7331"
    started = tmp_path / "runs" / "ddpg" / "Hopper-v4" / variant / "seed0"
    started.mkdir(parents=True)
    args = ["--algo", "ddpg", "--env", "Hopper-v4", "--learning-starts", "200"]
    args += ["--seed", "0", "--seed", "1", "--out", str(tmp_path)]
    command = shlex.join(["tacbench", "run", *args])
    (started / "config.json").write_text(json.dumps({"command": command}))
    with mock.patch("tacbench.trainers.trainer_for") as trainer_for:
        trainer_for.return_value.train.return_value = []
        result = CliRunner().invoke(run, [*args, "--seed", "99", "--resume"])
    assert result.exit_code == 0, result.output
    assert "seed 1: not started before the stop; starting it" in result.output
    # a seed the first command did not name is not one a stop came before
    assert "seed 99: nothing to resume" in result.output


def test_a_message_that_runs_share_is_said_once_after_them(tmp_path: Path) -> None:
    """A stopped group of members all end with the same resume command: with 900 members it
    was printed 900 times (about 1 MB of terminal). It is now said once, with how many runs
    share it; a run's own message stays on its line."""
    from tacbench.cli.common import report_outcomes
    from tacbench.runs import Outcome

    stop = "interrupted at step 157; resume with: tacbench run --seed 0 --seed 10 --resume"
    outcomes = [
        Outcome(0, tmp_path / "seed0", "interrupted", 157, stop),
        Outcome(10, tmp_path / "seed10", "failed", 120, "failed at step 120: non-finite loss"),
        Outcome(20, tmp_path / "seed20", "interrupted", 157, stop),
    ]

    @click.command()
    @click.pass_context
    def report(ctx: click.Context) -> None:
        report_outcomes(ctx, outcomes)

    result = CliRunner().invoke(report, [])
    assert result.output.splitlines() == [
        f"seed 0: interrupted, {tmp_path / 'seed0'}",
        f"seed 10: failed, {tmp_path / 'seed10'} (failed at step 120: non-finite loss)",
        f"seed 20: interrupted, {tmp_path / 'seed20'}",
        f"2 runs: {stop}",
    ]
    assert result.exit_code == 130


def test_a_sweep_into_another_results_folders_runs_is_refused(tmp_path: Path) -> None:
    run = tmp_path / "runs/tac/Hopper-v4/q1-a0.2/seed0"
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")
    (run / "status.json").write_text("{}")
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--seed", "0", "--q", "1"]
    result = CliRunner().invoke(cli, [*args, "--out", str(tmp_path / "runs")])
    assert result.exit_code == 2, result.output
    assert f"is the runs/ folder of the results folder {tmp_path}; give --out" in result.output
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["tac"]
