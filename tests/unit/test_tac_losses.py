"""TAC's losses: hand-computed values, ln_q of the policy density, q = 1 equals SAC v1, and
each loss's gradient reaches only the parameters it is meant to train."""

from __future__ import annotations

import math

import pytest
import torch

from tacbench.tac.losses import (
    Batch,
    TacLosses,
    lnq_of_policy,
    squashed_gaussian_sample,
    tac_losses,
)
from tacbench.tac.networks import Critic, TanhGaussianPolicy

pytestmark = pytest.mark.unit

OBS, ACT, HIDDEN = 3, 2, (8,)


def _nets(seeds: list[int]) -> tuple[TanhGaussianPolicy, Critic, Critic, Critic, Critic]:
    gens = [torch.Generator().manual_seed(s) for s in seeds]
    policy = TanhGaussianPolicy(OBS, ACT, HIDDEN, gens, -20.0, 2.0)
    q1, q2 = Critic(OBS, ACT, HIDDEN, gens), Critic(OBS, ACT, HIDDEN, gens)
    v = Critic(OBS, 0, HIDDEN, gens)
    v_target = Critic(OBS, 0, HIDDEN, gens).requires_grad_(False)
    return policy, q1, q2, v, v_target


def _batch(k: int, b: int, seed: int = 0) -> tuple[Batch, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    batch = Batch(
        obs=torch.randn(k, b, OBS, generator=g),
        action=torch.rand(k, b, ACT, generator=g) * 2 - 1,
        reward=torch.randn(k, b, generator=g),
        next_obs=torch.randn(k, b, OBS, generator=g),
        terminated=(torch.rand(k, b, generator=g) < 0.3).float(),
    )
    return batch, torch.randn(k, b, ACT, generator=g)


def _losses(nets: tuple, batch: Batch, eps: torch.Tensor, **kw: object) -> TacLosses:
    params = {"q": 1.5, "alpha": 0.2, "gamma": 0.99, "lnq": "joint", **kw}
    return tac_losses(*nets, batch, eps, **params)  # type: ignore[arg-type]


def test_losses_match_hand_computed_values_on_constant_networks() -> None:
    # All weights zero: every network outputs its last bias, so each loss has a closed form.
    nets = _nets([0])
    policy, q1, q2, v, v_target = nets
    with torch.no_grad():
        for net in nets:
            for w in net.net.weights:
                w.zero_()
        policy.net.biases[-1].copy_(torch.tensor([[[0.3, -0.2, 0.9, -0.5]]]))  # mu, raw log-std
        q1.net.biases[-1].fill_(1.0)
        q2.net.biases[-1].fill_(0.8)
        v.net.biases[-1].fill_(0.5)
        v_target.net.biases[-1].fill_(0.4)
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


def test_q_equal_one_gives_sac_v1_losses() -> None:
    """SAC v1 (Haarnoja et al. 2018, with its log(1 - tanh^2 + 1e-6)), written independently."""
    nets = _nets([3, 4])
    policy, q1, q2, v, v_target = nets
    with torch.no_grad():  # log_std near 0: the textbook log_prob(z) is accurate there
        policy.net.weights[-1].mul_(0.05)
        policy.net.biases[-1][..., ACT:] = math.atanh(20.0 / 11.0 - 1.0)
    batch, eps = _batch(2, 16)
    alpha, gamma = 0.2, 0.99
    for lnq in ("joint", "per-dim"):
        tac = _losses(nets, batch, eps, q=1.0, alpha=alpha, gamma=gamma, lnq=lnq)

        mu, log_std = policy(batch.obs)
        normal = torch.distributions.Normal(mu, log_std.exp())
        z = mu + log_std.exp() * eps
        action = torch.tanh(z)
        log_pi = (normal.log_prob(z) - torch.log(1 - action.pow(2) + 1e-6)).sum(-1)
        y_q = batch.reward + gamma * (1 - batch.terminated) * v_target(batch.next_obs)
        y_v = torch.min(q1(batch.obs, action), q2(batch.obs, action)) - alpha * log_pi
        sac = [
            0.5 * (q1(batch.obs, batch.action) - y_q).pow(2).mean(-1),
            0.5 * (q2(batch.obs, batch.action) - y_q).pow(2).mean(-1),
            0.5 * (v(batch.obs) - y_v).pow(2).mean(-1),
            (alpha * log_pi - q1(batch.obs, action)).mean(-1),
        ]
        for ours, theirs in zip((tac.q1, tac.q2, tac.v, tac.pi), sac, strict=True):
            torch.testing.assert_close(ours, theirs, rtol=1e-5, atol=1e-5)


def test_twin_q_at_q_equal_one_gives_sac_v2_critic_losses() -> None:
    """critic_target twin-q: SAC v2's Q target (Haarnoja et al. 2018b) from the target critics
    at a' ~ pi(.|s'), written independently; no V loss, and the target V plays no part."""
    nets = _nets([3, 4])
    policy, q1, q2, _, v_target = nets
    gens = [torch.Generator().manual_seed(s) for s in (5, 6)]
    targets = (Critic(OBS, ACT, HIDDEN, gens), Critic(OBS, ACT, HIDDEN, gens))
    with torch.no_grad():
        policy.net.weights[-1].mul_(0.05)
        policy.net.biases[-1][..., ACT:] = math.atanh(20.0 / 11.0 - 1.0)
    batch, eps = _batch(2, 16)
    eps_next = torch.randn(eps.shape, generator=torch.Generator().manual_seed(1))
    alpha, gamma = 0.2, 0.99
    tac = _losses(
        nets, batch, eps, q=1.0, alpha=alpha, gamma=gamma, target_critics=targets, eps_next=eps_next
    )

    mu, log_std = policy(batch.next_obs)
    normal = torch.distributions.Normal(mu, log_std.exp())
    z = mu + log_std.exp() * eps_next
    next_action = torch.tanh(z)
    log_pi = (normal.log_prob(z) - torch.log(1 - next_action.pow(2) + 1e-6)).sum(-1)
    soft = torch.min(*(t(batch.next_obs, next_action) for t in targets)) - alpha * log_pi
    y_q = batch.reward + gamma * (1 - batch.terminated) * soft
    torch.testing.assert_close(tac.q1, 0.5 * (q1(batch.obs, batch.action) - y_q).pow(2).mean(-1))
    torch.testing.assert_close(tac.q2, 0.5 * (q2(batch.obs, batch.action) - y_q).pow(2).mean(-1))
    assert not tac.v.any()
    with torch.no_grad():
        v_target.net.biases[-1].add_(10.0)
    again = _losses(
        nets, batch, eps, q=1.0, alpha=alpha, gamma=gamma, target_critics=targets, eps_next=eps_next
    )
    assert torch.equal(again.q1, tac.q1)
    with pytest.raises(ValueError, match="twin-q needs both"):
        _losses(nets, batch, eps, target_critics=targets)


def test_squashed_gaussian_log_density_matches_torch_distributions() -> None:
    mu = torch.tensor([[[0.1, -0.4, 1.2]]])
    log_std = torch.tensor([[[-0.5, 0.2, -1.0]]])
    eps = torch.tensor([[[0.3, -0.7, 1.1]]])
    action, log_dims = squashed_gaussian_sample(mu, log_std, eps)
    z = mu + eps * log_std.exp()
    expected = torch.distributions.Normal(mu, log_std.exp()).log_prob(z) - torch.log(
        1 - torch.tanh(z) ** 2 + 1e-6
    )
    torch.testing.assert_close(action, torch.tanh(z))
    torch.testing.assert_close(log_dims, expected, rtol=1e-5, atol=1e-6)


def test_saturated_tanh_raises_log_density_by_at_most_log_1e6() -> None:
    mu, log_std, eps = torch.full((1, 1, 1), 50.0), torch.zeros(1, 1, 1), torch.zeros(1, 1, 1)
    _, log_dims = squashed_gaussian_sample(mu, log_std, eps)
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
    assert lnq_of_policy(log_dims, q, "joint").item() == pytest.approx(joint, abs=1e-12)
    assert lnq_of_policy(log_dims, q, "per-dim").item() == pytest.approx(per_dim, rel=1e-12)


@pytest.mark.parametrize("q", [2.0, 3.0, 5.0])
def test_density_is_capped_at_ten_to_eight_over_q_minus_one_for_q_at_least_two(q: float) -> None:
    log_dims = torch.tensor([[[30.0, 10.0]]], dtype=torch.float64)  # densities e^30, e^10
    cap_lnq = (1e8 - 1) / (q - 1)  # ln_q(10^(8/(q-1)))
    assert lnq_of_policy(log_dims, q, "joint").item() == pytest.approx(cap_lnq, rel=1e-9)
    per_dim = lnq_of_policy(log_dims, q, "per-dim").item()
    dim_two = min(math.exp((q - 1) * 10.0), 1e8)
    assert per_dim == pytest.approx(cap_lnq + (dim_two - 1) / (q - 1), rel=1e-9)


def test_no_cap_below_q_two_and_per_dim_floor_at_1e_minus_6() -> None:
    log_dims = torch.tensor([[[30.0, -20.0]]], dtype=torch.float64)
    q = 1.9
    joint = lnq_of_policy(log_dims, q, "joint").item()
    assert joint == pytest.approx(math.expm1(0.9 * 10.0) / 0.9, rel=1e-12)
    per_dim = lnq_of_policy(log_dims, q, "per-dim").item()
    floored = (1e-6**0.9 - 1) / 0.9
    assert per_dim == pytest.approx(math.expm1(0.9 * 30.0) / 0.9 + floored, rel=1e-12)
    assert lnq_of_policy(log_dims, 1.0, "per-dim").item() == pytest.approx(
        30.0 + math.log(1e-6), rel=1e-12
    )


def _grad_norms(loss: torch.Tensor, nets: tuple) -> list[float]:
    norms = []
    for net in nets:
        params = [p for p in net.parameters() if p.requires_grad]
        if not params:
            norms.append(0.0)
            continue
        grads = torch.autograd.grad(loss, params, retain_graph=True, allow_unused=True)
        norms.append(sum(0.0 if g is None else g.abs().sum().item() for g in grads))
    return norms


def test_each_loss_trains_only_its_own_network() -> None:
    nets = _nets([1])
    batch, eps = _batch(1, 8)
    losses = _losses(nets, batch, eps)
    # order: policy, q1, q2, v, v_target
    expected = {
        "q1": [False, True, False, False, False],
        "q2": [False, False, True, False, False],
        "v": [False, False, False, True, False],
        "pi": [True, False, False, False, False],
    }
    for name, reaches in expected.items():
        norms = _grad_norms(getattr(losses, name).sum(), nets)
        assert [n > 0 for n in norms] == reaches, (name, norms)
    assert not any(p.requires_grad for p in nets[4].parameters())


def test_members_do_not_mix() -> None:
    pair = _nets([5, 6])
    alone = _nets([6])
    batch, eps = _batch(2, 8)
    both = _losses(pair, batch, eps, lnq="per-dim")
    single = _losses(alone, Batch(*(t[1:] for t in batch)), eps[1:], lnq="per-dim")
    for a, b in zip(both[:4], single[:4], strict=True):
        torch.testing.assert_close(a[1:], b, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(both.diagnostics[1:], single.diagnostics, rtol=1e-6, atol=1e-6)
