"""TAC's update: members with different q and alpha in one group get exactly the gradients of
single-q groups; the compiled update equals the eager one (float32 rounding) for such a group
and does not recompile for other q; the flat Adam step is torch's; act is the policy's
computation; a failed compilation falls back cleanly."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pytest
import torch
from torch.optim.adam import adam

from tacbench.config import RunConfig
from tacbench.tac import agent as agent_module
from tacbench.tac import gradient as gradient_module
from tacbench.tac.agent import TacAgent
from tacbench.tac.maths import (
    LOG_DENSITY_FLOOR,
    METRICS,
    Batch,
    Coefficients,
    coefficients,
    squashed_gaussian,
)
from tacbench.tac.networks import mlp, policy_head
from tacbench.tac.parameters import TacParameters
from tacbench.tac.update import gradients
from tests.helpers import assert_close_per_member, random_batch, tac_agent

pytestmark = pytest.mark.unit

OBS, ACT = 5, 3
SEEDS = [3, 4, 5]
CPU = torch.device("cpu")


def _agent(hidden: tuple[int, ...] = (16,), **overrides: Any) -> TacAgent:
    agent = tac_agent(OBS, ACT, SEEDS, hidden_sizes=hidden, **overrides)
    with torch.no_grad():  # a wide spread of log_std, so the ln_q floor and cap both matter
        params = agent.chunks[0].params
        params.networks.policy.weights[-1].mul_(4.0)
        params.target_networks.biases[-1].add_(0.3)  # the target differs from its source
    return agent


def _c(q: float | list[float], alpha: float | list[float] = 0.2) -> Coefficients:
    qs = q if isinstance(q, list) else [q] * len(SEEDS)
    alphas = alpha if isinstance(alpha, list) else [alpha] * len(SEEDS)
    return coefficients(qs, alphas, CPU)


def _batch(seed: int = 0, b: int = 64) -> tuple[Batch, torch.Tensor]:
    # wide observations and noise: log-densities below the floor and above the cap (see below)
    k = len(SEEDS)
    return random_batch(k, b, OBS, ACT, seed=seed, terminal=0.2, obs_scale=2, noise_scale=3)


def _compare(
    ours: TacAgent,
    reference: TacAgent,
    c: Coefficients,
    rtol: float,
    eps_next: torch.Tensor | None = None,
) -> None:
    """Both agents' metrics and gradients on one batch agree to ``rtol``; the retired member
    (index 1, when marked) gets no gradient."""
    batch, eps = _batch()
    expected, expected_grads = gradients(reference, batch, eps, c, eps_next)
    metrics, grads = gradients(ours, batch, eps, c, eps_next)
    assert metrics.shape == (len(SEEDS), len(METRICS))
    for i, name in enumerate(METRICS):
        assert_close_per_member(metrics[:, i], expected[:, i], rtol, name)
    assert sorted(grads) == sorted(expected_grads)
    for name, grad in expected_grads.items():
        assert_close_per_member(grads[name], grad, rtol, name)
        if not bool(ours.alive[1]):
            assert not grads[name][1].any(), name


@pytest.mark.parametrize("lnq", ["per-dim", "joint"])
def test_a_group_of_mixed_q_and_alpha_equals_single_q_groups(lnq: str) -> None:
    """Members at q = 1, 1.7 and 3 (the q >= 2 cap) with three alphas: each member's losses
    and gradients are those of a group where every member has its q and alpha."""
    qs, alphas = [1.0, 1.7, 3.0], [0.2, 0.1, 0.05]
    agent = _agent(lnq=lnq)
    batch, eps = _batch()
    mixed, mixed_grads = gradients(agent, batch, eps, _c(qs, alphas))
    for k, (q, alpha) in enumerate(zip(qs, alphas, strict=True)):
        single, single_grads = gradients(agent, batch, eps, _c(q, alpha))
        assert torch.equal(mixed[k], single[k]), (q, alpha)
        for name, grad in single_grads.items():
            assert torch.equal(mixed_grads[name][k], grad[k]), (name, q)


def test_the_comparison_covers_the_floor_and_the_cap() -> None:
    """The batch above puts per-dimension log-densities below the 1e-6 floor and above the
    q = 3 cap (log 10^4), so the clamps' gradient masks are compared, not just their insides."""
    agent = _agent()
    batch, eps = _batch()
    with torch.no_grad():
        mu, log_std = policy_head(
            mlp(agent.chunks[0].params.networks.policy, batch.obs), ACT, -20.0, 2.0
        )
        _, log_prob_dims = squashed_gaussian(mu, log_std, log_std.exp(), eps)
    assert (log_prob_dims < LOG_DENSITY_FLOOR).float().mean() > 0.005
    assert (log_prob_dims > 4 * math.log(10)).float().mean() > 0.01
    assert (log_prob_dims.sum(-1) > 4 * math.log(10)).float().mean() > 0.01


def _parameters(per_member_steps: bool = False) -> TacParameters:
    gens = [torch.Generator().manual_seed(s) for s in (0, 1)]
    return TacParameters(
        OBS, ACT, (4,), gens, twin_q_targets=False, device=CPU, per_member_steps=per_member_steps
    )


def test_per_member_adam_steps_update_only_the_active_members_each_by_its_own_count() -> None:
    """The episode schedule's Adam: member 0 makes three steps while member 1 makes one (the
    last); each ends where torch.optim.Adam ends after that many steps on its gradients, and
    member 1, weights, moments, step count and target, is bit-identical across the steps it
    skips."""
    flat, g = _parameters(per_member_steps=True), torch.Generator().manual_seed(2)
    params = [
        torch.nn.Parameter(flat.layout.networks(flat.data).policy.weights[0][k].clone())
        for k in (0, 1)
    ]
    optimizers = [torch.optim.Adam([p], lr=1e-3) for p in params]
    for step, active in enumerate(([True, False], [True, False], [True, True])):
        grad = torch.randn(flat.data.shape, generator=g)
        flat.grad.copy_(grad)
        before = flat.member_state(1)
        flat.adam_step(1e-3, np.array(active))
        flat.update_target(0.005, np.array(active))
        after = flat.member_state(1)
        if not active[1]:
            for part in ("params", "exp_avg", "exp_avg_sq"):
                values = before["params"] if part == "params" else before["adam"][part]
                now = after["params"] if part == "params" else after["adam"][part]
                assert all(torch.equal(now[n], v) for n, v in values.items()), (step, part)
            assert torch.equal(after["adam"]["step"], before["adam"]["step"])
        for k, (param, optimizer) in enumerate(zip(params, optimizers, strict=True)):
            if active[k]:
                param.grad = flat.layout.networks(grad).policy.weights[0][k].clone()
                optimizer.step()
    assert flat.steps.tolist() == [3.0, 1.0]
    weights = flat.networks.policy.weights[0]
    for k in (0, 1):
        torch.testing.assert_close(weights[k], params[k].detach(), rtol=1e-6, atol=1e-7)


def test_a_member_stepping_at_its_own_times_matches_it_alone() -> None:
    """Members with different step counts (each updated by its own rows of every block, by the
    same fused kernel) end where the same member trained alone ends, to float32 rounding (the
    kernel's vector loop and its tail round the last bit of a moment differently)."""
    group = _parameters(per_member_steps=True)
    alone = TacParameters(
        OBS, ACT, (4,), [torch.Generator().manual_seed(1)], twin_q_targets=False, device=CPU
    )
    g = torch.Generator().manual_seed(5)
    for active in ([False, True], [True, True], [True, True]):
        grads = {
            n: torch.randn(t.shape[1:], generator=g) for n, t in group._named(group.grad, None)
        }
        for (name, block), (_, single) in zip(
            group._named(group.grad, None), alone._named(alone.grad, None), strict=True
        ):
            block[1].copy_(grads[name])
            single[0].copy_(grads[name])
        group.adam_step(1e-3, np.array(active))
        alone.adam_step(1e-3)
    together, by_itself = group.member_state(1), alone.member_state(0)
    for name, value in by_itself["params"].items():
        torch.testing.assert_close(together["params"][name], value, rtol=1e-6, atol=0)
    for part in ("exp_avg", "exp_avg_sq"):
        for name, value in by_itself["adam"][part].items():
            torch.testing.assert_close(together["adam"][part][name], value, rtol=1e-6, atol=0)
    assert group.steps.tolist() == [2.0, 3.0] and alone.steps.tolist() == [3.0]


def test_flat_adam_step_equals_torch_adam() -> None:
    flat, g = _parameters(), torch.Generator().manual_seed(0)
    param = torch.nn.Parameter(flat.data.clone())
    optimizer = torch.optim.Adam([param], lr=1e-3)
    for _ in range(3):
        grad = torch.randn(flat.data.shape, generator=g)
        param.grad = grad
        flat.grad.copy_(grad)
        optimizer.step()
        flat.adam_step(1e-3)
    torch.testing.assert_close(flat.data, param.detach(), rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(flat.steps, torch.tensor([3.0, 3.0]))


def test_flat_adam_step_is_bit_identical_to_torch_fused_adam() -> None:
    flat, g = _parameters(), torch.Generator().manual_seed(1)
    n = flat.data.numel()
    data, m, v, step = flat.data.clone(), torch.zeros(n), torch.zeros(n), torch.zeros(())
    for _ in range(3):
        flat.grad.copy_(torch.randn(n, generator=g))
        adam([data], [flat.grad.clone()], [m], [v], [], [step], fused=True, foreach=False,
             capturable=False, differentiable=False, grad_scale=None, found_inf=None,
             has_complex=False, amsgrad=False, beta1=0.9, beta2=0.999, lr=1e-3,
             weight_decay=0.0, eps=1e-8, maximize=False)  # fmt: skip
        flat.adam_step(1e-3)
    assert torch.equal(flat.data, data) and torch.equal(flat.exp_avg_sq, v)
    assert torch.equal(flat.steps[0], step)


def test_act_is_the_policy_networks_computation_exactly() -> None:
    agent = _agent()
    obs = np.random.default_rng(0).normal(size=(len(SEEDS), 7, OBS))
    policy = agent.chunks[0].params.networks.policy

    def head(x: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        return policy_head(mlp(policy, torch.as_tensor(x, dtype=torch.float32)), ACT, -20.0, 2.0)

    mu, _ = head(obs)
    np.testing.assert_array_equal(agent.act_deterministic(obs), torch.tanh(mu).numpy())
    state = [g.get_state() for g in agent.generators]
    action = agent.act(obs[:, 0])
    for g, s in zip(agent.generators, state, strict=True):
        g.set_state(s)
    mu, log_std = head(obs[:, :1])
    noise = torch.stack([torch.randn(1, ACT, generator=g) for g in agent.generators])
    np.testing.assert_array_equal(action, torch.tanh(mu + noise * log_std.exp())[:, 0].numpy())


def test_compile_falls_back_to_the_uncompiled_update_where_it_fails(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def broken_compile(fn: Any, **_: Any) -> Any:
        def fail(*args: Any) -> Any:
            raise RuntimeError("no C++ compiler")

        return fail

    monkeypatch.setattr(gradient_module.torch, "compile", broken_compile)
    compiled, plain = _agent(compile="on"), _agent()
    batch, eps = _batch()
    with pytest.warns(RuntimeWarning, match=r"no C\+\+ compiler"):
        metrics, grads = gradients(compiled, batch, eps, _c(1.5))
    reference, reference_grads = gradients(plain, batch, eps, _c(1.5))
    assert torch.equal(metrics, reference)
    for name, grad in reference_grads.items():
        assert torch.equal(grads[name], grad), name
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once, then the fallback is silent
        gradients(compiled, batch, eps, _c(1.5))


@pytest.mark.compile
def test_compiled_update_equals_the_eager_one() -> None:
    """torch.compile of the update (seconds to half a minute of compilation, cached on disk
    afterwards): a group of members at q = 1, 1.5 and 3 (q = 1 and the q >= 2 cap in one graph),
    one of them retired, within float32 rounding of the eager update, then other q values
    without a fallback or a recompilation."""
    compiled, plain = _agent(compile="on"), _agent()
    for agent in (compiled, plain):
        agent.alive[1] = False
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _compare(compiled, plain, _c([1.0, 1.5, 3.0], [0.2, 0.1, 0.05]), 1e-5)
        frames = torch._dynamo.utils.counters["stats"]["unique_graphs"]
        assert frames >= 1
        for q in ([1.2, 2.0, 5.0], [0.5, 1.0001, 1.9]):
            _compare(compiled, plain, _c(q), 1e-5)
        assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == frames  # no recompile
    assert not [w for w in caught if "torch.compile of TAC's update" in str(w.message)]


@pytest.mark.compile
def test_compiled_update_of_the_authors_numerics_equals_the_eager_one() -> None:
    """The authors' profiles' options, which no other compiled test uses: ln_q of the density
    over the minibatch's largest (its maximum differentiated too), a clipped Jacobian and a
    Gaussian epsilon, across q = 1 and the cap."""
    settings: dict[str, Any] = {
        "lnq": "joint-batch-max",
        "jacobian_clip": 1e-3,
        "gaussian_eps": 1e-8,
    }
    compiled, plain = _agent(compile="on", **settings), _agent(**settings)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for q in ([1.0, 1.5, 3.0], [1.2, 2.0, 5.0]):
            _compare(compiled, plain, _c(q), 1e-5)
    assert not [w for w in caught if "torch.compile of TAC's update" in str(w.message)]


@pytest.mark.slow
@pytest.mark.parametrize("lnq", ["per-dim", "joint"])
def test_compiled_twin_q_update_equals_the_eager_one_across_q(lnq: str) -> None:
    """torch.compile with twin-q (tens of seconds of compilation): the same numbers, to the
    rounding of Inductor's reordered reductions, for a sequence of q values that crosses q = 1
    and the cap at q = 2, as a linear q schedule does."""
    compiled = _agent(compile="on", critic_target="twin-q", lnq=lnq)
    plain = _agent(critic_target="twin-q", lnq=lnq)
    eps_next = torch.randn(len(SEEDS), 64, ACT, generator=torch.Generator().manual_seed(9))
    for q in (1.0, 1.0001, 1.5, 2.0, 2.1, 3.0, 5.0, 1.2):
        _compare(compiled, plain, _c(q), 1e-5, eps_next)


def test_members_in_chunks_start_alike_and_get_the_gradients_of_one_stack(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A CPU agent holds more than CPU_MEMBERS_PER_CHUNK members in chunks of near-equal size
    (12 members: two of 6); their initial weights are exactly those of one stack, their losses
    and gradients those of one stack to float32 rounding."""
    config = RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, hidden_sizes=(16,), compile="off")
    seeds = list(range(12))
    chunked = TacAgent(OBS, ACT, config, seeds, CPU)
    assert [c.members for c in chunked.chunks] == [slice(0, 6), slice(6, 12)]
    monkeypatch.setattr(agent_module, "CPU_MEMBERS_PER_CHUNK", 12)
    whole = TacAgent(OBS, ACT, config, seeds, CPU)
    assert len(whole.chunks) == 1
    for k in seeds:
        for name, value in whole.member_state(k)["params"].items():
            assert torch.equal(chunked.member_state(k)["params"][name], value), (k, name)
    batch, eps = random_batch(12, 32, OBS, ACT, seed=3)
    # every member its own q and alpha: a chunk handed another chunk's would show
    qs = [1.0, 1.5, 3.0, 1.2, 2.0, 0.5, 0.7, 1.7, 5.0, 1.1, 2.5, 1.3]
    c = coefficients(qs, [0.2, 0.1, 0.05, 0.3] * 3, CPU)
    expected, expected_grads = gradients(whole, batch, eps, c)
    metrics, grads = gradients(chunked, batch, eps, c)
    for i, name in enumerate(METRICS):
        assert_close_per_member(metrics[:, i], expected[:, i], 2e-6, name)
    for name, grad in expected_grads.items():
        assert_close_per_member(grads[name], grad, 2e-6, name)
