"""Every baseline end to end on tiny budgets, on two task families (locomotion: Hopper;
manipulation: Pusher): the run directory, resume (off- and on-policy), crash recovery,
divergence, and the CLI (--algo, --hp and its errors)."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch
from click.testing import CliRunner

from baselines import ALGOS, OFF_POLICY, algos, callbacks, hyperparams
from baselines.config import BaselineConfig, make_configs
from baselines.trainer import train
from tacbench.cli import cli
from tacbench.launch import Outcome

pytestmark = pytest.mark.smoke

# Tiny budgets: off-policy learns from step 1000 with small batches; PPO/TRPO roll out 512
# steps, so the 1500-step budget cuts the third rollout short (it is not trained on).
TINY_HP = {
    "ddpg": ["learning_starts=1000", "batch_size=32"],
    "td3": ["learning_starts=1000", "batch_size=32"],
    "sac-sb3": ["learning_starts=1000", "batch_size=32"],
    "ppo": ["n_steps=512", "batch_size=64", "n_epochs=2"],
    "trpo": ["n_steps=512", "batch_size=64", "n_critic_updates=2"],
}
SETTINGS = {
    "total_steps": 1500,
    "eval_every": 500,
    "eval_episodes": 2,
    "checkpoint_every": 500,
    "log_every": 250,
}
TASKS = {"Hopper-v4": "Hopper", "Pusher-v5": "Pusher"}
METADATA_KEYS = {
    "algo",
    "env",
    "variant",
    "seed",
    "q",
    "alpha",
    "total_steps",
    "hp_overrides",
    "hyperparams_file",
    "command",
    "versions",
    "git_commit",
    "host",
    "created",
    "config",
}


def _config(algo: str, env: str = "Hopper-v4") -> BaselineConfig:
    torch.set_num_threads(1)
    return make_configs(algo, env, TASKS[env], [0], TINY_HP[algo], **SETTINGS)[0][0]


def _train(out: Path, config: BaselineConfig, **kw: Any) -> Outcome:
    (outcome,) = train([config], out, quiet=True, **kw)
    return outcome


def _without_wall_clock(path: Path) -> list[str]:
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    if "wall_s" not in header:
        return lines
    col = header.index("wall_s")
    return [",".join(v for i, v in enumerate(line.split(",")) if i != col) for line in lines]


def _same_results(a: Path, b: Path) -> None:
    for name in ("eval.csv", "train.csv", "losses.csv"):
        assert _without_wall_clock(a / name) == _without_wall_clock(b / name), name


@pytest.fixture(scope="module")
def completed(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str, str], Path]:
    """The run directory of an uninterrupted tiny run, trained once per (algo, env)."""
    cache: dict[tuple[str, str], Path] = {}

    def get(algo: str, env: str) -> Path:
        if (algo, env) not in cache:
            outcome = _train(tmp_path_factory.mktemp(f"{algo}-{env}"), _config(algo, env))
            assert outcome.state == "complete", outcome.message
            cache[algo, env] = outcome.directory
        return cache[algo, env]

    return get


@pytest.mark.parametrize("env", list(TASKS))
@pytest.mark.parametrize("algo", ALGOS)
def test_every_baseline_writes_a_complete_run_directory(
    completed: Callable[[str, str], Path], algo: str, env: str
) -> None:
    run = completed(algo, env)
    config = _config(algo, env)
    assert run.parts[-5:] == ("runs", algo, env, config.variant, "seed0")
    metadata = json.loads((run / "config.json").read_text())
    assert set(metadata) >= METADATA_KEYS
    assert (metadata["algo"], metadata["env"], metadata["seed"], metadata["q"]) == (
        algo,
        env,
        0,
        None,
    )
    assert metadata["alpha"] == (0.2 if algo == "sac-sb3" else None)
    assert metadata["config"] == config.to_dict()
    assert metadata["versions"]["stable_baselines3"] == version("stable-baselines3")
    table, _ = hyperparams.resolve(algo, env, TASKS[env])
    assert metadata["hp_overrides"] == {
        k: v for k, v in config.hyperparams.items() if table[k] != v
    }
    status = json.loads((run / "status.json").read_text())
    assert (status["state"], status["step"]) == ("complete", 1500)

    evals = pd.read_csv(run / "eval.csv")
    assert list(evals.columns) == ["step", "wall_s", "return_mean", "return_std", "length_mean"]
    assert evals["step"].tolist() == [500, 1000, 1500]
    assert np.isfinite(evals["return_mean"]).all() and (evals["length_mean"] >= 1).all()
    if env == "Pusher-v5":
        assert (evals["length_mean"] == 100).all()  # Pusher never terminates early
    episodes = pd.read_csv(run / "train.csv")
    assert list(episodes.columns) == ["step", "wall_s", "return", "length"]
    assert episodes["step"].is_monotonic_increasing and episodes["step"].iloc[-1] <= 1500
    assert episodes["length"].sum() == episodes["step"].iloc[-1]  # every step of every episode
    losses = pd.read_csv(run / "losses.csv")
    assert list(losses.columns) == ["step", *algos.loss_columns(config)]
    if algo in OFF_POLICY:  # SB3 updates from step 1001: 250 updates per 250-step window
        assert losses["step"].tolist() == [1250, 1500]
        assert losses["n_updates"].tolist() == [250, 500]
        assert np.isfinite(losses["critic_loss"]).all() and np.isfinite(losses["actor_loss"]).all()
    else:  # one row per trained rollout; the rollout cut at 1500 is not trained on
        assert losses["step"].tolist() == [512, 1024]
        assert np.isfinite(losses["value_loss"]).all()

    checkpoint = run / "checkpoint"
    state = torch.load(checkpoint / "state.pt", weights_only=True)
    assert state["step"] == 1500
    assert sorted(p.name for p in checkpoint.glob("*.zip")) == ["model-000000001500.zip"]
    replay = sorted(p.name for p in (checkpoint / "replay").glob("*.npz"))
    if algo in OFF_POLICY:
        assert replay == [
            "000000000000-000000000500.npz",
            "000000000500-000000001000.npz",
            "000000001000-000000001500.npz",
        ]
        with np.load(checkpoint / "replay" / replay[0]) as chunk:
            assert chunk["observations"].dtype == np.float32
            assert len(chunk["rewards"]) == 500
    else:
        assert replay == []
        assert (state["normalize"] is not None) == config.hyperparams["normalize"]


@pytest.mark.parametrize(
    ("algo", "stops", "stopped_at"),
    [
        ("sac-sb3", (730, 1234), (730, 1234)),
        ("ppo", (730, 1234), (1024, 1536)),
    ],
)
def test_stop_and_resume_equals_an_uninterrupted_run(
    tmp_path: Path,
    completed: Callable[[str, str], Path],
    algo: str,
    stops: tuple[int, ...],
    stopped_at: tuple[int, ...],
) -> None:
    """Off-policy runs stop at the step asked for; PPO/TRPO at the end of the rollout."""
    config = _config(algo)
    for stop_at, expected in zip(stops, stopped_at, strict=True):
        outcome = _train(tmp_path, config, resume=True, stop=lambda s, at=stop_at: s >= at)
        if expected >= 1500:  # the stop came in the last rollout: the run simply completes
            assert outcome.state == "complete"
            break
        assert (outcome.state, outcome.step) == ("interrupted", expected)
        assert "resume with" in outcome.message
        status = json.loads((outcome.directory / "status.json").read_text())
        assert (status["state"], status["step"]) == ("running", expected)
        assert torch.load(outcome.directory / "checkpoint" / "state.pt")["step"] == expected
    else:
        outcome = _train(tmp_path, config, resume=True)
    assert outcome.state == "complete"
    _same_results(completed(algo, "Hopper-v4"), outcome.directory)


def test_resume_after_a_crash_drops_rows_past_the_last_checkpoint(
    tmp_path: Path, completed: Callable[[str, str], Path]
) -> None:
    def crash(step: int) -> bool:
        if step >= 1300:
            raise RuntimeError("simulated crash")
        return False

    config = _config("ddpg")
    with pytest.raises(RuntimeError, match="simulated crash"):
        _train(tmp_path, config, stop=crash)
    run = tmp_path / "runs" / "ddpg" / "Hopper-v4" / config.variant / "seed0"
    assert json.loads((run / "status.json").read_text())["step"] == 1000  # last checkpoint
    assert pd.read_csv(run / "losses.csv")["step"].max() == 1250  # a row past it
    outcome = _train(tmp_path, config, resume=True)
    assert outcome.state == "complete"
    _same_results(completed("ddpg", "Hopper-v4"), run)
    assert not (run / "checkpoint" / "replay" / "000000001000-000000001300.npz").exists()


def test_non_finite_loss_marks_the_run_failed_and_keeps_the_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    record = callbacks.LossLogger.record
    calls = {"critic_loss": 0}

    def poisoned(self: callbacks.LossLogger, key: str, value: Any, exclude: Any = None) -> None:
        if key == "train/critic_loss":
            calls["critic_loss"] += 1
            value = float("inf") if calls["critic_loss"] >= 200 else value  # update 200: step 1200
        record(self, key, value, exclude)

    monkeypatch.setattr(callbacks.LossLogger, "record", poisoned)
    config = _config("sac-sb3")
    outcome = _train(tmp_path, config)
    status = json.loads((outcome.directory / "status.json").read_text())
    assert (outcome.state, status["state"], status["step"]) == ("failed", "failed", 1200)
    assert status["reason"].startswith("non-finite critic_loss at step 1200")
    assert "last checkpoint is kept" in status["reason"]
    assert torch.load(outcome.directory / "checkpoint" / "state.pt")["step"] == 1000
    again = _train(tmp_path, config, resume=True)
    assert again.state == "skipped" and "failed at step 1200" in again.message


CLI_TINY = ["--env", "Hopper-v4", "--steps", "300", "--eval-every", "100", "--eval-episodes", "1"]
CLI_TINY += ["--quiet"]


def test_cli_trains_two_seeds_then_skips_refuses_and_forces(tmp_path: Path) -> None:
    args = ["--algo", "sac-sb3", *CLI_TINY, "--learning-starts", "200", "--alpha", "0.1"]
    args += ["--hp", "batch_size=16", "--seed", "0", "--seed", "1", "--out", str(tmp_path)]
    runner = CliRunner()
    first = runner.invoke(cli, ["run", *args])
    assert first.exit_code == 0, first.output
    assert "overridden: {'ent_coef': 0.1, 'learning_starts': 200, 'batch_size': 16}" in first.output
    assert "seed 0: complete" in first.output and "seed 1: complete" in first.output
    (run,) = (tmp_path / "runs" / "sac-sb3" / "Hopper-v4").glob("*/seed1")
    assert run.parent.name.startswith("batch_size16-ent_coef0.1-learning_starts200-")
    metadata = json.loads((run / "config.json").read_text())
    assert sorted(shlex.split(metadata["command"])) == sorted(["tacbench", "run", *args])
    assert metadata["alpha"] == 0.1 and metadata["config"]["hyperparams"]["ent_coef"] == 0.1
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [100, 200, 300]

    again = runner.invoke(cli, ["run", *args])
    assert again.exit_code == 0 and "already complete (300 steps)" in again.output
    changed = runner.invoke(cli, ["run", *args, "--eval-every", "150"])
    assert changed.exit_code == 2 and "eval_every: 100 -> 150" in changed.output
    forced = runner.invoke(cli, ["run", *args, "--eval-every", "150", "--force"])
    assert forced.exit_code == 0, forced.output
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [150, 300]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--algo", "td3", "--hp", "lr=3e-4"], "unknown hyperparameter 'lr' for td3."),
        (["--algo", "td3", "--hp", "lr=3e-4"], "Valid keys: activation_fn, batch_size, buffer"),
        (["--algo", "ppo", "--hp", "n_steps=abc"], "n_steps for ppo must be an integer >= 2"),
        (["--algo", "ppo", "--hp", "n_steps"], "write key=value"),
        (["--algo", "ppo", "--q", "1.5"], "--q is a TAC option that ppo does not use"),
        (["--algo", "trpo", "--learning-starts", "5"], "--learning-starts is a TAC option"),
        (["--algo", "td3", "--alpha", "0.1"], "--alpha is a TAC option that td3 does not use"),
        (["--hp", "gamma=0.9"], "--hp sets a baseline's hyperparameters"),
        (["--algo", "sac"], "'sac' is not one of 'tac', 'ddpg', 'td3', 'sac-sb3'"),
    ],
)
def test_cli_refuses_bad_hyperparameters_clearly(
    tmp_path: Path, args: list[str], message: str
) -> None:
    result = CliRunner().invoke(cli, ["run", "--env", "Hopper-v4", *args, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "runs").exists()


def test_ctrl_c_stops_ppo_at_the_rollout_end_and_resume_completes(tmp_path: Path) -> None:
    args = [sys.executable, "-m", "tacbench", "run", "--algo", "ppo", "--env", "Hopper-v4"]
    args += ["--steps", "2500", "--hp", "n_steps=512", "--hp", "n_epochs=1"]
    args += ["--eval-every", "500", "--eval-episodes", "1", "--out", str(tmp_path)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    assert proc.stdout is not None
    for line in proc.stdout:
        if "step 500/2500" in line:
            proc.send_signal(signal.SIGINT)
            break
    output = proc.stdout.read()
    assert proc.wait(timeout=60) == 130, output
    assert "finishing this rollout, then checkpointing" in output
    assert "interrupted at step" in output and "--resume" in output
    (run,) = (tmp_path / "runs" / "ppo" / "Hopper-v4").glob("*/seed0")
    status = json.loads((run / "status.json").read_text())
    assert status["state"] == "running" and status["step"] % 512 == 0 and status["step"] < 2500
    resumed = subprocess.run([*args, "--resume"], capture_output=True, text=True, env=env)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [500, 1000, 1500, 2000, 2500]
    train_steps = pd.read_csv(run / "train.csv")["step"]
    assert train_steps.is_monotonic_increasing and not train_steps.duplicated().any()
