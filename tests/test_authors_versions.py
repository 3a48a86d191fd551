"""Each ``--profile authors-DATE`` computes what the authors' code computed on that date: its
ln_q of the policy, V target and policy loss equal a float64 NumPy port of that version's
formulas (docs/authors-versions.md), written here from the version table, not from tacbench's
code, on random inputs with saturated tanh dimensions and log std near both bounds."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tacbench import paper
from tacbench.paper import density_log_cap
from tacbench.tac.losses import tac_losses
from tacbench.tac.maths import Batch, Coefficients, lnq_of_policy, squashed_gaussian
from tests.helpers import tac_agent

pytestmark = pytest.mark.unit

VERSIONS = tuple(name for name in paper.PROFILES if name.startswith("authors-"))
QS = (0.5, 1.0, 1.5, 2.0, 3.0, 5.0)
OBS, ACT, B = 3, 6, 64
# per action dimension: the policy's mean and the raw log-std head output; log std is
# -20 + 11 (tanh(raw) + 1): raw -6 is -19.9999, raw 6 is 1.9999, raw -0.9 about -16.9 (sigma
# near Spinning Up's 1e-8); means of 9 and -12 saturate tanh
MU = np.array([0.3, 9.0, -12.0, 0.1, -0.5, 2.0])
RAW = np.array([6.0, -6.0, 0.5, -0.9, 0.0, 3.0])
ALPHA, Q1, Q2 = 0.2, 1.3, 0.7


def _ln_q(x: np.ndarray, q: float) -> np.ndarray:
    """The authors' q-logarithm: (x^(q-1) - 1)/(q-1), log at q = 1."""
    return np.log(x) if q == 1.0 else (x ** (q - 1.0) - 1.0) / (q - 1.0)


def _port_lnq(
    version: str, mu: np.ndarray, log_std: np.ndarray, eps: np.ndarray, q: float
) -> np.ndarray:
    """ln_q pi(a|s) per sample ``(B,)`` as that version of the authors' code computed it."""
    std = np.exp(log_std)
    u = mu + std * eps
    # (u - mu) / (sigma + 1e-8), with u - mu written as sigma eps: equal, without the
    # cancellation of u - mu where sigma is 1e-9 next to a mean of 9
    gauss = -0.5 * ((std * eps / (std + 1e-8)) ** 2 + 2.0 * log_std + np.log(2.0 * np.pi))
    low = 1e-3 if version == "authors-2019-01-07b" else 0.0
    log_dims = gauss - np.log(np.clip(1.0 - np.tanh(u) ** 2, low, 1.0) + 1e-6)
    if version == "authors-2019-01-07b":  # joint density over the batch's largest, >= 1e-8
        joint = log_dims.sum(axis=-1)
        return _ln_q(np.maximum(np.exp(joint - joint.max()), 1e-8), q)
    density = np.exp(log_dims)
    if version == "authors-2019-01-11b":  # per dimension, >= 1e-8, no cap
        return _ln_q(np.maximum(density, 1e-8), q).sum(axis=-1)
    if version == "authors-2019-01-16c":  # per dimension, capped for every q, >= 1e-8
        cap = np.inf if q == 1.0 else 10.0 ** (8.0 / (q - 1.0))
        return _ln_q(np.maximum(np.minimum(density, cap), 1e-8), q).sum(axis=-1)
    if version == "authors-2019-01-22":  # per dimension, capped for q >= 2, >= 1e-6
        cap = 10.0 ** (8.0 / (q - 1.0)) if q >= 2.0 else np.inf
        return _ln_q(np.maximum(np.minimum(density, cap), 1e-6), q).sum(axis=-1)
    raise AssertionError(f"no port of {version}: add its formulas here")


def _inputs(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    eps = rng.normal(size=(B, ACT)) * rng.choice([0.5, 1.0, 3.0], size=(B, 1))
    log_std = -20.0 + 11.0 * (np.tanh(RAW) + 1.0)
    return np.broadcast_to(MU, (B, ACT)), np.broadcast_to(log_std, (B, ACT)), eps


def _float64_coefficients(version: str, q: float) -> Coefficients:
    """As ``maths.coefficients`` makes them, in float64 (its tensors are float32)."""
    cap = density_log_cap(q, paper.PROFILES[version]["density_cap"])
    return Coefficients(*(torch.tensor([x], dtype=torch.float64) for x in (q - 1.0, cap, ALPHA)))


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("q", QS)
def test_lnq_of_the_policy_equals_the_version_port(version: str, q: float) -> None:
    settings = tac_agent(OBS, ACT, [0], q=q, profile=version).settings
    mu, log_std, eps = _inputs(seed=int(10 * q))
    t = [torch.from_numpy(np.ascontiguousarray(x))[None] for x in (mu, log_std, eps)]
    _, log_dims = squashed_gaussian(
        t[0], t[1], t[1].exp(), t[2], settings.jacobian_clip, settings.gaussian_eps
    )
    c = _float64_coefficients(version, q)
    ours = lnq_of_policy(log_dims, c, settings.lnq, settings.log_density_floor)[0].numpy()
    port = _port_lnq(version, mu, log_std, eps, q)
    assert np.isfinite(port).all()
    np.testing.assert_allclose(ours, port, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("q", QS)
def test_v_target_and_policy_loss_equal_the_version_port(version: str, q: float) -> None:
    # Networks with zero weights: the policy outputs MU and RAW, Q1 and Q2 the constants Q1, Q2,
    # V and the target V zero, so V's loss is half the mean squared V target.
    agent = tac_agent(OBS, ACT, [0], q=q, alpha=ALPHA, profile=version)
    params = agent.chunks[0].params
    theta = torch.zeros_like(params.data, dtype=torch.float64)
    nets = params.layout.networks(theta)
    nets.policy.biases[-1].copy_(torch.from_numpy(np.concatenate([MU, RAW]))[None, None])
    nets.critics.biases[-1].copy_(torch.tensor([[[Q1]], [[Q2]]], dtype=torch.float64))
    target = params.target_layout.layers(torch.zeros_like(params.target, dtype=torch.float64))
    mu, log_std, eps = _inputs(seed=int(10 * q) + 1)
    zeros = torch.zeros(1, B, dtype=torch.float64)
    batch = Batch(
        torch.zeros(1, B, OBS, dtype=torch.float64),
        torch.zeros(1, B, ACT, dtype=torch.float64),
        zeros,
        torch.zeros(1, B, OBS, dtype=torch.float64),
        zeros,
    )
    c = _float64_coefficients(version, q)
    losses = tac_losses(nets, target, batch, torch.from_numpy(eps)[None], c, agent.settings)

    lnq = _port_lnq(version, mu, log_std, eps, q)
    v_target = min(Q1, Q2) - ALPHA * lnq
    assert losses.v.item() == pytest.approx(0.5 * np.mean(v_target**2), rel=1e-9, abs=1e-12)
    assert losses.pi.item() == pytest.approx(np.mean(ALPHA * lnq - Q1), rel=1e-9, abs=1e-12)


def test_the_jacobian_clip_passes_the_gradient_through() -> None:
    """2019-01-07b raises 1 - tanh(u)^2 to at least 1e-3 as Spinning Up's clip_but_pass_gradient
    does: the value is clipped, the gradient is the unclipped 1 - tanh(u)^2's (over the clipped
    value + 1e-6), not the zero gradient of a plain clamp."""
    mu = torch.tensor([4.0], dtype=torch.float64, requires_grad=True)
    log_std, eps = (
        torch.tensor([-1.0], dtype=torch.float64),
        torch.tensor([0.5], dtype=torch.float64),
    )
    _, log_dims = squashed_gaussian(mu, log_std, log_std.exp(), eps, jacobian_clip=1e-3)
    log_dims.sum().backward()
    u = 4.0 + 0.5 * np.exp(-1.0)
    jacobian = 1.0 - np.tanh(u) ** 2
    assert jacobian < 1e-3  # the clip holds the value
    assert mu.grad is not None
    assert mu.grad.item() == pytest.approx(2.0 * np.tanh(u) * jacobian / (1e-3 + 1e-6), rel=1e-9)


def test_the_versions_differ_where_the_history_says() -> None:
    """The port itself: the four versions agree at q = 1.5 but for the batch-max version and
    the floors, and part at q = 3, where only 2019-01-16 and 2019-01-22 cap."""
    mu, log_std, eps = _inputs(seed=3)
    at = {v: _port_lnq(v, mu, log_std, eps, 3.0) for v in VERSIONS}
    assert at["authors-2019-01-11b"].max() > at["authors-2019-01-16c"].max()  # no cap
    np.testing.assert_allclose(at["authors-2019-01-16c"], at["authors-2019-01-22"], rtol=1e-6)
    assert (at["authors-2019-01-07b"] <= 0.0).all()  # a density over the batch's largest
    capped = (1e8 - 1.0) / 2.0  # ln_3 of the cap 10^(8/2)
    assert at["authors-2019-01-22"].max() <= ACT * capped + 1e-9


@pytest.mark.parametrize("version", VERSIONS)
def test_each_version_names_its_runs(version: str) -> None:
    variant = tac_agent(OBS, ACT, [0], profile=version).config.variant
    assert version.replace("-", "") in variant.split("-")
    assert paper.PROFILES[version]["hidden_sizes"] == (400, 300)  # every version's networks
