"""The report's "How to read this": what each number on the page is and how it was made."""

from __future__ import annotations

from tacbench.bootstrap import CONFIDENCE
from tacbench.report.build import Report
from tacbench.report.stats import ALL_TASKS
from tacbench.verdicts import EXACT_LABELLINGS, PERMUTATIONS


def how_to_read(report: Report) -> list[str]:
    """The bullets of the page's \"How to read this\": what each number is and how it was made."""
    o = report.options
    metric = (
        "evaluation returns (`eval.csv`, deterministic policy; the reference code plots these)"
        if o.metric == "eval"
        else "training-episode returns (`train.csv`; the paper plots average training returns)"
    )
    return [
        f"Metric: {metric}. Switch with `--metric {'train' if o.metric == 'eval' else 'eval'}`.",
        f"Curves: every run is put on a grid of evenly spaced steps per task (at most "
        f"{o.grid_points}, fewer if no run logged that many points; linear interpolation of "
        "evaluations, per-interval averages of training episodes), "
        "nothing is extrapolated, then seeds are averaged; the band is ± 1 sample standard "
        "deviation over seeds. After a partial run stops, fewer seeds make up the mean.",
        f"Final = mean of a run's last {o.last} logged returns; best = its highest logged "
        "return; AUC = area under its return curve divided by the steps it spans (its average "
        "return over training). Tables show mean ± std over seeds.",
        "Normalised score (aggregates and profiles): per task, (final - lowest final of any run) "
        "/ (highest - lowest), over every run in this report, so 0 and 1 are the worst and best "
        "runs here; adding or removing methods moves the aggregate numbers, not the per-task "
        "rankings or probabilities of improvement.",
        f"IQM = mean of the middle 50 % of runs; intervals are {int(CONFIDENCE * 100)} % "
        f"percentile intervals of a stratified bootstrap ({o.reps} replications, runs "
        "resampled within each task), computed with rliable's estimators; each interval "
        "resamples from a seed drawn from its own runs, so runs of other methods or tasks "
        "added to the report leave it unchanged.",
        "P(method > q = 1) is the chance that a random run of the method beats a random run of "
        "TAC q = 1 with the same alpha on the same task (0.5 = no difference), shown with its "
        "bootstrap interval. The verdict (larger or smaller) is a two-sided permutation test "
        "at 5 % of P(X > Y), with the runs relabelled within each task (exactly over every "
        f"labelling up to {EXACT_LABELLINGS:,} of them, else {PERMUTATIONS:,} random ones: "
        "'p-value'): with few runs the "
        "bootstrap interval is too narrow to be that test, so an interval that excludes 0.5 can "
        "still read 'not distinguishable'. Each comparison stands on its own, not corrected "
        "for the table's many comparisons, unlike the family-wise sequential decisions. Where "
        "it is 'not distinguishable', 'detectable (80 % power)' says how large a difference of "
        "mean final returns these run counts would have found: the smallest one this test "
        "finds in 80 % of normal samples with the runs' pooled standard deviation "
        "(docs/sequential.md), so the verdict reads 'no difference larger "
        "than that'. Where "
        "even every run of one side above every run of the other would be no evidence (that "
        "ranking's chance when both are alike, 2 / C(n + m, n) for n and m runs, on an 'all "
        "tasks' row 2 over the product of the tasks' C(n + m, n), is above 5 %: three runs a "
        "side on one task give 2 in 20), the verdict is 'too few runs'.",
        *(
            [
                f"On an '{ALL_TASKS}' row, 'detectable' is a shift of every task's mean final "
                "return, in standard deviations of that task's runs ('SD per task'; the tasks' "
                "returns are on different scales), found by the same test with the runs "
                "permuted within each task."
            ]
            if _aggregate_detectable(report)
            else []
        ),
        "Performance profiles: the fraction of runs whose normalised final score exceeds tau; "
        "a curve above another is better everywhere.",
        *(
            [
                "TAC q=auto: q learned by population-based training (`--q auto`); the members "
                "of a population copy each other, so they are not independent runs: its "
                "statistics (intervals, probabilities of improvement, profiles; the 'runs' "
                "column) count one value per population, the mean of its members' scores; the "
                "curves and the summary table show the members."
            ]
            if not report.trajectories.empty
            else []
        ),
        "TAC (best q) takes, per task, the q ≠ 1 with the highest mean final return on these "
        "same runs (as the paper did), so its numbers are optimistic; where it was picked among "
        "several q, its comparisons carry no test (verdict 'not tested: chosen on these runs').",
        "Partial runs (still running or stopped before their planned steps) are included and "
        "counted in the partial column; failed or unreadable runs are left out and listed below.",
    ]


def _aggregate_detectable(report: Report) -> bool:
    """Whether an "all tasks" row of the page states a detectable shift."""
    return any(
        bool(frame.loc[frame["env"] == ALL_TASKS, "detectable"].notna().any())
        for frame in (report.improvement, report.baselines)
        if not frame.empty
    )
