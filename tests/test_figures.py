"""The numbers behind the theory figures (the PNGs themselves are checked in the smoke test)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.special import softmax

from tacbench.errors import TacbenchError
from tacbench.theory.figures import (
    BANDIT_GRID_ALPHAS,
    BANDIT_GRID_QS,
    BANDIT_QS,
    BANDIT_REWARDS,
    QMAX_QS,
    bandit_policies_table,
    error_bounds_table,
    q_max_bounds_table,
    qexp_qlog_entropy_table,
    write_figures,
)
from tacbench.theory.mdp import GRID_ALPHA, GRID_QS, error_bounds, grid_world
from tacbench.theory.tsallis import exp_q, log_q

pytestmark = pytest.mark.unit


def test_qexp_qlog_entropy_table() -> None:
    table = qexp_qlog_entropy_table()
    assert list(table.columns) == ["function", "q", "x", "value"]
    assert set(table["function"]) == {"exp_q", "ln_q", "S_q"}
    assert np.isfinite(table["value"]).all()

    def part(name: str, q: float) -> pd.DataFrame:
        return table[(table["function"] == name) & (table["q"] == q)]

    np.testing.assert_allclose(part("exp_q", 1.0)["value"], np.exp(part("exp_q", 1.0)["x"]))
    for q in set(table["q"]):  # every q's own function, not q = 1's
        for name, function in (("exp_q", exp_q), ("ln_q", log_q)):
            rows = part(name, q)
            np.testing.assert_array_equal(rows["value"], function(rows["x"].to_numpy(), q))
    ln2 = part("ln_q", 2.0)
    np.testing.assert_allclose(ln2["value"], ln2["x"] - 1.0)  # ln_2(x) = x - 1
    s2 = part("S_q", 2.0)
    np.testing.assert_allclose(s2["value"], 2 * s2["x"] * (1 - s2["x"]), atol=1e-12)  # 1 - sum p^2
    s1 = part("S_q", 1.0).set_index("x")["value"]
    assert s1.loc[0.5] == pytest.approx(np.log(2.0))
    assert s1.loc[0.0] == 0.0 and s1.loc[1.0] == 0.0


def test_bandit_table_covers_both_figures_without_duplicates() -> None:
    table = bandit_policies_table()
    assert list(table.columns) == ["q", "alpha", "action", "reward", "prob"]
    pairs = set(zip(table["q"], table["alpha"], strict=True))
    expected = {(q, 1.0) for q in BANDIT_QS} | {
        (q, a) for q in BANDIT_GRID_QS for a in BANDIT_GRID_ALPHAS
    }
    assert pairs == expected and len(expected) == 26
    assert not table.duplicated(["q", "alpha", "action"]).any()
    assert len(table) == 26 * len(BANDIT_REWARDS)
    sums = table.groupby(["q", "alpha"])["prob"].sum()
    np.testing.assert_allclose(sums, 1.0, atol=1e-12)


def test_bandit_policies_match_closed_forms() -> None:
    table = bandit_policies_table().set_index(["q", "alpha"]).sort_index(kind="stable")
    r = np.asarray(BANDIT_REWARDS)
    np.testing.assert_allclose(table.loc[(1.0, 0.5), "prob"], softmax(r / 0.5), atol=1e-12)
    # q = 2, alpha = 1: sparsemax of r/2 = [1,1,1,1,2,2,2.25,2.5]; threshold 1.5625 keeps 4 arms.
    np.testing.assert_allclose(
        table.loc[(2.0, 1.0), "prob"], [0, 0, 0, 0, 0.0625, 0.0625, 0.3125, 0.5625], atol=1e-12
    )
    # q = 0.5 keeps every arm; larger q concentrates mass on the best arm.
    best = [table.loc[(q, 1.0), "prob"].iloc[-1] for q in BANDIT_QS]
    assert (table.loc[(0.5, 1.0), "prob"] > 0).all()
    assert best == sorted(best) and best[-1] > 0.9


def test_q_max_table_lies_within_its_bounds() -> None:
    table = q_max_bounds_table()
    assert list(table.columns) == ["q", "c", "q_max", "lower", "upper"]
    assert sorted(table["q"].unique()) == list(QMAX_QS)
    assert table["c"].min() == -2.0 and table["c"].max() == 2.0
    assert (table["lower"] <= table["q_max"] + 1e-12).all()
    assert (table["q_max"] <= table["upper"] + 1e-12).all()
    q1 = table[table["q"] == 1.0]
    np.testing.assert_allclose(q1["q_max"], np.log1p(np.exp(q1["c"])), atol=1e-12)
    at_zero = table[table["c"] == 0.0]  # f = [0, 0]: uniform policy, the upper bound is attained
    np.testing.assert_allclose(at_zero["q_max"], at_zero["upper"], atol=1e-12)


def test_error_bounds_table() -> None:
    table = error_bounds_table()
    assert list(table.columns) == ["q", "J", "lower_bound", "upper_bound"]
    assert tuple(table["q"]) == GRID_QS
    rows = error_bounds(grid_world(), GRID_QS, GRID_ALPHA)  # each column its own field
    assert table["J"].tolist() == [r.J for r in rows]
    assert table["lower_bound"].tolist() == [r.lower_bound for r in rows]
    assert table["upper_bound"].tolist() == [r.upper_bound for r in rows]
    assert (table["lower_bound"] < table["J"]).all() and (table["J"] < table["upper_bound"]).all()
    assert table["J"].is_monotonic_increasing  # less entropy, nearer the unregularised optimum
    assert table["upper_bound"].nunique() == 1


def test_write_figures_refuses_a_file_as_directory(tmp_path: Path) -> None:
    target = tmp_path / "taken"
    target.write_text("not a directory")
    with pytest.raises(TacbenchError, match="is not a directory"):
        write_figures(target)
