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
    losses row (``losses.csv``), for the figure."""
    frames = []
    for run in runs[runs["population"].fillna("") != ""].itertuples():
        logged = pd.read_csv(root / str(run.path) / "losses.csv", usecols=["step", "q"])
        config = json.loads((root / str(run.path) / "config.json").read_text())
        start = pd.DataFrame({"step": [0], "q": [config["q"]]})  # where the member started
        losses = pd.concat([start, logged], ignore_index=True)
        frames.append(
            losses.assign(env=run.env, method=run.method, population=run.population, seed=run.seed)
        )
    if not frames:
        return pd.DataFrame(columns=list(TRAJECTORY_COLUMNS))
    return pd.concat(frames, ignore_index=True)[list(TRAJECTORY_COLUMNS)]
