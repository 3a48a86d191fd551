"""The statistical tier (``tox -e regression-stat``; slow, never in CI): fresh seeds of the
same code pass the test against the committed distributions, and a deliberately weakened agent
(learning rate divided by 100) is flagged as a drop.

The test's logic on synthetic distributions runs in ``tests/test_regress.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tacbench import regress
from tacbench.regress.outcome import format_result
from tests.regression.conftest import REFERENCE, RUNNER

pytestmark = [pytest.mark.regression, pytest.mark.slow]


def test_fresh_seeds_of_the_same_code_pass(tmp_path: Path) -> None:
    (result,) = regress.check(REFERENCE, "stat", tmp_path, runner=RUNNER)
    assert result.rows and {row.status for row in result.rows} == {"ok"}, format_result(result)


def test_weakened_agent_is_flagged(plant_tac_setting: Callable[..., None], tmp_path: Path) -> None:
    plant_tac_setting(learning_rate=1e-5)
    (result,) = regress.check(REFERENCE, "stat", tmp_path, ["tac-Hopper-v4-q1"], runner=RUNNER)
    assert [row.status for row in result.rows] == ["drop"], format_result(result)
    assert result.verdict == "REGRESSION"
