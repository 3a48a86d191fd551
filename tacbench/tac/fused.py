"""The fused TAC update: :func:`tacbench.tac.losses.tac_losses` and its gradients, by hand.

Same maths as the eager path (losses.py stays the reference; tests compare the two on the same
batch; the formulas both compute come from :mod:`tacbench.tac.maths`), organised for speed on
small networks, where the eager path spends its time in autograd's bookkeeping and small-kernel
dispatch:

* no autograd: the forward pass keeps what the backward pass needs, and the gradients are
  written out by hand, straight into the flat gradient buffer (``tacbench.tac.parameters``);
* Q1 and Q2 are one member stack of 2K networks, evaluated once on 2B rows per member that
  hold both the buffer actions ``(s, a)`` and the reparameterised ones ``(s, a~)``; the ``(s, a~)``
  half serves the V target (no gradient) and the policy loss (gradient to a~ only).

Gradients, per member k with weight ``w_k = alive_k / B`` (the losses are means over B):
Q loss ``dL/dQ_i(s,a) = w (Q_i(s,a) - y_q)``; V loss ``dL/dV(s) = w (V(s) - y_v)``; policy loss
``dL/d a~ = -w dQ1/da~`` and ``dL/d log pi_i = w alpha d ln_q/d log pi_i``, then through
``a~ = tanh(z)``, ``z = mu + eps sigma``, ``log pi_i = log N(z_i) - log(1 - tanh(z_i)^2 + 1e-6)``
(``d/dz = 2 tanh(z) (1 - tanh^2) / (1 - tanh^2 + 1e-6)``) and the log_std head.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from tacbench.tac.losses import LossSettings
from tacbench.tac.maths import (
    Batch,
    Coefficients,
    SquashedSample,
    lnq_of_policy,
    log_std_from_tanh,
    squashed_gaussian,
)
from tacbench.tac.networks import (
    Layers,
    linear_input_grad,
    mlp_backward,
    mlp_with_inputs,
    relu_backward,
)
from tacbench.tac.parameters import Networks


class _Sample(NamedTuple):
    """a~ ~ pi(.|s), its per-dimension log-density, and what the policy's gradient needs."""

    squashed: SquashedSample
    std: torch.Tensor
    tanh_raw: torch.Tensor  # tanh of the raw log_std head, for the head's gradient


def _sample(out: torch.Tensor, eps: torch.Tensor, s: LossSettings) -> _Sample:
    """The reparameterised action from the policy's output ``(mu, raw)``."""
    act_dim = eps.shape[-1]
    mu, raw = out[..., :act_dim], out[..., act_dim:]
    tanh_raw = torch.tanh(raw)
    log_std = log_std_from_tanh(tanh_raw, s.log_std_min, s.log_std_max)
    std = log_std.exp()
    return _Sample(squashed_gaussian(mu, log_std, std, eps), std, tanh_raw)


def _for_both_critics(pairs: torch.Tensor) -> torch.Tensor:
    """``(K, R, in)`` inputs repeated for the 2K-member critic pair: ``(2K, R, in)``."""
    n_members, rows, width = pairs.shape
    return pairs.expand(2, n_members, rows, width).reshape(-1, rows, width)


def _soft_value(
    policy: Layers,
    target_critics: Layers,
    next_obs: torch.Tensor,
    eps_next: torch.Tensor,
    c: Coefficients,
    s: LossSettings,
) -> torch.Tensor:
    """twin-q's value of s': ``min(Q1-, Q2-)(s', a') - alpha ln_q pi(a'|s')``, a' ~ pi(.|s')."""
    sample = _sample(mlp_with_inputs(policy, next_obs)[0], eps_next, s).squashed
    lnq_next, _ = lnq_of_policy(sample.log_prob_dims, c, s.lnq)
    pairs = torch.cat([next_obs, sample.action], dim=-1)
    q_next = mlp_with_inputs(target_critics, _for_both_critics(pairs))[0]
    q_next = q_next.view(2, *eps_next.shape[:2])
    return torch.minimum(q_next[0], q_next[1]) - c.alpha[:, None] * lnq_next


def fused_gradients(
    nets: Networks,
    grads: Networks,
    target: Layers,
    batch: Batch,
    eps: torch.Tensor,
    alive: torch.Tensor,
    c: Coefficients,
    s: LossSettings,
    eps_next: torch.Tensor | None = None,
) -> torch.Tensor:
    """TAC's losses on one minibatch with their gradients written into ``grads``.

    ``target`` is the target V, or with ``eps_next`` (``critic_target`` twin-q, the noise of
    a' ~ pi(.|s')) the 2K target critics, whose soft value of s' then replaces the target V in
    the Q target; V gets no gradient then (its loss is reported as 0, its value as that soft
    value).

    Returns the per-member metrics ``(K, len(maths.METRICS))``. Members with ``alive`` False
    get zero gradients (a non-finite member gets non-finite ones, as in the eager path; members
    never mix).
    """
    n_members, batch_size, _ = eps.shape
    twin_q = eps_next is not None
    w = (alive.to(eps.dtype) / batch_size)[:, None]  # (K, 1): d mean / d sample, 0 if dead
    alpha = c.alpha[:, None]

    # a~ ~ pi(.|s) by the reparameterisation trick, and ln_q pi(a~|s)
    out, policy_inputs = mlp_with_inputs(nets.policy, batch.obs)
    sample = _sample(out, eps, s)
    new_action, log_prob_dims = sample.squashed.action, sample.squashed.log_prob_dims
    lnq_pi, lnq_slope = lnq_of_policy(log_prob_dims, c, s.lnq)
    grad_log_prob_dims = (alpha * w).unsqueeze(-1) * lnq_slope

    # Q1 and Q2 (2K members) on (s, a) and (s, a~) at once: rows :B and B: of a (2K, 2B) batch
    pairs = torch.cat(
        [
            torch.cat([batch.obs, batch.obs], dim=1),
            torch.cat([batch.action, new_action], dim=1),
        ],
        dim=-1,
    )
    q_out, critic_inputs = mlp_with_inputs(nets.critics, _for_both_critics(pairs))
    q_values = q_out.view(2, n_members, 2 * batch_size)
    q_data, q_new = q_values[..., :batch_size], q_values[..., batch_size:]

    # eqn:q_obj, with the target V's value of s' (or, twin-q, the target critics' soft value of
    # s'); only a true terminal drops the bootstrap
    if eps_next is None:
        v_next = mlp_with_inputs(target, batch.next_obs)[0].squeeze(-1)
    else:
        v_next = _soft_value(nets.policy, target, batch.next_obs, eps_next, c, s)
    q_target = batch.reward + s.gamma * (1.0 - batch.terminated) * v_next
    q_error = q_data - q_target  # (2, K, B)
    loss_q = 0.5 * q_error.square().mean(dim=-1)

    # eqn:v_obj, y = min(Q1, Q2)(s, a~) - alpha ln_q pi(a~|s); no V network with twin-q
    if not twin_q:
        v_out, v_inputs = mlp_with_inputs(nets.v, batch.obs)
        v_value = v_out.squeeze(-1)
        v_error = v_value - (torch.minimum(q_new[0], q_new[1]) - alpha * lnq_pi)
        loss_v = 0.5 * v_error.square().mean(dim=-1)
    else:
        v_value, loss_v = v_next, torch.zeros_like(loss_q[0])

    # eqn:pol_obj, alpha ln_q pi(a~|s) - Q1(s, a~) with Q1's weights frozen
    q1_new = q_new[0]
    loss_pi = (alpha * lnq_pi - q1_new).mean(dim=-1)

    # gradients of the Q and V losses reach only their own networks' weights
    mlp_backward(nets.critics, grads.critics, critic_inputs, (q_error * w).view(-1, batch_size, 1))
    if not twin_q:
        mlp_backward(nets.v, grads.v, v_inputs, (v_error * w).unsqueeze(-1))

    _policy_backward(
        nets, grads, policy_inputs, critic_inputs, sample, eps, grad_log_prob_dims, w, s
    )
    return torch.stack(
        [
            loss_q[0],
            loss_q[1],
            loss_v,
            loss_pi,
            log_prob_dims.sum(dim=-1).mean(dim=-1),
            lnq_pi.mean(dim=-1),
            q1_new.mean(dim=-1),
            v_value.mean(dim=-1),
            sample.std.mean(dim=(-2, -1)),
        ],
        dim=-1,
    )


def _policy_backward(
    nets: Networks,
    grads: Networks,
    policy_inputs: list[torch.Tensor],
    critic_inputs: list[torch.Tensor],
    sample: _Sample,
    eps: torch.Tensor,
    grad_log_prob_dims: torch.Tensor,
    w: torch.Tensor,
    s: LossSettings,
) -> None:
    """The policy loss's gradient into ``grads.policy``: ``dL/da~`` through Q1 (frozen: its
    input gradient only, on the ``(s, a~)`` rows of the critic pair's forward pass), then
    through the squashed sample and the log_std head."""
    n_members, batch_size, _ = eps.shape
    obs_dim = critic_inputs[0].shape[-1] - eps.shape[-1]
    g = (-w).unsqueeze(-1).expand(n_members, batch_size, 1)
    for i in reversed(range(1, len(nets.critics.weights))):
        weight = nets.critics.weights[i][:n_members]
        g = relu_backward(
            linear_input_grad(g, weight), critic_inputs[i][:n_members, batch_size:], 0
        )
    first = nets.critics.weights[0][:n_members]
    grad_new_action = torch.bmm(g, first[:, obs_dim:].transpose(1, 2))
    squashed = sample.squashed
    grad_z = torch.addcmul(
        grad_new_action * (1.0 - squashed.action.square()),
        grad_log_prob_dims,
        2.0 * squashed.action * (squashed.log_jacobian - squashed.log_jacobian_eps).exp(),
    )
    grad_log_std = torch.addcmul(-grad_log_prob_dims, grad_z, eps * sample.std)
    span = s.log_std_max - s.log_std_min
    grad_raw = grad_log_std * (0.5 * span) * (1.0 - sample.tanh_raw.square())
    mlp_backward(nets.policy, grads.policy, policy_inputs, torch.cat([grad_z, grad_raw], dim=-1))
