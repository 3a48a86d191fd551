"""The sequential comparisons (docs/sequential.md), checked: the committed paper-q-grid study
replayed through AdaStop, and synthetic grids at the designs the sweep runs, where the truth is
known.

``analyse(results, reps)`` returns the tables by name:

- ``replay`` and ``replay_runs``: the study at ``results`` replayed in seed order, each q
  against q = 1, for every design its five seeds allow;
- ``error_and_power``: for each design of :data:`DESIGNS`, over ``reps`` synthetic grids of
  normal scores, the share of grids with any wrong decision (the family-wise error rate, which
  must stay at most alpha) when every method is equal, and when one method is better by
  ``shift`` standard deviations, the share of grids that find it (the power), with the design's
  runs spent on average against its fixed ``n x K`` design.

``commands()`` lists the commands that make the docs' tables.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from tacbench import sequential as sq

STUDY = Path("results/studies/paper-q-grid-100k")
REPLAY_DESIGNS = ((1, 5), (2, 2), (4, 1), (5, 1))  # (n, K) that five seeds allow
REPS = 500
TABLES = ("replay", "replay_runs", "error_and_power")  # analyse's names, each written as CSV
SEED = 2024


@dataclass(frozen=True)
class Design:
    """A synthetic grid: ``methods`` methods of ``n x K`` runs each; comparisons against method
    0 (``control``) or every pair; in the power check method 1 is better by each of ``shifts``
    standard deviations (every method better by that much than the one before, with
    ``ladder``: the adastop package's own type-2 toy)."""

    name: str
    methods: int
    n: int
    K: int
    control: bool = True
    shifts: tuple[float, ...] = (1.0, 2.0, 3.0)
    ladder: bool = False
    alpha: float = sq.DEFAULT_ALPHA
    max_reps: int | None = None  # a design whose grids cost much more runs fewer of them


DESIGNS = (
    Design("paper-q-grid: 9 q, each against q = 1 (the sweep's defaults)", 9, 5, 2),
    Design("paper-comparison: TAC against 6 baselines", 7, 5, 2),
    Design("3 methods, every pair", 3, 5, 2, control=False),
    Design("adastop's toy: 4 agents, every pair, K = 3, n = 5", 4, 5, 3, False, (2.0,), True),
    # one look at 4 x 15 runs: about ten times a grid above (AdaStop's permutations)
    Design(
        "adastop's toy: 4 agents, every pair, K = 1, n = 15",
        4,
        15,
        1,
        control=False,
        shifts=(2.0,),
        ladder=True,
        max_reps=100,
    ),
)


def _means(design: Design, shift: float) -> dict[str, float]:
    """Each method's true mean: method 1 ``shift`` above the rest, or a ladder of steps."""
    return {
        f"m{k}": shift * k if design.ladder else (shift if k == 1 else 0.0)
        for k in range(design.methods)
    }


def _grid(
    design: Design, means: dict[str, float], rng: np.random.Generator
) -> dict[str, list[float]]:
    size = design.n * design.K
    return {m: rng.normal(mean, 1.0, size).tolist() for m, mean in means.items()}


def _wrong(decisions: dict[sq.Pair, str], means: dict[str, float]) -> bool:
    """Whether any decision is wrong: a difference declared where the means are equal, or the
    opposite of the true order."""
    for (a, b), decision in decisions.items():
        if decision not in sq.DECIDED:
            continue
        truth = np.sign(means[a] - means[b])
        if truth == 0 or (decision == "larger") != (truth > 0):
            return True
    return False


def check(design: Design, shift: float, reps: int, seed: int = SEED) -> dict[str, float]:
    """``reps`` grids of ``design`` with the methods ``shift`` apart (0: all equal): the share
    with a wrong decision, the share that find every true difference, and the runs spent."""
    rng = np.random.default_rng([seed, design.methods, design.n, design.K, int(shift * 100)])
    means = _means(design, shift)
    wrong = found = spent = 0
    for rep in range(reps):
        scores = _grid(design, means, rng)
        control = "m0" if design.control else None
        result = sq.run_sequential(scores, design.n, design.K, design.alpha, control, seed=rep)
        decisions = result.decisions
        wrong += _wrong(decisions, means)
        true_pairs = [p for p in decisions if means[p[0]] != means[p[1]]]
        found += bool(true_pairs) and all(decisions[p] in sq.DECIDED for p in true_pairs)
        spent += result.runs_spent
    return {"wrong": wrong / reps, "found": found / reps, "runs": spent / reps}


def error_and_power(reps: int = REPS, designs: Sequence[Design] = DESIGNS) -> pd.DataFrame:
    """One row per design and shift (0 first: the family-wise error rate under no difference)."""
    rows = []
    for design in designs:
        fixed = design.methods * design.n * design.K
        count = min(reps, design.max_reps or reps)
        for shift in (0.0, *design.shifts):
            measured = check(design, shift, count)
            rows.append(
                {
                    "design": design.name,
                    "alpha": design.alpha,
                    "shift_sd": shift,
                    "reps": count,
                    "wrong_decision": measured["wrong"],
                    "monte_carlo_se": float(np.sqrt(design.alpha * (1 - design.alpha) / count)),
                    "found": measured["found"] if shift else np.nan,
                    "runs": measured["runs"],
                    "fixed_design_runs": fixed,
                }
            )
    return pd.DataFrame(rows)


def replay(results: Path = STUDY) -> dict[str, pd.DataFrame]:
    """The study at ``results`` replayed at every design of :data:`REPLAY_DESIGNS`."""
    decisions, spending = [], []
    for n, K in REPLAY_DESIGNS:
        replays = sq.replay_study(results, n, K)
        design = f"n={n}, K={K}"
        table = sq.decision_table(replays).astype({"interim": float})  # NaN: not decided
        decisions.append(table.assign(design=design))
        spending.append(sq.spending_table(replays).assign(design=design))
    return {"replay": pd.concat(decisions), "replay_runs": pd.concat(spending)}


def analyse(results: Path = STUDY, reps: int = REPS) -> dict[str, pd.DataFrame]:
    """The replay tables and the synthetic checks, by name."""
    return {**replay(results), "error_and_power": error_and_power(reps)}


def commands(results: Path = STUDY, reps: int = REPS) -> list[str]:
    """The command that makes the tables of docs/sequential.md."""
    return [f"tacbench study sequential analyse --results {results} --reps {reps}"]
