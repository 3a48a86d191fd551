"""The adaptive study (docs/adaptive.md): does learning q (``--q auto``) or alpha (``--alpha
auto``) beat the fixed values, on the same seeds?

Per task: two ``--q auto`` populations of eight (seeds 0-70 and 80-150), fixed q = 1 and the
paper's best fixed q on those 16 seeds, and ``--alpha auto`` at q = 1 and at the best q on seeds
0-40 (against the fixed runs of the same seeds). ``tacbench study adaptive commands`` prints
the commands; ``tacbench study adaptive analyse --results DIR`` the tables.

A run's final return is the report's: the mean of its last 10 evaluations. A population is one
unit (its members copy each other): it is compared with the mean of the fixed runs of its own
eight seeds, so each task gives two paired differences. The learned-alpha runs are compared with
the fixed-alpha runs of the same seeds, unpaired: rliable's bootstrap interval of the difference
of the two means, each group resampled on its own.
"""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from tacbench import paper
from tacbench.bootstrap import mean_difference
from tacbench.errors import TacbenchError, one_line
from tacbench.report.load import RunSet, load_runs
from tacbench.report.tables import DEFAULT_LAST, run_scores
from tacbench.studies import cautions as cautions_of

ENVS = ("HalfCheetah-v4", "Hopper-v4")
BEST_Q = {env: paper.TASK_FACTS[paper.task_name(env)].best_q for env in ENVS}
POPULATIONS = (tuple(range(0, 80, 10)), tuple(range(80, 160, 10)))
ALPHA_SEEDS = paper.SEEDS[:5]  # the paper-q-grid study's seeds (results/studies/)
STEPS = 100_000
REPS = 10_000
TABLES = ("populations", "alpha", "final_q", "final_q_summary", "cautions")  # analyse's names


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


def finals(runset: RunSet) -> tuple[pd.DataFrame, list[str]]:
    """One row per finished run of the study: env, variant, q (NaN: learned), seed,
    population, path and final return; and cautions naming what was left out: run directories
    that cannot be used, runs short of their budget, and a population short of a member (its
    members copy each other: it is one unit)."""
    scores = run_scores(runset.data, DEFAULT_LAST)
    study = _study_runs(runset.runs)
    cautions = cautions_of.skipped_runs(runset.skipped) + cautions_of.short_runs(study)
    table = study[~study["partial"]].join(scores, on="run")
    whole = pd.Series(True, index=table.index)
    for (env, population), members in table[table["population"] != ""].groupby(
        ["env", "population"]
    ):
        missing = _member_seeds(str(population)) - set(members["seed"])
        if missing:
            whole[members.index] = False
            members_of = "member" if len(missing) == 1 else "members"
            cautions.append(
                f"{env}: left out the population {population}: its {members_of} of "
                f"{cautions_of.seeds(missing)} did not finish or cannot be used"
            )
    table = table[whole]
    return table[["env", "variant", "q", "seed", "population", "path", "final"]], cautions


def _member_seeds(population: str) -> set[int]:
    """The seeds a population's name lists (``seeds 0,10,20``: the loader's name)."""
    return {int(seed) for seed in population.removeprefix("seeds ").split(",")}


def population_table(table: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """Each population's mean final return against the fixed runs of its own seeds, and
    cautions naming the fixed runs missing for a comparison (its columns are then empty)."""
    rows, cautions = [], []
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
            if len(fixed) != len(seeds):
                missing = cautions_of.seeds(seeds - set(fixed["seed"]))
                cautions.append(
                    f"{env} {population}: no finished {variant} run of {missing}; its "
                    f"'fixed {label}' columns are empty"
                )
        rows.append(row)
    return pd.DataFrame(rows), cautions


def alpha_table(table: pd.DataFrame, reps: int = REPS) -> tuple[pd.DataFrame, list[str]]:
    """Learned minus fixed alpha at q = 1 and the best q, on the same seeds; and cautions
    naming the comparisons left out for want of runs."""
    rows, cautions = [], []
    for env, best in BEST_Q.items():
        if not (table["env"] == env).any():
            continue  # analyse says so, once
        for q in (1.0, best):
            learned = table[(table["env"] == env) & (table["variant"] == f"q{q:g}-aauto0.2")]
            fixed = table[
                (table["env"] == env)
                & (table["variant"] == f"q{q:g}-a0.2")
                & table["seed"].isin(learned["seed"])
            ]
            if learned.empty or len(fixed) != len(learned):
                missing = cautions_of.seeds(set(learned["seed"]) - set(fixed["seed"]))
                lacking = (
                    f"no finished q{q:g}-aauto0.2 run"
                    if learned.empty
                    else f"no finished q{q:g}-a0.2 run of {missing}"
                )
                cautions.append(f"{env} q = {q:g}: learned alpha left out, {lacking}")
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
    return pd.DataFrame(rows), cautions


def final_q(root: Path, table: pd.DataFrame) -> pd.DataFrame:
    """Each finished population member's q at the end (the last row of its losses.csv, under
    ``root``)."""
    learned = table[table["q"].isna()]
    if learned.empty:
        raise TacbenchError(
            f"no finished population of learned-q runs (--q auto) on {' or '.join(ENVS)} under "
            f"{root}; the study compares them with fixed q on the same seeds: tacbench study "
            "adaptive commands lists its runs."
        )
    rows = []
    for run in learned.itertuples():
        rows.append({"env": run.env, "population": run.population, "seed": run.seed})
        rows[-1]["final q"] = _last_q(root / str(run.path) / "losses.csv")
    return pd.DataFrame(rows).sort_values(["env", "population", "seed"], ignore_index=True)


def _last_q(losses: Path) -> float:
    """The q in the last row of a learned-q run's losses.csv; a TacbenchError if it has none."""
    try:
        q = pd.read_csv(losses, usecols=["q"])["q"]
    except (OSError, ValueError) as err:  # missing, empty, no q column
        raise TacbenchError(
            f"cannot read the learned q from {losses} ({one_line(err)}); restore the run's "
            "losses.csv."
        ) from None
    if not losses.read_bytes().endswith(b"\n"):  # a cut row's q reads as a number
        raise TacbenchError(f"{losses} ends in a torn line; restore the run's losses.csv.")
    if q.empty or not np.isfinite(q.iloc[-1]):
        raise TacbenchError(
            f"{losses} records no learned q in its last row; restore the run's losses.csv."
        )
    return float(q.iloc[-1])


def analyse(results: Path) -> dict[str, pd.DataFrame]:
    """Every table of the study, by name (:data:`TABLES`): populations, alpha, final_q,
    final_q_summary, and ``cautions`` (one ``caution`` per row, naming what was left out)."""
    runset = load_runs(results, "eval")
    table, cautions = finals(runset)
    ends = final_q(runset.root, table)
    summary = ends.groupby(["env", "population"])["final q"].describe()
    populations, missing_fixed = population_table(table)
    alpha, missing_alpha = alpha_table(table)
    tables = {
        "populations": populations,
        "alpha": alpha,
        "final_q": ends,
        "final_q_summary": summary[["min", "50%", "max"]].reset_index(),
    }
    cautions += missing_fixed + missing_alpha
    cautions += [
        f"{env}: no finished run of the study" for env in ENVS if env not in set(table["env"])
    ]
    tables["cautions"] = pd.DataFrame({"caution": cautions}, dtype=str)
    return tables
