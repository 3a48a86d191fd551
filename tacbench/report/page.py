"""The report's words and formatted tables: a :class:`Report` turned into page sections."""

from __future__ import annotations

import json
import math
from collections import Counter

import pandas as pd

from tacbench.errors import plural
from tacbench.report.build import Report
from tacbench.report.reading import how_to_read
from tacbench.report.render import Bullets, Code, Image, Section, Table, Text
from tacbench.report.stats import ALL_TASKS
from tacbench.sequential import NOT_DISTINGUISHABLE

TITLE = "tacbench report"


def _num(value: float, digits: int = 1) -> str:
    return "n/a" if value is None or math.isnan(value) else f"{value:.{digits}f}"


def _pm(mean: float, std: float, digits: int = 1) -> str:
    """Mean ± std; "n/a" without a mean (a method whose every run failed)."""
    return "n/a" if math.isnan(mean) else f"{_num(mean, digits)} ± {_num(std, digits)}"


def _ci(point: float, low: float, high: float, digits: int = 2) -> str:
    return f"{_num(point, digits)} [{_num(low, digits)}, {_num(high, digits)}]"


def _p_value(value: float) -> str:
    """A test's p-value: three decimals, below 0.001 as such ("" where there is no test)."""
    if value is None or math.isnan(value):
        return ""
    return "< 0.001" if value < 0.001 else f"{value:.3f}"


def _steps(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{int(value):,}"


def _q(value: float) -> str:
    return "" if math.isnan(value) else f"{value:g}"


def summary_display(report: Report) -> pd.DataFrame:
    """The per-task table as shown: one row per task and method."""
    s = report.summary
    return pd.DataFrame(
        {
            "task": s["env"],
            "method": s["method"],
            "alpha": s["alpha"],
            "seeds": s["seeds"],
            "partial": s["partial"],
            "failed": s["failed"],
            "steps reached": [
                _steps(a) if a == b or math.isnan(a) else f"{_steps(a)}–{_steps(b)}"
                for a, b in zip(s["steps_min"], s["steps_max"], strict=True)
            ],
            "planned": [_steps(v) for v in s["planned"]],
            f"final (last {report.options.last})": [
                _pm(m, d) for m, d in zip(s["final_mean"], s["final_std"], strict=True)
            ],
            "best": [_pm(m, d) for m, d in zip(s["best_mean"], s["best_std"], strict=True)],
            "AUC (mean return)": [
                _pm(m, d) for m, d in zip(s["auc_mean"], s["auc_std"], strict=True)
            ],
        }
    )


def best_q_display(report: Report) -> pd.DataFrame:
    """The best-q table as shown: a task with several settings names each row's."""
    b = report.best_q
    several = b["env"].duplicated(keep=False)  # a task with runs of several settings
    return pd.DataFrame(
        {
            "task": [
                f"{env} [{setting}]" if named else env
                for env, setting, named in zip(b["env"], b["setting"], several, strict=True)
            ],
            "best q (final)": [
                f"{_q(q)} ({_pm(m, d)})"
                for q, m, d in zip(b["best_q"], b["best_final"], b["best_final_std"], strict=True)
            ],
            "best q ≠ 1": [_q(q) for q in b["best_q_not_1"]],
            "P(best q ≠ 1 > q = 1) [95 % CI]": [
                _ci(p, lo, hi)
                for p, lo, hi in zip(b["p_best_over_q1"], b["p_low"], b["p_high"], strict=True)
            ],
            "ranking (final return)": b["ranking"],
            "paper's best q": b["paper_q"],
            "its rank here": b["paper_q_rank"],
            "agrees": b["agrees"],
            "best in [1, 2)": b["best_in_1_2"],
            "alpha here (paper)": [
                f"{a} ({'n/a' if pa is None or pd.isna(pa) else f'{pa:g}'})"
                for a, pa in zip(b["alpha"], b["paper_alpha"], strict=True)
            ],
            "paper says": b["paper_note"],
        }
    )


def q_ranges_display(report: Report) -> pd.DataFrame:
    """The q-range table as shown (:mod:`tacbench.report.ranges`): a task with runs at several
    alphas names each row's."""
    r = report.q_ranges
    last = report.options.last
    several = r.groupby("env")["alpha"].transform("nunique") > 1
    return pd.DataFrame(
        {
            "task": [
                f"{env} [a{alpha:g}]" if named else env
                for env, alpha, named in zip(r["env"], r["alpha"], several, strict=True)
            ],
            "q range": r["range"],
            "q": r["qs"],
            "runs": r["runs"],
            "IQM final [95 % CI]": [
                _ci(p, lo, hi, 1 if env != ALL_TASKS else 2)
                for env, p, lo, hi in zip(
                    r["env"], r["iqm"], r["iqm_low"], r["iqm_high"], strict=True
                )
            ],
            f"spread (std of last {last})": [_num(v) for v in r["spread"]],
            "P(1 <= q < 2 > this range) [95 % CI]": [
                "" if math.isnan(p) else _ci(p, lo, hi)
                for p, lo, hi in zip(r["p_middle"], r["p_low"], r["p_high"], strict=True)
            ],
            "p-value": [_p_value(v) for v in r["p_value"]],
            "verdict": r["verdict"].fillna(""),
        }
    )


def _estimates_display(frame: pd.DataFrame, first: list[str]) -> pd.DataFrame:
    shown = frame[first].copy()
    shown["IQM [95 % CI]"] = [
        _ci(p, lo, hi)
        for p, lo, hi in zip(frame["iqm"], frame["iqm_low"], frame["iqm_high"], strict=True)
    ]
    shown["mean [95 % CI]"] = [
        _ci(p, lo, hi)
        for p, lo, hi in zip(frame["mean"], frame["mean_low"], frame["mean_high"], strict=True)
    ]
    return shown


def _probability_display(frame: pd.DataFrame, identity: list[str], label: str) -> pd.DataFrame:
    """A table of P(X > Y): ``identity`` columns (``env`` shown as task), then ``label``'s
    interval, its test's p-value, the verdict, the mean difference and, if not distinguishable,
    the detectable one."""
    shown = frame[identity].rename(columns={"env": "task"})
    shown[f"{label} [95 % CI]"] = [
        _ci(p, lo, hi) for p, lo, hi in zip(frame["p"], frame["low"], frame["high"], strict=True)
    ]
    shown["p-value"] = [_p_value(v) for v in frame["p_value"]]
    shown["verdict"] = frame["verdict"]
    shown["mean difference"] = [_num(v) for v in frame["difference"]]
    shown["detectable (80 % power)"] = _detectable(
        frame["detectable"], frame["verdict"], frame["env"]
    )
    return shown


def _detectable(values: pd.Series, verdicts: pd.Series, envs: pd.Series | None = None) -> list[str]:
    """Each not-distinguishable verdict's detectable difference ("" for the others); on an
    "all tasks" row a shift in standard deviations of each task's runs."""
    tasks = [None] * len(values) if envs is None else list(envs)
    shown = []
    for v, d, task in zip(values, verdicts, tasks, strict=True):
        if d != NOT_DISTINGUISHABLE:
            shown.append("")
        elif math.isinf(v):
            shown.append("beyond these run counts")
        elif task == ALL_TASKS:
            shown.append("n/a" if math.isnan(v) else f"{v:.2f} SD per task")
        else:
            shown.append(_num(v))
    return shown


def _overview(report: Report) -> list[str]:
    runs = report.runset.runs
    o = report.options
    items = [
        f"{plural(len(runs), 'run')} on {plural(len(report.envs), 'task')} "
        f"({', '.join(report.envs)}) and {plural(len(report.methods), 'method')}, from "
        f"`{report.runset.root}`.",
        f"Regenerate: `tacbench report --results {o.results} --out {o.out} --metric {o.metric} "
        f"--format {o.fmt} --reps {o.reps} --last {o.last} --grid-points {o.grid_points}`.",
    ]
    if runs["partial"].any():
        items.append(f"{plural(int(runs['partial'].sum()), 'partial run')} included (see Runs).")
    if report.runset.skipped:
        skipped = plural(len(report.runset.skipped), "run directory", "run directories")
        items.append(f"{skipped} skipped (see Runs).")
    items += [f"Caution: {caution}" for caution in report.cautions]
    return items


def _provenance(report: Report) -> list[Table | Code | Text]:
    runs = report.runset.runs
    versions = Counter(runs["versions"])
    keys = sorted({k for v in versions for k in json.loads(v)})
    table = pd.DataFrame(
        [{"runs": n, **json.loads(v)} for v, n in versions.most_common()], columns=["runs", *keys]
    ).fillna("")
    commits = Counter(runs["git_commit"])
    hosts = Counter(runs["host"])
    created = sorted(c for c in runs["created"] if c)
    span = f"{created[0]} to {created[-1]}" if created else "unknown"
    commands = sorted(set(runs["command"]))
    return [
        Table(table, "Library versions recorded in config.json, with the number of runs"),
        Text(
            "Git commits: "
            + ", ".join(f"`{c or 'unknown'}` ({n})" for c, n in commits.most_common())
            + ". Hosts: "
            + ", ".join(f"{h or 'unknown'} ({n})" for h, n in hosts.most_common())
            + f". Runs created {span}."
        ),
        Code(
            "The command that produced the runs"
            if len(commands) == 1
            else f"The {len(commands)} distinct commands that produced the runs",
            commands,
        ),
    ]


def _runs_section(report: Report) -> list[Table | Text]:
    runs = report.runset.runs
    partial = runs[runs["partial"]]
    shown = {
        "run": partial["path"],
        "state": partial["state"],
        "steps reached": [_steps(v) for v in partial["step_reached"]],
        "planned": [_steps(v) for v in partial["total_steps"]],
        "note": partial["note"],
    }
    blocks: list[Table | Text] = [
        Table(pd.DataFrame(shown), "Partial runs (included)")
        if len(partial)
        else Text("Every loaded run is complete.")
    ]
    noted = runs[~runs["partial"] & runs["note"].fillna("").astype(bool)]
    if len(noted):  # rows dropped (non-finite returns) from a complete run
        notes = pd.DataFrame({"run": noted["path"], "note": noted["note"]})
        blocks.append(Table(notes, "Complete runs with a note (included)"))
    if report.runset.skipped:
        skipped = pd.DataFrame(
            {
                "run directory": [s.path for s in report.runset.skipped],
                "reason": [s.reason for s in report.runset.skipped],
            }
        )
        blocks.append(Table(skipped, "Skipped run directories (left out of everything)"))
    return blocks


def _sequential_section(report: Report) -> list[Section]:
    """The decisions of a sequential sweep (``sweep --until-decided``), where one ran here."""
    if report.sequential.empty:
        return []
    d = report.sequential
    decisions = pd.DataFrame(
        {
            "task": d["env"],
            "method": d["method"],
            "against": d["against"],
            "decision": d["decision"],
            "decided at interim": ["" if pd.isna(v) else f"{v:g}" for v in d["interim"]],
            "runs of the pair": d["runs"],
            "detectable (80 % power)": _detectable(d["detectable"], d["decision"]),
        }
    )
    spent = report.spending.rename(
        columns={"env": "task", "runs": "runs spent", "fixed_design_runs": "fixed design"}
    )
    return [
        Section(
            "Sequential decisions",
            [
                Text(
                    "`tacbench sweep --until-decided` trained these runs in interims and "
                    "AdaStop decided each comparison from the runs' final returns, the "
                    "family-wise error rate shared by a task's comparisons "
                    "(`sweep/sequential.json`, docs/sequential.md). 'not distinguishable': "
                    "still open after the last interim; 'detectable': as in the improvement "
                    "tables."
                ),
                Table(decisions, "Decisions per task"),
                Table(spent, "Runs spent, against the fixed design of n x K seeds per method"),
            ],
        )
    ]


def sections(report: Report) -> list[Section]:
    """The whole page, in order."""
    anchors = report.anchors.assign(
        low=[_num(v) for v in report.anchors["low"]], high=[_num(v) for v in report.anchors["high"]]
    ).rename(columns={"env": "task", "low": "score 0 (lowest final)", "high": "score 1 (highest)"})
    per_task = report.per_task.rename(columns={"env": "task"})
    aggregate = _estimates_display(report.aggregate, ["method", "tasks", "runs"])
    return [
        Section("Overview", [Bullets(_overview(report))]),
        Section("How to read this", [Bullets(how_to_read(report))]),
        Section(
            "Effect of the entropic index",
            [
                Image("q_sweep", "TAC for every q: mean over seeds, shaded ± 1 std."),
                Image(
                    "q_trajectories",
                    "TAC q=auto: the q of every population member over training (pbt.csv has "
                    "each decision).",
                ),
                Table(best_q_display(report), "Best q per task, compared with the paper"),
                Table(
                    q_ranges_display(report),
                    "The paper's claim by range of q (section 7.1: 1 <= q < 2 better than "
                    "0 < q < 1 and q >= 2 in stable convergence and final return): TAC's runs "
                    "with a fixed alpha pooled per range; spread = mean within-run std of the "
                    "last logged returns (lower is steadier); the verdict is the permutation "
                    "test of P(1 <= q < 2 > this range), as the improvement table's; 'all tasks' "
                    "pools normalised scores",
                )
                if not report.q_ranges.empty
                else Text(
                    "The paper's claim by range of q (section 7.1) needs TAC runs at 1 <= q < 2 "
                    "and in another range on one task; these runs have none to compare."
                ),
            ],
        ),
        Section(
            "Comparison with actor-critic methods",
            [
                Image(
                    "comparison",
                    "TAC at its best q ≠ 1 (blue pentagons), SAC = TAC q = 1 (red squares) "
                    "and the baselines: mean over seeds, shaded ± 1 std.",
                ),
                Table(summary_display(report), "Per task and method (mean ± std over seeds)"),
                *(
                    [
                        Table(
                            _probability_display(
                                report.baselines,
                                ["method", "baseline", "env", "tasks"],
                                "P(method > baseline)",
                            ),
                            "TAC against each baseline: P(method > baseline) is the chance that a "
                            "random run of the method beats a random run of the baseline on the "
                            "same task (final returns; read as P(method > q = 1) below)",
                        )
                    ]
                    if not report.baselines.empty
                    else []
                ),
            ],
        ),
        Section(
            "Statistics (rliable)",
            [
                Image("intervals", "Aggregate IQM and mean of normalised final scores."),
                Table(aggregate, "Aggregate over tasks (normalised scores)"),
                Table(anchors, "Normalisation anchors per task"),
                Image("intervals_per_task", "Per task IQM of the final return."),
                Table(
                    _estimates_display(per_task, ["task", "method", "runs"]),
                    "Per task (final return)",
                ),
                Image("improvement", f"P(method > q = 1); '{ALL_TASKS}' averages over tasks."),
                Table(
                    _probability_display(
                        report.improvement, ["method", "env", "tasks"], "P(method > q = 1)"
                    ),
                    "Probability of improvement over q = 1",
                )
                if not report.improvement.empty
                else Text(
                    "The probability of improvement over q = 1 needs TAC runs at q = 1 and at "
                    "another q on one task, with the same alpha and products; these runs have "
                    "none to compare."
                ),
                Image("profiles", "Score distributions with 95 % bands."),
            ],
        ),
        *_sequential_section(report),
        Section("Runs", _runs_section(report)),
        Section("Provenance", _provenance(report)),
    ]
