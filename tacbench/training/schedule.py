"""When each member updates: how many gradient updates each member has earned after a step.

* ``update_schedule`` step: one update after every step; episode (paper Algorithm 1): at each of
  the member's episode ends, as many updates as that episode had steps.
* ``warmup_updates`` off: updates start after step ``learning_starts``; on (the authors' code):
  at the member's first episode end, while the random warm-up may still be running.

Members of one group earn updates independently (their episodes end at different steps); an
update round trains only the members that are due (the others stay exactly as they are).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tacbench.config import RunConfig

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def updates_due(
    config: RunConfig,
    step: int,
    done: BoolArray,
    finished_length: IntArray,
    started: BoolArray,
) -> IntArray:
    """The updates each member has earned after environment step ``step`` (1-based): ``done``
    marks the members whose episode just ended after ``finished_length`` steps; ``started``,
    updated in place, marks the members whose updates have begun."""
    if config.warmup_updates == "on":
        started |= done
    else:
        started[:] = step >= config.learning_starts
    if config.update_schedule == "step":
        return started.astype(np.int64)
    return np.where(started & done, finished_length, 0).astype(np.int64)


def rounds(due: IntArray) -> list[BoolArray]:
    """The members updated in each update round: round r holds those due more than r updates."""
    return [due > r for r in range(int(due.max(initial=0)))]
