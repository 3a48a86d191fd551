"""rliable estimators and their bootstrap intervals: values, unequal run counts, coverage."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from rliable import metrics
from scipy.stats import norm, trim_mean

from tacbench.bootstrap import strata_seed
from tacbench.detectable import detectable_shift
from tacbench.report.stats import (
    ALL_TASKS,
    detectable_runs,
    improvement_over_baselines,
    improvement_over_q1,
    interval_estimates,
    iqm,
    per_task_estimates,
    performance_profile,
    probability_of_improvement,
)
from tacbench.verdicts import TOO_FEW_RUNS

pytestmark = pytest.mark.unit


def test_point_estimates_are_rliables() -> None:
    rng = np.random.default_rng(1)
    matrix = rng.normal(size=(7, 3))
    estimates = interval_estimates(list(matrix.T), 200, seed=0)
    assert estimates["iqm"][0] == pytest.approx(metrics.aggregate_iqm(matrix))
    assert estimates["mean"][0] == pytest.approx(metrics.aggregate_mean(matrix))
    other = rng.normal(0.3, 1.0, size=(5, 3))
    p, _, _ = probability_of_improvement(list(other.T), list(matrix.T), 200, seed=0)
    assert p == pytest.approx(metrics.probability_of_improvement(other, matrix))


@pytest.mark.parametrize("runs", [1, 2, 3, 4, 5, 7, 8, 10, 13, 40])
def test_the_bootstraps_iqm_is_rliables_for_every_run_count(runs: int) -> None:
    tasks = list(np.random.default_rng(runs).normal(size=(runs, 3)).T)
    matrix = np.stack(tasks, axis=1)
    assert iqm(*tasks) == pytest.approx(metrics.aggregate_iqm(matrix), rel=1e-12)
    assert iqm(*tasks) == pytest.approx(trim_mean(matrix.ravel(), 0.25), rel=1e-12)


def test_tasks_may_have_different_run_counts() -> None:
    tasks = [np.array([1.0, 2.0, 3.0, 4.0]), np.array([10.0, 20.0])]
    estimates = interval_estimates(tasks, 300, seed=0)
    assert estimates["iqm"][0] == pytest.approx(trim_mean(np.concatenate(tasks), 0.25))
    assert estimates["mean"][0] == pytest.approx((2.5 + 15.0) / 2)
    p, low, high = probability_of_improvement(
        [np.array([5.0, 6.0]), np.array([1.0])],
        [np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0])],
        300,
        seed=0,
    )
    assert p == pytest.approx((1.0 + 0.75) / 2)  # task 2: one tie and one win of two pairs
    assert low <= p <= high


def test_degenerate_and_separated_samples() -> None:
    # one run: the bootstrap draws it again and again; "4.0 [4.0, 4.0]" read as certain
    point, low, high = interval_estimates([np.array([4.0])], 100, seed=0)["iqm"]
    assert point == 4.0 and math.isnan(low) and math.isnan(high)
    point, low, high = interval_estimates([np.array([4.0]), np.array([2.0])], 100, seed=0)["mean"]
    assert point == 3.0 and math.isnan(low) and math.isnan(high)  # one run on each task
    assert not math.isnan(interval_estimates([np.array([4.0, 5.0])], 100, seed=0)["iqm"][1])
    p, low, high = probability_of_improvement([np.array([4.0])], [np.array([2.0])], 100, seed=0)
    assert p == 1.0 and math.isnan(low) and math.isnan(high)
    same = [np.array([1.0, 2.0, 3.0])]
    assert probability_of_improvement(same, same, 100, seed=0)[0] == 0.5
    high = [np.array([10.0, 11.0])]
    assert probability_of_improvement(high, same, 100, seed=0) == (1.0, 1.0, 1.0)


def test_mean_and_iqm_intervals_cover_the_true_values_at_about_95_percent() -> None:
    """Each bootstrap gives both intervals: one set of trials checks both. Three tasks of 10
    runs, N(-1, 1), N(0, 1) and N(1, 1): the mean of the task means is 0, and the pooled
    mixture is symmetric about 0, so its interquartile mean is 0 too."""
    rng = np.random.default_rng(12345)
    trials, hits = 300, {"mean": 0, "iqm": 0}
    for trial in range(trials):
        tasks = [rng.normal(mu, 1.0, size=10) for mu in (-1.0, 0.0, 1.0)]
        estimates = interval_estimates(tasks, 500, seed=trial)
        for name in hits:
            _, low, high = estimates[name]
            hits[name] += low <= 0.0 <= high
    # the percentile bootstrap under-covers slightly with 10 runs per task (0.92-0.94 here);
    # 300 trials -> sd 1.3 %. The band leaves out 99 % intervals (0.96-0.97 on these trials)
    for name, count in hits.items():
        assert 0.90 <= count / trials <= 0.96, name


def test_each_interval_is_its_own_statistics() -> None:
    """The coverage test above holds for any interval centred on a symmetric estimate (both
    true values are 0), so an IQM interval computed as the mean's would pass it: with one
    outlying run the two must differ, the IQM's leaving the outlier out."""
    tasks = [np.array([0.0] * 7 + [100.0]), np.array([1.0, 2.0, 3.0, 4.0])]
    estimates = interval_estimates(tasks, 1000, seed=0)
    iqm_value, iqm_low, iqm_high = estimates["iqm"]
    mean_value, mean_low, mean_high = estimates["mean"]
    assert iqm_value == pytest.approx(trim_mean(np.concatenate(tasks), 0.25))
    assert mean_value == pytest.approx((100.0 / 8 + 2.5) / 2)
    assert iqm_high < mean_value and iqm_low <= iqm_value <= iqm_high
    assert mean_low <= mean_value <= mean_high and mean_high > 5.0


def test_improvement_intervals_cover_the_true_probability() -> None:
    rng = np.random.default_rng(7)
    true_p = norm.cdf(0.8 / np.sqrt(2))  # P(X > Y) for X ~ N(0.8, 1), Y ~ N(0, 1)
    hits = 0
    trials = 200
    for trial in range(trials):
        xs = [rng.normal(0.8, 1.0, size=10) for _ in range(2)]
        ys = [rng.normal(0.0, 1.0, size=10) for _ in range(2)]
        _, low, high = probability_of_improvement(xs, ys, 500, seed=trial)
        hits += low <= true_p <= high
    # 0.915 here; 99 % intervals cover 0.98 of these trials, 90 % ones fewer than 0.88
    assert 0.88 <= hits / trials <= 0.96


def test_performance_profile_values_and_bands() -> None:
    tasks = [np.array([0.1, 0.5, 0.9]), np.array([0.2, 0.6])]
    taus = np.array([0.0, 0.3, 0.5, 0.55, 1.0])
    profile, low, high = performance_profile(tasks, taus, 400, seed=0)
    np.testing.assert_allclose(profile, [1.0, 0.6, 0.4, 0.4, 0.0])  # above tau, not at it
    assert np.all(low <= profile) and np.all(profile <= high)
    assert low[0] == high[0] == 1.0 and low[-1] == high[-1] == 0.0


def test_improvement_compares_with_q1_runs_of_the_same_alpha_and_alpha_mode() -> None:
    rows = []
    for env in ("A", "B"):
        for q, alpha, variant, finals in (
            (1.0, 0.2, "q1-a0.2", [1.0, 2.0]),
            (1.0, 0.1, "q1-a0.1", [50.0, 60.0]),
            (1.0, 0.2, "q1-aauto0.2", [10.0, 11.0]),
            (1.5, 0.2, "q1.5-a0.2", [3.0, 4.0]),
            (1.5, 0.2, "q1.5-aauto0.2", [5.0, 6.0]),
        ):
            label = ("SAC" if q == 1.0 else "TAC q=1.5") + (" auto" if "auto" in variant else "")
            rows += [
                {
                    "env": env,
                    "method": label,
                    "q": q,
                    "alpha": alpha,
                    "variant": variant,
                    "final": f,
                }
                for f in finals
            ]
    scores = pd.DataFrame(rows)
    methods = ["TAC q=1.5", "TAC q=1.5 auto"]
    table = improvement_over_q1(scores, methods, 200, 0)
    assert table["env"].tolist() == ["A", "B", ALL_TASKS] * 2
    # fixed 0.2 against fixed 0.2 (1, 2): wins; learned against learned (10, 11): losses
    assert table["p"].tolist() == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    assert table["tasks"].tolist() == [1, 1, 2] * 2


def test_improvement_compares_bf16_runs_with_bf16_q1_runs_only() -> None:
    """A float32 q = 1.5 was compared with the q = 1 runs of both products pooled (here P 0.5,
    not distinguishable, where against its float32 q = 1 alone it wins every pair); a bf16 one
    compares with bf16 q = 1 runs, and a task without them is left out."""
    runs = (
        ("A", "SAC", 1.0, "q1-a0.2", [1.0, 2.0]),
        ("A", "SAC bf16", 1.0, "q1-a0.2-bf16", [100.0, 200.0]),
        ("A", "TAC q=1.5", 1.5, "q1.5-a0.2", [3.0, 4.0]),
        ("A", "TAC q=1.5 bf16", 1.5, "q1.5-a0.2-bf16", [150.0, 160.0]),
        ("B", "SAC", 1.0, "q1-a0.2", [1.0, 2.0]),
        ("B", "TAC q=1.5 bf16", 1.5, "q1.5-a0.2-bf16", [150.0, 160.0]),
    )
    scores = pd.DataFrame(
        [
            {"env": e, "method": m, "q": q, "alpha": 0.2, "variant": v, "final": f}
            for e, m, q, v, finals in runs
            for f in finals
        ]
    )
    table = improvement_over_q1(scores, ["TAC q=1.5", "TAC q=1.5 bf16"], 200, 0)
    assert table[["method", "env", "p"]].values.tolist() == [
        ["TAC q=1.5", "A", 1.0],
        ["TAC q=1.5 bf16", "A", 0.5],
    ]


def test_baseline_comparison_pairs_each_method_with_each_baseline_on_shared_tasks() -> None:
    finals = {
        ("A", "TAC (best q)"): [5.0, 6.0, 7.0],
        ("A", "DDPG"): [1.0, 2.0],
        ("A", "PPO"): [10.0, 11.0],
        ("B", "TAC (best q)"): [5.0, 6.0],
        ("B", "DDPG"): [1.0, 2.0, 3.0],
        ("C", "TAC (best q)"): [0.0, 1.0],  # no baseline ran here: left out
    }
    scores = pd.DataFrame(
        [{"env": env, "method": m, "final": f} for (env, m), fs in finals.items() for f in fs]
    )
    table = improvement_over_baselines(scores, ["TAC (best q)"], ["DDPG", "PPO"], 200, 0)
    assert table[["baseline", "env"]].values.tolist() == [
        ["DDPG", "A"],
        ["DDPG", "B"],
        ["DDPG", ALL_TASKS],
        ["PPO", "A"],
    ]
    assert table["p"].tolist() == [1.0, 1.0, 1.0, 0.0]
    assert table["tasks"].tolist() == [1, 1, 2, 1]
    # three runs against two (or two against three) are too few for any verdict; both tasks
    # together are enough (10 x 10 rankings)
    assert table["verdict"].tolist()[:3] == [TOO_FEW_RUNS, TOO_FEW_RUNS, "larger"]
    assert table["difference"].iloc[0] == pytest.approx(6.0 - 1.5)
    # two runs against one on two tasks are too few even together (3 x 3 rankings)
    few = _finals({(env, m): fs for env in "AB" for m, fs in (("T", [5.0, 6.0]), ("D", [1.0]))})
    table = improvement_over_baselines(few, ["T"], ["D"], 200, 0)
    assert table["env"].tolist() == ["A", "B", ALL_TASKS]
    assert table["verdict"].tolist() == [TOO_FEW_RUNS] * 3


def _finals(cells: dict[tuple[str, str], list[float]]) -> pd.DataFrame:
    return pd.DataFrame(
        [{"env": env, "method": m, "final": f} for (env, m), fs in cells.items() for f in fs]
    )


def test_adding_a_method_or_a_task_leaves_every_other_interval_as_it_was() -> None:
    """Each interval resamples from a seed derived from its scores, not from its position."""
    rng = np.random.default_rng(3)
    cells = {
        (env, method): list(rng.normal(mu, 1.0, size=5))
        for env in ("A", "B")
        for method, mu in (("TAC (best q)", 0.4), ("DDPG", 0.0))
    }
    more = {
        **cells,
        ("A", "PPO"): list(rng.normal(size=5)),
        ("C", "TAC (best q)"): list(rng.normal(size=5)),
        ("C", "DDPG"): list(rng.normal(size=5)),
    }
    seed = 0
    few = improvement_over_baselines(_finals(cells), ["TAC (best q)"], ["DDPG"], 300, seed)
    many = improvement_over_baselines(_finals(more), ["TAC (best q)"], ["PPO", "DDPG"], 300, seed)
    columns = ["baseline", "env", "p", "low", "high"]
    per_task = many[many["env"].isin(["A", "B"]) & (many["baseline"] == "DDPG")]
    pd.testing.assert_frame_equal(
        few.loc[few["env"] != ALL_TASKS, columns].reset_index(drop=True),
        per_task[columns].reset_index(drop=True),
    )
    first = {key: more[key] for key in more if key not in cells} | cells  # new cells first
    before = per_task_estimates(_finals(cells), 300, seed).set_index(["env", "method"])
    after = per_task_estimates(_finals(first), 300, seed).set_index(["env", "method"])
    assert after.index[0] == ("A", "PPO")  # so the old cells moved, and kept their intervals
    pd.testing.assert_frame_equal(before, after.loc[before.index])


def test_the_same_comparison_gets_the_same_interval_under_any_label() -> None:
    x, y = np.array([5.0, 1.0, 3.0, 4.0]), np.array([2.0, 0.5, 3.5])
    cells = {("A", "TAC q=2"): list(x), ("A", "TAC (best q)"): list(x), ("A", "DDPG"): list(y)}
    methods = ["TAC q=2", "TAC (best q)"]
    table = improvement_over_baselines(_finals(cells), methods, ["DDPG"], 300, 0)
    assert table["low"].nunique() == 1 and table["high"].nunique() == 1


def test_strata_seeds_depend_on_the_scores_their_order_and_the_base() -> None:
    a, b = [1.0, 2.0, 3.0], [4.0]
    assert strata_seed(0, [a, b]) == strata_seed(0, [np.array(a), np.array(b, dtype=np.float32)])
    assert strata_seed(0, [a, b]) != strata_seed(0, [b, a])
    assert strata_seed(0, [a, b]) != strata_seed(0, [[1.0, 2.0], [3.0, 4.0]])  # framed by counts
    assert strata_seed(0, [a, b]) != strata_seed(1, [a, b])
    assert strata_seed(0, [a, b]) != strata_seed(0, [a, [4.5]])
    assert strata_seed(0, [a, b]) == strata_seed(0, [[1.0, 2.0, 3.0 + 1e-13], b])  # float32
    assert strata_seed(0, [a, b]) == 2402604160  # pinned: committed reports regenerate anywhere


def test_the_order_runs_were_loaded_in_does_not_move_an_interval() -> None:
    x, y = np.array([3.0, 9.0, 1.0, 4.0, 7.0]), np.array([2.0, 6.0, 5.0, 0.5])
    assert probability_of_improvement([x], [y], 300, 0) == probability_of_improvement(
        [x[::-1]], [np.sort(y)], 300, 0
    )
    assert interval_estimates([x, y], 300, 0) == interval_estimates([np.sort(x), y[::-1]], 300, 0)


def test_an_open_all_tasks_verdict_states_the_shift_it_could_have_detected() -> None:
    rng = np.random.default_rng(11)
    cells = {
        (env, method): list(rng.normal(0.0, scale, size=5))
        for env, scale in (("A", 1.0), ("B", 1000.0))
        for method in ("TAC (best q)", "DDPG")
    }
    table = improvement_over_baselines(_finals(cells), ["TAC (best q)"], ["DDPG"], 300, 0)
    rows = table.set_index("env")
    assert rows.loc[ALL_TASKS, "verdict"] == "not distinguishable"
    references = [np.array(cells[(env, "DDPG")]) for env in ("A", "B")]
    mine = [np.array(cells[(env, "TAC (best q)")]) for env in ("A", "B")]
    assert rows.loc[ALL_TASKS, "detectable"] == pytest.approx(detectable_shift(references, mine))
    assert np.isnan(rows.loc[ALL_TASKS, "difference"])  # returns of two tasks do not add up


def test_a_decided_comparison_states_no_detectable_difference() -> None:
    """The detectable difference answers "how large a difference could these runs have missed?",
    a question only an open verdict asks; it needs two runs a side, however many the other has."""
    cells = {("A", "TAC (best q)"): [10.0, 11, 12, 13, 14], ("A", "DDPG"): [0.0, 1, 2, 3, 4]}
    table = improvement_over_baselines(_finals(cells), ["TAC (best q)"], ["DDPG"], 300, 0)
    (row,) = table.to_dict("records")
    assert row["verdict"] == "larger" and np.isnan(row["detectable"])
    assert np.isfinite(detectable_runs(np.arange(2.0), np.arange(20.0)))
    assert np.isnan(detectable_runs(np.arange(1.0), np.arange(20.0)))
