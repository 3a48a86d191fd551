"""The fused update (tacbench.tac.fused) against the eager reference (losses.tac_losses and
autograd): same losses, diagnostics and gradients on the same batch, the same Adam step, the
same target-V average, interchangeable checkpoints, and a clean torch.compile fallback."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pytest
import torch
from torch.optim.adam import adam

from tacbench import machine
from tacbench.config import RunConfig
from tacbench.tac import agent as agent_module
from tacbench.tac import speed
from tacbench.tac.agent import METRICS, TacAgent
from tacbench.tac.flat import FlatParameters
from tacbench.tac.losses import LOG_DENSITY_FLOOR, Batch, squashed_gaussian_sample

pytestmark = pytest.mark.unit

OBS, ACT = 5, 3
SEEDS = [3, 4, 5]


def _agent(impl: str, hidden: tuple[int, ...] = (16,), **overrides: Any) -> TacAgent:
    config = RunConfig(
        env="Hopper-v4", q=1.5, alpha=0.2, hidden_sizes=hidden, impl=impl, **overrides
    )
    agent = TacAgent(OBS, ACT, config, SEEDS, torch.device("cpu"))
    with torch.no_grad():  # a wide spread of log_std, so the ln_q floor and cap both matter
        agent.policy.net.weights[-1].mul_(4.0)
        agent.v_target.net.biases[-1].fill_(0.3)  # differs from V
    return agent


def _batch(seed: int = 0, b: int = 64) -> tuple[Batch, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    k = len(SEEDS)
    batch = Batch(
        obs=torch.randn(k, b, OBS, generator=g) * 2,
        action=torch.rand(k, b, ACT, generator=g) * 2 - 1,
        reward=torch.randn(k, b, generator=g),
        next_obs=torch.randn(k, b, OBS, generator=g) * 2,
        terminated=(torch.rand(k, b, generator=g) < 0.2).float(),
    )
    return batch, torch.randn(k, b, ACT, generator=g) * 3.0


def _close(ours: torch.Tensor, reference: torch.Tensor, rtol: float, name: str) -> None:
    """Equal up to ``rtol`` of the reference's largest magnitude (float32 rounding)."""
    scale = reference.abs().max().item()
    error = (ours - reference).abs().max().item()
    assert error <= rtol * max(scale, 1e-12), (name, error, scale)


@pytest.mark.parametrize("lnq", ["per-dim", "joint"])
@pytest.mark.parametrize("q", [0.5, 1.0, 1.5, 2.0, 3.0])
@pytest.mark.parametrize("hidden", [(16,), (8, 8)])
def test_fused_losses_and_gradients_equal_the_eager_ones(
    lnq: str, q: float, hidden: tuple[int, ...]
) -> None:
    eager, fused = _agent("eager", hidden, lnq=lnq), _agent("fused", hidden, lnq=lnq)
    for agent in (eager, fused):
        agent.alive[1] = False  # a retired member: zero gradients, its metrics still reported
    batch, eps = _batch()
    reference, reference_grads = eager.gradients(batch, eps, q)
    metrics, grads = fused.gradients(batch, eps, q)
    assert metrics.shape == (len(SEEDS), len(METRICS))
    for i, name in enumerate(METRICS):
        _close(metrics[:, i], reference[:, i], 2e-6, name)
    assert sorted(grads) == sorted(reference_grads)
    for name, grad in reference_grads.items():
        _close(grads[name], grad, 2e-6, name)
        assert not grads[name][1].any(), name  # the retired member


@pytest.mark.parametrize(("q", "lnq"), [(1.0, "per-dim"), (1.5, "per-dim"), (3.0, "joint")])
def test_twin_q_fused_losses_and_gradients_equal_the_eager_ones(q: float, lnq: str) -> None:
    eager = _agent("eager", lnq=lnq, critic_target="twin-q")
    fused = _agent("fused", lnq=lnq, critic_target="twin-q")
    for agent in (eager, fused):
        agent.alive[1] = False
        with torch.no_grad():  # target critics that differ from the online ones
            for target in agent.critic_targets or ():
                target.net.biases[-1].add_(0.5)
    batch, eps = _batch()
    eps_next = torch.randn(eps.shape, generator=torch.Generator().manual_seed(9))
    reference, reference_grads = eager.gradients(batch, eps, q, eps_next)
    metrics, grads = fused.gradients(batch, eps, q, eps_next)
    for i, name in enumerate(METRICS):
        _close(metrics[:, i], reference[:, i], 2e-6, name)
    assert not reference[:, METRICS.index("loss_v")].any()
    for name, grad in grads.items():
        if name.startswith("v."):  # no V network with twin-q: no gradient on either path
            assert name not in reference_grads and not grad.any(), name
            continue
        _close(grad, reference_grads[name], 2e-6, name)
        assert not grad[1].any(), name


def test_the_comparison_covers_the_floor_and_the_cap() -> None:
    """The batch above puts per-dimension log-densities below the 1e-6 floor and above the
    q = 3 cap (log 10^4), so the clamps' gradient masks are compared, not just their insides."""
    agent = _agent("eager")
    batch, eps = _batch()
    with torch.no_grad():
        mu, log_std = agent.policy(batch.obs)
        _, log_prob_dims = squashed_gaussian_sample(mu, log_std, eps)
    assert (log_prob_dims < LOG_DENSITY_FLOOR).float().mean() > 0.005
    assert (log_prob_dims > 4 * math.log(10)).float().mean() > 0.01
    assert (log_prob_dims.sum(-1) > 4 * math.log(10)).float().mean() > 0.01


def test_flat_adam_step_equals_torch_adam() -> None:
    g = torch.Generator().manual_seed(0)
    tensors = [torch.randn(2, 4, 3, generator=g), torch.randn(2, 1, 3, generator=g)]
    params = [torch.nn.Parameter(t.clone()) for t in tensors]
    flat = FlatParameters([[t] for t in tensors], torch.device("cpu"))
    optimizer = torch.optim.Adam(params, lr=1e-3)
    for _ in range(3):
        grads = [torch.randn(t.shape, generator=g) for t in tensors]
        for param, grad, block in zip(params, grads, flat.grad_blocks, strict=True):
            param.grad = grad
            block[0].copy_(grad)
        optimizer.step()
        flat.adam_step(1e-3)
    for param, block in zip(params, flat.blocks, strict=True):
        torch.testing.assert_close(block[0], param.detach(), rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(flat.step, torch.tensor(3.0))


def test_flat_adam_step_is_bit_identical_to_torch_fused_adam() -> None:
    g = torch.Generator().manual_seed(1)
    flat = FlatParameters([[torch.randn(3, 5, generator=g)]], torch.device("cpu"))
    data, m, v, step = flat.data.clone(), torch.zeros(15), torch.zeros(15), torch.zeros(())
    for _ in range(3):
        flat.grad.copy_(torch.randn(15, generator=g))
        adam([data], [flat.grad.clone()], [m], [v], [], [step], fused=True, foreach=False,
             capturable=False, differentiable=False, grad_scale=None, found_inf=None,
             has_complex=False, amsgrad=False, beta1=0.9, beta2=0.999, lr=1e-3,
             weight_decay=0.0, eps=1e-8, maximize=False)  # fmt: skip
        flat.adam_step(1e-3)
    assert torch.equal(flat.data, data) and torch.equal(flat.exp_avg_sq, v)
    assert torch.equal(flat.step, step)


def _params(agent: TacAgent) -> dict[str, torch.Tensor]:
    return {name: p.detach().clone() for name, p in agent._named_parameters()}


def test_one_update_moves_the_weights_and_target_v_like_the_eager_update() -> None:
    eager, fused = _agent("eager"), _agent("fused")
    batch, _ = _batch(b=32)
    arrays = {name: value.numpy() for name, value in batch._asdict().items()}
    before = _params(eager)
    torch.testing.assert_close(
        eager.update(arrays, 1.5), fused.update(arrays, 1.5), rtol=2e-6, atol=1e-6
    )
    after_eager, after_fused = _params(eager), _params(fused)
    for name, value in after_eager.items():
        moved = (value - before[name]).abs().max().item()
        error = (after_fused[name] - value).abs().max().item()
        # Adam's first step moves each weight by about lr = 1e-3 whatever its gradient's size,
        # so gradients that agree to rounding move the weights alike but for tiny ones
        assert error <= max(1e-2 * moved, 1e-7), (name, error, moved)
    assert not torch.equal(after_fused["v_target.net.weights.0"], before["v_target.net.weights.0"])


@pytest.mark.parametrize(("source", "target"), [("fused", "eager"), ("eager", "fused")])
def test_checkpoints_load_across_the_two_paths(source: str, target: str) -> None:
    trained = _agent(source)
    batch, _ = _batch(b=16)
    arrays = {name: value.numpy() for name, value in batch._asdict().items()}
    for _ in range(2):
        trained.update(arrays, 1.5)
    restored = _agent(target)
    restored.load_member_states([trained.member_state(k) for k in range(len(SEEDS))])
    for k in range(len(SEEDS)):
        saved, loaded = trained.member_state(k), restored.member_state(k)
        for name, value in saved["params"].items():
            assert torch.equal(loaded["params"][name], value), name
        assert len(loaded["adam"]) == len(saved["adam"]) == 16
        for ours, theirs in zip(loaded["adam"], saved["adam"], strict=True):
            for key, value in theirs.items():
                assert torch.equal(ours[key], value), key
    twin = _agent(source)  # the same continuation on the source's own path, for comparison
    twin.load_member_states([trained.member_state(k) for k in range(len(SEEDS))])
    torch.testing.assert_close(
        restored.update(arrays, 1.5), twin.update(arrays, 1.5), rtol=2e-6, atol=1e-6
    )


def test_act_is_the_policy_modules_computation_exactly() -> None:
    agent = _agent("fused")
    obs = np.random.default_rng(0).normal(size=(len(SEEDS), 7, OBS))
    mu, _ = agent.policy(torch.as_tensor(obs, dtype=torch.float32))
    np.testing.assert_array_equal(agent.act_deterministic(obs), torch.tanh(mu).detach().numpy())
    state = [g.get_state() for g in agent.generators]
    action = agent.act(obs[:, 0])
    for g, s in zip(agent.generators, state, strict=True):
        g.set_state(s)
    mu, log_std = agent.policy(torch.as_tensor(obs[:, :1], dtype=torch.float32))
    noise = torch.stack([torch.randn(1, ACT, generator=g) for g in agent.generators])
    expected = torch.tanh(mu + noise * log_std.exp())[:, 0].detach().numpy()
    np.testing.assert_array_equal(action, expected)


def test_compile_falls_back_to_the_fused_update_where_it_fails(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def broken_compile(fn: Any, **_: Any) -> Any:
        def fail(*args: Any) -> Any:
            raise RuntimeError("no C++ compiler")

        return fail

    monkeypatch.setattr(speed.torch, "compile", broken_compile)
    compiled, plain = _agent("fused", compile=True), _agent("fused")
    batch, eps = _batch()
    with pytest.warns(RuntimeWarning, match=r"no C\+\+ compiler"):
        metrics, grads = compiled.gradients(batch, eps, 1.5)
    reference, reference_grads = plain.gradients(batch, eps, 1.5)
    assert torch.equal(metrics, reference)
    for name, grad in reference_grads.items():
        assert torch.equal(grads[name], grad), name
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once, then the fallback is silent
        compiled.gradients(batch, eps, 1.5)


def _chunks_of(monkeypatch: pytest.MonkeyPatch, members: int) -> None:
    """Make the compiled update take ``members`` members at a time."""
    monkeypatch.setattr(agent_module, "members_fitting_l2", lambda *_: members)


def test_members_fitting_l2_counts_the_critics_hidden_layers() -> None:
    # HalfCheetah, the paper's 1x300 and batch 100: 480 KB of critic activations per member
    assert speed.members_fitting_l2(100, (300,), 2 << 20) == 4  # an Intel Xeon's 2 MiB
    assert speed.members_fitting_l2(100, (300,), 1 << 20) == 2  # an AMD Zen 5's 1 MiB
    assert speed.members_fitting_l2(100, (256, 300), 1 << 18) == 1  # never fewer than one
    assert machine.l2_cache_bytes() >= 1 << 16


@pytest.mark.parametrize("sysfs, size", [("2048K", 2 << 20), ("1M", 1 << 20), ("x", 0)])
def test_cache_sizes_are_read_as_sysfs_writes_them(sysfs: str, size: int) -> None:
    assert machine._parse_cache_size(sysfs) == size


@pytest.mark.parametrize("critic_target", ["v", "twin-q"])
@pytest.mark.parametrize("members", [1, 2, 3])
def test_the_update_in_member_chunks_equals_the_whole_stack(
    monkeypatch: pytest.MonkeyPatch, critic_target: str, members: int
) -> None:
    """The compiled update's member chunks (here uncompiled: torch.compile is the identity),
    a ragged last chunk and a retired member included: the same losses and gradients."""
    monkeypatch.setattr(speed.torch, "compile", lambda fn, **_: fn)
    _chunks_of(monkeypatch, members)
    calls = []
    whole_stack = speed.fused_gradients

    def counted(*args: Any) -> torch.Tensor:
        calls.append(args[4].shape[0])  # eps: (members, B, A)
        return whole_stack(*args)

    monkeypatch.setattr(speed, "fused_gradients", counted)
    chunked = _agent("fused", compile=True, critic_target=critic_target)
    plain = _agent("fused", critic_target=critic_target)
    for agent in (chunked, plain):
        agent.alive[1] = False
    batch, eps = _batch()
    eps_next = None if critic_target == "v" else eps.flip(1)
    metrics, grads = chunked.gradients(batch, eps, 1.5, eps_next)
    assert calls == {1: [1, 1, 1], 2: [2, 1], 3: [3]}[members]  # chunk sizes of three members
    reference, reference_grads = plain.gradients(batch, eps, 1.5, eps_next)
    _close(metrics, reference, 1e-6, "metrics")
    for name, grad in reference_grads.items():
        _close(grads[name], grad, 1e-6, name)


def test_compiled_update_equals_the_fused_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """torch.compile of the fused update (about half a minute of compilation, cached on disk
    afterwards), in chunks of two of the three members: one update's losses and gradients
    within float32 rounding of the uncompiled one, and no fallback."""
    _chunks_of(monkeypatch, 2)
    compiled, plain = _agent("fused", compile=True), _agent("fused")
    batch, eps = _batch()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _compare_compiled(compiled, plain, batch, eps, 1.5, None)
    assert not [w for w in caught if "torch.compile of the fused update" in str(w.message)]


@pytest.mark.slow
@pytest.mark.parametrize("critic_target", ["v", "twin-q"])
def test_compiled_update_equals_the_fused_one_across_q(critic_target: str) -> None:
    """torch.compile (tens of seconds of compilation): the same numbers, to the rounding of
    Inductor's reordered reductions, for a sequence of q values that crosses q = 1 and the cap
    at q = 2, as a linear q schedule does."""
    compiled = _agent("fused", compile=True, critic_target=critic_target)
    plain = _agent("fused", critic_target=critic_target)
    batch, eps = _batch()
    eps_next = (
        None
        if critic_target == "v"
        else torch.randn(eps.shape, generator=torch.Generator().manual_seed(9))
    )
    for q in (1.0, 1.0001, 1.5, 2.0, 2.1, 3.0, 5.0, 1.2):
        _compare_compiled(compiled, plain, batch, eps, q, eps_next)


def _compare_compiled(
    compiled: TacAgent,
    plain: TacAgent,
    batch: Batch,
    eps: torch.Tensor,
    q: float,
    eps_next: torch.Tensor | None,
) -> None:
    """The compiled agent's losses and gradients within 1e-5 of the uncompiled one's."""
    metrics, grads = compiled.gradients(batch, eps, q, eps_next)
    reference, reference_grads = plain.gradients(batch, eps, q, eps_next)
    for i, name in enumerate(METRICS):
        _close(metrics[:, i], reference[:, i], 1e-5, f"{name} at q={q}")
    for name, grad in reference_grads.items():
        _close(grads[name], grad, 1e-5, f"{name} at q={q}")
