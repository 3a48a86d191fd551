"""The exact tier (``tox -e regression``, CI): the committed short runs and the theory CSVs are
reproduced to the last digit, and changes planted in what tacbench computes are caught.

The committed runs are this machine's CPU class's; on library versions or a CPU class other
than theirs the run tests fail with the reason and the command that records that class's set
(the theory CSVs are still compared), so the tier is never green having compared nothing. The
planted changes are checked against references of two runs recorded by the test itself, so they
are caught on any machine.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from baselines import hyperparams
from tacbench import envs, regress
from tacbench.cli import cli
from tacbench.regress import manifest as mf
from tacbench.regress.exact import update_exact
from tacbench.regress.outcome import TierResult, format_result
from tacbench.regress.specs import EXACT_RUNS
from tests.regression.conftest import REFERENCE, RUNNER

pytestmark = pytest.mark.regression

# this machine's CPU class's reference runs; on a class without them one test fails, saying how
# to record them
RUN_NAMES = (
    [run["name"] for run in mf.read_manifest(REFERENCE, "exact")["runs"]]
    if mf.tier_directory(REFERENCE, "exact").is_dir()
    else ["(no references for this CPU class)"]
)
TAC_RUN, BASELINE_RUN = "tac-Hopper-v4-q2", "ppo-Humanoid-v4"  # cheap ones to plant changes in


@pytest.fixture(scope="module")
def planting_reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Exact references of the two runs that changes are planted in, recorded here and now by
    ``tacbench regress --update``'s code (so the planted-change tests run on any CPU class)."""
    reference = tmp_path_factory.mktemp("planting") / "reference"
    specs = [spec for spec in EXACT_RUNS if spec.name in (TAC_RUN, BASELINE_RUN)]
    update_exact(reference, reference.parent / "work", specs, log=lambda _: None, runner=RUNNER)
    return reference


@pytest.fixture(scope="module")
def exact_check() -> dict[str, TierResult]:
    """One check of the whole exact tier (theory CSVs included), shared by the tests below."""
    return {result.tier: result for result in regress.check(REFERENCE, "exact", runner=RUNNER)}


def _statuses(result: TierResult, name: str) -> dict[str, str]:
    if result.skipped:  # compared nothing: never green (record this class's set, the reason says)
        pytest.fail(result.skipped)
    return {row.part: row.status for row in result.rows if row.item == name}


def test_theory_csvs_reproduce(exact_check: dict[str, TierResult]) -> None:
    result = exact_check["theory"]
    assert [row.item for row in result.rows] == mf.read_manifest(REFERENCE, "theory")["files"]
    assert all(row.status == "match" for row in result.rows), format_result(result)


@pytest.mark.parametrize("name", RUN_NAMES)
def test_reference_run_reproduces(exact_check: dict[str, TierResult], name: str) -> None:
    statuses = _statuses(exact_check["exact"], name)
    assert list(statuses) == ["status", *mf.read_manifest(REFERENCE, "exact")["files"]]
    assert set(statuses.values()) == {"match"}, format_result(exact_check["exact"])


def test_planting_reference_reproduces(planting_reference: Path) -> None:
    (result,) = regress.check(
        planting_reference, "exact", names=[TAC_RUN, BASELINE_RUN], runner=RUNNER
    )
    assert result.verdict == "PASS", format_result(result)
    assert {row.status for row in result.rows} == {"match"}


def test_planted_polyak_rate_is_caught_with_exit_status_one(
    plant_tac_setting: Callable[..., None], planting_reference: Path, tmp_path: Path
) -> None:
    plant_tac_setting(tau=0.01)
    args = ["regress", "--only", TAC_RUN, "--against", str(planting_reference)]
    result = CliRunner().invoke(cli, [*args, "--work", str(tmp_path)])
    assert result.exit_code == 1, result.output
    assert f"{TAC_RUN}  losses.csv  DRIFT" in result.output
    assert f"{TAC_RUN}  eval.csv    DRIFT" in result.output
    assert f"{TAC_RUN}: config differs from the reference's: tau: 0.005 -> 0.01" in result.output
    assert "REGRESSION" in result.output.splitlines()[-1]


def test_planted_evaluation_seed_changes_eval_csv_alone(
    monkeypatch: pytest.MonkeyPatch, planting_reference: Path, tmp_path: Path
) -> None:
    original = envs.eval_seeds
    monkeypatch.setattr(envs, "eval_seeds", lambda seed, step, n: original(seed + 1, step, n))
    (result,) = regress.check(
        planting_reference, "exact", tmp_path, [TAC_RUN, BASELINE_RUN], runner=RUNNER
    )
    for name in (TAC_RUN, BASELINE_RUN):
        assert _statuses(result, name) == {
            "status": "match",
            "eval.csv": "drift",  # other episodes evaluated ...
            "train.csv": "match",  # ... and training untouched by evaluation
            "losses.csv": "match",
        }, format_result(result)
    assert not any("config differs" in note for note in result.notes)


def test_planted_hyperparameter_table_change_is_caught(
    monkeypatch: pytest.MonkeyPatch, planting_reference: Path, tmp_path: Path
) -> None:
    original = hyperparams.resolve

    def planted(algo: str, env: str, task: str | None) -> tuple[dict[str, Any], list[str]]:
        table, sections = original(algo, env, task)
        return {**table, "log_std_init": -1.0}, sections  # a value the run does not pin

    monkeypatch.setattr(hyperparams, "resolve", planted)
    (result,) = regress.check(planting_reference, "exact", tmp_path, [BASELINE_RUN], runner=RUNNER)
    statuses = _statuses(result, BASELINE_RUN)
    assert statuses["eval.csv"] == statuses["losses.csv"] == "drift", format_result(result)
    assert result.verdict == "REGRESSION"
    assert any("'log_std_init': -1.0" in note for note in result.notes)
