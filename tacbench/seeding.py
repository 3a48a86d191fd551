"""A run's independent random streams, all from its seed.

Seeding every generator of a run with the seed itself ties them together: numpy's
``default_rng(seed)`` and Gymnasium's ``env.reset(seed=seed)`` are both
``PCG64(SeedSequence(seed))``, so a run's first random warm-up actions were the very numbers
its first initial state was drawn from. :func:`run_streams` gives each consumer its own child of
``SeedSequence(seed)`` (``spawn``), which are independent by construction. The evaluation
episodes have their own seeds already (:func:`tacbench.envs.eval_seeds`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class RunStreams(NamedTuple):
    """The seeds of a run's random streams."""

    torch_seed: int  # the learner: initial weights, exploration and reparameterisation noise
    numpy: np.random.SeedSequence  # the loop: warm-up actions, minibatch indices
    env_seed: int  # the training environment's resets


def run_streams(seed: int) -> RunStreams:
    """Independent streams for the run with ``seed`` (three children of its SeedSequence)."""
    torch_child, numpy_child, env_child = np.random.SeedSequence(seed).spawn(3)
    return RunStreams(
        int(torch_child.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1)),  # < 2^63
        numpy_child,
        int(env_child.generate_state(1, dtype=np.uint32)[0]),
    )
