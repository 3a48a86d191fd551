"""The parity study (docs/parity.md): is our TAC at q = 1 a correct SAC?

TAC at q = 1 (the paper's "SAC") and stable-baselines3's SAC configured to match it
(``sac-sb3``) are trained on the same tasks, seeds and budget through ``tacbench run``; this
module prints those commands and analyses their run directories:

- learning curves: mean and standard deviation over seeds of the evaluation return at each
  evaluation step, per task and algorithm (a table and a figure);
- final return: per run, the mean evaluation return over the last ``fraction`` of the steps;
  per task, the difference of the two algorithms' means (TAC minus SB3) with a percentile
  bootstrap confidence interval (rliable's), seeds resampled independently within each
  algorithm.

``tacbench study parity commands`` prints the study's commands; ``tacbench study parity
analyse --results DIR`` (repeatable: the runs of several folders, say an ablation's TAC runs
and the study's SB3 runs) prints the tables and writes the figure; ``--finals CSV`` adds final
returns recorded by an earlier study whose runs are not kept (one row per run: env, method,
seed, return), so a new method can be compared with them.
"""

from __future__ import annotations

import dataclasses
import shlex
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from tacbench import paper
from tacbench.errors import TacbenchError

ENVS = ("Hopper-v4", "HalfCheetah-v4")
SEEDS = paper.SEEDS[:5]
STEPS = 100_000
FRACTION = 0.1  # final return: the evaluations in the last 10% of the steps
REPS = 10_000
TABLES = ("curves", "finals", "summary", "cautions")  # analyse's names, each written as CSV
FIGURE = "curves.png"
TAC, TAC_TWIN_Q, TAC_REFERENCE, SB3 = "TAC q=1", "TAC q=1 twin-q", "TAC q=1 reference", "SAC (SB3)"
# the paper's TAC (target V), TAC with SAC v2's target, TAC as the authors' code ran it, SB3
TAC_METHODS = (TAC, TAC_TWIN_Q, TAC_REFERENCE)
METHODS = (*TAC_METHODS, SB3)


def commands(
    envs: Sequence[str] = ENVS,
    seeds: Sequence[int] = SEEDS,
    steps: int = STEPS,
    out: str = "results/parity",
) -> list[str]:
    """The ``tacbench run`` commands of the study: per task, TAC at q = 1 with the paper's
    target V, with ``--critic-target twin-q`` and in ``--profile reference`` (the seeds as
    members of one process), and sac-sb3 (the seeds one after another)."""
    seed_flags = [flag for seed in seeds for flag in ("--seed", str(seed))]
    lines = []
    for env in envs:
        facts = paper.task_facts(env)
        alpha = paper.DEFAULT_ALPHA if facts is None else facts.alpha
        common = ["--env", env, *seed_flags, "--steps", str(steps), "--out", out, "--quiet"]
        tac = ["tacbench", "run", "--q", "1", "--alpha", f"{alpha:g}"]
        lines.append(shlex.join([*tac, *common]))
        lines.append(shlex.join([*tac, "--critic-target", "twin-q", *common]))
        lines.append(shlex.join([*tac, "--profile", "reference", *common]))
        lines.append(shlex.join(["tacbench", "run", "--algo", "sac-sb3", *common]))
    return lines


def load(results: Path | Sequence[Path], by_variant: bool = False) -> pd.DataFrame:
    """Evaluation returns of the study's runs (TAC at q = 1, with either critic target or in the
    reference profile, and sac-sb3) in one results folder or several, runs trained to their
    budget only, one budget per task. Columns: method (one of :data:`METHODS`; with
    ``by_variant``, TAC runs are named ``TAC <variant>`` instead, for an ablation's variants of
    one method), env, seed, step, return."""
    return _load(results, by_variant)[0]


def _load(results: Path | Sequence[Path], by_variant: bool) -> tuple[pd.DataFrame, list[str]]:
    """:func:`load`, and cautions naming the run directories it left out (by folder and path,
    where there are several folders)."""
    from tacbench.report.load import load_runs  # the report package: only when runs are read
    from tacbench.studies import cautions

    folders = [results] if isinstance(results, Path) else list(results)
    where = " and ".join(str(folder) for folder in folders)
    picked, tidy, left_out = [], [], []
    for number, folder in enumerate(folders):
        runset = load_runs(folder, "eval")
        runs, skipped = runset.runs.copy(), list(runset.skipped)
        if len(folders) > 1:  # name each left-out run by its folder too
            runs["path"] = [f"{folder}/{path}" for path in runs["path"]]
            skipped = [dataclasses.replace(s, path=f"{folder}/{s.path}") for s in skipped]
        chosen = runs[((runs["algo"] == "tac") & (runs["q"] == 1.0)) | (runs["algo"] == "sac-sb3")]
        left_out += cautions.skipped_runs(skipped) + cautions.short_runs(chosen)
        picked.append(chosen[~chosen["partial"]].assign(folder=number))
        tidy.append(runset.data.assign(folder=number))
    chosen = pd.concat(picked, ignore_index=True)
    if chosen.empty:
        raise TacbenchError(
            f"no complete run of TAC at q = 1 or of sac-sb3 under {where}; tacbench study "
            "parity commands lists the study's runs."
        )
    twice = chosen[chosen.duplicated(["algo", "env", "variant", "seed"], keep=False)]
    if not twice.empty:
        run = twice.iloc[0]
        raise TacbenchError(
            f"{run['algo']} {run['variant']} seed {run['seed']} on {run['env']} is in more than "
            f"one of {where}; give each run once (one folder for it, or --results of folders "
            "that do not overlap)."
        )
    budgets = chosen.groupby("env")["total_steps"].unique()
    mixed = {env: sorted(steps) for env, steps in budgets.items() if len(steps) > 1}
    if mixed:
        env, steps = next(iter(mixed.items()))
        raise TacbenchError(
            f"the runs of {env} under {where} have budgets of "
            f"{' and '.join(f'{s:,.0f}' for s in steps)} steps; the study compares runs of one "
            "budget: keep the runs of one."
        )
    pairs = zip(chosen["algo"], chosen["variant"], strict=True)
    chosen["method"] = [_method(algo, variant, by_variant) for algo, variant in pairs]
    several = chosen.groupby(["method", "env"])["variant"].nunique()
    if (several > 1).any():
        raise TacbenchError(
            f"several variants of one method on one task under {where}: "
            f"{several[several > 1].to_dict()}; keep one per method and task."
        )
    data = pd.concat(tidy, ignore_index=True).merge(
        chosen[["folder", "run", "method"]], on=["folder", "run"]
    )
    return data[["method", "env", "seed", "step", "return"]].reset_index(drop=True), left_out


def _method(algo: str, variant: str, by_variant: bool = False) -> str:
    """The study's name of a run: SB3, or TAC by its profile and critic target (or, with
    ``by_variant``, by its whole variant)."""
    if algo == "sac-sb3":
        return SB3
    if by_variant:
        return f"TAC {variant}"
    parts = variant.split("-")
    if "ref" in parts:
        return TAC_REFERENCE
    return TAC_TWIN_Q if "twinq" in parts else TAC


def curves(data: pd.DataFrame) -> pd.DataFrame:
    """Mean, standard deviation and number of seeds of the evaluation return per task, method
    and step."""
    grouped = data.groupby(["env", "method", "step"])["return"]
    table = grouped.agg(["mean", "std", "count"]).reset_index()
    return table.rename(columns={"count": "seeds"})


def final_returns(data: pd.DataFrame, fraction: float = FRACTION) -> pd.DataFrame:
    """Per run: the mean evaluation return over its last ``fraction`` of steps."""
    last = data.groupby(["env", "method", "seed"])["step"].transform("max")
    start = (1.0 - fraction) * last  # 0.55 x 100,000 is 55,000.00000000001: close is at it
    tail = data[(data["step"] >= start) | np.isclose(data["step"], start, rtol=1e-12, atol=0)]
    return tail.groupby(["env", "method", "seed"])["return"].mean().reset_index()


FINALS_COLUMNS = ("env", "method", "seed", "return")


def recorded_finals(path: Path, finals: pd.DataFrame) -> pd.DataFrame:
    """``finals`` with the final returns recorded in the CSV at ``path`` added (columns
    :data:`FINALS_COLUMNS`; others are kept out). A method and task in both, a seed recorded
    twice and a return that is not a finite number are errors."""
    try:
        recorded = pd.read_csv(path)
    except (OSError, UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as err:
        raise TacbenchError(f"{path} is not a readable CSV ({err}).") from None
    missing = [c for c in FINALS_COLUMNS if c not in recorded.columns]
    if missing:
        raise TacbenchError(f"{path} lacks the columns {missing}; it needs {list(FINALS_COLUMNS)}.")
    from tacbench.envs import resolve_env_id  # Gymnasium's registry: only when a file is read

    for env in sorted(set(recorded["env"].astype(str))):
        try:
            known = resolve_env_id(env)
        except TacbenchError as err:
            raise TacbenchError(f"{path}: {err}") from None
        if known != env:
            raise TacbenchError(
                f"{path} names the task {env!r}; write its Gymnasium id, {known!r}, as the run "
                "directories do."
            )
    unknown = sorted(set(recorded["method"]) - set(METHODS))
    if unknown:
        raise TacbenchError(f"{path}: unknown methods {unknown}; the study's are {list(METHODS)}.")
    recorded = recorded[list(FINALS_COLUMNS)].copy()
    recorded["return"] = pd.to_numeric(recorded["return"], errors="coerce")
    bad = recorded.index[~np.isfinite(recorded["return"])]
    if len(bad):
        raise TacbenchError(
            f"{path}: the return of data row {bad[0] + 1} is not a finite number; every row "
            "needs one."
        )
    repeated = recorded[recorded.duplicated(["env", "method", "seed"])]
    if not repeated.empty:
        first = repeated.iloc[0]
        raise TacbenchError(
            f"{path} records seed {first['seed']} of {first['method']} on {first['env']} more "
            "than once; keep one row per seed."
        )
    both = recorded[["env", "method"]].merge(finals[["env", "method"]].drop_duplicates())
    if not both.empty:
        pairs = sorted({(e, m) for e, m in zip(both["env"], both["method"], strict=True)})
        raise TacbenchError(
            f"{path} records {pairs}, which the run directories or an earlier --finals file "
            "also hold: keep one source."
        )
    return pd.concat([finals, recorded], ignore_index=True)


def bootstrap_difference(
    a: np.ndarray, b: np.ndarray, reps: int = REPS, seed: int = 0
) -> tuple[float, float, float]:
    """mean(a) - mean(b) and its 95% percentile interval from rliable's bootstrap (a and b
    resampled independently, with replacement)."""
    from tacbench.bootstrap import mean_difference  # rliable (about 1 s): only when it is used

    return mean_difference(a, b, reps, seed)


SUMMARY_COLUMNS = (
    *("env", "method", "TAC mean", "TAC std", "TAC seeds", "SB3 mean", "SB3 std", "SB3 seeds"),
    *("TAC - SB3", "CI low", "CI high"),
)


def summary(finals: pd.DataFrame, reps: int = REPS) -> tuple[pd.DataFrame, list[str]]:
    """Per task and TAC method present: its final return and SB3's (mean, std, seeds), and
    TAC minus SB3 with its 95% bootstrap interval; and cautions naming each task that lacks
    one side (its row's differences are empty, or it has no row)."""
    rows, cautions = [], []
    others = sorted(set(finals["method"]) - set(METHODS))
    for env, group in finals.groupby("env"):
        sb3 = group.loc[group["method"] == SB3, "return"].to_numpy()
        if not len(sb3):
            cautions.append(
                f"{env}: no finished SB3 run (nor recorded finals: --finals); its TAC - SB3 "
                "columns are empty"
            )
        if set(group["method"]) <= {SB3}:
            cautions.append(f"{env}: no finished TAC run; it has no row")
        for method in (*TAC_METHODS, *others):
            tac = group.loc[group["method"] == method, "return"].to_numpy()
            if not len(tac):
                continue
            row: dict[str, object] = {"env": env, "method": method}
            for name, scores in (("TAC", tac), ("SB3", sb3)):
                row[f"{name} mean"] = scores.mean() if len(scores) else np.nan
                row[f"{name} std"] = scores.std(ddof=1) if len(scores) > 1 else np.nan
                row[f"{name} seeds"] = len(scores)
            if len(sb3):
                row["TAC - SB3"], row["CI low"], row["CI high"] = bootstrap_difference(
                    tac, sb3, reps
                )
            rows.append(row)
    return pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS)), cautions


def plot(table: pd.DataFrame, path: Path) -> None:
    """The learning curves, one panel per task, mean +/- one standard deviation over seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = sorted(table["env"].unique())
    methods = [m for m in METHODS if m in set(table["method"])]
    methods += sorted(set(table["method"]) - set(METHODS))
    fig, axes = plt.subplots(1, len(envs), figsize=(5 * len(envs), 3.6), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        for i, method in enumerate(methods):
            color = f"C{i % 10}"  # matplotlib's default colour cycle
            rows = table[(table["env"] == env) & (table["method"] == method)]
            if rows.empty:
                continue
            std = rows["std"].fillna(0.0)
            ax.plot(rows["step"], rows["mean"], color=color, label=method)
            low, high = rows["mean"] - std, rows["mean"] + std
            ax.fill_between(rows["step"], low, high, color=color, alpha=0.2)
        ax.set(title=env, xlabel="environment steps", ylabel="evaluation return")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def analyse(
    results: Path | Sequence[Path],
    *,
    by_variant: bool = False,
    fraction: float = FRACTION,
    finals: Sequence[Path] = (),
    reps: int = REPS,
) -> dict[str, pd.DataFrame]:
    """Every table of the study, by name (:data:`TABLES`), from the runs of one results folder
    or several: curves, finals (with the recorded ``finals`` CSVs added), summary (the
    differences to SB3) and cautions (a task that lacks one side)."""
    if not 0 < fraction <= 1:
        raise TacbenchError(f"--fraction must be in (0, 1] (got {fraction}).")
    data, cautions = _load(results, by_variant)
    table, final = curves(data), final_returns(data, fraction)
    for path in finals:
        final = recorded_finals(path, final)
    differences, gaps = summary(final, reps)
    cautions += gaps
    caution = pd.DataFrame({"caution": cautions}, dtype=str)
    return {"curves": table, "finals": final, "summary": differences, "cautions": caution}


def figure(tables: dict[str, pd.DataFrame], out: Path) -> Path:
    """The learning curves of :func:`analyse`'s tables as ``out/curves.png``."""
    path = out / FIGURE
    plot(tables["curves"], path)
    return path
