"""All TAC losses in one pure function, commented with the paper's equation labels.

Shapes: K members, B samples, A action dimensions. Every loss is per member, shape ``(K,)``;
the members never mix, so summing the losses over members gives each member exactly the
gradient it would get alone.

Paper references are to the appendix "Implementation Detail" of ``tsallis-rl-paper.tex``:
``eqn:q_obj`` (Q loss), ``eqn:v_obj`` (V loss), ``eqn:pol_obj`` (policy loss), the
"Reparameterization Trick" (density of the squashed Gaussian) and the "Numerical Issue" (the
density cap for q >= 2). Where the paper is silent the reference code decides (REFERENCE.md).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F

from tacbench.tac.networks import Critic, TanhGaussianPolicy
from tacbench.tsallis import log_q_of_log

LOG_DENSITY_FLOOR = math.log(1e-6)  # reference code: each per-dimension density >= 1e-6
JACOBIAN_EPS_LOG = math.log(1e-6)  # SAC v1 and reference code: log(1 - tanh(z)^2 + 1e-6)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)

# Diagnostics written to losses.csv besides the four losses (means over the batch).
DIAGNOSTICS = ("log_pi", "lnq_pi", "q1_pi", "v", "std")


class Batch(NamedTuple):
    """A member-batched minibatch; actions are in the policy's [-1, 1] units."""

    obs: torch.Tensor  # (K, B, obs_dim)
    action: torch.Tensor  # (K, B, A)
    reward: torch.Tensor  # (K, B)
    next_obs: torch.Tensor  # (K, B, obs_dim)
    terminated: torch.Tensor  # (K, B), 1.0 where s' is terminal (never for a time-limit end)


class TacLosses(NamedTuple):
    """Per-member losses, each ``(K,)``, and ``(K, len(DIAGNOSTICS))`` detached diagnostics."""

    q1: torch.Tensor
    q2: torch.Tensor
    v: torch.Tensor
    pi: torch.Tensor
    diagnostics: torch.Tensor


def squashed_gaussian_sample(
    mu: torch.Tensor, log_std: torch.Tensor, eps: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparameterised action ``a = tanh(mu + eps * sigma)`` and ``log pi_i(a_i|s)`` per dimension.

    Paper, "Reparameterization Trick": ``pi(a|s) = N(z; mu, sigma) |da/dz|^-1``. The paper prints
    the Jacobian as ``prod_i (1 - tanh(z_i))``; the correct one (as in SAC) is
    ``prod_i (1 - tanh(z_i)^2)``. Each factor gets SAC v1's (and the reference code's) ``+ 1e-6``,
    which bounds a saturated dimension's log-density increase at ``-log(1e-6)``; its log is
    ``logaddexp(log(1 - tanh(z)^2), log 1e-6)`` with ``log(1 - tanh(z)^2)`` computed stably as
    ``2 (log 2 - z - softplus(-2 z))``.
    """
    z = mu + eps * log_std.exp()
    log_normal = -0.5 * eps.square() - log_std - _HALF_LOG_2PI
    log_jacobian = 2.0 * (math.log(2.0) - z - F.softplus(-2.0 * z))
    log_jacobian = torch.logaddexp(log_jacobian, torch.full_like(log_jacobian, JACOBIAN_EPS_LOG))
    return torch.tanh(z), log_normal - log_jacobian


def lnq_of_policy(log_prob_dims: torch.Tensor, q: float, lnq: str) -> torch.Tensor:
    """``ln_q pi(a|s)``, shape ``(K, B)``, from per-dimension log-densities ``(K, B, A)``.

    ``joint`` (paper): ln_q of the joint density ``exp(sum_i log pi_i)``. ``per-dim`` (reference
    code): ``sum_i ln_q(pi_i)`` with each pi_i floored at 1e-6. Both equal ``log pi`` at q = 1.
    For q >= 2 the density is capped at ``10^(8/(q-1))`` (paper, "Numerical Issue"), so
    ``ln_q <= (10^8 - 1)/(q-1)``. The density itself is never formed, only its log.
    """
    cap = 8.0 * math.log(10.0) / (q - 1.0) if q >= 2.0 else None
    if lnq == "joint":
        log_prob = log_prob_dims.sum(dim=-1)
        return log_q_of_log(log_prob if cap is None else log_prob.clamp(max=cap), q)
    return log_q_of_log(log_prob_dims.clamp(min=LOG_DENSITY_FLOOR, max=cap), q).sum(dim=-1)


def tac_losses(
    policy: TanhGaussianPolicy,
    q1: Critic,
    q2: Critic,
    v: Critic,
    v_target: Critic,
    batch: Batch,
    eps: torch.Tensor,
    *,
    q: float,
    alpha: float,
    gamma: float,
    lnq: str,
    target_critics: tuple[Critic, Critic] | None = None,
    eps_next: torch.Tensor | None = None,
) -> TacLosses:
    """TAC's Q, V and policy losses on one minibatch (SAC v1 with ``log`` replaced by ``ln_q``).

    ``eps`` ``(K, B, A)`` is the standard normal noise of the reparameterised action. Each loss's
    graph reaches only the parameters it trains: Q losses -> Q1, Q2; V loss -> V; policy loss ->
    policy (Q1 is evaluated there with frozen weights). The target V is never trained here.

    ``target_critics`` (``critic_target`` twin-q, SAC v2's target of Haarnoja et al. 2018b)
    replace the target V in the Q target by ``min(Q1-, Q2-)(s', a') - alpha ln_q pi(a'|s')``,
    a' ~ pi(.|s') drawn with ``eps_next``; there is then no V loss (reported as 0) and the
    ``v`` diagnostic is that soft value of s'.
    """
    if (target_critics is None) != (eps_next is None):
        raise ValueError("twin-q needs both the target critics and eps_next")
    # a~ ~ pi(.|s) by the reparameterisation trick, and ln_q pi(a~|s)
    mu, log_std = policy(batch.obs)
    new_action, log_prob_dims = squashed_gaussian_sample(mu, log_std, eps)
    lnq_pi = lnq_of_policy(log_prob_dims, q, lnq)

    # eqn:q_obj  J_theta = E[ 1/2 (Q_theta(s,a) - r - gamma V_psi-(s'))^2 ]; time-limit ends
    # are not terminal, so only a true terminal state drops the bootstrap (reference code).
    # twin-q: V_psi-(s') is replaced by the target critics' soft value of s' (SAC v2).
    with torch.no_grad():
        if target_critics is None or eps_next is None:
            v_next = v_target(batch.next_obs)
        else:
            next_mu, next_log_std = policy(batch.next_obs)
            next_action, next_log_prob_dims = squashed_gaussian_sample(
                next_mu, next_log_std, eps_next
            )
            q1_next, q2_next = (net(batch.next_obs, next_action) for net in target_critics)
            v_next = torch.minimum(q1_next, q2_next) - alpha * lnq_of_policy(
                next_log_prob_dims, q, lnq
            )
        q_target = batch.reward + gamma * (1.0 - batch.terminated) * v_next
    loss_q1 = 0.5 * (q1(batch.obs, batch.action) - q_target).square().mean(dim=-1)
    loss_q2 = 0.5 * (q2(batch.obs, batch.action) - q_target).square().mean(dim=-1)

    # eqn:v_obj  J_psi = E[ 1/2 (y - V_psi(s))^2 ], y = min(Q1, Q2)(s, a~) - alpha ln_q pi(a~|s)
    # with a~ drawn from the current policy (reference code; the paper's a_t is ambiguous).
    if target_critics is None:
        with torch.no_grad():
            q_min = torch.minimum(q1(batch.obs, new_action), q2(batch.obs, new_action))
            v_target_value = q_min - alpha * lnq_pi
        v_value = v(batch.obs)
        loss_v = 0.5 * (v_value - v_target_value).square().mean(dim=-1)
    else:
        v_value, loss_v = v_next, torch.zeros_like(loss_q1)

    # eqn:pol_obj  J_phi = E[ alpha ln_q pi(a~|s) - Q(s, a~) ], with Q = Q1 (reference code)
    q1_pi = q1(batch.obs, new_action, frozen=True)
    loss_pi = (alpha * lnq_pi - q1_pi).mean(dim=-1)

    with torch.no_grad():
        diagnostics = torch.stack(
            [
                log_prob_dims.sum(dim=-1).mean(dim=-1),
                lnq_pi.mean(dim=-1),
                q1_pi.mean(dim=-1),
                v_value.mean(dim=-1),
                log_std.exp().mean(dim=(-2, -1)),
            ],
            dim=-1,
        )
    return TacLosses(loss_q1, loss_q2, loss_v, loss_pi, diagnostics)
