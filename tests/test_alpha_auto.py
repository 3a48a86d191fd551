"""``--alpha auto``: SAC v2's temperature rule with ln_q (tacbench/tac/losses.py). At q = 1 it
is stable-baselines3's alpha loss and gradient with SB3's target -dim(A); alpha moves toward its
target; a group without it is untouched; members, the compiled path, checkpoints and the
command line carry it."""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from click.testing import CliRunner
from stable_baselines3 import SAC

from tacbench.cli import cli
from tacbench.config import RunConfig
from tacbench.config_checks import check_alpha_target
from tacbench.errors import TacbenchError
from tacbench.tac.agent import TacAgent
from tacbench.tac.maths import (
    ALPHA_METRICS,
    METRICS,
    Batch,
    coefficients,
    default_lnq_target,
    lnq_of_policy,
)
from tacbench.tac.update import gradients, update
from tests.helpers import random_batch, random_minibatch, tac_agent

pytestmark = pytest.mark.unit

OBS, ACT = 5, 3
CPU = torch.device("cpu")
ALPHA_COLUMN, LOSS_COLUMN = (len(METRICS) + ALPHA_METRICS.index(n) for n in ("alpha", "loss_alpha"))


def _agent(seeds: list[int], alphas: list[float] | None, **settings: Any) -> TacAgent:
    mode = "fixed" if alphas is None else "auto"
    agent = tac_agent(OBS, ACT, seeds, q=1.0, alpha_mode=mode, initial_alphas=alphas, **settings)
    with torch.no_grad():  # a policy near unit std, so no density reaches the per-dim floor
        agent.chunks[0].params.networks.policy.weights[-1].mul_(0.01)
    return agent


def _batch(k: int, b: int = 256, seed: int = 0) -> tuple[Batch, torch.Tensor]:
    return random_batch(k, b, OBS, ACT, seed=seed)


@pytest.mark.parametrize("lnq", ["per-dim", "joint"])
def test_at_q_one_the_alpha_loss_and_gradient_are_stable_baselines3s(lnq: str) -> None:
    agent = _agent([0], [0.3], lnq=lnq)
    batch, eps = _batch(1)
    metrics, grads = gradients(agent, batch, eps, coefficients([1.0], [0.2], CPU))
    mean_log_pi = metrics[0, METRICS.index("lnq_pi")]  # ln_1 = log: E[log pi] of the batch
    # stable-baselines3 (sac.py, SAC.train) on the same log-probabilities, its own target
    # entropy (-dim(A)) and log ent_coef
    env = gym.make("Pendulum-v1")  # any env with a 3-dimensional action space would do
    env.action_space = gym.spaces.Box(-1.0, 1.0, (ACT,), np.float32)
    model = SAC("MlpPolicy", env, ent_coef="auto_0.3", device="cpu")
    assert model.target_entropy == -ACT
    log_prob = mean_log_pi.expand(256).reshape(-1, 1)
    ent_coef_loss = -(model.log_ent_coef * (log_prob + model.target_entropy).detach()).mean()
    ent_coef_loss.backward()
    assert metrics[0, ALPHA_COLUMN] == pytest.approx(0.3)  # the alpha in force: its start
    assert metrics[0, LOSS_COLUMN].item() == pytest.approx(ent_coef_loss.item(), rel=1e-5)
    assert model.log_ent_coef.grad is not None
    assert grads["log_alpha"][0].item() == pytest.approx(model.log_ent_coef.grad.item(), rel=1e-5)


@pytest.mark.parametrize(("q", "lnq"), [(1.0, "per-dim"), (1.5, "per-dim"), (2.0, "joint")])
def test_the_default_target_is_ln_q_of_the_density_sacs_target_implies(q: float, lnq: str) -> None:
    target = default_lnq_target(coefficients([q], [0.2], CPU), ACT, lnq)
    lnq_e = (math.e ** (q - 1) - 1) / (q - 1) if q != 1 else 1.0
    expected = ACT * lnq_e if lnq == "per-dim" else (math.e ** (ACT * (q - 1)) - 1) / (q - 1)
    assert target.item() == pytest.approx(expected if q != 1 else ACT, rel=1e-6)


@pytest.mark.parametrize(("target", "direction"), [(1000.0, 1.0), (-1000.0, -1.0)])
def test_alpha_moves_toward_its_target(target: float, direction: float) -> None:
    # a target entropy far above the policy's raises alpha; far below, lowers it
    agent = _agent([0, 1], [0.2, 0.05], target_entropy=target)
    c = coefficients([1.0, 1.5], [0.2, 0.2], CPU)
    alphas = []
    for step in range(30):
        batch, _ = _batch(2, seed=step)
        metrics = update(agent, {name: getattr(batch, name) for name in Batch._fields}, c)
        alphas.append(metrics[:, ALPHA_COLUMN])
    moves = torch.stack(alphas).diff(dim=0) * direction
    assert (moves > 0).all()  # every update, each member from its own start
    assert alphas[0].tolist() == pytest.approx([0.2, 0.05])


def test_a_fixed_alpha_group_has_no_alpha_parameter_and_the_same_update() -> None:
    fixed = _agent([0], None)
    assert fixed.chunks[0].params.networks.log_alpha is None
    batch, eps = _batch(1)
    metrics, grads = gradients(fixed, batch, eps, coefficients([1.5], [0.7], CPU))
    assert metrics.shape == (1, len(METRICS)) and "log_alpha" not in grads
    # a learned alpha starting at 0.7: the same losses, one more metric pair; the coefficients'
    # alpha (0.2) is not the one in force
    learned = _agent([0], [0.7])
    auto_metrics, auto_grads = gradients(learned, batch, eps, coefficients([1.5], [0.2], CPU))
    # to rounding: exp(log(0.7)) is not 0.7 in float32
    torch.testing.assert_close(auto_metrics[:, : len(METRICS)], metrics, rtol=1e-6, atol=0)
    for name, grad in grads.items():
        torch.testing.assert_close(auto_grads[name], grad, rtol=1e-5, atol=1e-8)


def test_alpha_and_its_adam_state_are_in_the_member_state() -> None:
    agent = _agent([0, 1], [0.2, 0.1])
    c = coefficients([1.0, 1.0], [0.2, 0.2], CPU)
    update(agent, random_minibatch(2, 256, OBS, ACT), c)
    state = agent.member_state(1)
    assert state["params"]["log_alpha"].item() != pytest.approx(math.log(0.1))  # it trained
    assert state["adam"]["exp_avg"]["log_alpha"].item() != 0.0
    copy = _agent([5, 6], [1.0, 1.0])
    copy.load_member_states([agent.member_state(0), state])
    after = copy.member_state(1)["params"]["log_alpha"]
    assert torch.equal(after, state["params"]["log_alpha"])


@pytest.mark.slow
def test_the_compiled_update_learns_alpha_as_the_eager_one() -> None:
    compiled = _agent([0, 1], [0.2, 0.1], compile="on")
    plain = _agent([0, 1], [0.2, 0.1])
    batch, eps = _batch(2)
    c = coefficients([1.0, 2.0], [0.2, 0.2], CPU)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no fallback to eager
        got, got_grads = gradients(compiled, batch, eps, c)
    expected, expected_grads = gradients(plain, batch, eps, c)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(
        got_grads["log_alpha"], expected_grads["log_alpha"], rtol=1e-5, atol=1e-7
    )


def test_the_run_variant_and_config_say_auto() -> None:
    config = RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, alpha_mode="auto", compile="off")
    assert config.variant == "q1.5-aauto0.2"
    with_target = RunConfig(
        env="Hopper-v4", q=1.5, alpha=0.2, alpha_mode="auto", target_entropy=-2.0, compile="off"
    )
    assert with_target.variant == "q1.5-aauto0.2-te-2"
    with pytest.raises(TacbenchError, match="--target-entropy is the target of a learned alpha"):
        RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, target_entropy=-2.0, compile="off")
    with pytest.raises(TacbenchError, match="--alpha-mode must be one of fixed, auto"):
        RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, alpha_mode="learned", compile="off")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--alpha", "auto", "--alpha", "0.1"], "does not mix with other --alpha values"),
        (["--alpha", "auto", "--alpha-mode", "fixed"], "does not mix with other --alpha values"),
        (["--alpha", "sometimes"], "is neither a number nor 'auto'"),
        (["--target-entropy", "-3"], "add --alpha auto"),
    ],
)
def test_bad_alpha_requests_are_usage_errors(tmp_path: Path, args: list[str], message: str) -> None:
    result = CliRunner().invoke(
        cli, ["run", "--env", "Hopper-v4", "--steps", "10", "--out", str(tmp_path), *args]
    )
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    ("lnq", "q", "refused"),
    [("joint", 5.0, True), ("joint", 2.0, False), ("per-dim", 25.0, True), ("per-dim", 5.0, False)],
)
def test_a_default_target_at_the_density_cap_is_refused(lnq: str, q: float, refused: bool) -> None:
    """Where the cap binds at the default target's density (joint at q = 5 on six action
    dimensions, per-dim above q = 19.4), the target is the most the capped ln_q can be, so the
    temperature loss could only lower alpha: no density of any policy reaches above it there,
    and below the cap it does. Such a run is refused unless --target-entropy is given."""
    c = coefficients([q], [0.2], CPU)
    target = default_lnq_target(c, 6, lnq)
    log_densities = torch.linspace(-30.0, 30.0, 601)[None, :, None].expand(1, 601, 6)
    assert bool((lnq_of_policy(log_densities, c, lnq) > target).any()) is not refused
    config = RunConfig(env="HalfCheetah-v4", q=q, alpha=0.2, alpha_mode="auto", lnq=lnq)
    if refused:
        with pytest.raises(TacbenchError, match="lies at the density cap"):
            check_alpha_target(config, act_dim=6)
        explicit = dataclasses.replace(config, target_entropy=-6.0)
        check_alpha_target(explicit, act_dim=6)  # an explicit target is the user's to choose
    else:
        check_alpha_target(config, act_dim=6)


@pytest.mark.parametrize(("lnq", "q", "act_dim"), [("joint", 7.0, 17), ("per-dim", 100.0, 6)])
def test_a_default_target_that_overflows_without_the_cap_is_refused(
    lnq: str, q: float, act_dim: int
) -> None:
    """With --density-cap off the target ln_q(e^17) at q = 7 (Humanoid, joint) and 6 ln_q(e) at
    q = 100 are past float32's range: inf, and alpha NaN at the first update."""
    c = coefficients([q], [0.2], CPU, "off")
    assert bool(torch.isinf(default_lnq_target(c, act_dim, lnq)).all())
    config = RunConfig(
        env="Humanoid-v4", q=q, alpha=0.2, alpha_mode="auto", lnq=lnq, density_cap="off"
    )
    with pytest.raises(TacbenchError, match=r"overflows float32 \(inf\).*--target-entropy"):
        check_alpha_target(config, act_dim=act_dim)
    check_alpha_target(dataclasses.replace(config, q=2.0), act_dim=act_dim)  # finite: e^17
    check_alpha_target(dataclasses.replace(config, target_entropy=-6.0), act_dim=act_dim)


def test_a_population_is_checked_at_the_top_of_its_q_range() -> None:
    auto = RunConfig(env="Hopper-v4", q=1.0, alpha=0.2, q_mode="auto", alpha_mode="auto")
    auto = dataclasses.replace(auto, q_range=(0.7, 30.0))
    remedy = r"at q = 30 .* give --target-entropy or narrow --q-range\."
    with pytest.raises(TacbenchError, match=remedy):
        check_alpha_target(auto, act_dim=3)
