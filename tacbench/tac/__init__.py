"""Tsallis Actor-Critic: the algorithm, nothing else (no I/O, no environments).

``maths`` the formulas below the losses; ``networks`` member-batched MLPs; ``parameters`` the
flat parameter buffers, Adam and the targets; ``losses`` all losses in one function; ``update``
their gradient by autograd (optionally compiled), Adam and the targets; ``agent`` act, update and
per-member state; ``buffer`` the member-batched replay buffer.
"""

from tacbench.tac.agent import TacAgent
from tacbench.tac.buffer import ReplayBuffer
from tacbench.tac.losses import TacLosses, tac_losses
from tacbench.tac.maths import METRICS, Batch, Coefficients, coefficients

__all__ = [
    "METRICS",
    "Batch",
    "Coefficients",
    "ReplayBuffer",
    "TacAgent",
    "TacLosses",
    "coefficients",
    "tac_losses",
]
