"""``tacbench run`` end to end on tiny budgets: every suite task, both update schedules, both
ln_q forms, several q; determinism, resume equivalence, members, Ctrl-C, the CLI contract."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.config import PAPER_ALPHA, PAPER_BEST_Q, RunConfig
from tacbench.envs import SUITE
from tacbench.launch import Outcome
from tacbench.training import LOSS_COLUMNS, train

pytestmark = pytest.mark.smoke

TINY: dict[str, Any] = {
    "total_steps": 1500,
    "learning_starts": 1000,
    "eval_every": 500,
    "eval_episodes": 2,
    "batch_size": 32,
    "log_every": 250,
    "checkpoint_every": 500,
}
# ln_q of the joint density overflows float32 at the first update on several tasks at their
# paper q (docs/tac.md, Numerics); joint mode is smoke-tested where it stays finite.
JOINT_FINITE = ("Hopper", "Swimmer", "Pusher")


def _config(env: str = "Hopper-v4", q: float = 1.5, alpha: float = 0.2, **kw: Any) -> RunConfig:
    return RunConfig(env=env, q=q, alpha=alpha, **{**TINY, **kw})


def _train(out: Path, *configs: RunConfig, **kw: Any) -> list[Outcome]:
    return train(list(configs), out, quiet=True, **kw)


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


@pytest.mark.parametrize(
    ("task", "lnq"), [(task, "per-dim") for task in SUITE] + [(t, "joint") for t in JOINT_FINITE]
)
def test_every_suite_task_trains_into_a_run_directory(tmp_path: Path, task: str, lnq: str) -> None:
    config = _config(SUITE[task], q=PAPER_BEST_Q[task], alpha=PAPER_ALPHA[task], lnq=lnq)
    (outcome,) = _train(tmp_path, config)
    run = tmp_path / "runs" / "tac" / SUITE[task] / config.variant / "seed0"
    assert outcome.directory == run
    status = json.loads((run / "status.json").read_text())
    metadata = json.loads((run / "config.json").read_text())
    assert metadata["config"] == config.to_dict()
    assert (metadata["env"], metadata["q"], metadata["alpha"]) == (
        SUITE[task],
        config.q,
        config.alpha,
    )
    evals = pd.read_csv(run / "eval.csv")
    assert list(evals.columns) == ["step", "wall_s", "return_mean", "return_std", "length_mean"]
    assert list(pd.read_csv(run / "train.csv").columns) == ["step", "wall_s", "return", "length"]
    assert list(pd.read_csv(run / "losses.csv").columns) == ["step", *LOSS_COLUMNS]
    checkpoint = torch.load(run / "checkpoint" / "state.pt", weights_only=True)
    assert (outcome.state, status["state"], status["step"]) == ("complete", "complete", 1500)
    assert checkpoint["step"] == 1500
    assert evals["step"].tolist() == [500, 1000, 1500]
    assert np.isfinite(evals["return_mean"]).all()
    losses = pd.read_csv(run / "losses.csv")
    assert losses["step"].tolist() == [1000, 1250, 1500]  # first update after step 1000
    assert losses["updates"].tolist() == [1, 250, 250]
    assert np.isfinite(losses.drop(columns="step")).all().all()


def test_non_finite_loss_marks_the_run_failed_and_keeps_the_last_checkpoint(tmp_path: Path) -> None:
    # Humanoid at q = 1.2 with the joint ln_q: log pi ~ 270 at the first update overflows float32
    (outcome,) = _train(tmp_path, _config("Humanoid-v4", q=1.2, alpha=0.05, lnq="joint"))
    status = json.loads((outcome.directory / "status.json").read_text())
    assert (outcome.state, status["state"], status["step"]) == ("failed", "failed", 1000)
    assert status["reason"].startswith("non-finite loss_v")
    assert "--lnq per-dim" in status["reason"]
    checkpoint = torch.load(outcome.directory / "checkpoint" / "state.pt", weights_only=True)
    assert checkpoint["step"] == 500
    assert pd.read_csv(outcome.directory / "eval.csv")["step"].tolist() == [500]
    (again,) = _train(tmp_path, _config("Humanoid-v4", q=1.2, alpha=0.05, lnq="joint"), resume=True)
    assert again.state == "skipped" and "failed at step 1000" in again.message


@pytest.mark.parametrize("q", [0.5, 1.0, 1.5, 2.0, 5.0])
def test_q_values(tmp_path: Path, q: float) -> None:
    (outcome,) = _train(tmp_path, _config(q=q, eval_every=0))
    assert outcome.state == "complete"
    losses = pd.read_csv(outcome.directory / "losses.csv")
    assert (losses["q"] == q).all()
    assert np.isfinite(losses.drop(columns="step")).all().all()
    assert not (outcome.directory / "eval.csv").read_text().strip().count("\n")  # header only


def test_episode_schedule_updates_once_per_step_of_each_finished_episode(tmp_path: Path) -> None:
    config = _config(update_schedule="episode", lnq="per-dim", eval_every=0, log_every=100_000)
    (outcome,) = _train(tmp_path, config)
    assert outcome.state == "complete"
    episodes = pd.read_csv(outcome.directory / "train.csv")
    expected = episodes.loc[episodes["step"] >= config.learning_starts, "length"].sum()
    losses = pd.read_csv(outcome.directory / "losses.csv")
    assert losses["step"].tolist() == [1500]
    assert losses["updates"].item() == expected > 0


def test_linear_q_schedule_is_logged(tmp_path: Path) -> None:
    (outcome,) = _train(tmp_path, _config(q=2.0, q_schedule="linear", eval_every=0))
    q = pd.read_csv(outcome.directory / "losses.csv")["q"].tolist()
    assert q == pytest.approx([1 + (1000 / 1500 - 0.1) / 0.8, 1 + (1250 / 1500 - 0.1) / 0.8, 2.0])


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    (outcome,) = _train(tmp_path_factory.mktemp("reference"), _config())
    assert outcome.state == "complete"
    return outcome.directory


def test_same_seed_same_results(tmp_path: Path, reference_run: Path) -> None:
    (outcome,) = _train(tmp_path, _config())
    _same_results(reference_run, outcome.directory)
    assert len(pd.read_csv(outcome.directory / "eval.csv")) == 3
    (other,) = _train(tmp_path / "other", _config(seed=1))
    assert _without_wall_clock(other.directory / "eval.csv") != _without_wall_clock(
        outcome.directory / "eval.csv"
    )


def test_stop_and_resume_equals_an_uninterrupted_run(tmp_path: Path, reference_run: Path) -> None:
    for stop_at in (0, 730, 1234):  # before the start, in warm-up, learning; mid-episode
        (outcome,) = _train(tmp_path, _config(), resume=True, stop=lambda s, at=stop_at: s >= at)
        assert (outcome.state, outcome.step) == ("interrupted", stop_at)
        status = json.loads((outcome.directory / "status.json").read_text())
        assert (status["state"], status["step"]) == ("running", stop_at)
    (outcome,) = _train(tmp_path, _config(), resume=True)
    assert outcome.state == "complete"
    _same_results(reference_run, outcome.directory)


def test_resume_on_an_env_without_exact_state_starts_a_fresh_episode(tmp_path: Path) -> None:
    config = _config("Pendulum-v1", q=1.0, eval_every=0)
    (first,) = _train(tmp_path, config, stop=lambda s: s >= 1100)
    assert (first.state, first.step) == ("interrupted", 1100)
    (outcome,) = _train(tmp_path, config, resume=True)
    assert outcome.state == "complete"
    episodes = pd.read_csv(outcome.directory / "train.csv")
    # 200-step episodes; the one in progress at 1100 is dropped and a new one starts there
    assert episodes["step"].tolist() == [200, 400, 600, 800, 1000, 1300, 1500]
    assert (episodes["length"] == 200).all()


def test_resume_after_a_crash_drops_rows_past_the_last_checkpoint(
    tmp_path: Path, reference_run: Path
) -> None:
    def crash(step: int) -> bool:
        if step >= 1300:
            raise RuntimeError("simulated crash")
        return False

    with pytest.raises(RuntimeError, match="simulated crash"):
        _train(tmp_path, _config(), stop=crash)
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / _config().variant / "seed0"
    assert json.loads((run / "status.json").read_text())["step"] == 1000  # last checkpoint
    assert pd.read_csv(run / "losses.csv")["step"].max() == 1250  # a row past it
    (outcome,) = _train(tmp_path, _config(), resume=True)
    assert outcome.state == "complete"
    _same_results(reference_run, run)


def test_members_start_exactly_as_they_would_alone(tmp_path: Path) -> None:
    warm_up = {"total_steps": 600, "learning_starts": 10_000, "eval_every": 600}
    grouped = _train(tmp_path / "group", _config(seed=0, **warm_up), _config(seed=10, **warm_up))
    (alone,) = _train(tmp_path / "alone", _config(seed=10, **warm_up))
    member = grouped[1].directory
    assert [o.state for o in grouped] == ["complete", "complete"]
    for name in ("eval.csv", "train.csv"):
        assert _without_wall_clock(member / name) == _without_wall_clock(alone.directory / name)
    a = torch.load(member / "checkpoint" / "state.pt", weights_only=True)
    b = torch.load(alone.directory / "checkpoint" / "state.pt", weights_only=True)
    for name, value in b["agent"]["params"].items():
        assert torch.equal(a["agent"]["params"][name], value), name
    chunks = sorted(p.name for p in (alone.directory / "checkpoint" / "replay").iterdir())
    assert chunks == ["000000000000-000000000500.npz", "000000000500-000000000600.npz"]
    for chunk in chunks:
        with (
            np.load(member / "checkpoint" / "replay" / chunk) as x,
            np.load(alone.directory / "checkpoint" / "replay" / chunk) as y,
        ):
            for key in y.files:
                np.testing.assert_array_equal(x[key], y[key], err_msg=key)
    other = torch.load(grouped[0].directory / "checkpoint" / "state.pt", weights_only=True)
    assert not torch.equal(
        other["agent"]["params"]["q1.net.weights.0"], b["agent"]["params"]["q1.net.weights.0"]
    )


CLI_TINY = ["--env", "Hopper-v4", "--steps", "300", "--learning-starts", "200"]
CLI_TINY += ["--eval-every", "100", "--eval-episodes", "1", "--quiet"]


def test_cli_run_skip_refuse_and_force(tmp_path: Path) -> None:
    args = [*CLI_TINY, "--out", str(tmp_path)]
    runner = CliRunner()
    first = runner.invoke(cli, ["run", *args])
    assert first.exit_code == 0, first.output
    assert "q = 2: the paper's best q for Hopper" in first.output
    assert "seed 0: complete" in first.output
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200" / "seed0"
    metadata = json.loads((run / "config.json").read_text())
    assert sorted(shlex.split(metadata["command"])) == sorted(["tacbench", "run", *args])
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [100, 200, 300]

    again = runner.invoke(cli, ["run", *args])
    assert again.exit_code == 0
    assert "seed 0: skipped" in again.output and "already complete (300 steps)" in again.output

    changed = runner.invoke(cli, ["run", *args, "--eval-every", "150"])
    assert changed.exit_code == 2
    assert "eval_every: 100 -> 150" in changed.output

    forced = runner.invoke(cli, ["run", *args, "--eval-every", "150", "--force"])
    assert forced.exit_code == 0, forced.output
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [150, 300]


def test_cli_user_errors_and_failed_run(tmp_path: Path) -> None:
    runner = CliRunner()
    for env, message in [("Hoper-v4", "Closest registered names"), ("CartPole-v1", "Discrete")]:
        result = runner.invoke(cli, ["run", "--env", env, "--out", str(tmp_path)])
        assert (result.exit_code, message in result.output) == (2, True), result.output
    args = ["--env", "Humanoid-v4", "--lnq", "joint", "--steps", "300", "--learning-starts", "200"]
    failed = runner.invoke(cli, ["run", *args, "--eval-every", "0", "--out", str(tmp_path)])
    assert failed.exit_code == 1, failed.output
    assert "seed 0: failed" in failed.output


def test_ctrl_c_checkpoints_and_resume_completes(tmp_path: Path) -> None:
    args = [sys.executable, "-m", "tacbench", "run", "--env", "Hopper-v4", "--steps", "2000"]
    args += ["--learning-starts", "1000", "--eval-every", "500", "--eval-episodes", "1"]
    args += ["--out", str(tmp_path)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    assert proc.stdout is not None
    for line in proc.stdout:
        if "step 1000/2000" in line:
            proc.send_signal(signal.SIGINT)
            break
    output = proc.stdout.read()
    assert proc.wait(timeout=60) == 130, output
    assert "interrupted at step" in output and "--resume" in output
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls1000" / "seed0"
    status = json.loads((run / "status.json").read_text())
    assert status["state"] == "running" and 1000 <= status["step"] < 2000
    resumed = subprocess.run([*args, "--resume"], capture_output=True, text=True, env=env)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    evals = pd.read_csv(run / "eval.csv")
    assert evals["step"].tolist() == [500, 1000, 1500, 2000]
    train_steps = pd.read_csv(run / "train.csv")["step"]
    assert train_steps.is_monotonic_increasing and not train_steps.duplicated().any()


def test_twin_q_critic_target_trains_and_resumes_exactly(tmp_path: Path) -> None:
    config = _config(critic_target="twin-q")
    (reference,) = _train(tmp_path / "reference", config)
    assert reference.state == "complete"
    assert reference.directory.parent.name == "q1.5-a0.2-twinq-ls1000-bs32"
    (stopped,) = _train(tmp_path / "resumed", config, stop=lambda step: step >= 1234)
    assert stopped.state == "interrupted"
    (resumed,) = _train(tmp_path / "resumed", config, resume=True)
    assert resumed.state == "complete"
    _same_results(reference.directory, resumed.directory)
    losses = pd.read_csv(resumed.directory / "losses.csv")
    assert (losses["loss_v"] == 0).all() and losses["loss_q1"].gt(0).all()
