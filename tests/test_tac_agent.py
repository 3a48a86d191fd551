"""The member-batched networks and agent: per-member initialisation, act, update, state."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch

from tacbench.config import RunConfig
from tacbench.tac import METRICS, TacAgent, coefficients
from tacbench.tac.maths import ALPHA_METRICS, Coefficients
from tacbench.tac.networks import glorot_uniform, init_layers, mlp, policy_head
from tacbench.tac.update import update
from tests.helpers import random_minibatch, tac_agent

pytestmark = pytest.mark.unit

OBS, ACT = 5, 3


def _agent(seeds: list[int], **settings: Any) -> TacAgent:
    return tac_agent(OBS, ACT, seeds, **settings)


def _c(k: int, q: float = 1.5) -> Coefficients:
    return coefficients([q] * k, [0.2] * k, torch.device("cpu"))


def _batch(k: int, b: int = 12, seed: int = 0) -> dict[str, np.ndarray]:
    return random_minibatch(k, b, OBS, ACT, seed=seed, terminal=0.2)


def _params(agent: TacAgent, k: int) -> dict[str, torch.Tensor]:
    return agent.member_state(k)["params"]


def test_batched_mlp_applies_each_members_own_weights() -> None:
    gens = [torch.Generator().manual_seed(s) for s in (1, 2)]
    net = init_layers([4, 6, 2], gens)
    with torch.no_grad():
        for bias in net.biases:
            bias.normal_()
    x = torch.randn(2, 7, 4)
    out = mlp(net, x)
    assert out.shape == (2, 7, 2)
    for k in range(2):
        w0, b0, w1, b1 = net.weights[0][k], net.biases[0][k], net.weights[1][k], net.biases[1][k]
        torch.testing.assert_close(out[k], torch.relu(x[k] @ w0 + b0) @ w1 + b1)


def test_a_value_head_of_width_one_is_the_same_product() -> None:
    gens = [torch.Generator().manual_seed(s) for s in (1, 2, 3)]
    net = init_layers([4, 6, 1], gens)
    x = torch.randn(3, 7, 4)
    hidden = torch.relu(torch.bmm(x, net.weights[0]) + net.biases[0])
    torch.testing.assert_close(mlp(net, x), torch.bmm(hidden, net.weights[1]) + net.biases[1])


def test_glorot_uniform_bounds_and_zero_biases() -> None:
    weights = glorot_uniform(300, 6, [torch.Generator().manual_seed(0)])
    limit = math.sqrt(6 / 306)
    assert weights.abs().max() <= limit
    assert weights.abs().max() > 0.9 * limit
    assert not init_layers([3, 4], [torch.Generator().manual_seed(0)]).biases[0].any()


def test_log_std_stays_within_bounds() -> None:
    net = init_layers([OBS, 8, 2 * ACT], [torch.Generator().manual_seed(0)])
    _, log_std = policy_head(mlp(net, torch.randn(1, 50, OBS) * 1e4), ACT, -20.0, 2.0)
    assert log_std.min() >= -20.0
    assert log_std.max() <= 2.0


def test_member_initialisation_does_not_depend_on_other_members() -> None:
    alone, grouped = _agent([10]), _agent([0, 10, 20])
    for name, value in _params(alone, 0).items():
        assert torch.equal(value, _params(grouped, 1)[name]), name
    assert not torch.equal(_params(grouped, 0)["q1.weights.0"], _params(grouped, 1)["q1.weights.0"])


def test_target_v_starts_as_a_copy_of_v() -> None:
    params = _params(_agent([3]), 0)
    for key in ("weights.0", "biases.0", "weights.1"):
        assert torch.equal(params[f"v.{key}"], params[f"v_target.{key}"])


def test_actions_are_bounded_and_deterministic_action_is_tanh_mu() -> None:
    agent = _agent([0, 1])
    obs = np.random.default_rng(0).normal(size=(2, OBS))
    action = agent.act(obs)
    assert action.shape == (2, ACT)
    assert np.all(np.abs(action) <= 1.0)
    det = agent.act_deterministic(obs[:, None])
    obs_tensor = torch.as_tensor(obs[:, None], dtype=torch.float32)
    mu, _ = policy_head(mlp(agent.chunks[0].params.networks.policy, obs_tensor), ACT, -20.0, 2.0)
    np.testing.assert_allclose(det, torch.tanh(mu).numpy())


def test_update_changes_weights_and_moves_target_v_by_tau() -> None:
    agent = _agent([0], tau=0.005)
    before = _params(agent, 0)
    metrics = update(agent, _batch(1), _c(1))
    after = _params(agent, 0)
    assert metrics.shape == (1, len(METRICS))
    assert torch.isfinite(metrics).all()
    for net in ("policy", "q1", "q2", "v"):
        assert not torch.equal(before[f"{net}.weights.0"], after[f"{net}.weights.0"])
    expected = 0.995 * before["v_target.weights.0"] + 0.005 * after["v.weights.0"]
    torch.testing.assert_close(after["v_target.weights.0"], expected)


def test_members_train_independently() -> None:
    """Member 1 of a pair ends where the same seed alone ends, even if member 0 diverges."""
    pair, alone = _agent([4, 5]), _agent([5])
    for step in range(3):
        batch = _batch(2, seed=step)
        batch["reward"][0] = np.nan  # member 0 diverges at once
        pair.alive &= torch.tensor([step == 0, True])  # the trainer retires it after step 0
        update(pair, batch, _c(2))
        update(alone, {key: value[1:] for key, value in batch.items()}, _c(1))
    for name, value in _params(alone, 0).items():
        torch.testing.assert_close(_params(pair, 1)[name], value, rtol=1e-6, atol=1e-7)


def test_member_state_round_trip_continues_identically() -> None:
    agent = _agent([7, 8])
    for step in range(2):
        update(agent, _batch(2, seed=step), _c(2))
    restored = _agent([0, 1])
    restored.load_member_states([agent.member_state(0), agent.member_state(1)])
    batch = _batch(2, seed=5)
    torch.testing.assert_close(
        update(agent, batch, _c(2)), update(restored, batch, _c(2)), rtol=0, atol=0
    )
    np.testing.assert_array_equal(agent.act(batch["obs"][:, 0]), restored.act(batch["obs"][:, 0]))
    for k in range(2):
        for name, value in _params(agent, k).items():
            assert torch.equal(value, _params(restored, k)[name]), name


def test_twin_q_moves_the_target_critics_by_tau_and_leaves_v_alone() -> None:
    agent = _agent([0], tau=0.005, critic_target="twin-q")
    before = _params(agent, 0)
    for name in ("weights.0", "biases.0", "weights.1"):
        for net in ("q1", "q2"):  # the targets start as copies
            assert torch.equal(before[f"{net}_target.{name}"], before[f"{net}.{name}"])
    metrics = update(agent, _batch(1), _c(1))
    after = _params(agent, 0)
    assert metrics[0, METRICS.index("loss_v")] == 0.0
    for net in ("q1", "q2"):
        for name in ("weights.0", "biases.1"):
            target, online = f"{net}_target.{name}", f"{net}.{name}"
            expected = 0.995 * before[target] + 0.005 * after[online]
            torch.testing.assert_close(after[target], expected)
    assert not any(name.startswith("v_target.") for name in after)  # no target V
    for name, value in before.items():  # V is not trained
        if name.startswith("v."):
            assert torch.equal(after[name], value), name


def test_twin_q_member_state_round_trip_continues_identically() -> None:
    agent = _agent([7, 8], critic_target="twin-q")
    for step in range(2):
        update(agent, _batch(2, seed=step), _c(2))
    restored = _agent([0, 1], critic_target="twin-q")
    restored.load_member_states([agent.member_state(0), agent.member_state(1)])
    assert "q1_target.weights.0" in agent.member_state(0)["params"]
    batch = _batch(2, seed=5)
    torch.testing.assert_close(
        update(agent, batch, _c(2)), update(restored, batch, _c(2)), rtol=0, atol=0
    )
    for k in range(2):
        for name, value in _params(agent, k).items():
            assert torch.equal(value, _params(restored, k)[name]), name


@pytest.mark.parametrize(
    ("settings", "chunks"),
    [({"update_schedule": "episode"}, 3), ({"warmup_updates": "on"}, 1)],
    ids=["episode-schedule", "warmup-updates"],
)
def test_a_member_without_an_update_is_bit_identical_after_the_groups_update(
    settings: dict[str, str], chunks: int
) -> None:
    """Only the members due update (the episode schedule: a chunk per member, the others'
    skipped; updates during warm-up in the step schedule: one chunk, masked); the others'
    weights, Adam state, targets and generators are exactly as before."""
    agent = _agent([3, 4, 5], **settings)
    assert len(agent.chunks) == chunks
    batch = _batch(3)
    update(agent, batch, _c(3))  # everyone once, so the moments are not zero
    before = [agent.member_state(k) for k in range(3)]
    update(agent, _batch(3, seed=1), _c(3), members=[True, False, True])
    after = [agent.member_state(k) for k in range(3)]
    assert torch.equal(after[1]["generator"], before[1]["generator"])
    for part in ("exp_avg", "exp_avg_sq", "step"):
        same = after[1]["adam"][part], before[1]["adam"][part]
        if part == "step":
            assert torch.equal(*same)
        else:
            assert all(torch.equal(v, same[1][n]) for n, v in same[0].items()), part
    assert all(torch.equal(v, before[1]["params"][n]) for n, v in after[1]["params"].items())
    for k in (0, 2):  # the members that updated moved, their step counts are 2
        assert not torch.equal(
            after[k]["params"]["q1.weights.0"], before[k]["params"]["q1.weights.0"]
        )
        assert after[k]["adam"]["step"].item() == 2.0


def test_members_updating_at_their_own_times_each_train_as_if_alone() -> None:
    """With per-member updates a CPU agent holds each member in its own chunk and a round
    touches only the chunks that are due: after rounds with different members due, every
    member's weights and Adam state are exactly those of the same seed trained alone on its
    own rows of the same minibatches."""
    seeds, due = [3, 4, 5], [[True, True, True], [True, False, True], [False, True, False]]
    group = _agent(seeds, update_schedule="episode")
    assert [c.members for c in group.chunks] == [slice(0, 1), slice(1, 2), slice(2, 3)]
    alone = [_agent([seed], update_schedule="episode") for seed in seeds]
    for r, members in enumerate(due):
        batch = _batch(3, seed=r)
        metrics = update(group, batch, _c(3), members=members)
        for k in np.flatnonzero(members):
            own = update(alone[k], {n: v[k : k + 1] for n, v in batch.items()}, _c(1))
            assert torch.equal(metrics[k], own[0])
        assert (metrics[~torch.as_tensor(members)] == 0).all()
    for k, single in enumerate(alone):
        state, expected = group.member_state(k), single.member_state(0)
        assert torch.equal(state["adam"]["step"], expected["adam"]["step"])
        for part, name in (("params", None), ("adam", "exp_avg"), ("adam", "exp_avg_sq")):
            mine, theirs = state[part], expected[part]
            if name is not None:
                mine, theirs = mine[name], theirs[name]
            assert mine.keys() == theirs.keys()
            assert all(torch.equal(mine[n], theirs[n]) for n in theirs), (k, part, name)


@pytest.mark.parametrize("learned_alpha", [False, True])
def test_a_round_with_no_member_due_changes_nothing(learned_alpha: bool) -> None:
    """Zeros of the usual width (with the alpha metrics when alpha is learned); no weight moves."""
    config = RunConfig(
        env="Hopper-v4",
        q=1.5,
        alpha=0.2,
        hidden_sizes=(16,),
        compile="off",
        update_schedule="episode",
        alpha_mode="auto" if learned_alpha else "fixed",
    )
    alphas = [0.2, 0.2] if learned_alpha else None
    agent = TacAgent(OBS, ACT, config, [3, 4], torch.device("cpu"), initial_alphas=alphas)
    before = [agent.member_state(k)["params"] for k in range(2)]
    metrics = update(agent, _batch(2), _c(2), members=[False, False])
    assert metrics.shape[0] == 2 and (metrics == 0).all()
    assert metrics.shape[1] == len(METRICS) + (len(ALPHA_METRICS) if learned_alpha else 0)
    for k in range(2):
        after = agent.member_state(k)["params"]
        assert all(torch.equal(v, before[k][n]) for n, v in after.items())


def test_the_losses_constants_come_from_the_config_settings_of_the_same_name() -> None:
    from tacbench.tac.agent import loss_settings

    config = RunConfig(
        env="Hopper-v4",
        q=1.5,
        alpha=0.2,
        gamma=0.95,
        lnq="joint-batch-max",
        log_std_min=-5.0,
        jacobian_clip=1e-3,
        gaussian_eps=1e-6,
        density_floor=1e-4,
        matmul_precision="bf16",
    )
    s = loss_settings(config, action_scale=2.0)
    assert (s.gamma, s.lnq, s.log_std_min, s.log_std_max) == (0.95, "joint-batch-max", -5.0, 2.0)
    assert (s.jacobian_clip, s.gaussian_eps, s.action_scale) == (1e-3, 1e-6, 2.0)
    assert s.log_density_floor == pytest.approx(math.log(1e-4)) and s.bf16_products
    assert s.target_entropy is None
