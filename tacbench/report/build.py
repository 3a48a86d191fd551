"""From a results directory to every table and figure of the report (nothing written here).

:func:`analyse` runs the layers in order: load -> per-run scores -> tables -> curves ->
rliable statistics -> figures, and returns them in a :class:`Report`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from tacbench import memory
from tacbench.errors import TacbenchError
from tacbench.paper import task_sort_key
from tacbench.report import plots
from tacbench.report.curves import run_matrix, seed_curves
from tacbench.report.load import RunSet, load_runs
from tacbench.report.methods import (
    BEST_Q_LABEL,
    Q_AUTO_LABEL,
    SAC_LABEL,
    assign_methods,
    method_sort_key,
)
from tacbench.report.mixing import cautions, eval_intervals
from tacbench.report.population import one_per_population, q_trajectories, unlogged_q
from tacbench.report.ranges import q_range_table
from tacbench.report.series import METRIC_SOURCES, Metric
from tacbench.report.stats import (
    ALL_TASKS,
    DEFAULT_REPS,
    aggregate_estimates,
    detectable_runs,
    improvement_over_baselines,
    improvement_over_q1,
    per_task_estimates,
    profile_table,
)
from tacbench.report.tables import (
    DEFAULT_LAST,
    best_q_rows,
    best_q_table,
    normalise,
    run_scores,
    summary_table,
)
from tacbench.sequential import (
    NOT_DISTINGUISHABLE,
    SequentialResult,
    decision_table,
    spending_table,
)
from tacbench.sequential_record import RECORD_FILE, read_record, results_of_record
from tacbench.verdicts import CHOSEN_ON_THESE_RUNS

FORMATS: tuple[str, ...] = ("png", "svg", "pdf")
DEFAULT_GRID_POINTS = 200
PROFILE_TAUS = np.linspace(0.0, 1.0, 101)
_IDENTITY = ["algo", "env", "variant", "q", "alpha", "seed", "population"]


@dataclass(frozen=True)
class ReportOptions:
    """What to report on and how; the defaults are the CLI's (see ``docs/report.md``)."""

    results: Path
    out: Path
    metric: str = "eval"
    fmt: str = "png"
    reps: int = DEFAULT_REPS
    last: int = DEFAULT_LAST
    grid_points: int = DEFAULT_GRID_POINTS
    seed: int = 0

    def __post_init__(self) -> None:
        if self.metric not in METRIC_SOURCES:
            raise TacbenchError(
                f"unknown metric {self.metric!r}; use one of {sorted(METRIC_SOURCES)}"
            )
        if self.fmt not in FORMATS:
            raise TacbenchError(f"unknown figure format {self.fmt!r}; use one of {FORMATS}")
        for name, minimum in (("reps", 100), ("last", 1), ("grid_points", 2)):
            if getattr(self, name) < minimum:
                raise TacbenchError(f"--{name.replace('_', '-')} must be at least {minimum}")


@dataclass
class Report:
    """Everything the report shows; tables are DataFrames, figures matplotlib Figures."""

    options: ReportOptions
    runset: RunSet
    scores: pd.DataFrame
    failed: pd.DataFrame
    summary: pd.DataFrame
    best_q: pd.DataFrame
    curves: pd.DataFrame
    anchors: pd.DataFrame
    per_task: pd.DataFrame
    aggregate: pd.DataFrame
    improvement: pd.DataFrame
    baselines: pd.DataFrame  # TAC (best q) and SAC against each baseline
    profiles: pd.DataFrame
    q_ranges: pd.DataFrame
    envs: list[str]
    methods: list[str]
    qs: dict[str, float]
    trajectories: pd.DataFrame  # TAC q=auto: each member's q over training
    sequential: pd.DataFrame  # sweep --until-decided: each comparison's decision (or empty)
    spending: pd.DataFrame  # ... and each task's runs against the fixed design
    figures: dict[str, Figure] = field(default_factory=dict)

    @property
    def cautions(self) -> list[str]:
        """What the comparisons take as alike (:func:`mixing.cautions`, and for evaluation
        returns :func:`mixing.eval_intervals`), and the populations' members whose q was not
        logged (:func:`population.unlogged_q`)."""
        runset, last = self.runset, self.options.last
        spacing = eval_intervals(runset.data, last) if runset.metric == "eval" else []
        return [*cautions(runset.runs, last), *spacing, *unlogged_q(self.trajectories)]

    @property
    def tac_methods(self) -> list[str]:
        """TAC methods (SAC included) in q order, then TAC q=auto."""
        return [m for m in self.methods if not math.isnan(self.qs[m]) or m.startswith(Q_AUTO_LABEL)]

    @property
    def comparison_methods(self) -> list[str]:
        """TAC at the best q, SAC, then the baselines (the paper's comparison figure); TAC
        q=auto is in the q-sweep figure."""
        chosen = [
            m
            for m in self.methods
            if (math.isnan(self.qs[m]) and not m.startswith(Q_AUTO_LABEL))
            or m.startswith(SAC_LABEL)
        ]
        return sorted(chosen, key=lambda m: (m != BEST_Q_LABEL, not m.startswith(SAC_LABEL)))


def _failed_runs(runset: RunSet) -> pd.DataFrame:
    rows = [s.identity for s in runset.skipped if s.identity is not None]
    return pd.DataFrame(rows, columns=_IDENTITY)


def _with_best_q(scores: pd.DataFrame, best: pd.DataFrame) -> pd.DataFrame:
    """``scores`` plus a copy of each task's best-q (q != 1) runs labelled TAC (best q)."""
    chosen = scores.merge(best[["env", "method"]], on=["env", "method"])
    return pd.concat([scores, chosen.assign(method=BEST_Q_LABEL)], ignore_index=True)


def _untested_where_chosen(table: pd.DataFrame, best: pd.DataFrame) -> pd.DataFrame:
    """``table`` (improvement or baselines) without a test for TAC (best q) on each task whose q
    was picked among several by these runs (:func:`best_q_rows`' ``candidates``), and over all
    tasks where such a task is among them: the picked q's P against a fixed level is biased
    upwards (equal q values on six tasks were called larger 62 % of the time), so its p-value is
    left empty and its verdict says why. P and its interval stay, optimistic (docs/report.md)."""
    chosen = set(best.loc[best["candidates"] > 1, "env"])
    if table.empty or not chosen:
        return table
    pairs = ["method", "baseline"] if "baseline" in table else ["method"]  # a row's own tasks
    picked = table["env"].isin(chosen).groupby([table[c] for c in pairs]).transform("any")
    over_chosen = table["env"].eq(ALL_TASKS) & picked
    rows = (table["method"] == BEST_Q_LABEL) & (table["env"].isin(chosen) | over_chosen)
    table = table.copy()
    table.loc[rows, ["p_value", "detectable"]] = np.nan
    table.loc[rows, "verdict"] = CHOSEN_ON_THESE_RUNS
    return table


def _in_order(frame: pd.DataFrame, envs: list[str], methods: list[str]) -> pd.DataFrame:
    """Rows by task (paper order, 'all tasks' first) then method (figure order)."""
    ranks = {
        "env": {e: i for i, e in enumerate([ALL_TASKS, *envs])},
        "method": {m: i for i, m in enumerate(methods)},
    }
    columns = [c for c in ("env", "method") if c in frame.columns]
    if frame.empty or not columns:
        return frame
    return frame.sort_values(
        columns, key=lambda col: col.map(ranks[str(col.name)]), kind="stable"
    ).reset_index(drop=True)


def _tac_comparators(methods: list[str]) -> list[str]:
    """TAC at its best q, then SAC: the TAC side of the comparison with the baselines."""
    return [m for m in methods if m == BEST_Q_LABEL or m.startswith(SAC_LABEL)]


def _baselines(methods: list[str], qs: dict[str, float]) -> list[str]:
    """The methods that are not TAC (no q, and neither TAC at its best q nor TAC q=auto)."""
    return [
        m
        for m in methods
        if math.isnan(qs[m]) and m != BEST_Q_LABEL and not m.startswith(Q_AUTO_LABEL)
    ]


def _sequential_results(results: Path) -> tuple[dict[str, SequentialResult], pd.DataFrame]:
    """What ``<results>/sweep/sequential.json`` recorded (nothing without one), and its
    decision table with, for each comparison left not distinguishable, the difference its
    runs could have detected (``detectable``, as in the improvement tables)."""
    path = results / "sweep" / RECORD_FILE
    if not path.exists():
        return {}, decision_table({}).assign(detectable=np.nan)
    record = read_record(path)
    recorded = results_of_record(record)
    table = decision_table(recorded)
    detectable = [
        detectable_runs(np.array(given[against]), np.array(given[method]))
        if decision == NOT_DISTINGUISHABLE
        else np.nan
        for method, against, decision, given in zip(
            table["method"],
            table["against"],
            table["decision"],
            [record["interims"][env][-1]["scores"] for env in table["env"]],
            strict=True,
        )
    ]
    return recorded, table.assign(detectable=detectable)


def _check_bootstrap_fits(runs: int, reps: int) -> None:
    """Refuse ``reps`` replications that would not fit in memory. A bootstrap holds, for each
    replication, a resampling index of every run it draws from (at most all ``runs``) and its
    values, twice while they are put together: 101 of them for the performance profiles. (The
    curves need no guard: their grid is never finer than the rows the runs logged.) Measured:
    90 runs, about 1.2 kB a replication; this says 2.3 kB."""
    per_replication = 8 * (runs + 2 * len(PROFILE_TAUS))
    needs = {"the bootstrap's replications": per_replication * reps}
    memory.check_fits(needs, "--reps", "this report")


def analyse(options: ReportOptions) -> Report:
    """Load the runs under ``options.results`` and compute every table, statistic and figure."""
    metric = cast(Metric, options.metric)
    runset = load_runs(options.results, metric)
    failed = _failed_runs(runset)
    identities = [runset.runs[_IDENTITY], *([failed[_IDENTITY]] if len(failed) else [])]
    labels = assign_methods(pd.concat(identities, ignore_index=True))
    runs = runset.runs.assign(method=labels.iloc[: len(runset.runs)].to_numpy())
    failed = failed.assign(method=labels.iloc[len(runset.runs) :].to_numpy())

    scores = runs.join(run_scores(runset.data, options.last), on="run")
    scores["score"], anchors = normalise(scores)
    summary = summary_table(scores, failed)
    best = best_q_rows(summary)
    extended = _with_best_q(scores, best)
    independent = one_per_population(extended)  # what the statistics count
    _check_bootstrap_fits(len(independent), options.reps)

    grids, values = run_matrix(runset.data, runs, options.grid_points, metric)
    rows = pd.Index(runs["run"]).get_indexer(extended["run"])
    curves = seed_curves(grids, values[rows], extended.reset_index(drop=True))

    qs = {str(m): float(q) for m, q in extended.groupby("method")["q"].first().items()}
    qs[BEST_Q_LABEL] = math.nan
    methods = sorted(qs, key=lambda m: method_sort_key(m, qs[m]))
    q_methods = [m for m in methods if not math.isnan(qs[m]) and qs[m] != 1.0]
    q_methods += [m for m in methods if m.startswith(Q_AUTO_LABEL)]
    improvement = _untested_where_chosen(
        improvement_over_q1(independent, [*q_methods, BEST_Q_LABEL], options.reps, options.seed),
        best,
    )
    envs = sorted((str(e) for e in runs["env"].unique()), key=task_sort_key)
    recorded, decisions = _sequential_results(options.results)
    methods = [m for m in methods if m in set(extended["method"])]
    # the summary also lists the methods whose every run on a task failed, in their q's place
    failed_qs = {str(m): float(q) for m, q in failed.groupby("method")["q"].first().items()}
    listed = {**failed_qs, **qs}
    summarised = sorted(set(summary["method"]), key=lambda m: method_sort_key(m, listed[m]))
    report = Report(
        options=options,
        runset=runset,
        scores=scores,
        failed=failed,
        summary=_in_order(summary, envs, summarised),
        best_q=_in_order(best_q_table(summary, improvement), envs, methods),
        curves=curves,
        anchors=_in_order(anchors, envs, methods),
        per_task=_in_order(
            per_task_estimates(independent, options.reps, options.seed), envs, methods
        ),
        aggregate=_in_order(
            aggregate_estimates(independent, options.reps, options.seed), envs, methods
        ),
        improvement=_in_order(improvement, envs, methods),
        profiles=profile_table(independent, PROFILE_TAUS, options.reps, options.seed),
        q_ranges=_in_order(
            q_range_table(scores, runset.data, options.last, options.reps, options.seed),
            envs,
            methods,
        ),
        baselines=_in_order(
            _untested_where_chosen(
                improvement_over_baselines(
                    independent,
                    _tac_comparators(methods),
                    _baselines(methods, qs),
                    options.reps,
                    options.seed,
                ),
                best,
            ),
            envs,
            methods,
        ),
        envs=envs,
        methods=methods,
        qs=qs,
        trajectories=q_trajectories(runs, runset.root),
        sequential=decisions,
        spending=spending_table(recorded),
    )
    report.figures = make_figures(report)
    return report


def make_figures(report: Report) -> dict[str, Figure]:
    """Every figure of the report by file stem; figures without data are left out."""
    ylabel = "evaluation return" if report.options.metric == "eval" else "training return"
    tac_envs = [
        e for e in report.envs if e in set(report.curves.loc[report.curves["q"].notna(), "env"])
    ]
    figures: dict[str, Figure] = {}
    if tac_envs:
        figures["q_sweep"] = plots.curve_figure(
            report.curves,
            tac_envs,
            report.tac_methods,
            report.qs,
            "Effect of the entropic index q: TAC, mean ± 1 std over seeds",
            ylabel,
        )
    if not report.trajectories.empty:
        figures["q_trajectories"] = plots.q_trajectory_figure(
            report.trajectories,
            [e for e in report.envs if e in set(report.trajectories["env"])],
            "TAC q=auto: each member's q (colour: population)",
        )
    if report.comparison_methods:  # none where TAC q=auto is the only method
        figures["comparison"] = plots.curve_figure(
            report.curves,
            report.envs,
            report.comparison_methods,
            report.qs,
            "Comparison with actor-critic methods (TAC at its best q ≠ 1 per task), mean ± 1 std",
            ylabel,
        )
    figures["intervals"] = plots.interval_figure(
        report.aggregate,
        report.methods,
        report.qs,
        "All tasks: normalised final score, 95 % stratified-bootstrap intervals",
    )
    figures["intervals_per_task"] = plots.task_interval_figure(
        report.per_task,
        report.envs,
        report.methods,
        report.qs,
        "Per task: final return, IQM over seeds with 95 % bootstrap intervals",
    )
    if not report.improvement.empty:
        panels = [p for p in [ALL_TASKS, *report.envs] if p in set(report.improvement["env"])]
        figures["improvement"] = plots.improvement_figure(
            report.improvement,
            panels,
            report.methods,
            report.qs,
            "Probability of improvement over q = 1 (same task, same alpha), 95 % intervals",
        )
    figures["profiles"] = plots.profile_figure(
        report.profiles,
        {
            "TAC entropic indices": report.tac_methods,
            "Comparison": report.comparison_methods,
        },
        report.qs,
        "Performance profiles: normalised final scores of all runs, 95 % bands",
    )
    return figures
