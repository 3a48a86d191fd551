"""The adaptive study (docs/adaptive.md): does learning q (``--q auto``) or alpha (``--alpha
auto``) beat the fixed values, on the same seeds?

Per task: two ``--q auto`` populations of eight (seeds 0-70 and 80-150), fixed q = 1 and the
paper's best fixed q on those 16 seeds, and ``--alpha auto`` at q = 1 and at the best q on seeds
0-40 (against the fixed runs of the same seeds). ``tacbench study adaptive commands`` prints
the commands; ``tacbench study adaptive analyse --results DIR`` the tables.

A run's final return is the report's: the mean of its last 10 evaluations. A population is one
unit (its members copy each other): it is compared with the mean of the fixed runs of its own
eight seeds, so each task gives two paired differences. The learned-alpha runs are compared with
the fixed-alpha runs of the same seeds, seed by seed, with rliable's bootstrap interval of the
mean difference.
"""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from tacbench import paper
from tacbench.bootstrap import mean_difference
from tacbench.errors import TacbenchError
from tacbench.report.load import load_runs
from tacbench.report.tables import DEFAULT_LAST, run_scores

ENVS = ("HalfCheetah-v4", "Hopper-v4")
BEST_Q = {env: paper.TASK_FACTS[paper.task_name(env)].best_q for env in ENVS}
POPULATIONS = (tuple(range(0, 80, 10)), tuple(range(80, 160, 10)))
ALPHA_SEEDS = paper.SEEDS[:5]  # the paper-q-grid study's seeds (results/studies/)
STEPS = 100_000
REPS = 10_000


def _seeds(seeds: Sequence[int]) -> list[str]:
    return [arg for s in seeds for arg in ("--seed", str(s))]


def commands(out: str = "results/adaptive") -> list[str]:
    """The study's ``tacbench run`` commands, one population or group of members each."""
    lines = []
    for env, best in BEST_Q.items():
        common = ["--env", env, "--steps", str(STEPS), "--out", out, "--quiet"]
        for population in POPULATIONS:
            lines.append(["--q", "auto", *_seeds(population), *common])
        every = sorted({s for p in POPULATIONS for s in p})
        lines.append(["--q", "1", "--q", f"{best:g}", *_seeds(every), *common])
        lines.append(["--q", "1", "--q", f"{best:g}", "--alpha", "auto", *_seeds(ALPHA_SEEDS)])
        lines[-1] += common
    return [shlex.join(["tacbench", "run", *line]) for line in lines]


def _study_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """The study's runs among ``runs``: TAC's on its tasks (a folder may hold others too)."""
    return runs[(runs["algo"] == "tac") & runs["env"].isin(ENVS)]


def finals(results: Path) -> pd.DataFrame:
    """One row per run of the study: env, variant, q (NaN: learned), seed, population, final
    return."""
    runset = load_runs(results, "eval")
    scores = run_scores(runset.data, DEFAULT_LAST)
    table = _study_runs(runset.runs).join(scores, on="run")
    return table[["env", "variant", "q", "seed", "population", "final"]]


def population_table(table: pd.DataFrame) -> pd.DataFrame:
    """Each population's mean final return against the fixed runs of its own seeds."""
    rows = []
    for (env, population), members in table[table["q"].isna()].groupby(["env", "population"]):
        seeds = set(members["seed"])
        row: dict[str, object] = {"env": env, "population": population}
        row["q auto"] = members["final"].mean()
        for label, variant in (("q = 1", "q1-a0.2"), ("best q", f"q{BEST_Q[str(env)]:g}-a0.2")):
            fixed = table[
                (table["env"] == env) & (table["variant"] == variant) & table["seed"].isin(seeds)
            ]
            row[f"fixed {label}"] = fixed["final"].mean() if len(fixed) == len(seeds) else np.nan
            row[f"auto - {label}"] = row["q auto"] - row[f"fixed {label}"]  # type: ignore[operator]
        rows.append(row)
    return pd.DataFrame(rows)


def alpha_table(table: pd.DataFrame, reps: int = REPS) -> pd.DataFrame:
    """Learned minus fixed alpha at q = 1 and the best q, on the same seeds."""
    rows = []
    for env, best in BEST_Q.items():
        for q in (1.0, best):
            learned = table[(table["env"] == env) & (table["variant"] == f"q{q:g}-aauto0.2")]
            fixed = table[
                (table["env"] == env)
                & (table["variant"] == f"q{q:g}-a0.2")
                & table["seed"].isin(learned["seed"])
            ]
            if learned.empty or len(fixed) != len(learned):
                continue
            a, b = learned.sort_values("seed"), fixed.sort_values("seed")
            diff, low, high = mean_difference(a["final"], b["final"], reps, seed=0)
            rows.append(
                {
                    "env": env,
                    "q": q,
                    "seeds": len(a),
                    "alpha auto": a["final"].mean(),
                    "alpha auto std": a["final"].std(ddof=1),
                    "fixed": b["final"].mean(),
                    "fixed std": b["final"].std(ddof=1),
                    "auto - fixed": diff,
                    "CI low": low,
                    "CI high": high,
                }
            )
    return pd.DataFrame(rows)


def final_q(results: Path) -> pd.DataFrame:
    """Each population member's q at the end (the last losses.csv row)."""
    runset = load_runs(results, "eval")
    study = _study_runs(runset.runs)
    learned = study[study["q"].isna()]
    if learned.empty:
        raise TacbenchError(
            f"no population of learned-q runs (--q auto) on {' or '.join(ENVS)} under {results}; "
            "the study compares "
            "them with fixed q on the same seeds: tacbench study adaptive commands lists its runs."
        )
    rows = []
    for run in learned.itertuples():
        losses = pd.read_csv(runset.root / str(run.path) / "losses.csv", usecols=["step", "q"])
        rows.append({"env": run.env, "population": run.population, "seed": run.seed})
        rows[-1]["final q"] = float(losses["q"].iloc[-1])
    return pd.DataFrame(rows).sort_values(["env", "population", "seed"], ignore_index=True)


def analyse(results: Path) -> dict[str, pd.DataFrame]:
    """Every table of the study, by name: populations, alpha, final_q, final_q_summary."""
    table = finals(results)
    ends = final_q(results)
    summary = ends.groupby(["env", "population"])["final q"].describe()
    return {
        "populations": population_table(table),
        "alpha": alpha_table(table),
        "final_q": ends,
        "final_q_summary": summary[["min", "50%", "max"]].reset_index(),
    }
