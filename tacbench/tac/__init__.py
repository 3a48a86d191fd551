"""Tsallis Actor-Critic: the algorithm, nothing else (no I/O, no environments).

Start reading at ``update``: one update, top to bottom. Below it: ``losses`` all losses in one
function; ``gradient`` their gradient by autograd (optionally compiled); ``parameters`` the flat
parameter buffers, Adam and the targets; ``agent`` the members, acting and per-member state;
``maths`` the formulas below the losses; ``networks`` member-batched MLPs; ``buffer`` the
member-batched replay buffer.
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
