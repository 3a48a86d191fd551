"""docs/results.md's whole-paper table: every cell that a committed report decides is the
report's verdict and interval.

The table has one row per claim of the paper and one column per task. A cell reads
``**confirmed** 0.84 [0.67, 0.97]``: P(the claim's side beats the other side) with its 95 %
interval, and the report's verdict, its permutation test at 5 % (confirmed where the claim's
side is ahead, contradicted where behind, not distinguishable where the test does not reject;
too few runs where no ranking of these run counts could), or ``not run``. Rows whose verdict is a
reading of curves rather than one interval (early convergence) are checked for their form only.
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest

from tacbench.paper import TASK_FACTS, task_name
from tests.helpers import Q_GRID_STUDIES, STUDIES

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
TASKS = tuple(Q_GRID_STUDIES)
BASELINES = {"DDPG": "DDPG", "TD3": "TD3", "SB3's SAC": "SAC (SB3)", "PPO": "PPO", "TRPO": "TRPO"}
VERDICTS = {"larger": "confirmed", "smaller": "contradicted"}
NOT_RUN = "not run"
HEADING = "## The whole paper, task by task"


def _cell(p: float, low: float, high: float, verdict: str) -> str:
    return f"**{VERDICTS.get(verdict, verdict)}** {p:.2f} [{low:.2f}, {high:.2f}]"


def _report(study: str, table: str) -> pd.DataFrame:
    return pd.read_csv(STUDIES / study / "report" / f"{table}.csv")


def _range_cell(env: str, q_range: str) -> str:
    ranges = _report(Q_GRID_STUDIES[env], "q_ranges")
    row = ranges[(ranges["env"] == env) & (ranges["range"] == q_range)]
    if row.empty:
        return NOT_RUN
    return _cell(*row[["p_middle", "p_low", "p_high", "verdict"]].iloc[0])


def _best_q_cell(env: str) -> str:
    facts = TASK_FACTS[task_name(env)]
    improvement = _report(Q_GRID_STUDIES[env], "improvement")
    row = improvement[
        (improvement["env"] == env) & (improvement["method"] == f"TAC q={facts.best_q:g}")
    ]
    return f"q = {facts.best_q:g}: " + _cell(*row[["p", "low", "high", "verdict"]].iloc[0])


def _baseline_rows(env: str) -> pd.DataFrame:
    baselines = _report("comparison-100k", "baselines")
    return baselines[(baselines["env"] == env) & (baselines["method"] == "TAC (best q)")]


def _baseline_cell(env: str, baseline: str) -> str:
    rows = _baseline_rows(env)
    row = rows[rows["baseline"] == baseline]
    if row.empty:
        return NOT_RUN
    return _cell(*row[["p", "low", "high", "verdict"]].iloc[0])


def _state_of_the_art_cell(env: str) -> str:
    """Ahead of every baseline: contradicted by any baseline ahead of TAC, confirmed only when
    all five ran and TAC is ahead of each, too few runs where a comparison has too few."""
    rows = _baseline_rows(env)
    names = {label: name for name, label in BASELINES.items()}
    ahead_of_tac = rows[rows["verdict"] == "smaller"]["baseline"]
    if len(ahead_of_tac):
        return "**contradicted**: " + ", ".join(names[b] for b in ahead_of_tac) + " ahead"
    if len(rows) < len(BASELINES):
        return NOT_RUN + f" ({len(rows)} of {len(BASELINES)} baselines)"
    if (rows["verdict"] == "larger").all():
        return "**confirmed**"
    if (rows["verdict"] == "too few runs").any():
        return "**too few runs**"
    return "**not distinguishable**"


EXPECTED = {
    "1 <= q < 2 beats q >= 2": lambda env: _range_cell(env, "q >= 2"),
    "1 <= q < 2 beats 0 < q < 1": lambda env: _range_cell(env, "0 < q < 1"),
    "the paper's best q beats q = 1": _best_q_cell,
    **{
        f"TAC at the paper's best q beats {name}": (
            lambda env, label=label: _baseline_cell(env, label)
        )
        for name, label in BASELINES.items()
    },
    "TAC at the paper's best q is state-of-the-art": _state_of_the_art_cell,
}


def _table() -> dict[str, list[str]]:
    text = (ROOT / "docs" / "results.md").read_text()
    assert HEADING in text, f"docs/results.md has no section {HEADING!r}"
    lines = text.split(HEADING, 1)[1].split("\n")
    start = next(i for i, line in enumerate(lines) if line.startswith("| "))
    end = next(i for i in range(start, len(lines)) if not lines[i].startswith("|"))
    header, _, *rows = lines[start:end]  # the first table of the section
    assert [c.strip() for c in header.strip("|").split(" | ")][1:] == list(TASKS), header
    table = {}
    for row in rows:
        cells = [c.strip() for c in row.strip().strip("|").split(" | ")]
        claim = re.sub(r" \(.*\)$", "", cells[0])
        table[claim] = cells[1:]
    return table


@pytest.mark.parametrize("claim", list(EXPECTED))
def test_each_cell_is_its_reports_verdict(claim: str) -> None:
    table = _table()
    assert claim in table, f"docs/results.md's whole-paper table lacks the row {claim!r}"
    expected = [EXPECTED[claim](env) for env in TASKS]
    assert table[claim] == expected, "expected | " + " | ".join(expected) + " |"


def test_every_row_has_a_verdict_in_every_cell() -> None:
    for claim, cells in _table().items():
        assert len(cells) == len(TASKS), claim
        for cell in cells:
            verdicts = ("**confirmed", "**contradicted", "**not dist", "**too few", NOT_RUN)
            assert cell.startswith(verdicts) or (re.match(r"q = [\d.]+: \*\*", cell)), (claim, cell)
