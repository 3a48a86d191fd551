"""Sizes an argument can make arbitrarily large, checked against this machine before anything
is written: the memory a run's networks, minibatches and replay buffer or a report's bootstrap
will need (estimated from the flags, refused with the estimate when it exceeds the machine's
memory) and a thread count above the machine's cores."""

from __future__ import annotations

import itertools
import os
from collections.abc import Mapping, Sequence

from tacbench.errors import TacbenchError

FLOAT32 = 4
GiB = 1 << 30
# an update's activations: each network runs forward about four times (the batch, the next
# states, the policy's actions, the target), and autograd keeps each layer's output, its
# pre-activation and its gradient (about three copies of each)
ACTIVATION_COPIES = 4 * 3
# parameters, gradients and Adam's two moments, plus a target copy
PARAMETER_COPIES = 5
# one evaluation episode's records until its row is written: its seed, return and length as
# NumPy values and as the Python numbers the row is made from
EVAL_EPISODE_BYTES = 3 * (8 + 32)


def evaluation_bytes(episodes: int, members: int = 1) -> int:
    """What one evaluation of ``episodes`` episodes per member holds beside its environments
    (a bounded pool, :func:`tacbench.envs.eval_pool_size`)."""
    return members * episodes * EVAL_EPISODE_BYTES


def machine_memory() -> int:
    """This machine's physical memory in bytes."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def mlp_parameters(sizes: Sequence[int]) -> int:
    """Weights and biases of a ``sizes[0] -> ... -> sizes[-1]`` MLP."""
    return sum(a * b + b for a, b in itertools.pairwise(sizes))


def actor_critic_bytes(
    obs_dim: int,
    act_dim: int,
    hidden: Sequence[int],
    batch_size: int,
    members: int = 1,
    *,
    value_network: bool = True,
) -> dict[str, int]:
    """An actor-critic's networks (a Gaussian policy, a pair of Q critics and, with
    ``value_network``, TAC's V) and one update's activations, in bytes, for ``members``
    members."""
    widths = list(hidden)
    parameters = (
        mlp_parameters([obs_dim, *widths, 2 * act_dim])
        + 2 * mlp_parameters([obs_dim + act_dim, *widths, 1])
        + (mlp_parameters([obs_dim, *widths, 1]) if value_network else 0)
    )
    networks = 4 if value_network else 3
    activations = batch_size * (sum(widths) + obs_dim + act_dim) * networks * ACTIVATION_COPIES
    return {
        "networks": members * parameters * PARAMETER_COPIES * FLOAT32,
        "an update's activations": members * activations * FLOAT32,
    }


def check_fits(needs: Mapping[str, int], flags: str, what: str = "this run") -> None:
    """Refuse (TacbenchError) ``what`` when the sum of ``needs`` (bytes by part) exceeds this
    machine's memory, naming the parts and the ``flags`` that size them."""
    total, available = sum(needs.values()), machine_memory()
    if total <= available:
        return
    parts = ", ".join(f"{name} {size / GiB:,.1f} GiB" for name, size in needs.items())
    raise TacbenchError(
        f"{what} would need about {total / GiB:,.1f} GiB ({parts}), more than this machine's "
        f"{available / GiB:,.1f} GiB; make {flags} smaller."
    )


def check_threads(threads: int) -> None:
    """Refuse more torch threads than this machine has cores: they only wait for each other."""
    cores = os.cpu_count() or 1
    if threads > cores:
        raise TacbenchError(
            f"--threads {threads} is more than this machine's {cores} cores; use at most {cores} "
            "(threads beyond the cores slow a run down)."
        )
