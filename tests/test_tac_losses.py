"""TAC's losses: hand-computed values, ln_q of the policy density, q = 1 equals SAC v1, and
each loss's gradient reaches only the parameters it is meant to train."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tacbench.tac.losses import LossSettings, TacLosses, tac_losses
from tacbench.tac.maths import (
    Batch,
    coefficients,
    lnq_of_policy,
    log_q_of_log,
    squashed_gaussian,
)
from tacbench.tac.networks import Layers, mlp, policy_head
from tacbench.tac.parameters import Networks, TacParameters
from tacbench.theory.tsallis import log_q
from tests.helpers import random_batch

pytestmark = pytest.mark.unit

OBS, ACT, HIDDEN = 3, 2, (8,)


class Nets:
    """Differentiable views of a fresh TacParameters (``theta`` requires grad) and the
    networks as functions, for writing the textbook losses independently."""

    def __init__(self, seeds: list[int], *, twin_q: bool = False) -> None:
        gens = [torch.Generator().manual_seed(s) for s in seeds]
        self.k = len(seeds)
        self.params = TacParameters(
            OBS, ACT, HIDDEN, gens, twin_q_targets=twin_q, device=torch.device("cpu")
        )
        self.theta = self.params.data.clone().requires_grad_()
        self.views: Networks = self.params.layout.networks(self.theta)
        self.target: Layers = self.params.target_networks

    def critic(self, i: int, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        net = self.views.critics.members(slice(i * self.k, (i + 1) * self.k))
        return mlp(net, torch.cat([obs, action], dim=-1)).squeeze(-1)

    def v(self, obs: torch.Tensor) -> torch.Tensor:
        return mlp(self.views.v, obs).squeeze(-1)

    def v_target(self, obs: torch.Tensor) -> torch.Tensor:
        return mlp(self.target, obs).squeeze(-1)

    def policy(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return policy_head(mlp(self.views.policy, obs), ACT, -20.0, 2.0)


def _batch(k: int, b: int, seed: int = 0) -> tuple[Batch, torch.Tensor]:
    return random_batch(k, b, OBS, ACT, seed=seed, terminal=0.3)


def _losses(
    nets: Nets,
    batch: Batch,
    eps: torch.Tensor,
    *,
    q: float = 1.5,
    alpha: float = 0.2,
    gamma: float = 0.99,
    lnq: str = "joint",
    eps_next: torch.Tensor | None = None,
    action_scale: float = 1.0,
) -> TacLosses:
    c = coefficients([q] * nets.k, [alpha] * nets.k, torch.device("cpu"))
    settings = LossSettings(gamma, lnq, -20.0, 2.0, action_scale)
    return tac_losses(nets.views, nets.target, batch, eps, c, settings, eps_next)


def _lnq(log_dims: torch.Tensor, q: float, form: str) -> float:
    c = coefficients([q], [0.2], torch.device("cpu"))
    c = type(c)(*(t.double() for t in c))
    return lnq_of_policy(log_dims, c, form).item()


def test_losses_match_hand_computed_values_on_constant_networks() -> None:
    # All weights zero: every network outputs its last bias, so each loss has a closed form.
    nets = Nets([0])
    with torch.no_grad():
        nets.theta.zero_()
        nets.target.weights[0].zero_()
        nets.target.weights[1].zero_()
        nets.views.policy.biases[-1].copy_(torch.tensor([[[0.3, -0.2, 0.9, -0.5]]]))  # mu, raw
        nets.views.critics.biases[-1].copy_(torch.tensor([[[1.0]], [[0.8]]]))  # Q1, Q2
        nets.views.v.biases[-1].fill_(0.5)
        nets.target.biases[-1].fill_(0.4)
    batch = Batch(
        obs=torch.zeros(1, 2, OBS),
        action=torch.zeros(1, 2, ACT),
        reward=torch.tensor([[1.0, -0.5]]),
        next_obs=torch.zeros(1, 2, OBS),
        terminated=torch.tensor([[0.0, 1.0]]),
    )
    eps = torch.tensor([[[0.5, -1.0], [-1.5, 0.25]]])
    q, alpha, gamma = 1.5, 0.2, 0.99
    losses = _losses(nets, batch, eps, q=q, alpha=alpha, gamma=gamma)

    mu, raw = (0.3, -0.2), (0.9, -0.5)
    log_std = [-20.0 + 11.0 * (math.tanh(r) + 1.0) for r in raw]
    lnq = []
    for sample in eps[0].tolist():
        log_p = 0.0
        for i in range(ACT):
            z = mu[i] + sample[i] * math.exp(log_std[i])
            log_normal = -0.5 * sample[i] ** 2 - log_std[i] - 0.5 * math.log(2 * math.pi)
            log_p += log_normal - math.log(1.0 - math.tanh(z) ** 2 + 1e-6)
        lnq.append((math.exp((q - 1.0) * log_p) - 1.0) / (q - 1.0))
    q_target = [1.0 + gamma * 0.4, -0.5]
    expected_q1 = 0.5 * ((1.0 - q_target[0]) ** 2 + (1.0 - q_target[1]) ** 2) / 2
    expected_q2 = 0.5 * ((0.8 - q_target[0]) ** 2 + (0.8 - q_target[1]) ** 2) / 2
    expected_v = 0.5 * sum((0.5 - (0.8 - alpha * x)) ** 2 for x in lnq) / 2
    expected_pi = sum(alpha * x - 1.0 for x in lnq) / 2

    assert losses.q1.item() == pytest.approx(expected_q1, rel=1e-6)
    assert losses.q2.item() == pytest.approx(expected_q2, rel=1e-6)
    assert losses.v.item() == pytest.approx(expected_v, rel=1e-5)
    assert losses.pi.item() == pytest.approx(expected_pi, rel=1e-5)


def _near_unit_std(nets: Nets) -> None:
    """log_std near 0, where the textbook log_prob(z) is accurate."""
    with torch.no_grad():
        nets.views.policy.weights[-1].mul_(0.05)
        nets.views.policy.biases[-1][..., ACT:] = math.atanh(20.0 / 11.0 - 1.0)


def _textbook_log_pi(
    nets: Nets, obs: torch.Tensor, eps: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    mu, log_std = nets.policy(obs)
    normal = torch.distributions.Normal(mu, log_std.exp())
    z = mu + log_std.exp() * eps
    action = torch.tanh(z)
    return action, (normal.log_prob(z) - torch.log(1 - action.pow(2) + 1e-6)).sum(-1)


def test_q_equal_one_gives_sac_v1_losses() -> None:
    """SAC v1 (Haarnoja et al. 2018, with its log(1 - tanh^2 + 1e-6)), written independently."""
    nets = Nets([3, 4])
    _near_unit_std(nets)
    batch, eps = _batch(2, 16)
    alpha, gamma = 0.2, 0.99
    for lnq in ("joint", "per-dim"):
        tac = _losses(nets, batch, eps, q=1.0, alpha=alpha, gamma=gamma, lnq=lnq)
        action, log_pi = _textbook_log_pi(nets, batch.obs, eps)
        y_q = batch.reward + gamma * (1 - batch.terminated) * nets.v_target(batch.next_obs)
        q_min = torch.min(nets.critic(0, batch.obs, action), nets.critic(1, batch.obs, action))
        y_v = q_min - alpha * log_pi
        sac = [
            0.5 * (nets.critic(0, batch.obs, batch.action) - y_q).pow(2).mean(-1),
            0.5 * (nets.critic(1, batch.obs, batch.action) - y_q).pow(2).mean(-1),
            0.5 * (nets.v(batch.obs) - y_v).pow(2).mean(-1),
            (alpha * log_pi - nets.critic(0, batch.obs, action)).mean(-1),
        ]
        for ours, theirs in zip((tac.q1, tac.q2, tac.v, tac.pi), sac, strict=True):
            torch.testing.assert_close(ours, theirs, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("action_scale", [1.0, 3.0])
def test_twin_q_at_q_equal_one_gives_sac_v2_critic_losses(action_scale: float) -> None:
    """critic_target twin-q: SAC v2's Q target (Haarnoja et al. 2018b) from the target critics
    at a' ~ pi(.|s'), written independently; no V loss. With an action scale (the reference
    profile) the target critics see a' in the critics' units, as the buffer's actions are."""
    nets = Nets([3, 4], twin_q=True)
    _near_unit_std(nets)
    with torch.no_grad():  # target critics that differ from the critics
        nets.target.biases[-1].add_(torch.tensor([[[0.3]], [[-0.2]], [[0.1]], [[0.4]]]))
    batch, eps = _batch(2, 16)
    eps_next = torch.randn(eps.shape, generator=torch.Generator().manual_seed(1))
    alpha, gamma = 0.2, 0.99
    tac = _losses(
        nets, batch, eps, q=1.0, alpha=alpha, gamma=gamma, eps_next=eps_next,
        action_scale=action_scale,
    )  # fmt: skip

    next_action, log_pi = _textbook_log_pi(nets, batch.next_obs, eps_next)
    pairs = torch.cat([batch.next_obs, next_action * action_scale], dim=-1)
    targets = [mlp(nets.target.members(slice(i * 2, (i + 1) * 2)), pairs) for i in (0, 1)]
    soft = torch.min(*targets).squeeze(-1) - alpha * log_pi
    y_q = batch.reward + gamma * (1 - batch.terminated) * soft
    q1, q2 = (nets.critic(i, batch.obs, batch.action) for i in (0, 1))
    torch.testing.assert_close(tac.q1, 0.5 * (q1 - y_q).pow(2).mean(-1))
    torch.testing.assert_close(tac.q2, 0.5 * (q2 - y_q).pow(2).mean(-1))
    assert not tac.v.any()


def test_squashed_gaussian_log_density_matches_torch_distributions() -> None:
    mu = torch.tensor([[[0.1, -0.4, 1.2]]])
    log_std = torch.tensor([[[-0.5, 0.2, -1.0]]])
    eps = torch.tensor([[[0.3, -0.7, 1.1]]])
    action, log_prob_dims = squashed_gaussian(mu, log_std, log_std.exp(), eps)
    z = mu + eps * log_std.exp()
    expected = torch.distributions.Normal(mu, log_std.exp()).log_prob(z) - torch.log(
        1 - torch.tanh(z) ** 2 + 1e-6
    )
    torch.testing.assert_close(action, torch.tanh(z))
    torch.testing.assert_close(log_prob_dims, expected, rtol=1e-5, atol=1e-6)


def test_saturated_tanh_raises_log_density_by_at_most_log_1e6() -> None:
    mu, log_std, eps = torch.full((1, 1, 1), 50.0), torch.zeros(1, 1, 1), torch.zeros(1, 1, 1)
    _, log_dims = squashed_gaussian(mu, log_std, log_std.exp(), eps)
    gaussian = -0.5 * math.log(2 * math.pi)
    assert log_dims.item() == pytest.approx(gaussian - math.log(1e-6), rel=1e-5)
    assert torch.isfinite(log_dims).all()


@pytest.mark.parametrize(
    ("q", "joint", "per_dim"),
    [
        # per-dim densities 2 and 1/2: joint density 1, so ln_q(joint) = 0 for every q
        (1.0, 0.0, math.log(2) + math.log(0.5)),
        (2.0, 0.0, (2 - 1) + (0.5 - 1)),
        (0.5, 0.0, (2**-0.5 - 1) / -0.5 + (0.5**-0.5 - 1) / -0.5),
        (1.5, 0.0, (2**0.5 - 1) / 0.5 + (0.5**0.5 - 1) / 0.5),
    ],
)
def test_lnq_joint_and_per_dim_by_hand(q: float, joint: float, per_dim: float) -> None:
    log_dims = torch.tensor([[[math.log(2.0), math.log(0.5)]]], dtype=torch.float64)
    assert _lnq(log_dims, q, "joint") == pytest.approx(joint, abs=1e-12)
    assert _lnq(log_dims, q, "per-dim") == pytest.approx(per_dim, rel=1e-12)


@pytest.mark.parametrize("q", [2.0, 3.0, 5.0])
def test_density_is_capped_at_ten_to_eight_over_q_minus_one_for_q_at_least_two(q: float) -> None:
    log_dims = torch.tensor([[[30.0, 10.0]]], dtype=torch.float64)  # densities e^30, e^10
    cap_lnq = (1e8 - 1) / (q - 1)  # ln_q(10^(8/(q-1)))
    assert _lnq(log_dims, q, "joint") == pytest.approx(cap_lnq, rel=1e-6)
    per_dim = _lnq(log_dims, q, "per-dim")
    dim_two = min(math.exp((q - 1) * 10.0), 1e8)
    assert per_dim == pytest.approx(cap_lnq + (dim_two - 1) / (q - 1), rel=1e-6)


def test_no_cap_below_q_two_and_per_dim_floor_at_1e_minus_6() -> None:
    log_dims = torch.tensor([[[30.0, -20.0]]], dtype=torch.float64)
    q = 1.9
    assert _lnq(log_dims, q, "joint") == pytest.approx(math.expm1(0.9 * 10.0) / 0.9, rel=1e-6)
    floored = (1e-6**0.9 - 1) / 0.9
    assert _lnq(log_dims, q, "per-dim") == pytest.approx(
        math.expm1(0.9 * 30.0) / 0.9 + floored, rel=1e-6
    )
    assert _lnq(log_dims, 1.0, "per-dim") == pytest.approx(30.0 + math.log(1e-6), rel=1e-12)


def test_members_with_different_q_and_alpha_get_the_losses_they_would_get_apart() -> None:
    """q and alpha are per member: a group of members at q = 1, 1.5 and 3 (the q >= 2 cap) and
    three alphas has each member's losses equal to a single-q group's on the same batch."""
    batch, eps = _batch(3, 8)
    qs, alphas = [1.0, 1.5, 3.0], [0.2, 0.1, 0.05]
    for lnq in ("per-dim", "joint"):
        group = Nets([1, 2, 3])
        c = coefficients(qs, alphas, torch.device("cpu"))
        s = LossSettings(0.99, lnq, -20.0, 2.0)
        mixed = tac_losses(group.views, group.target, batch, eps, c, s)
        for k, (q, alpha) in enumerate(zip(qs, alphas, strict=True)):
            same = coefficients([q] * 3, [alpha] * 3, torch.device("cpu"))
            alone = tac_losses(group.views, group.target, batch, eps, same, s)
            assert mixed.alpha is None and alone.alpha is None  # a fixed alpha: no alpha loss
            for a, b in zip(mixed[:5], alone[:5], strict=True):
                assert torch.equal(a[k], b[k]), (lnq, q)


def _networks_reached(nets: Nets, loss: torch.Tensor) -> dict[str, bool]:
    """Which networks' weights the gradient of ``loss`` reaches."""
    (grad,) = torch.autograd.grad(loss, nets.theta, retain_graph=True)
    views, k = nets.params.layout.networks(grad), nets.k
    return {
        "policy": any(bool(w.any()) for w in views.policy.weights),
        "q1": any(bool(w[:k].any()) for w in views.critics.weights),
        "q2": any(bool(w[k:].any()) for w in views.critics.weights),
        "v": any(bool(w.any()) for w in views.v.weights),
    }


def test_each_loss_trains_only_its_own_network() -> None:
    nets = Nets([1])
    batch, eps = _batch(1, 8)
    losses = _losses(nets, batch, eps)
    for name, trains in {"q1": "q1", "q2": "q2", "v": "v", "pi": "policy"}.items():
        reached = _networks_reached(nets, getattr(losses, name).sum())
        assert reached == {net: net == trains for net in reached}, name


def test_members_do_not_mix() -> None:
    pair = Nets([5, 6])
    alone = Nets([6])
    batch, eps = _batch(2, 8)
    both = _losses(pair, batch, eps, lnq="per-dim")
    single = _losses(alone, Batch(*(t[1:] for t in batch)), eps[1:], lnq="per-dim")
    for a, b in zip(both[:4], single[:4], strict=True):
        torch.testing.assert_close(a[1:], b, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(both.diagnostics[1:], single.diagnostics, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("q", [0.5, 1.0, 1.5, 2.0, 5.0])
def test_log_q_of_log_matches_numpy_and_has_the_slope_p_to_the_q_minus_one(q: float) -> None:
    log_p = torch.linspace(-30.0, 5.0, 50, dtype=torch.float64, requires_grad=True)
    out = log_q_of_log(log_p, torch.tensor(q - 1.0, dtype=torch.float64))
    assert np.allclose(out.detach().numpy(), log_q(np.exp(log_p.detach().numpy()), q))
    out.sum().backward()
    assert log_p.grad is not None and torch.isfinite(log_p.grad).all()
    # d ln_q(p) / d log p = p^(q-1)
    assert torch.allclose(log_p.grad, torch.exp((q - 1.0) * log_p.detach()))


def test_q_equal_one_members_get_finite_gradients_from_huge_log_densities() -> None:
    """The q = 1 branch of ln_q must not poison its gradient with the other branch's overflow
    (expm1 of a large log p is inf; 0 * inf would be NaN)."""
    log_p = torch.tensor([[400.0], [400.0]], requires_grad=True)
    out = log_q_of_log(log_p, torch.tensor([[0.0], [-0.5]]))
    out[0].sum().backward()
    assert log_p.grad is not None and log_p.grad.tolist() == [[1.0], [0.0]]


def test_the_log_pi_diagnostic_is_the_joint_log_density() -> None:
    """losses.csv's log_pi is log pi(a|s) summed over the action's dimensions (SAC's), whatever
    the ln_q form; at q = 1 with the joint form it equals the lnq_pi diagnostic."""
    nets = Nets([3, 4])
    _near_unit_std(nets)
    batch, eps = _batch(2, 16)
    _, log_pi = _textbook_log_pi(nets, batch.obs, eps)
    for lnq in ("joint", "per-dim"):
        diagnostics = _losses(nets, batch, eps, q=1.0, lnq=lnq).diagnostics
        torch.testing.assert_close(diagnostics[:, 0], log_pi.mean(-1))
    joint = _losses(nets, batch, eps, q=1.0, lnq="joint").diagnostics
    torch.testing.assert_close(joint[:, 0], joint[:, 1])


def test_q_minus_one_is_the_float32_of_the_exact_difference() -> None:
    """q - 1 is taken in float64 before the cast: float32(1.2) - 1 would be 0.20000005, and
    every ln_q of such a q would round otherwise than the recorded runs'."""
    c = coefficients([1.2, 0.5, 3.0], [0.2] * 3, torch.device("cpu"))
    assert c.q_minus_one.tolist() == [float(np.float32(d)) for d in (0.2, -0.5, 2.0)]
