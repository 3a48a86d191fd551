"""The run directory contract (docs/results-schema.md) for every learner: TAC (both critic
targets) and each baseline, on a locomotion (Hopper) and a manipulation task (Pusher), each
trained once on a tiny budget: the path, config.json, status.json, the three CSVs' columns and
rows, the TensorBoard events of those rows, and the checkpoint's layout."""

from __future__ import annotations

import json
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from baselines import OFF_POLICY, algos, hyperparams
from tacbench.paper import paper_task
from tacbench.runs import EVAL_COLUMNS, TRAIN_COLUMNS
from tacbench.training import LOSS_COLUMNS
from tests.helpers import LEARNERS, assert_tensorboard_matches_csvs, tiny_configs, train

pytestmark = pytest.mark.smoke

METADATA_KEYS = {"algo", "env", "variant", "seed", "q", "alpha", "total_steps", "command"}
METADATA_KEYS |= {"cpu_clock", "versions", "git_commit", "host", "created", "config"}
TASKS = ("Hopper-v4", "Pusher-v5")


@pytest.fixture(scope="module")
def trained(
    tmp_path_factory: pytest.TempPathFactory, uninterrupted: Callable[[str], Path]
) -> Callable[[str, str], Path]:
    """The run directory of one uninterrupted tiny run per (learner, env), trained once (on
    Hopper, the session's ``uninterrupted`` run: the same config)."""
    cache: dict[tuple[str, str], Path] = {}

    def get(learner: str, env: str) -> Path:
        if env == "Hopper-v4":
            return uninterrupted(learner)
        if (learner, env) not in cache:
            out = tmp_path_factory.mktemp(f"{learner}-{env}")
            (outcome,) = train(out, tiny_configs(learner, env))
            assert outcome.state == "complete", outcome.message
            cache[learner, env] = outcome.directory
        return cache[learner, env]

    return get


@pytest.mark.parametrize("env", TASKS)
@pytest.mark.parametrize("learner", LEARNERS)
def test_every_learner_writes_the_documented_run_directory(
    trained: Callable[[str, str], Path], learner: str, env: str
) -> None:
    run = trained(learner, env)
    (config,) = tiny_configs(learner, env)
    assert run.parts[-5:] == ("runs", config.algo, env, config.variant, "seed0")
    metadata = json.loads((run / "config.json").read_text())
    assert set(metadata) >= METADATA_KEYS
    assert (metadata["algo"], metadata["env"], metadata["seed"]) == (config.algo, env, 0)
    # --compile auto is recorded as what the run used: too short to compile, off
    used = {**config.to_dict(), **({"compile": "off"} if config.algo == "tac" else {})}
    assert metadata["config"] == used
    assert metadata["versions"]["stable_baselines3"] == version("stable-baselines3")
    status = json.loads((run / "status.json").read_text())
    assert (status["state"], status["step"]) == ("complete", 1500)
    assert set(status) == {"state", "step", "reason", "updated"}
    assert_tensorboard_matches_csvs(run)  # on by default, for every learner

    evals = pd.read_csv(run / "eval.csv")
    assert tuple(evals.columns) == EVAL_COLUMNS
    assert evals["step"].tolist() == [500, 1000, 1500]
    assert np.isfinite(evals["return_mean"]).all() and (evals["length_mean"] >= 1).all()
    if env == "Pusher-v5":
        assert (evals["length_mean"] == 100).all()  # Pusher never terminates early
    episodes = pd.read_csv(run / "train.csv")
    assert tuple(episodes.columns) == TRAIN_COLUMNS
    assert episodes["step"].is_monotonic_increasing and episodes["step"].iloc[-1] <= 1500
    assert episodes["length"].sum() == episodes["step"].iloc[-1]  # every step of every episode

    losses = pd.read_csv(run / "losses.csv")
    checkpoint = run / "checkpoint"
    # two generations are kept, each recorded by its manifest; the newest lists its files
    previous = 1024 if config.algo in ("ppo", "trpo") else 1000  # PPO, TRPO: at rollout ends
    manifests = sorted(p.name for p in checkpoint.glob("manifest-*.json"))
    assert manifests == [f"manifest-{previous:012d}.json", "manifest-000000001500.json"]
    listed = json.loads((checkpoint / manifests[-1]).read_text())["files"]
    state = torch.load(checkpoint / "state-000000001500.pt", weights_only=True)
    assert state["step"] == 1500
    replay = sorted(p.name for p in (checkpoint / "replay").glob("*.npz"))
    chunks = ["000000000000-000000000500.npz", "000000000500-000000001000.npz"]
    chunks.append("000000001000-000000001500.npz")
    states = sorted(p.name for p in checkpoint.glob("state-*.pt"))
    assert states == [f"state-{previous:012d}.pt", "state-000000001500.pt"]
    assert not list(checkpoint.rglob("*.tmp"))

    def assert_listed(*names: str) -> None:
        sizes = {name: entry["size"] for name, entry in listed.items()}
        assert sizes == {name: (checkpoint / name).stat().st_size for name in names}

    if config.algo == "tac":
        assert (metadata["q"], metadata["alpha"]) == (1.5, 0.2)
        assert metadata["members"] == [{"q": 1.5, "alpha": 0.2, "seed": 0}]
        assert list(losses.columns) == ["step", *LOSS_COLUMNS]
        assert losses["step"].tolist() == [1000, 1250, 1500]  # first update after step 1000
        assert losses["updates"].tolist() == [1, 250, 250]
        assert np.isfinite(losses.drop(columns="step")).all().all()
        assert replay == chunks
        assert_listed("state-000000001500.pt", *(f"replay/{chunk}" for chunk in chunks))
        return
    assert metadata["q"] is None
    assert metadata["alpha"] == (0.2 if config.algo == "sac-sb3" else None)
    table, _ = hyperparams.resolve(config.algo, env, paper_task(env))
    assert metadata["hp_overrides"] == {
        k: v for k, v in config.hyperparams.items() if table[k] != v
    }
    assert list(losses.columns) == ["step", *algos.loss_columns(config)]
    models = sorted(p.name for p in checkpoint.glob("*.zip"))
    assert models == [f"model-{previous:012d}.zip", "model-000000001500.zip"]
    if config.algo in OFF_POLICY:  # SB3 updates from step 1001: 250 updates per 250-step window
        assert losses["step"].tolist() == [1250, 1500]
        assert losses["n_updates"].tolist() == [250, 500]
        assert np.isfinite(losses["critic_loss"]).all() and np.isfinite(losses["actor_loss"]).all()
        assert replay == chunks
        assert_listed(
            "state-000000001500.pt",
            "model-000000001500.zip",
            *(f"replay/{chunk}" for chunk in chunks),
        )
        with np.load(checkpoint / "replay" / replay[0]) as chunk:
            assert chunk["observations"].dtype == np.float32
            assert len(chunk["rewards"]) == 500
    else:  # one row per trained rollout; the rollout cut at 1500 is not trained on
        assert losses["step"].tolist() == [512, 1024]
        assert np.isfinite(losses["value_loss"]).all()
        assert replay == []
        assert_listed("state-000000001500.pt", "model-000000001500.zip")
        assert (state["normalize"] is not None) == config.hyperparams["normalize"]


@pytest.mark.parametrize("learner", ["tac", "td3"])
def test_no_tensorboard_writes_no_event_files(tmp_path: Path, learner: str) -> None:
    (outcome,) = train(tmp_path, tiny_configs(learner, total_steps=500, tensorboard=False))
    assert outcome.state == "complete"
    assert not (outcome.directory / "tensorboard").exists()
    assert (
        json.loads((outcome.directory / "config.json").read_text())["config"]["tensorboard"]
        is False
    )
