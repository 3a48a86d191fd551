"""The baselines' own behaviour end to end on tiny budgets: divergence, and the CLI (--algo, --hp
and its errors). Their run directory, resume and determinism are tested with TAC's, for every
learner (test_run_directory.py, test_resume.py, test_determinism.py)."""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from click.testing import CliRunner

from baselines import algos, callbacks
from tacbench import trainers
from tacbench.cli import cli
from tacbench.progress import Progress
from tests.helpers import TINY_HP, TINY_RUN, checkpoint_state, tiny_configs, train

pytestmark = pytest.mark.smoke


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
    configs = tiny_configs("sac-sb3")
    (outcome,) = train(tmp_path, configs)
    status = json.loads((outcome.directory / "status.json").read_text())
    assert (outcome.state, status["state"], status["step"]) == ("failed", "failed", 1200)
    assert status["reason"].startswith("non-finite critic_loss at step 1200")
    assert "last checkpoint is kept" in status["reason"]
    assert checkpoint_state(outcome.directory)["step"] == 1000
    (again,) = train(tmp_path, configs, resume=True)
    assert again.state == "failed" and again.message.startswith("skipped: failed at step 1200")
    (unkept,) = train(tmp_path / "unkept", tiny_configs("sac-sb3", checkpoint_every=0))
    assert unkept.message.endswith("; no checkpoint had been written yet")


def test_a_model_sb3_refuses_to_build_leaves_no_run_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SB3 checks some settings only as it builds the model. The run directory was opened
    first, so such a refusal left a run "running" at step 0 that the same command then refused
    (and --resume failed again); now nothing is written before the model exists."""

    def refuse(config: Any, venv: Any) -> Any:
        raise AssertionError("`batch_size` must be greater than 1")

    monkeypatch.setattr(algos, "build_model", refuse)
    with pytest.raises(AssertionError, match="batch_size"):
        train(tmp_path, tiny_configs("ppo"))
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and p.suffix != ".lock"]


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
        (  # used to run with the target unused, in a variant of its own
            ["--algo", "sac-sb3", "--target-entropy", "5"],
            "target_entropy=5.0 (--target-entropy) is what a learned alpha aims at",
        ),
        (  # a sweep has no --alpha: it named only that
            ["--algo", "sac-sb3", "--hp", "target_entropy=-1"],
            "sac-sb3's alpha is fixed here (ent_coef=0.2); add --alpha auto (or --alpha-mode auto)",
        ),
        (  # used to learn alpha
            ["--algo", "sac-sb3", "--alpha", "auto", "--alpha-mode", "fixed"],
            "--alpha auto learns alpha; it does not mix with --alpha-mode fixed",
        ),
        (["--algo", "ppo", "--hp", "batch_size=1"], "PPO normalises the advantages"),
        (  # used to train without a single update, and no warning
            ["--algo", "td3", "--hp", "gradient_steps=0"],
            "td3 would make no gradient step, and its networks would never be updated",
        ),
        (  # used to say that --hp learning_starts was given twice
            ["--algo", "td3", "--learning-starts", "100", "--hp", "learning_starts=200"],
            "--hp learning_starts=200 sets learning_starts, which --learning-starts 100 sets "
            "too; give one of the two.",
        ),
        (
            ["--algo", "sac-sb3", "--alpha-mode", "auto", "--hp", "ent_coef=0.3"],
            "--hp ent_coef=0.3 sets ent_coef, which --alpha-mode auto sets too",
        ),
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


@pytest.mark.parametrize("train_freq", ["7", "[1,episode]"])
def test_an_off_policy_rollout_is_cut_at_the_budget(tmp_path: Path, train_freq: str) -> None:
    """With train_freq above one step SB3 collects whole rollouts: TD3 trained to step 1,505 (a
    losses row and a checkpoint there) and an episode ended at 1,501 though the run said
    complete at 1,500."""
    args = ["--algo", "td3", *CLI_TINY, "--learning-starts", "100", "--checkpoint-every", "130"]
    args += ["--log-every", "50", "--hp", f"train_freq={train_freq}", "--hp", "batch_size=16"]
    result = CliRunner().invoke(cli, ["run", *args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    (run,) = (tmp_path / "runs" / "td3" / "Hopper-v4").glob("*/seed0")
    assert json.loads((run / "status.json").read_text())["step"] == 300
    assert pd.read_csv(run / "losses.csv")["step"].max() == 300
    assert pd.read_csv(run / "train.csv")["step"].max() <= 300
    steps = [int(p.stem.split("-")[1]) for p in (run / "checkpoint").glob("manifest-*.json")]
    assert max(steps) == 300


def test_an_off_policy_stop_waits_for_the_rollout_and_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With train_freq above one step a stop takes effect at the rollout's end; it used to wait
    there without a word, as only PPO and TRPO announced it."""
    said: list[str] = []
    monkeypatch.setattr(Progress, "message", lambda self, text: said.append(text))
    configs, _ = trainers.make_configs(
        "ddpg", "Hopper-v4", "Hopper", [0], TINY_RUN, hp=[*TINY_HP["ddpg"], "train_freq=400"]
    )
    (outcome,) = train(tmp_path, configs, resume=True, stop=lambda step: step >= 730)
    assert (outcome.state, outcome.step) == ("interrupted", 800)
    assert "stop requested at step 730: finishing this rollout, then checkpointing" in said
    assert checkpoint_state(outcome.directory)["step"] == 800
    said.clear()
    (default,) = train(tmp_path / "every-step", tiny_configs("ddpg"), stop=lambda s: s >= 730)
    assert (default.state, default.step) == ("interrupted", 730)
    assert not any(text.startswith("stop requested") for text in said)  # it stops at once


def test_a_stop_names_the_seeds_it_came_before(tmp_path: Path) -> None:
    """A baseline's seeds train one after another: a stop during the first leaves the others
    untouched, and the stop's report names them too (it used to list the first seed alone)."""
    configs = tiny_configs("ddpg", seeds=[0, 10, 20])
    first, *later = train(tmp_path, configs, stop=lambda step: step >= 730)
    assert (first.state, first.step) == ("interrupted", 730)
    assert [(o.seed, o.state, o.step) for o in later] == [
        (10, "interrupted", 0),
        (20, "interrupted", 0),
    ]
    assert all("the stop came before this seed's turn" in o.message for o in later)
    assert not any(o.directory.exists() for o in later)
    resumed = train(tmp_path, configs, resume=True)
    assert [o.state for o in resumed] == ["complete"] * 3
