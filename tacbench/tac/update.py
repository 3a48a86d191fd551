"""One TAC update, top to bottom: the front door to the algorithm.

``tacbench run`` reaches :func:`update` in four hops (``cli/run.py`` -> ``trainers.py`` ->
``training/__init__.py`` -> ``training/loop.py``), once per environment step (or, in the episode
schedule, once per step of an episode that ended). Everything it calls is one level down:

- :mod:`tacbench.tac.losses`: every loss, once, with the paper's equation labels;
- :mod:`tacbench.tac.gradient`: their gradient by autograd, eager or compiled (``--compile``);
- :mod:`tacbench.tac.parameters`: the flat parameter buffers, Adam and the target average;
- :mod:`tacbench.tac.agent`: the members, their generators and how they are chunked.

K members update together, each on its own minibatch with its own noise, q and alpha; their
numbers never mix (each member's gradient is its own losses').
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt
import torch

from tacbench.tac.agent import Chunk, TacAgent
from tacbench.tac.maths import Batch, Coefficients


def update(
    agent: TacAgent,
    minibatch: Mapping[str, npt.ArrayLike],
    c: Coefficients,
    members: Sequence[bool] | None = None,
) -> torch.Tensor:
    """One gradient step of every live member on its own minibatch ``(K, B, ...)`` (drawn from
    its replay buffer, :meth:`ReplayBuffer.sample`) with its q and alpha from ``c``; with
    ``members`` (the episode schedule, updates during warm-up) only of those, the others'
    weights, Adam state, targets and generators left exactly as they are (their rows of
    ``minibatch`` are ignored).

    Returns the detached metrics ``(K, len(METRICS))``; a member not trained has a row of
    meaningless values (zeros where its whole chunk was skipped, else computed on its ignored
    minibatch rows): callers mask by ``members``, as the training loop does. A member
    marked dead (``agent.alive`` False) contributes nothing to the step of the others.
    """
    # the minibatch, as float32 tensors on the agent's device
    batch = Batch(*(agent.tensor(minibatch[name]) for name in Batch._fields))
    # the reparameterisation noise of a~ ~ pi(.|s), and with twin-q of a' ~ pi(.|s'), each
    # member's from its own generator
    eps, eps_next = agent.draw_noise(batch.action.shape[1], members)
    active = None if members is None else np.asarray(members, dtype=bool)
    metrics: list[torch.Tensor | None] = []
    for chunk in agent.chunks:  # members in chunks, one after the other (agent.py)
        m, params = chunk.members, chunk.params
        if active is not None and not active[m].any():
            metrics.append(None)  # nobody to train: the chunk is not touched at all
            continue
        trained = agent.alive[m]
        if active is not None:
            trained = trained & torch.as_tensor(active[m], device=trained.device)
        # the losses of losses.tac_losses (eqn:q_obj, eqn:v_obj, eqn:pol_obj) and their gradient
        metrics.append(_gradient(agent, chunk, batch, eps, trained, c, eps_next))
        with torch.no_grad():
            # Adam, then the Polyak average of the target networks
            params.adam_step(agent.learning_rate, None if active is None else active[m])
            params.update_target(agent.tau, None if active is None else active[m])
    return _in_member_order(agent, metrics)


def gradients(
    agent: TacAgent,
    batch: Batch,
    eps: torch.Tensor,
    c: Coefficients,
    eps_next: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The metrics of :func:`update` and the gradient of every trained parameter (named as in
    :meth:`TacAgent.member_state`) for one minibatch and noise, by the agent's gradient (compiled
    if its update is), without changing any weight. For comparing the paths."""
    metrics: list[torch.Tensor | None] = []
    named = []
    for chunk in agent.chunks:  # each chunk's gradient read before the next one's is taken
        metrics.append(_gradient(agent, chunk, batch, eps, agent.alive[chunk.members], c, eps_next))
        named.append({k: g.clone() for k, g in chunk.params.named_gradients().items()})
    grads = {name: torch.cat([g[name] for g in named]) for name in named[0]}
    return _in_member_order(agent, metrics), grads


def _gradient(
    agent: TacAgent,
    chunk: Chunk,
    batch: Batch,
    eps: torch.Tensor,
    trained: torch.Tensor,
    c: Coefficients,
    eps_next: torch.Tensor | None,
) -> torch.Tensor:
    """The chunk's members' losses and their gradient, which becomes ``chunk.params.grad`` (zero
    for members not ``trained``) until the next one; returns their metrics."""
    m, p = chunk.members, chunk.params
    with torch.no_grad():
        grad, metrics = agent.gradient(
            p.data,
            p.target,
            p.layout,
            p.target_layout,
            Batch(*(t[m] for t in batch)),
            eps[m],
            trained,
            Coefficients(*(t[m] for t in c)),
            agent.settings,
            None if eps_next is None else eps_next[m],
        )
    # the gradient graph's own output, not a copy (a pass over every parameter): it is read by
    # Adam before the next gradient of this graph is taken (on a GPU, it overwrites it)
    p.grad = grad
    return metrics


def _in_member_order(agent: TacAgent, metrics: list[torch.Tensor | None]) -> torch.Tensor:
    """The chunks' metrics as one ``(K, width)`` tensor, zeros for a chunk not trained."""
    width = len(agent.metric_names)
    return torch.cat(
        [
            torch.zeros(chunk.members.stop - chunk.members.start, width, device=agent.device)
            if x is None
            else x
            for chunk, x in zip(agent.chunks, metrics, strict=True)
        ]
    )
