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
        ("TAC eager", 1),
        ("TAC eager+compile", 1),
        ("TAC fused", 1),
        ("TAC fused+compile", 1),
        ("TAC eager", 4),
        ("TAC eager+compile", 4),
        ("TAC fused", 4),
        ("TAC fused+compile", 4),
    ]
    assert [c.name for c in contestants(BenchOptions(members=1, sb3=False, eager=False))] == [
        "TAC fused"
    ]


def test_table_reports_rates_member_rates_and_ratios_to_sb3() -> None:
    sb3 = BenchResult(Contestant("SB3 SAC", 1), steps=[100, 100], seconds=[1.0, 1.0])
    fused = BenchResult(Contestant("TAC fused", 10, "fused"), steps=[50, 50], seconds=[0.5, 0.25])
    assert fused.rate == pytest.approx(100 / 0.75)
    assert fused.member_rate == pytest.approx(1000 / 0.75)
    assert fused.spread == pytest.approx((100.0, 200.0))
    lines = table([sb3, fused]).splitlines()
    assert lines[2] == "| SB3 SAC | 1 | 100 | 100 | 1.00x | 100-100 |"
    assert lines[3] == "| TAC fused | 10 | 133 | 1333 | 13.33x | 100-200 |"


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
    assert "| SB3 SAC | 1 |" in result.output and "| TAC fused | 2 |" in result.output
    record = json.loads(out.read_text())
    assert [(r["name"], r["members"]) for r in record["results"]] == [
        ("SB3 SAC", 1),
        ("TAC eager", 1),
        ("TAC fused", 1),
        ("TAC eager", 2),
        ("TAC fused", 2),
    ]
    assert all(r["steps"] == [2, 2] and len(r["seconds"]) == 2 for r in record["results"])
    assert record["machine"]["cores"] >= 1


def test_bench_command_refuses_bad_options() -> None:
    result = CliRunner().invoke(cli, ["bench", "--steps", "1", "--rounds", "3"])
    assert result.exit_code == 2
    assert "--steps must be at least --rounds" in result.output
