"""One TAC update for K members, behind one interface: the gradients (eager or fused, either
one optionally under ``torch.compile``), then one fused Adam step and the target average.

* ``eager`` (the reference): autograd, through ``torch.func.grad``, over
  :func:`tacbench.tac.losses.tac_losses`, the losses written once with the paper's equation
  labels. Adding a loss term is one edit there.
* ``fused`` (the default, docs/performance.md): :func:`tacbench.tac.fused.fused_gradients`, the
  same maths with the gradients written by hand, about twice as fast uncompiled on small
  networks. Tests compare it with ``eager`` on the same batch (float32 rounding).
* ``compile``: ``torch.compile`` of the chosen gradient function. On a CPU, Inductor turns the
  elementwise chains into a few C++ loops and, with its C++ wrapper, calls them from C++ (it
  needs a C++ compiler; the first update compiles for seconds to tens of seconds, cached on
  disk afterwards). q and alpha enter as per-member tensors, so one graph serves every q, a
  group of members with different q, and a q schedule, without recompiling. On a GPU it uses
  mode ``reduce-overhead`` (CUDA graphs) with the persistent buffers marked static. Where
  compilation fails, a warning says so and the uncompiled function runs instead.

Both paths write into the same flat gradient buffer (:class:`TacParameters`), so Adam and the
target update are shared, and a checkpoint is the same whichever path wrote it.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import torch

from tacbench.config import IMPLS
from tacbench.tac.fused import fused_gradients
from tacbench.tac.losses import LossSettings, tac_losses
from tacbench.tac.maths import Batch, Coefficients
from tacbench.tac.networks import Layers
from tacbench.tac.parameters import TacParameters

CPU_COMPILE_OPTIONS: dict[str, str | int | bool | Callable[..., Any]] = {
    # the C++ wrapper: 7% off the K = 1 update (HalfCheetah, Intel Xeon, in-process A/B)
    "cpp_wrapper": True,
    # Inductor unrolls reductions over at most 8 elements into scalar code by default; the sums
    # over the action dimensions (ln_q pi, log pi) then ran libm's scalar expm1 element by
    # element. Vectorised instead: 7% off the K = 10 compiled update, K = 1 unchanged (Intel
    # Xeon, in-process A/B, median of 40 paired rounds)
    "unroll_reductions_threshold": 1,
    # one planned pool for the intermediate buffers instead of an allocation for each, and no
    # re-check of the input sizes and strides, which Dynamo's guards have checked already: 13%
    # off the K = 1 compiled update, 11% off K = 10 (Intel Xeon, in-process A/B, median of 30
    # paired rounds)
    "memory_planning": True,
    "size_asserts": False,
    "alignment_asserts": False,
}

Gradients = Callable[..., torch.Tensor]


def eager_gradients(
    params: TacParameters,
    batch: Batch,
    eps: torch.Tensor,
    alive: torch.Tensor,
    c: Coefficients,
    s: LossSettings,
    eps_next: torch.Tensor | None = None,
) -> torch.Tensor:
    """The reference path: the gradient of :func:`tac_losses` summed over the live members, by
    autograd, written into ``params.grad``; returns the metrics ``(K, len(METRICS))``."""
    grad, metrics = _loss_gradient(
        params.data, params, params.target_networks, batch, eps, alive, c, s, eps_next
    )
    params.grad.copy_(grad)
    return metrics


def _total_loss(
    theta: torch.Tensor,
    params: TacParameters,
    target: Layers,
    batch: Batch,
    eps: torch.Tensor,
    alive: torch.Tensor,
    c: Coefficients,
    s: LossSettings,
    eps_next: torch.Tensor | None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The sum of the live members' four losses at parameters ``theta`` (``params.data``'s
    layout), and the detached metrics."""
    losses = tac_losses(params.views(theta), target, batch, eps, c, s, eps_next)
    per_member = torch.stack([losses.q1, losses.q2, losses.v, losses.pi], dim=-1)
    total = torch.where(alive, per_member.sum(dim=-1), 0.0).sum()
    return total, torch.cat([per_member.detach(), losses.diagnostics], dim=-1)


_loss_gradient = torch.func.grad(_total_loss, has_aux=True)


def _fused(
    params: TacParameters,
    batch: Batch,
    eps: torch.Tensor,
    alive: torch.Tensor,
    c: Coefficients,
    s: LossSettings,
    eps_next: torch.Tensor | None = None,
) -> torch.Tensor:
    """The fused path on ``params``' views (gradients written into ``params.grad``)."""
    return fused_gradients(
        params.networks, params.gradients, params.target_networks, batch, eps, alive, c, s, eps_next
    )


def _compiled(
    function: Gradients, device: torch.device, persistent: list[torch.Tensor]
) -> Gradients:
    """``function`` compiled for ``device`` on first use, or, where compilation fails, as is
    (with one warning)."""
    if device.type == "cuda":
        for tensor in persistent:
            torch._dynamo.mark_static_address(tensor)
        current = [torch.compile(function, mode="reduce-overhead")]
    else:
        current = [torch.compile(function, options=CPU_COMPILE_OPTIONS)]

    def gradients(*args: Any) -> torch.Tensor:
        try:
            return current[0](*args)
        except Exception as err:  # compilation failed: the same function, uncompiled
            if current[0] is function:
                raise
            warnings.warn(
                f"torch.compile of TAC's update failed ({type(err).__name__}: {err}); "
                "continuing without it",
                RuntimeWarning,
                stacklevel=2,
            )
            current[0] = function
            return function(*args)

    return gradients


class TacUpdate:
    """Gradients by ``impl`` (optionally compiled), one Adam step, the target average."""

    def __init__(
        self,
        params: TacParameters,
        settings: LossSettings,
        *,
        impl: str,
        compile: bool,
        learning_rate: float,
        tau: float,
    ) -> None:
        if impl not in IMPLS:
            raise ValueError(f"impl must be one of {IMPLS} (got {impl!r})")
        self.params, self.settings = params, settings
        self.learning_rate, self.tau = learning_rate, tau
        function: Gradients = _fused if impl == "fused" else eager_gradients
        if compile:
            persistent = [params.data, params.grad, params.target]
            function = _compiled(function, params.data.device, persistent)
        self._gradients = function

    def gradients(
        self,
        batch: Batch,
        eps: torch.Tensor,
        alive: torch.Tensor,
        c: Coefficients,
        eps_next: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The metrics ``(K, len(METRICS))`` of one minibatch, the gradient of every trained
        parameter written into ``params.grad``; no weight changes."""
        with torch.no_grad():
            return self._gradients(self.params, batch, eps, alive, c, self.settings, eps_next)

    def __call__(
        self,
        batch: Batch,
        eps: torch.Tensor,
        alive: torch.Tensor,
        c: Coefficients,
        eps_next: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """One update of every member: :meth:`gradients`, Adam, the target average."""
        metrics = self.gradients(batch, eps, alive, c, eps_next)
        with torch.no_grad():
            self.params.adam_step(self.learning_rate)
            self.params.update_target(self.tau)
        return metrics
