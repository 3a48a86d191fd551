"""What the paper reports about the q sweep, so a report can compare its ranking with it.

Sources (``tsallis-rl-paper.tex``): section "Effect of Entropic Index" (the q grid, alpha, the best
q per task) and appendix "Full Experimental Results" (Hopper and Swimmer). The paper ran the
``-v2`` tasks; runs of any version (``Hopper-v4``, ``Hopper-v5``) are matched on the task name.
"""

from __future__ import annotations

from dataclasses import dataclass

PAPER_TASK_ORDER: tuple[str, ...] = (
    "HalfCheetah",
    "Ant",
    "Pusher",
    "Humanoid",
    "Hopper",
    "Swimmer",
)
"""The paper's panel order: the four main-text tasks, then the two appendix tasks."""

PAPER_ALPHA: dict[str, float] = {"Humanoid": 0.05}
"""Entropy coefficient of the sweep where it is not 0.2 (section "Effect of Entropic Index")."""

PAPER_DEFAULT_ALPHA = 0.2


@dataclass(frozen=True)
class PaperBestQ:
    """The paper's verdict on one task: its best q (None where it names none) and why."""

    q: float | None
    note: str


PAPER_BEST_Q: dict[str, PaperBestQ] = {
    "HalfCheetah": PaperBestQ(1.5, "q = 1.5 best within 1 <= q < 2"),
    "Ant": PaperBestQ(1.5, "q = 1.5 best; SAC (q = 1) third in the comparison"),
    "Humanoid": PaperBestQ(1.2, "q = 1.2 best, 'dramatically' ahead of the others"),
    "Pusher": PaperBestQ(1.2, "final returns similar for all q; q = 1.2 converges slightly faster"),
    "Hopper": PaperBestQ(None, "1 <= q <= 2 perform similarly"),
    "Swimmer": PaperBestQ(None, "every q stuck in a local optimum"),
}
"""The paper's best q per task (main text and appendix "Full Experimental Results")."""


def task_name(env_id: str) -> str:
    """The task name without its version: ``"Hopper-v4"`` -> ``"Hopper"``."""
    head, sep, tail = env_id.rpartition("-v")
    return head if sep and tail.isdigit() else env_id


def paper_best_q(env_id: str) -> PaperBestQ | None:
    """The paper's best-q entry for a Gymnasium id, or None for a task the paper did not run."""
    return PAPER_BEST_Q.get(task_name(env_id))


def paper_alpha(env_id: str) -> float | None:
    """The entropy coefficient of the paper's sweep on a task, or None if it did not run it."""
    name = task_name(env_id)
    if name not in PAPER_TASK_ORDER:
        return None
    return PAPER_ALPHA.get(name, PAPER_DEFAULT_ALPHA)


def task_sort_key(env_id: str) -> tuple[int, str]:
    """Sort key putting tasks in the paper's panel order, unknown tasks after, alphabetically."""
    name = task_name(env_id)
    index = PAPER_TASK_ORDER.index(name) if name in PAPER_TASK_ORDER else len(PAPER_TASK_ORDER)
    return index, env_id
