"""All TAC losses in one pure function, commented with the paper's equation labels; autograd
differentiates it on every path (:mod:`tacbench.tac.gradient`).

Shapes: K members, B samples, A action dimensions. Every loss is per member, shape ``(K,)``; the
members never mix, so summing the losses over members gives each member exactly the gradient it
would get alone. q and alpha are per member (:class:`~tacbench.tac.maths.Coefficients`).

Paper references are to the appendix "Implementation Detail" of ``tsallis-rl-paper.tex``:
``eqn:q_obj`` (Q loss), ``eqn:v_obj`` (V loss), ``eqn:pol_obj`` (policy loss); with a learned
alpha (--alpha auto, not in the paper) SAC v2's temperature loss with ``ln_q``. The formulas
below them (the squashed Gaussian's density, ln_q, the cap) are in :mod:`tacbench.tac.maths`.
Where the paper is silent the reference code decides (REFERENCE.md)."""

from __future__ import annotations

from typing import NamedTuple

import torch

from tacbench.tac.maths import (
    LOG_DENSITY_FLOOR,
    Batch,
    Coefficients,
    default_lnq_target,
    lnq_of_policy,
    squashed_gaussian,
)
from tacbench.tac.networks import Layers, mlp, policy_head
from tacbench.tac.parameters import Networks


class LossSettings(NamedTuple):
    """The constants of the losses that all members share."""

    gamma: float
    lnq: str  # "per-dim", "joint" or "joint-batch-max" (maths.lnq_of_policy)
    log_std_min: float
    log_std_max: float
    action_scale: float = 1.0  # the critics see the policy's actions times this (buffer alike)
    target_entropy: float | None = None  # --alpha auto: of E[-ln_q pi]; None: the default
    log_density_floor: float = LOG_DENSITY_FLOOR  # maths.lnq_of_policy
    jacobian_clip: float = 0.0  # maths.squashed_gaussian
    gaussian_eps: float = 0.0  # maths.squashed_gaussian
    bf16_products: bool = False  # --matmul-precision bf16 (networks.linear)


class TacLosses(NamedTuple):
    """Per-member losses, each ``(K,)``, and ``(K, len(DIAGNOSTICS))`` detached diagnostics;
    with a learned alpha its loss and the alpha in force ``(K,)`` (maths.ALPHA_METRICS)."""

    q1: torch.Tensor
    q2: torch.Tensor
    v: torch.Tensor
    pi: torch.Tensor
    diagnostics: torch.Tensor
    alpha: torch.Tensor | None = None
    alpha_in_force: torch.Tensor | None = None


def _policy_sample(
    policy: Layers, obs: torch.Tensor, eps: torch.Tensor, s: LossSettings
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """a ~ pi(.|s) by the reparameterisation trick: the action, its per-dimension log-density
    and the policy's standard deviation."""
    mu, log_std = policy_head(
        mlp(policy, obs, bf16=s.bf16_products), eps.shape[-1], s.log_std_min, s.log_std_max
    )
    std = log_std.exp()
    action, log_prob_dims = squashed_gaussian(
        mu, log_std, std, eps, s.jacobian_clip, s.gaussian_eps
    )
    return action, log_prob_dims, std


def tac_losses(
    nets: Networks,
    target: Layers,
    batch: Batch,
    eps: torch.Tensor,
    c: Coefficients,
    s: LossSettings,
    eps_next: torch.Tensor | None = None,
) -> TacLosses:
    """TAC's Q, V and policy losses on one minibatch (SAC v1 with ``log`` replaced by ``ln_q``).

    The buffer's actions are in the critics' units: the policy's [-1, 1], or with
    ``s.action_scale`` (the reference profile) times the action bound, as the policy's actions
    are before they reach a critic; densities are always those of the unscaled action.

    ``eps`` ``(K, B, A)`` is the standard normal noise of the reparameterised action. ``target``
    is the target V (K members) or, given ``eps_next`` (``critic_target`` twin-q, SAC v2's target
    of Haarnoja et al. 2018b), the target critic pair (2K), which then replaces the target V in
    the Q target by ``min(Q1-, Q2-)(s', a') - alpha ln_q pi(a'|s')``, a' ~ pi(.|s') drawn with
    ``eps_next``; there is no V loss then (reported as 0) and the ``v`` diagnostic is that soft
    value of s'. Each loss's graph reaches only the parameters it trains: Q losses -> Q1, Q2;
    V loss -> V; policy loss -> policy (the critics are evaluated there with frozen weights).
    """
    k = eps.shape[0]
    # --alpha auto: the learned alpha, as it is before this step's update of it (SB3 alike)
    alpha_in_force = c.alpha if nets.log_alpha is None else nets.log_alpha.detach().exp()
    alpha = alpha_in_force[:, None]
    # a~ ~ pi(.|s) by the reparameterisation trick, and ln_q pi(a~|s)
    new_action, log_prob_dims, std = _policy_sample(nets.policy, batch.obs, eps, s)
    lnq_pi = lnq_of_policy(log_prob_dims, c, s.lnq, s.log_density_floor)

    # eqn:q_obj  J_theta = E[ 1/2 (Q_theta(s,a) - r - gamma V_psi-(s'))^2 ]; time-limit ends
    # are not terminal, so only a true terminal state drops the bootstrap (reference code).
    # twin-q: V_psi-(s') is replaced by the target critics' soft value of s' (SAC v2).
    with torch.no_grad():
        if eps_next is None:
            v_next = mlp(target, batch.next_obs, bf16=s.bf16_products).squeeze(-1)
        else:
            next_action, next_log_prob_dims, _ = _policy_sample(
                nets.policy, batch.next_obs, eps_next, s
            )
            next_action = next_action * s.action_scale
            pairs = torch.cat([batch.next_obs, next_action], dim=-1).repeat(2, 1, 1)
            q_next = mlp(target, pairs, bf16=s.bf16_products).view(2, k, -1)
            lnq_next = lnq_of_policy(next_log_prob_dims, c, s.lnq, s.log_density_floor)
            v_next = torch.minimum(q_next[0], q_next[1]) - alpha * lnq_next
        q_target = batch.reward + s.gamma * (1.0 - batch.terminated) * v_next
    # Q1 and Q2 are one stack of 2K critics: both evaluated at (s, a) at once
    q_pairs = torch.cat([batch.obs, batch.action], dim=-1).repeat(2, 1, 1)
    q_data = mlp(nets.critics, q_pairs, bf16=s.bf16_products)
    loss_q1, loss_q2 = (0.5 * (q_data.view(2, k, -1) - q_target).square().mean(dim=-1)).unbind()

    # eqn:pol_obj  J_phi = E[ alpha ln_q pi(a~|s) - Q(s, a~) ], with Q = Q1 (reference code),
    # its weights frozen: the gradient reaches a~, not Q1
    new_pairs = torch.cat([batch.obs, new_action * s.action_scale], dim=-1)
    q1_pi = mlp(
        nets.critics.members(slice(0, k)), new_pairs, frozen=True, bf16=s.bf16_products
    ).squeeze(-1)
    loss_pi = (alpha * lnq_pi - q1_pi).mean(dim=-1)

    # eqn:v_obj  J_psi = E[ 1/2 (y - V_psi(s))^2 ], y = min(Q1, Q2)(s, a~) - alpha ln_q pi(a~|s)
    # with a~ drawn from the current policy (reference code; the paper's a_t is ambiguous).
    if eps_next is None:
        with torch.no_grad():
            q2_pi = mlp(
                nets.critics.members(slice(k, 2 * k)), new_pairs, bf16=s.bf16_products
            ).squeeze(-1)
            v_target_value = torch.minimum(q1_pi, q2_pi) - alpha * lnq_pi
        v_value = mlp(nets.v, batch.obs, bf16=s.bf16_products).squeeze(-1)
        loss_v = 0.5 * (v_value - v_target_value).square().mean(dim=-1)
    else:
        v_value, loss_v = v_next, torch.zeros_like(loss_q1)

    # --alpha auto, SAC v2's temperature loss (Haarnoja et al. 2018b, eq. 18, on log alpha as
    # stable-baselines3 does): J(alpha) = E[-log alpha (ln_q pi(a~|s) + H_target)], with ln_q in
    # place of log and H_target the target of E[-ln_q pi] (default: maths.default_lnq_target)
    loss_alpha = None
    if nets.log_alpha is not None:
        if s.target_entropy is None:
            entropy_target = -default_lnq_target(c, eps.shape[-1], s.lnq)[:, None]
        else:
            entropy_target = torch.full_like(lnq_pi[:, :1], s.target_entropy)
        loss_alpha = -(nets.log_alpha * (lnq_pi.detach() + entropy_target).mean(dim=-1))

    with torch.no_grad():
        diagnostics = torch.stack(
            [
                log_prob_dims.sum(dim=-1).mean(dim=-1),
                lnq_pi.mean(dim=-1),
                q1_pi.mean(dim=-1),
                v_value.mean(dim=-1),
                std.mean(dim=(-2, -1)),
            ],
            dim=-1,
        )
    return TacLosses(loss_q1, loss_q2, loss_v, loss_pi, diagnostics, loss_alpha, alpha_in_force)
