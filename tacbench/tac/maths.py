"""The formulas of TAC's losses below the losses themselves (:mod:`tacbench.tac.losses`): the
squashed Gaussian's density, ln_q, the q >= 2 cap, the log-std mapping, and the order of the
metrics an update reports. The agent's ``act`` and the losses take them from here.

Shapes: K members, B samples, A action dimensions. Every per-member quantity (q, alpha, the
density cap) is a tensor with a leading K, so members with different q or alpha share one
batched computation and one compiled graph: the q = 1 case and the q >= 2 cap are selected per
member with ``torch.where`` and ``clamp``, never by a Python branch.

Paper references are to the appendix "Implementation Detail" of ``tsallis-rl-paper.tex``: the
"Reparameterization Trick" (density of the squashed Gaussian) and the "Numerical Issue" (the
density cap for q >= 2). Where the paper is silent the reference code decides (REFERENCE.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import torch
import torch.nn.functional as F

from tacbench.paper import density_log_cap

LOG_DENSITY_FLOOR = math.log(1e-6)  # reference code: each per-dimension density >= 1e-6
JACOBIAN_EPS = 1e-6  # SAC v1 and reference code: log(1 - tanh(z)^2 + 1e-6)
JACOBIAN_EPS_LOG = math.log(JACOBIAN_EPS)
HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)

LOSSES = ("loss_q1", "loss_q2", "loss_v", "loss_pi")
# Diagnostics written to losses.csv besides the four losses (means over the batch).
DIAGNOSTICS = ("log_pi", "lnq_pi", "q1_pi", "v", "std")
METRICS = LOSSES + DIAGNOSTICS  # the columns of an update's metrics, (K, len(METRICS))
# with a learned alpha (--alpha auto): the alpha in force and its loss, appended to METRICS
ALPHA_METRICS = ("alpha", "loss_alpha")


class Batch(NamedTuple):
    """A member-batched minibatch; actions are in the critics' units (losses.LossSettings)."""

    obs: torch.Tensor  # (K, B, obs_dim)
    action: torch.Tensor  # (K, B, A)
    reward: torch.Tensor  # (K, B)
    next_obs: torch.Tensor  # (K, B, obs_dim)
    terminated: torch.Tensor  # (K, B), 1.0 where s' is terminal (never for a time-limit end)


class Coefficients(NamedTuple):
    """Each member's entropic index and entropy coefficient, as ``(K,)`` float32 tensors.

    ``q_minus_one`` is computed in float64 before the cast (``q - 1`` of a float32 q would round
    differently, e.g. for q = 1.2); ``log_cap`` is :func:`density_log_cap`.
    """

    q_minus_one: torch.Tensor
    log_cap: torch.Tensor
    alpha: torch.Tensor


def coefficients(
    qs: Sequence[float], alphas: Sequence[float], device: torch.device, cap_rule: str = "paper"
) -> Coefficients:
    """:class:`Coefficients` of members with entropic indices ``qs`` and coefficients
    ``alphas``, their density caps by ``cap_rule`` (:func:`density_log_cap`), on ``device`` (the
    copy does not wait for the device)."""

    def tensor(values: Sequence[float]) -> torch.Tensor:
        return torch.tensor(values, dtype=torch.float32).to(device, non_blocking=True)

    return Coefficients(
        tensor([q - 1.0 for q in qs]),
        tensor([density_log_cap(q, cap_rule) for q in qs]),
        tensor(list(alphas)),
    )


def log_std_from_tanh(
    tanh_raw: torch.Tensor, log_std_min: float, log_std_max: float
) -> torch.Tensor:
    """The policy's log standard deviation from the tanh of its raw head output, rescaled to
    ``[log_std_min, log_std_max]`` (reference code)."""
    return log_std_min + 0.5 * (log_std_max - log_std_min) * (tanh_raw + 1.0)


def squashed_gaussian(
    mu: torch.Tensor,
    log_std: torch.Tensor,
    std: torch.Tensor,
    eps: torch.Tensor,
    jacobian_clip: float = 0.0,
    gaussian_eps: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparameterised action ``a = tanh(mu + eps * sigma)`` and ``log pi_i(a_i|s)`` per dimension.

    Paper, "Reparameterization Trick": ``pi(a|s) = N(z; mu, sigma) |da/dz|^-1``. The paper prints
    the Jacobian as ``prod_i (1 - tanh(z_i))``; the correct one (as in SAC) is
    ``prod_i (1 - tanh(z_i)^2)``. Each factor gets SAC v1's (and the reference code's) ``+ 1e-6``,
    which bounds a saturated dimension's log-density increase at ``-log(1e-6)``; its log is
    ``logaddexp(log(1 - tanh(z)^2), log 1e-6)`` with ``log(1 - tanh(z)^2)`` computed stably as
    ``2 (log 2 - z - softplus(-2 z))``. ``std`` is ``log_std.exp()``, passed in because the
    caller reports it too.

    Two options reproduce versions of the authors' code (docs/authors-versions.md):
    ``jacobian_clip`` > 0 raises ``1 - tanh(z)^2`` to at least that value before the ``+ 1e-6``,
    passing the gradient straight through (Spinning Up's ``clip_but_pass_gradient``);
    ``gaussian_eps`` > 0 standardises ``z - mu`` by ``sigma + gaussian_eps`` instead of
    ``sigma`` (Spinning Up's ``gaussian_likelihood``), which matters only for sigma near it.
    """
    z = mu + eps * std
    log_jacobian = 2.0 * (math.log(2.0) - z - F.softplus(-2.0 * z))
    if jacobian_clip > 0.0:
        jacobian = log_jacobian.exp()
        raised = jacobian + (jacobian.clamp(min=jacobian_clip) - jacobian).detach()
        log_jacobian_eps = torch.log(raised + JACOBIAN_EPS)
    else:
        log_jacobian_eps = torch.logaddexp(
            log_jacobian, log_jacobian.new_full((), JACOBIAN_EPS_LOG)
        )
    standard = eps if gaussian_eps == 0.0 else eps * std / (std + gaussian_eps)
    log_prob_dims = (-0.5 * standard.square() - log_std - HALF_LOG_2PI) - log_jacobian_eps
    return torch.tanh(z), log_prob_dims


def log_q_of_log(log_p: torch.Tensor, q_minus_one: torch.Tensor) -> torch.Tensor:
    """``ln_q(p)`` from ``log p``, differentiably, per member.

    ``ln_q(p) = expm1((q-1) log p) / (q-1)`` (:func:`tacbench.theory.tsallis.log_q`), ``log p``
    itself where q = 1; ``q_minus_one`` broadcasts against ``log_p``. The density is never
    formed, only its log (it over- or underflows for peaked or many-dimensional policies).
    """
    is_one = q_minus_one == 0.0
    # the branch that q = 1 does not take gets finite inputs, so that autograd's zero gradient
    # through it stays zero (no 0/0, no 0 * inf from expm1 of a large log p)
    safe = torch.where(is_one, 1.0, q_minus_one)
    e = torch.expm1(safe * torch.where(is_one, 0.0, log_p))
    return torch.where(is_one, log_p, e / safe)


def per_member(values: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``(K,)`` values shaped to broadcast against a ``(K, ...)`` tensor ``like``."""
    return values.view(-1, *([1] * (like.dim() - 1)))


def lnq_of_policy(
    log_prob_dims: torch.Tensor,
    c: Coefficients,
    lnq: str,
    log_floor: float = LOG_DENSITY_FLOOR,
) -> torch.Tensor:
    """``ln_q pi(a|s)`` ``(K, B)`` from per-dimension log-densities ``(K, B, A)``.

    ``joint`` (paper): ln_q of the joint density ``exp(sum_i log pi_i)``. ``per-dim`` (reference
    code): ``sum_i ln_q(pi_i)``, each pi_i floored at ``exp(log_floor)``. ``joint-batch-max``
    (the authors' code of 2019-01-07, 3c5cf2b): ln_q of the joint density divided by the largest
    in the minibatch (each member's B rows; the maximum is differentiated too), floored alike.
    All equal ``log pi`` at q = 1 (the floored forms where no density is below the floor) but
    the last, which is ``log pi`` minus the batch's largest.
    Each density is capped at ``exp(c.log_cap)`` (:func:`density_log_cap`) before the floor,
    so for q >= 2 each density's ``ln_q <= (10^8 - 1)/(q-1)`` (per-dim: A times that). A clamp
    passes the gradient only inside its bounds.
    """
    if lnq == "per-dim":
        log_densities = log_prob_dims
    else:
        log_densities = log_prob_dims.sum(dim=-1)
        if lnq == "joint-batch-max":
            log_densities = log_densities - log_densities.amax(dim=-1, keepdim=True)
    capped = log_densities.clamp(max=per_member(c.log_cap, log_densities))
    if lnq != "joint":
        capped = capped.clamp(min=log_floor)
    lnq_values = log_q_of_log(capped, per_member(c.q_minus_one, capped))
    return lnq_values.sum(dim=-1) if lnq == "per-dim" else lnq_values


def default_lnq_target(c: Coefficients, act_dim: int, lnq: str) -> torch.Tensor:
    """The default target of E[ln_q pi] of ``--alpha auto``, per member ``(K,)``: ln_q of the
    policy whose every dimension has log-density 1, i.e. the density that SAC's target entropy
    -dim(A) implies (E[log pi] = dim(A)). Per-dimension form: ``A ln_q(e)``; joint form:
    ``ln_q(e^A)``; both ``A`` at q = 1, where the target entropy is SAC v2's ``-dim(A)``.
    Computed with :func:`lnq_of_policy` itself, the formula the loss compares it with."""
    ones = c.q_minus_one.new_ones(c.q_minus_one.shape[0], 1, act_dim)
    return lnq_of_policy(ones, c, lnq)[:, 0]
