"""``TAC q=auto`` in the report: one value per population, and where each member's q went.

The members of one ``--q auto`` population (tacbench/training/pbt.py) are not independent runs:
they copy each other's learners. The report's statistics (intervals, probabilities of
improvement, profiles) therefore count one value per population, the mean of its members'
scores (:func:`one_per_population`); the curves and the summary table still show the members.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

TRAJECTORY_COLUMNS = ("env", "method", "population", "seed", "step", "q")


def one_per_population(scores: pd.DataFrame) -> pd.DataFrame:
    """``scores`` (one row per run) with the runs of each population replaced by one row: the
    mean ``final`` and ``score`` of its members (the other columns from its first member)."""
    members = scores["population"].fillna("") != ""
    if not members.any():
        return scores
    keys = ["env", "method", "population"]
    grouped = scores[members].groupby(keys, sort=False)
    merged = grouped.first().join(grouped[["final", "score"]].mean(), rsuffix="_mean")
    merged["final"], merged["score"] = merged.pop("final_mean"), merged.pop("score_mean")
    return pd.concat([scores[~members], merged.reset_index()[scores.columns]], ignore_index=True)


def q_trajectories(runs: pd.DataFrame, root: Path) -> pd.DataFrame:
    """Each population member's q from step 0 (its starting q, the run's config) and at every
    losses row (``losses.csv``), for the figure; its starting q alone where the log is missing
    or unreadable (results copied without it: :func:`unlogged_q`)."""
    frames = []
    for run in runs[runs["population"].fillna("") != ""].itertuples():
        logged = _logged_q(root / str(run.path) / "losses.csv")
        config = json.loads((root / str(run.path) / "config.json").read_text())
        start = pd.DataFrame({"step": [0], "q": [config["q"]]})  # where the member started
        losses = pd.concat([start, logged], ignore_index=True)
        frames.append(
            losses.assign(env=run.env, method=run.method, population=run.population, seed=run.seed)
        )
    if not frames:
        return pd.DataFrame(columns=list(TRAJECTORY_COLUMNS))
    return pd.concat(frames, ignore_index=True)[list(TRAJECTORY_COLUMNS)]


def _logged_q(losses_csv: Path) -> pd.DataFrame:
    """A member's q by step from its losses.csv (no rows where it is missing or unreadable)."""
    try:
        return pd.read_csv(losses_csv, usecols=["step", "q"])
    except (OSError, ValueError):  # missing, empty, damaged, or without a q column
        return pd.DataFrame({"step": pd.Series(dtype=int), "q": pd.Series(dtype=float)})


def unlogged_q(trajectories: pd.DataFrame) -> list[str]:
    """A caution per task whose population members logged no q (:func:`q_trajectories`)."""
    rows = trajectories.groupby(["env", "population", "seed"], sort=False).size()
    alone = rows[rows == 1]  # the starting q only
    return [
        f"{env}: {len(group)} TAC q=auto member{'s' if len(group) != 1 else ''} whose losses.csv "
        "is missing or has no readable q column: the q trajectories show their starting q alone."
        for env, group in alone.groupby(level="env", sort=False)
    ]
