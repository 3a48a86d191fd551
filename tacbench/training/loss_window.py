"""The open window of every member's ``losses.csv``: each metric summed over the updates since
the member's last row, and how many updates that was. A row is their mean; a checkpoint keeps
the open window, so a resumed run writes the same rows."""

from __future__ import annotations

import numpy as np
import torch


class LossWindow:
    """The metric sums (on the learner's device) and update counts of ``members`` members."""

    def __init__(self, members: int, metrics: int, device: torch.device):
        self.sums = torch.zeros(members, metrics, device=device)
        self.counts = np.zeros(members, dtype=np.int64)

    def add(self, metrics: torch.Tensor, updated: np.ndarray, every_member: bool) -> None:
        """Add one round's ``metrics`` (members x metrics) of the members flagged in
        ``updated``; ``every_member``: all of them updated, so no mask is needed."""
        if every_member:
            self.sums += metrics
        else:
            active = torch.as_tensor(updated, device=metrics.device)[:, None]
            self.sums += torch.where(active, metrics, 0.0)
        self.counts += updated

    def close(self, members: list[int]) -> list[tuple[int, int, list[float]]]:
        """For each of ``members`` with updates in its window: (member, updates, mean of each
        metric); those windows start afresh."""
        logged = [k for k in members if self.counts[k]]
        if not logged:
            return []
        counts = torch.as_tensor(self.counts, device=self.sums.device)
        mean = (self.sums / counts.clamp(min=1)[:, None]).cpu()
        rows = [(k, int(self.counts[k]), mean[k].tolist()) for k in logged]
        for k in logged:
            self.sums[k] = 0.0
            self.counts[k] = 0
        return rows

    def member_state(self, k: int) -> tuple[torch.Tensor, int]:
        """Member k's open window, for its checkpoint."""
        return self.sums[k].cpu().clone(), int(self.counts[k])

    def load_member_state(self, k: int, sums: torch.Tensor, count: int) -> None:
        """Restore member k's window from :meth:`member_state`."""
        self.sums[k] = sums.to(self.sums.device)
        self.counts[k] = count
