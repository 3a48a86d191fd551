"""The fused TAC update: :func:`tacbench.tac.losses.tac_losses` and its gradients, by hand.

Same maths as the eager path (losses.py stays the reference; tests compare the two on the same
batch), organised for speed on small networks, where the eager path spends its time in
autograd's bookkeeping, Adam's per-parameter loop and small-kernel dispatch:

* no autograd: the forward pass keeps what the backward pass needs, and the gradients are
  written out by hand, straight into the flat gradient buffer (``tacbench.tac.flat``);
* Q1 and Q2 are one member stack of 2K networks, evaluated once on 2B rows per member that
  hold both the buffer actions ``(s, a)`` and the reparameterised ones ``(s, a~)``; the ``(s, a~)``
  half serves the V target (no gradient) and the policy loss (gradient to a~ only), so
  ``Q1(s, a~)`` is computed once where the eager path computes it twice;
* layers with one output (the value heads) use a multiply-and-sum instead of a batched
  matrix-vector product, which MKL runs several times slower for K > 1;
* one fused Adam call on the whole buffer, and one ``lerp_`` for the target V.

Gradients, per member k with weight ``w_k = alive_k / B`` (the losses are means over B):
Q loss ``dL/dQ_i(s,a) = w (Q_i(s,a) - y_q)``; V loss ``dL/dV(s) = w (V(s) - y_v)``; policy loss
``dL/d a~ = -w dQ1/da~`` and ``dL/d log pi_i = w alpha d ln_q/d log pi_i``, then through
``a~ = tanh(z)``, ``z = mu + eps sigma``, ``log pi_i = log N(z_i) - log(1 - tanh(z_i)^2 + 1e-6)``
(``d/dz = 2 tanh(z) (1 - tanh^2) / (1 - tanh^2 + 1e-6)``) and the log_std head.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F

from tacbench.tac.losses import (
    _HALF_LOG_2PI,
    JACOBIAN_EPS_LOG,
    LOG_DENSITY_FLOOR,
    Batch,
)

# ReLU's backward, g where the ReLU's output is > 0 (the overload itself: no per-call lookup)
_threshold_backward = torch.ops.aten.threshold_backward.default


class Layers(NamedTuple):
    """M stacked MLPs, layer by layer: weights ``(M, in, out)`` and biases ``(M, 1, out)``."""

    weights: list[torch.Tensor]
    biases: list[torch.Tensor]


class FusedNets(NamedTuple):
    """Parameter views of the agent's networks (or their gradients) for the fused update."""

    policy: Layers  # K members
    critics: Layers  # 2K: the K members of Q1, then the K members of Q2
    v: Layers  # K members


class TacScalars(NamedTuple):
    """The constants of one update (:func:`tac_scalars`).

    q enters as 0-d tensors, ``q - 1`` and the log of the density cap, and two flags (q = 1;
    q >= 2, where the paper's cap applies) select the code. So ``torch.compile`` compiles at most
    three variants and never specialises on q's value, which a linear q schedule changes at every
    step (and which, left as a Python float, compiled to wrong caps for q >= 2 in torch 2.13).
    """

    q_minus_one: torch.Tensor
    log_cap: torch.Tensor
    q_is_one: bool
    capped: bool
    alpha: float
    gamma: float
    lnq: str
    log_std_min: float
    log_std_max: float


def tac_scalars(
    q: float,
    alpha: float,
    gamma: float,
    lnq: str,
    log_std_min: float,
    log_std_max: float,
    device: torch.device,
) -> TacScalars:
    """:class:`TacScalars` for entropic index ``q``; the cap is ``10^(8/(q-1))`` for q >= 2
    (paper, "Numerical Issue"; losses.lnq_of_policy)."""
    capped = q >= 2.0
    log_cap = 8.0 * math.log(10.0) / (q - 1.0) if capped else math.inf
    return TacScalars(
        torch.tensor(q - 1.0).to(device, non_blocking=True),  # no stream synchronisation
        torch.tensor(log_cap).to(device, non_blocking=True),
        q == 1.0,
        capped,
        alpha,
        gamma,
        lnq,
        log_std_min,
        log_std_max,
    )


def _linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``x @ weight + bias`` for stacked MLPs; a width-1 layer as multiply-and-sum. Under
    ``torch.compile`` the bias is added after the product, where Inductor fuses it into the next
    elementwise kernel (``baddbmm`` first copies the broadcast bias into the output)."""
    if weight.shape[-1] == 1:
        return torch.linalg.vecdot(x, weight.transpose(1, 2)).unsqueeze(-1).add_(bias)
    if torch.compiler.is_compiling():
        return torch.bmm(x, weight) + bias
    return torch.baddbmm(bias, x, weight)


def _linear_input_grad(grad: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``grad @ weight^T``: the gradient at a layer's input; width 1 as a broadcast product."""
    if weight.shape[-1] == 1:
        return grad * weight.transpose(1, 2)
    return torch.bmm(grad, weight.transpose(1, 2))


def forward(net: Layers, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """The output of ReLU MLPs ``(M, B, in) -> (M, B, out)`` and the input of every layer."""
    inputs = []
    last = len(net.weights) - 1
    for i, (weight, bias) in enumerate(zip(net.weights, net.biases, strict=True)):
        inputs.append(x)
        x = _linear(x, weight, bias)
        if i < last:
            x = x.relu_()
    return x, inputs


def backward(
    net: Layers, grads: Layers, inputs: list[torch.Tensor], grad_out: torch.Tensor
) -> None:
    """Write into ``grads`` the weight and bias gradients given the gradient at the output and
    the layer inputs of :func:`forward` (only their first ``grad_out.shape[1]`` rows are used)."""
    rows = grad_out.shape[1]
    g = grad_out
    for i in reversed(range(len(net.weights))):
        x = inputs[i][:, :rows]
        weight_grad = grads.weights[i]
        if weight_grad.shape[-1] == 1:  # (M, in, 1) has the memory layout of (M, 1, in)
            torch.bmm(g.transpose(1, 2), x, out=weight_grad.view(weight_grad.shape[0], 1, -1))
        else:
            torch.bmm(x.transpose(1, 2), g, out=weight_grad)
        torch.sum(g, dim=1, keepdim=True, out=grads.biases[i])
        if i:
            g = _threshold_backward(_linear_input_grad(g, net.weights[i]), x, 0)


def _log_q(log_p: torch.Tensor, c: TacScalars) -> tuple[torch.Tensor, torch.Tensor | None]:
    """``ln_q`` from the log (tacbench.tsallis.log_q_of_log) and its slope ``d ln_q / d log p
    = p^(q-1)`` (None for 1 at q = 1)."""
    if c.q_is_one:
        return log_p, None
    e = torch.expm1(c.q_minus_one * log_p)
    return e / c.q_minus_one, e + 1.0


class _Sample(NamedTuple):
    """a~ = tanh(mu + eps sigma) and what its log-density and gradients need."""

    action: torch.Tensor
    std: torch.Tensor
    tanh_raw: torch.Tensor
    log_jacobian: torch.Tensor
    log_jacobian_eps: torch.Tensor
    log_prob_dims: torch.Tensor


def _sample(out: torch.Tensor, eps: torch.Tensor, c: TacScalars) -> _Sample:
    """The reparameterised action from the policy's output ``(mu, raw)`` and its per-dimension
    log-density (losses.squashed_gaussian_sample)."""
    act_dim = eps.shape[-1]
    mu, raw = out[..., :act_dim], out[..., act_dim:]
    tanh_raw = torch.tanh(raw)
    span = c.log_std_max - c.log_std_min
    log_std = c.log_std_min + 0.5 * span * (tanh_raw + 1.0)
    std = log_std.exp()
    z = mu + eps * std
    log_jacobian = 2.0 * (math.log(2.0) - z - F.softplus(-2.0 * z))
    log_jacobian_eps = torch.logaddexp(log_jacobian, log_jacobian.new_full((), JACOBIAN_EPS_LOG))
    log_prob_dims = (-0.5 * eps.square() - log_std - _HALF_LOG_2PI) - log_jacobian_eps
    return _Sample(torch.tanh(z), std, tanh_raw, log_jacobian, log_jacobian_eps, log_prob_dims)


def _lnq(
    log_prob_dims: torch.Tensor, c: TacScalars, scale: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``ln_q pi`` ``(K, B)`` (losses.lnq_of_policy) and the gradient of ``scale * ln_q pi``
    with respect to each log pi_i ``(K, B, A)``; clamp passes the gradient only inside its
    bounds."""
    cap = c.log_cap if c.capped else None
    if c.lnq == "joint":
        log_prob = log_prob_dims.sum(dim=-1)
        lnq_pi, slope = _log_q(log_prob if cap is None else log_prob.clamp(max=cap), c)
        grad_log_prob = scale if slope is None else slope * scale
        if cap is not None:
            grad_log_prob = grad_log_prob * (log_prob <= cap)
        return lnq_pi, grad_log_prob.unsqueeze(-1)
    floored = log_prob_dims.clamp(min=LOG_DENSITY_FLOOR)
    lnq_dims, slope = _log_q(floored if cap is None else floored.clamp(max=cap), c)
    inside = log_prob_dims >= LOG_DENSITY_FLOOR
    if cap is not None:
        inside &= log_prob_dims <= cap
    grad_log_prob_dims = scale.unsqueeze(-1) * inside
    if slope is not None:
        grad_log_prob_dims = grad_log_prob_dims * slope
    return lnq_dims.sum(dim=-1), grad_log_prob_dims


def _for_both_critics(pairs: torch.Tensor) -> torch.Tensor:
    """``(K, R, in)`` inputs repeated for the 2K-member critic pair: ``(2K, R, in)``."""
    n_members, rows, width = pairs.shape
    return pairs.expand(2, n_members, rows, width).reshape(-1, rows, width)


def _soft_value(
    policy: Layers,
    target_critics: Layers,
    next_obs: torch.Tensor,
    eps_next: torch.Tensor,
    c: TacScalars,
    w: torch.Tensor,
) -> torch.Tensor:
    """twin-q's value of s': ``min(Q1-, Q2-)(s', a') - alpha ln_q pi(a'|s')``, a' ~ pi(.|s')."""
    sample = _sample(forward(policy, next_obs)[0], eps_next, c)
    lnq_next, _ = _lnq(sample.log_prob_dims, c, w)
    pairs = torch.cat([next_obs, sample.action], dim=-1)
    q_next = forward(target_critics, _for_both_critics(pairs))[0].view(2, *eps_next.shape[:2])
    return torch.minimum(q_next[0], q_next[1]) - c.alpha * lnq_next


def fused_gradients(
    nets: FusedNets,
    grads: FusedNets,
    v_target: Layers,
    batch: Batch,
    eps: torch.Tensor,
    alive: torch.Tensor,
    c: TacScalars,
    target_critics: Layers | None = None,
    eps_next: torch.Tensor | None = None,
) -> torch.Tensor:
    """TAC's losses on one minibatch with their gradients written into ``grads``.

    With ``target_critics`` (``critic_target`` twin-q: the 2K target critics, and ``eps_next``,
    the noise of a' ~ pi(.|s')) the Q target uses their soft value of s' instead of the target
    V, and V gets no gradient (its loss is reported as 0, its value as that soft value).

    Returns the per-member metrics ``(K, 9)``: the Q1, Q2, V and policy losses, then
    ``losses.DIAGNOSTICS``, as ``TacAgent.update`` reports them. Members with ``alive`` False
    get zero gradients (a non-finite member gets non-finite ones, as in the eager path; members
    never mix).
    """
    n_members, batch_size, _ = eps.shape
    obs_dim = batch.obs.shape[-1]
    if (target_critics is None) != (eps_next is None):
        raise ValueError("twin-q needs both the target critics and eps_next")
    w = (alive.to(eps.dtype) / batch_size)[:, None]  # (K, 1): d mean / d sample, 0 if dead

    # a~ ~ pi(.|s) by the reparameterisation trick, and ln_q pi(a~|s)
    out, policy_inputs = forward(nets.policy, batch.obs)
    sample = _sample(out, eps, c)
    new_action, std, log_prob_dims = sample.action, sample.std, sample.log_prob_dims
    lnq_pi, grad_log_prob_dims = _lnq(log_prob_dims, c, c.alpha * w)

    # Q1 and Q2 (2K members) on (s, a) and (s, a~) at once: rows :B and B: of a (2K, 2B) batch
    pairs = torch.cat(
        [
            torch.cat([batch.obs, batch.obs], dim=1),
            torch.cat([batch.action, new_action], dim=1),
        ],
        dim=-1,
    )
    q_out, critic_inputs = forward(nets.critics, _for_both_critics(pairs))
    q_values = q_out.view(2, n_members, 2 * batch_size)
    q_data, q_new = q_values[..., :batch_size], q_values[..., batch_size:]

    # eqn:q_obj, with the target V's value of s' (or, twin-q, the target critics' soft value of
    # s'); only a true terminal drops the bootstrap
    if target_critics is None or eps_next is None:
        v_next = forward(v_target, batch.next_obs)[0].squeeze(-1)
    else:
        v_next = _soft_value(nets.policy, target_critics, batch.next_obs, eps_next, c, w)
    q_target = batch.reward + c.gamma * (1.0 - batch.terminated) * v_next
    q_error = q_data - q_target  # (2, K, B)
    loss_q = 0.5 * q_error.square().mean(dim=-1)

    # eqn:v_obj, y = min(Q1, Q2)(s, a~) - alpha ln_q pi(a~|s); no V network with twin-q
    if target_critics is None:
        v_out, v_inputs = forward(nets.v, batch.obs)
        v_value = v_out.squeeze(-1)
        v_error = v_value - (torch.minimum(q_new[0], q_new[1]) - c.alpha * lnq_pi)
        loss_v = 0.5 * v_error.square().mean(dim=-1)
    else:
        v_value, loss_v = v_next, torch.zeros_like(loss_q[0])

    # eqn:pol_obj, alpha ln_q pi(a~|s) - Q1(s, a~) with Q1's weights frozen
    q1_new = q_new[0]
    loss_pi = (c.alpha * lnq_pi - q1_new).mean(dim=-1)

    # gradients of the Q and V losses reach only their own networks' weights
    backward(nets.critics, grads.critics, critic_inputs, (q_error * w).view(-1, batch_size, 1))
    if target_critics is None:
        backward(nets.v, grads.v, v_inputs, (v_error * w).unsqueeze(-1))

    # the policy loss: dL/da~ through Q1 (frozen: its input gradient only), then the sample
    g = (-w).unsqueeze(-1).expand(n_members, batch_size, 1)
    for i in reversed(range(len(nets.critics.weights))):
        weight = nets.critics.weights[i][:n_members]
        if i:
            g = _threshold_backward(
                _linear_input_grad(g, weight), critic_inputs[i][:n_members, batch_size:], 0
            )
        else:
            grad_new_action = torch.bmm(g, weight[:, obs_dim:].transpose(1, 2))
    grad_z = torch.addcmul(
        grad_new_action * (1.0 - new_action.square()),
        grad_log_prob_dims,
        2.0 * new_action * (sample.log_jacobian - sample.log_jacobian_eps).exp(),
    )
    grad_log_std = torch.addcmul(-grad_log_prob_dims, grad_z, eps * std)
    span = c.log_std_max - c.log_std_min
    grad_raw = grad_log_std * (0.5 * span) * (1.0 - sample.tanh_raw.square())
    backward(nets.policy, grads.policy, policy_inputs, torch.cat([grad_z, grad_raw], dim=-1))

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
            std.mean(dim=(-2, -1)),
        ],
        dim=-1,
    )
