"""``tacbench bench``: the contestants, the table and its ratios, option checks, and one tiny
end-to-end run through the CLI (a few steps of Pendulum; no timing is asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from tacbench.bench import BenchOptions, BenchResult, Contestant, contestants, table
from tacbench.cli import cli
from tacbench.errors import TacbenchError

pytestmark = pytest.mark.unit


def test_contestants_cover_both_paths_at_one_and_k_members() -> None:
    rows = [(c.name, c.members) for c in contestants(BenchOptions(members=4, compile=True))]
    assert rows == [
        ("SB3 SAC", 1),
        ("TAC", 1),
        ("TAC compiled", 1),
        ("TAC", 4),
        ("TAC compiled", 4),
    ]
    options = BenchOptions(members=1, sb3=False, eager=False, compile=True)
    assert [c.name for c in contestants(options)] == ["TAC compiled"]


def test_table_reports_rates_member_rates_and_ratios_to_sb3() -> None:
    sb3 = BenchResult(Contestant("SB3 SAC", 1), steps=[100, 100], seconds=[1.0, 1.0])
    tac = BenchResult(Contestant("TAC", 10, tac=True), steps=[50, 50], seconds=[0.5, 0.25])
    assert tac.rate == pytest.approx(100 / 0.75)
    assert tac.member_rate == pytest.approx(1000 / 0.75)
    assert tac.spread == pytest.approx((100.0, 200.0))
    lines = table([sb3, tac]).splitlines()
    assert lines[2] == "| SB3 SAC | 1 | 100 | 100 | 1.00x | 100-100 |"
    assert lines[3] == "| TAC | 10 | 133 | 1333 | 13.33x | 100-200 |"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"rounds": 0}, "--rounds"),
        ({"steps": 2, "rounds": 3}, "--steps"),
        ({"members": 0}, "--members"),
    ],
)
def test_bench_options_are_checked(options: dict[str, int], message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        BenchOptions(**options)  # type: ignore[arg-type]


def test_bench_command_runs_every_contestant_and_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    args = ["bench", "--env", "Pendulum-v1", "--members", "2", "--steps", "4", "--rounds", "2"]
    result = CliRunner().invoke(cli, [*args, "--learning-starts", "3", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "| SB3 SAC | 1 |" in result.output and "| TAC | 2 |" in result.output
    record = json.loads(out.read_text())
    assert [(r["name"], r["members"]) for r in record["results"]] == [
        ("SB3 SAC", 1),
        ("TAC", 1),
        ("TAC", 2),
    ]
    assert all(r["steps"] == [2, 2] and len(r["seconds"]) == 2 for r in record["results"])
    assert record["machine"]["cores"] >= 1


def test_bench_command_refuses_bad_options() -> None:
    result = CliRunner().invoke(cli, ["bench", "--steps", "1", "--rounds", "3"])
    assert result.exit_code == 2
    assert "--steps must be at least --rounds" in result.output
