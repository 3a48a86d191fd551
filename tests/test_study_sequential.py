"""``tacbench study sequential``: the synthetic checks count wrong decisions and findings
right, and the adastop package's own toys pass at CI's small sizes (docs/sequential.md has
the full-size numbers)."""

from __future__ import annotations

import math

import pytest

from tacbench.studies import sequential as study

pytestmark = pytest.mark.unit


def test_a_decision_is_wrong_where_the_means_are_equal_or_the_order_is_reversed() -> None:
    means = {"m0": 0.0, "m1": 1.0, "m2": 0.0}
    assert not study._wrong({("m1", "m0"): "larger", ("m2", "m0"): "continue"}, means)
    assert study._wrong({("m1", "m0"): "smaller"}, means)
    assert study._wrong({("m2", "m0"): "larger"}, means)
    assert not study._wrong({("m2", "m0"): "not distinguishable"}, means)


def test_the_package_toys_find_every_difference_and_equal_methods_rarely_differ() -> None:
    """adastop's tests/test_error_toy.py: four agents, every pair, 2 standard deviations
    apart (type 2: at least 80 % of grids decide every pair) or equal (type 1)."""
    toys = [d for d in study.DESIGNS if d.ladder]
    assert [(d.K, d.n) for d in toys] == [(3, 5), (1, 15)]
    small, large = toys  # the one-look toy costs about ten times more per grid
    assert study.check(small, 2.0, reps=10)["found"] >= 0.8
    assert study.check(small, 0.0, reps=10)["wrong"] <= 0.3  # 2 alpha + 1 / (4 sqrt(10))
    assert study.check(large, 2.0, reps=3)["found"] == 1.0


def test_the_table_has_a_row_per_design_and_shift_and_spends_no_more_than_fixed() -> None:
    small = [study.Design("two methods", 2, 4, 1, shifts=(3.0,))]
    table = study.error_and_power(reps=5, designs=small)
    assert table["shift_sd"].tolist() == [0.0, 3.0]
    # no shift: nothing to find; 3 standard deviations: found in most of the (seeded) grids
    assert math.isnan(table["found"].iloc[0])
    assert table["found"].iloc[1] == study.check(small[0], 3.0, 5)["found"] >= 0.6
    assert (table["runs"] <= table["fixed_design_runs"]).all()
