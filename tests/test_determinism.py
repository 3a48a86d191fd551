"""Reproducibility from the seed, for every learner: the same config trained twice writes the
same CSVs (apart from wall-clock times), another seed does not; a TAC member starts exactly as
it would alone, whatever shares its process."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from tacbench.envs import make_env
from tacbench.seeding import run_streams
from tacbench.tac.agent import TacAgent
from tests.helpers import (
    LEARNERS,
    assert_same_results,
    checkpoint_state,
    results_of,
    tiny_configs,
    train,
)

pytestmark = pytest.mark.smoke


@pytest.mark.parametrize("learner", LEARNERS)
def test_same_seed_same_results_another_seed_other_results(
    tmp_path: Path, uninterrupted: Callable[[str], Path], learner: str
) -> None:
    first = uninterrupted(learner)  # the session's run of tiny_configs(learner), trained once
    (second,) = train(tmp_path / "second", tiny_configs(learner))
    (other,) = train(tmp_path / "other", tiny_configs(learner, seeds=[1]))
    assert second.state == other.state == "complete"
    assert_same_results(first, second.directory)
    assert results_of(other.directory)["eval.csv"] != results_of(first)["eval.csv"]


def test_members_start_exactly_as_they_would_alone(tmp_path: Path) -> None:
    warm_up = {"total_steps": 600, "learning_starts": 10_000, "eval_every": 600}
    grouped = train(tmp_path / "group", tiny_configs("tac", seeds=[0, 10], **warm_up))
    (alone,) = train(tmp_path / "alone", tiny_configs("tac", seeds=[10], **warm_up))
    member = grouped[1].directory
    assert [o.state for o in grouped] == ["complete", "complete"]
    for name in ("eval.csv", "train.csv"):
        assert results_of(member)[name] == results_of(alone.directory)[name]
    a = checkpoint_state(member)
    b = checkpoint_state(alone.directory)
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
    other = checkpoint_state(grouped[0].directory)
    assert not torch.equal(
        other["agent"]["params"]["q1.weights.0"], b["agent"]["params"]["q1.weights.0"]
    )


def test_a_runs_random_streams_are_independent_children_of_its_seed(tmp_path: Path) -> None:
    """The warm-up actions, the initial state and the weights come from three children of
    SeedSequence(seed), not from the seed itself (which made the first warm-up actions the very
    numbers the initial state was drawn from)."""
    streams = run_streams(7)
    again = run_streams(7)
    assert (again.torch_seed, again.env_seed) == (streams.torch_seed, streams.env_seed)
    assert (again.numpy.generate_state(2) == streams.numpy.generate_state(2)).all()
    assert streams.env_seed != run_streams(8).env_seed
    assert len({streams.torch_seed, streams.env_seed, 7}) == 3
    (config,) = tiny_configs("tac", seeds=[7], total_steps=500, eval_every=0)
    (outcome,) = train(tmp_path, [config])
    # learning starts after 500 steps: the checkpoint holds the initial weights, drawn from the
    # torch child's seed, not from 7
    saved = checkpoint_state(outcome.directory)["agent"]["params"]
    from_child = TacAgent(11, 3, config, [streams.torch_seed], torch.device("cpu"))
    for name, value in from_child.member_state(0)["params"].items():
        assert torch.equal(saved[name], value), name
    from_seed = TacAgent(11, 3, config, [7], torch.device("cpu")).member_state(0)["params"]
    weights = [name for name in from_seed if ".weights." in name]  # the biases start at zero
    assert not any(torch.equal(saved[name], from_seed[name]) for name in weights)
    with np.load(
        outcome.directory / "checkpoint" / "replay" / "000000000000-000000000500.npz"
    ) as r:
        first_action, first_obs = r["action"][0], r["rows"][0]
    expected = np.random.default_rng(streams.numpy).uniform(-1.0, 1.0, 3).astype(np.float32)
    np.testing.assert_array_equal(first_action, expected)
    env = make_env("Hopper-v4")
    np.testing.assert_array_equal(first_obs, env.reset(seed=streams.env_seed)[0].astype(np.float32))
    assert not np.array_equal(first_obs, env.reset(seed=7)[0].astype(np.float32))
    env.close()
