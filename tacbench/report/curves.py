"""Learning curves on a common step grid, per run and averaged over seeds.

Runs log at different steps (evaluation intervals differ between trainers, training episodes end
anywhere), so every run is put on one grid per task before seeds are averaged:

* the grid has ``n`` evenly spaced steps ``H/n, 2 H/n, ..., H`` where ``H`` is the last logged
  step of the task's longest run and ``n`` is ``points`` (default 200), or fewer when no run of
  the task logged that many rows (200 points over 1M steps is the reference code's 5,000-step
  evaluation interval, so its evaluations land on the grid exactly);
* ``eval``: each run is linearly interpolated between its logged steps;
* ``train``: each grid step gets the mean return of the training episodes that ended since the
  previous grid step (the reference code's per-epoch "average training return"); a grid step
  with no episode ending in it is interpolated between its neighbours;
* a run has no value before its first or after its last logged step: nothing is extrapolated, so
  a partial run stops contributing where it stopped.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tacbench.report.series import Metric

CURVE_COLUMNS = ("env", "method", "q", "step", "mean", "std", "n")


def task_grid(horizon: float, points: int) -> np.ndarray:
    """``points`` evenly spaced steps ending at ``horizon`` (the first is ``horizon / points``)."""
    return horizon * np.arange(1, points + 1, dtype=np.float64) / points


def on_grid(steps: np.ndarray, returns: np.ndarray, grid: np.ndarray, metric: Metric) -> np.ndarray:
    """One run's returns on ``grid`` (NaN where the run has no data), see the module docstring."""
    out = np.full(len(grid), np.nan)
    if metric == "eval":
        inside = (grid >= steps[0]) & (grid <= steps[-1])
        out[inside] = np.interp(grid[inside], steps, returns)
        return out
    bins = np.searchsorted(grid, steps, side="left")
    keep = bins < len(grid)
    counts = np.bincount(bins[keep], minlength=len(grid))
    sums = np.bincount(bins[keep], weights=returns[keep], minlength=len(grid))
    filled = np.flatnonzero(counts)
    if len(filled) == 0:
        return out
    span = np.arange(filled[0], filled[-1] + 1)
    out[span] = np.interp(span, filled, sums[filled] / counts[filled])
    return out


def run_matrix(
    data: pd.DataFrame, runs: pd.DataFrame, points: int, metric: Metric
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every run on its task's grid: (grid per env, array of shape (runs, the longest grid)).
    A task's grid has at most ``points`` steps, and no more than the most rows a run of the
    task logged, so the array is never larger than the data it comes from, whatever ``points``.

    Row ``i`` of the array belongs to ``runs.iloc[i]``; a task with a shorter grid leaves the
    trailing columns NaN.
    """
    horizons = data.groupby("env")["step"].max()
    most_rows = {str(env): int(n) for env, n in runs.groupby("env")["rows"].max().items()}
    grids = {
        str(env): task_grid(float(h), min(points, most_rows[str(env)]))
        for env, h in horizons.items()
    }
    values = np.full((len(runs), max(len(grid) for grid in grids.values())), np.nan)
    run_ids = data["run"].to_numpy()
    bounds = np.flatnonzero(np.diff(run_ids)) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [len(data)]])
    steps, returns = data["step"].to_numpy(), data["return"].to_numpy()
    position = {run: i for i, run in enumerate(runs["run"])}
    for start, end in zip(starts, ends, strict=True):
        row = position[int(run_ids[start])]
        grid = grids[str(runs["env"].iat[row])]
        values[row, : len(grid)] = on_grid(steps[start:end], returns[start:end], grid, metric)
    return grids, values


def seed_curves(
    grids: dict[str, np.ndarray], values: np.ndarray, runs: pd.DataFrame
) -> pd.DataFrame:
    """Mean, sample standard deviation (ddof 1; NaN for one seed) and count over seeds.

    ``runs`` needs columns ``env``, ``method`` and ``q``, one row per row of ``values``. Grid
    steps no run of a method reaches are left out.
    """
    frames = []
    for (env, method), group in runs.groupby(["env", "method"], sort=False):
        grid = grids[str(env)]
        block = values[runs.index.get_indexer(group.index), : len(grid)]
        present = ~np.isnan(block)
        n = present.sum(axis=0)
        filled = np.where(present, block, 0.0)
        mean = filled.sum(axis=0) / np.maximum(n, 1)
        squares = np.where(present, (block - mean) ** 2, 0.0).sum(axis=0)
        std = np.where(n > 1, np.sqrt(squares / np.maximum(n - 1, 1)), np.nan)
        keep = n > 0
        frames.append(
            pd.DataFrame(
                {
                    "env": env,
                    "method": method,
                    "q": group["q"].iat[0],
                    "step": grid[keep],
                    "mean": mean[keep],
                    "std": std[keep],
                    "n": n[keep],
                }
            )
        )
    return pd.concat(frames, ignore_index=True)[list(CURVE_COLUMNS)]
