"""The regression checks' logic without training: CSV comparison, the permutation test on
synthetic distributions, manifests, version gating, and the ``tacbench regress`` exit codes."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from tacbench import hardware, regress
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.regress import exact, stat
from tacbench.regress import manifest as mf
from tacbench.regress.outcome import Row, TierResult, format_result
from tacbench.regress.specs import EXACT_RUNS, STAT_ALPHA, STAT_GROUPS, ReferenceRun
from tacbench.runs import locks

pytestmark = pytest.mark.unit

REFERENCE = Path(__file__).resolve().parents[1] / "results" / "reference"
CSV = "step,q,loss\n1000,1.5,0.25\n2000,1.5,0.125\n"


# --- comparing CSV text ---------------------------------------------------------------------


def test_identical_csv_text_matches() -> None:
    assert exact.compare_csv(CSV, CSV) == ("match", "2 rows")


def test_a_changed_last_digit_is_drift_with_where_and_how_much() -> None:
    status, detail = exact.compare_csv(CSV, CSV.replace("0.125", "0.12500000000000003"))
    assert status == "drift"
    assert "from row 2 (step 2000)" in detail
    assert "1 values differ, most in loss: 0.125 -> 0.12500000000000003" in detail
    assert "relative 2.2e-16" in detail


def test_missing_rows_and_changed_columns_are_drift() -> None:
    status, detail = exact.compare_csv(CSV, "\n".join(CSV.splitlines()[:2]) + "\n")
    assert status == "drift"
    assert "2 -> 1 rows" in detail
    assert "from row 2 (step 2000)" in detail
    status, detail = exact.compare_csv(CSV, CSV.replace("loss", "loss_pi"))
    assert status == "drift"
    assert "columns" in detail and "loss_pi" in detail


@pytest.mark.parametrize("fresh", [CSV.rstrip("\n"), CSV + "\n", "step,q,loss\n"])
def test_texts_of_the_same_rows_in_other_bytes_are_drift_not_a_traceback(fresh: str) -> None:
    """A lost last newline or an added blank line gave an IndexError."""
    reference = CSV if fresh != "step,q,loss\n" else "step,q,loss\n\n"
    assert exact.compare_csv(reference, fresh) == (
        "drift",
        "the same rows, other bytes (a line ending or a blank line)",
    )


def test_clock_columns_are_dropped_and_nothing_else() -> None:
    text = "step,wall_s,return_mean\n500,0.091,32.48253645959404\n1000,0.789,48.1\n"
    assert mf.without_clocks(text) == "step,return_mean\n500,32.48253645959404\n1000,48.1\n"
    both = "step,wall_s,cpu_s,return_mean\n500,0.091,0.088,32.48253645959404\n1000,0.789,,48.1\n"
    assert mf.without_clocks(both) == mf.without_clocks(text)
    assert mf.without_clocks(CSV) == CSV


# --- the permutation test on synthetic distributions -------------------------------------------


def test_permutation_pvalue_is_exact_on_small_samples() -> None:
    # 4 scores, 6 splits; the observed split is the most extreme downwards
    assert stat.permutation_pvalue([1.0, 2.0], [-1.0, 0.0]) == pytest.approx(1 / 6)
    assert stat.permutation_pvalue([1.0, 2.0], [3.0, 4.0]) == 1.0
    # ties: every split gives the same difference, so nothing is evidence of a drop
    assert stat.permutation_pvalue([5.0, 5.0, 5.0], [5.0, 5.0, 5.0]) == 1.0


def test_permutation_pvalue_falls_back_to_monte_carlo_on_large_samples() -> None:
    rng = np.random.default_rng(1)
    ref, fresh = rng.normal(0, 1, 15), rng.normal(-3, 1, 15)  # C(30, 15) > 1.5e8 splits
    p = stat.permutation_pvalue(ref, fresh)
    assert p == pytest.approx(1 / (stat.MONTE_CARLO_DRAWS + 1))


def test_false_alarm_rate_is_at_most_alpha_for_same_distribution() -> None:
    rng = np.random.default_rng(7)
    trials, alpha = 2000, 0.05
    alarms = sum(
        stat.permutation_pvalue(rng.normal(1000, 400, 5), rng.normal(1000, 400, 5)) < alpha
        for _ in range(trials)
    )
    # exact test: P(p < alpha) <= alpha; 2000 trials give a standard error of about 0.005
    assert alarms / trials <= alpha + 0.015


def test_same_distribution_passes_and_a_real_drop_is_flagged() -> None:
    """Hopper-like score spreads (8 vs 8 seeds, the statistical tier's size): noise passes, a
    weakened agent (mean halved) is a drop, an improvement is not."""
    rng = np.random.default_rng(3)
    ref = rng.normal(1500, 500, 8)
    same = stat.compare_scores("g", ref, rng.normal(1500, 500, 8), STAT_ALPHA / 2)
    assert same.status == "ok", same.detail
    weak = stat.compare_scores("g", ref, rng.normal(400, 150, 8), STAT_ALPHA / 2)
    assert weak.status == "drop"
    assert "mean 1276.0 -> 449.0 (-827.0, -65%" in weak.detail
    assert "p = 0.0029, a drop if p < 0.0250" in weak.detail
    better = stat.compare_scores("g", ref, ref + 800, STAT_ALPHA / 2)
    assert better.status == "ok"


def test_power_against_a_halved_return_with_eight_seeds() -> None:
    rng = np.random.default_rng(11)
    flagged = [
        stat.permutation_pvalue(rng.normal(1500, 500, 8), rng.normal(750, 250, 8)) < 0.025
        for _ in range(50)
    ]
    assert np.mean(flagged) >= 0.9


def test_bootstrap_interval_covers_the_shift() -> None:
    rng = np.random.default_rng(5)
    low, high = stat.bootstrap_interval(rng.normal(0, 1, 50), rng.normal(-2, 1, 50))
    assert low < -2 < high and high < 0


def test_committed_scores_against_synthetic_fresh_sets() -> None:
    """The committed reference scores: an unlucky resample of themselves (the best seed's
    score replaced by the worst's: a lower mean, no real change) passes, half of them is a
    drop (at the Bonferroni level of a full check)."""
    manifest = mf.read_manifest(REFERENCE, "stat")
    alpha = manifest["alpha"] / len(manifest["groups"])
    for group in manifest["groups"]:
        scores = np.array(list(group["scores"].values()))
        unlucky = np.sort(scores)
        unlucky[-1] = unlucky[0]
        assert unlucky.mean() < scores.mean()
        assert stat.compare_scores("g", scores, unlucky, alpha).status == "ok"
        assert stat.compare_scores("g", scores, scores * 0.5, alpha).status == "drop"


def test_a_check_splits_its_level_over_the_groups_it_checks(tmp_path: Path) -> None:
    """The tier's false-alarm bound (5 % per check) rests on dividing the level by the groups
    checked (Bonferroni); no test pinned it. A fake runner returns each group's recorded scores
    (stat.score reads them back), so only the threshold is at stake."""
    reference = tmp_path / "reference"
    (reference / "stat").mkdir(parents=True)
    manifest = mf.read_manifest(REFERENCE, "stat")
    (reference / "stat" / mf.MANIFEST).write_text(json.dumps(manifest))
    scores = {e["name"]: list(e["scores"].values()) for e in manifest["groups"]}

    def runner(args: list[str], out: Path) -> mf.CommandResult:
        seeds = [int(args[i + 1]) for i, arg in enumerate(args) if arg == "--seed"]
        group = next(e["name"] for e in manifest["groups"] if e["args"] == args[: len(e["args"])])
        directories = []
        for seed, value in zip(seeds, scores[group], strict=False):
            directory = out / f"seed{seed}"
            directory.mkdir(parents=True)
            (directory / "status.json").write_text('{"state": "complete", "step": 1}')
            rows = "".join(f"{step},{value}\n" for step in range(manifest["last"]))
            (directory / "eval.csv").write_text("step,return_mean\n" + rows)
            directories.append(directory)
        return mf.CommandResult(0, "", tuple(directories))

    both = stat.check_stat(reference, tmp_path / "work", log=lambda line: None, runner=runner)
    level = manifest["alpha"] / len(manifest["groups"])
    assert len(both.rows) == len(manifest["groups"]) >= 2
    assert all(f"a drop if p < {level:.4f}" in row.detail for row in both.rows)
    first = manifest["groups"][0]["name"]
    alone = stat.check_stat(
        reference, tmp_path / "alone", [first], log=lambda line: None, runner=runner
    )
    assert [row.item for row in alone.rows] == [first]
    assert f"a drop if p < {manifest['alpha']:.4f}" in alone.rows[0].detail


def test_score_is_the_mean_of_the_last_evaluations(tmp_path: Path) -> None:
    path = tmp_path / "eval.csv"
    path.write_text("step,return_mean\n1,10\n2,20\n3,30\n4,50\n")
    assert stat.score(path, 3) == pytest.approx(100 / 3)
    with pytest.raises(TacbenchError, match="has 4 evaluations; the score needs 5"):
        stat.score(path, 5)


# --- manifests, gating, specs ------------------------------------------------------------------


def test_specs_cover_every_task_q_and_baseline() -> None:
    args = [dict(zip(s.args[::2], s.args[1::2], strict=False)) for s in EXACT_RUNS]
    from tacbench.paper import ENV_IDS

    assert {a["--env"] for a in args} == set(ENV_IDS.values())
    assert {a["--env"] for a in args if "--algo" not in a} == set(ENV_IDS.values())
    assert {a["--q"] for a in args if "--q" in a} == {"1", "1.5", "2"}
    assert {a["--algo"] for a in args if "--algo" in a} == {"ddpg", "td3", "sac-sb3", "ppo", "trpo"}
    assert len({s.name for s in EXACT_RUNS}) == len(EXACT_RUNS)
    for group in STAT_GROUPS:
        assert not set(group.reference_seeds) & set(group.check_seeds)


def test_committed_manifests_record_provenance() -> None:
    classes = mf.recorded_cpu_classes(REFERENCE)
    assert classes
    exact = {cpu: mf.read_manifest(REFERENCE, "exact", cpu) for cpu in classes}
    manifests = [(tier, mf.read_manifest(REFERENCE, tier)) for tier in ("theory", "stat")]
    for tier, manifest in [*manifests, *(("exact", m) for m in exact.values())]:
        assert manifest["regenerate"].startswith(f"tacbench regress --update --tier {tier}")
        assert set(manifest["environment"]["versions"]) == {"python", *mf.RECORDED_PACKAGES}
        assert {"created", "git_commit", "platform"} <= set(manifest)
    for cpu, manifest in exact.items():
        assert manifest["environment"]["cpu"] == cpu
        runs = manifest["runs"]
        assert [r["name"] for r in runs] == [s.name for s in EXACT_RUNS]
        assert all(r["command"].startswith("tacbench run ") for r in runs)
        for run in runs:
            assert {p.name for p in (REFERENCE / "exact" / cpu / run["name"]).iterdir()} == set(
                manifest["files"]
            )


def test_cpu_class_names_vendor_family_model_and_instruction_set() -> None:
    intel = "processor\t: 0\nvendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel\t\t: 207\n"
    intel += "model name\t: Intel(R) Xeon(R) Processor\n\nprocessor\t: 1\nvendor_id\t: Other\n"
    assert hardware.cpu_identity(intel) == ["GenuineIntel", "6", "207"]
    assert hardware.cpu_name(intel) == "Intel(R) Xeon(R) Processor"
    arm = "processor\t: 0\nCPU implementer\t: 0x41\nCPU architecture: 8\nCPU part\t: 0xd0c\n"
    assert hardware.cpu_identity(arm) == ["0x41", "8", "0xd0c"]
    here = hardware.cpu_class()
    assert here.endswith(torch.backends.cpu.get_cpu_capability())
    assert mf.environment()["cpu"] == here
    assert mf.tier_directory(REFERENCE, "exact") == REFERENCE / "exact" / here
    assert mf.tier_directory(REFERENCE, "stat") == REFERENCE / "stat"


def test_environment_differences_name_what_changed() -> None:
    here = mf.environment()
    assert mf.environment_differences(here, here) == []
    old = json.loads(json.dumps(here))
    old["versions"]["torch"], old["cpu_capability"] = "0.0.1", "NONE"
    assert mf.environment_differences(old, here) == [
        f"cpu_capability NONE recorded, {here['cpu_capability']} here",
        f"torch 0.0.1 recorded, {here['versions']['torch']} here",
    ]


def test_missing_or_foreign_manifest_says_how_to_regenerate(tmp_path: Path) -> None:
    with pytest.raises(TacbenchError, match="tacbench regress --update --tier exact --against"):
        mf.read_manifest(tmp_path, "exact")
    (tmp_path / "stat").mkdir()
    (tmp_path / "stat" / mf.MANIFEST).write_text('{"tier": "stat", "format": 99}')
    with pytest.raises(TacbenchError, match="not a format-1 stat manifest"):
        mf.read_manifest(tmp_path, "stat")


def _copy_exact_reference(tmp_path: Path) -> tuple[Path, Path]:
    """A committed exact set, copied as this machine's CPU class's set (its recorded
    environment made this machine's), and its manifest's path."""
    copy = tmp_path / "reference"
    recorded = REFERENCE / "exact" / mf.recorded_cpu_classes(REFERENCE)[0]
    shutil.copytree(recorded, mf.tier_directory(copy, "exact"))
    path = mf.tier_directory(copy, "exact") / mf.MANIFEST
    manifest = json.loads(path.read_text())
    manifest["environment"] = mf.environment()
    path.write_text(json.dumps(manifest))
    return copy, path


def test_exact_tier_is_skipped_with_the_reason_on_other_versions(tmp_path: Path) -> None:
    reference, path = _copy_exact_reference(tmp_path)
    manifest = json.loads(path.read_text())
    manifest["environment"]["versions"]["torch"] = "1.0.0"
    path.write_text(json.dumps(manifest))
    (result,) = regress.check(reference, "exact", names=["tac-Hopper-v4-q2"])
    assert result.verdict == "SKIPPED" and not result.rows
    assert "torch 1.0.0 recorded" in result.skipped
    assert "tacbench regress --update --tier exact" in result.skipped


def test_exact_tier_is_skipped_on_a_cpu_class_without_references(tmp_path: Path) -> None:
    reference = tmp_path / "reference"
    other = reference / "exact" / "x86_64-SomeVendor-1-2-AVX2"
    shutil.copytree(REFERENCE / "exact" / mf.recorded_cpu_classes(REFERENCE)[0], other)
    (result,) = regress.check(reference, "exact", names=["tac-Hopper-v4-q2"])
    assert result.verdict == "SKIPPED" and not result.rows
    assert f"no exact references for this machine's CPU class {hardware.cpu_class()}" in (
        result.skipped
    )
    assert "recorded for x86_64-SomeVendor-1-2-AVX2" in result.skipped
    assert "tacbench regress --update --tier exact" in result.skipped
    with pytest.raises(TacbenchError, match="no reference named nope"):
        regress.check(reference, "exact", names=["nope"])


def test_a_recorded_command_that_is_refused_is_a_regression(tmp_path: Path) -> None:
    reference, path = _copy_exact_reference(tmp_path)
    manifest = json.loads(path.read_text())
    manifest["runs"][0]["args"].append("--no-such-flag")
    path.write_text(json.dumps(manifest))
    name = manifest["runs"][0]["name"]
    (result,) = regress.check(reference, "exact", names=[name])
    (row,) = result.rows
    assert (row.item, row.part, row.status) == (name, "run", "missing")
    assert "(exit status 2): Error: No such option '--no-such-flag'" in row.detail
    assert result.verdict == "REGRESSION"


# --- the CLI ---------------------------------------------------------------------------------


def _fake_theory(monkeypatch: pytest.MonkeyPatch, csvs: dict[str, str]) -> None:
    monkeypatch.setattr(exact, "_theory_csvs", lambda work: dict(csvs))


def test_regress_cli_exit_codes_on_theory_csvs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    reference = tmp_path / "ref"
    _fake_theory(monkeypatch, {"a.csv": CSV})
    result = CliRunner().invoke(
        cli, ["regress", "--update", "--tier", "theory", "--against", str(reference)]
    )
    assert result.exit_code == 0, result.output
    assert (reference / "theory" / "a.csv").read_text() == CSV
    result = CliRunner().invoke(cli, ["regress", "--tier", "theory", "--against", str(reference)])
    assert result.exit_code == 0 and "PASS (1 match" in result.output
    _fake_theory(monkeypatch, {"a.csv": CSV.replace("0.25", "0.5"), "b.csv": CSV})
    result = CliRunner().invoke(cli, ["regress", "--tier", "theory", "--against", str(reference)])
    assert result.exit_code == 1
    assert "a.csv  csv   DRIFT" in result.output
    assert "loss: 0.25 -> 0.5 (relative 0.5)" in result.output
    assert "not in the references (regenerate to include): b.csv" in result.output
    assert "REGRESSION (1 drift" in result.output


def test_an_unknown_only_name_lists_each_known_name_once(tmp_path: Path) -> None:
    """On a class without exact references, the names were listed once per recorded class."""
    classes = mf.recorded_cpu_classes(REFERENCE)[:2]
    for index, cpu in enumerate(classes):
        shutil.copytree(REFERENCE / "exact" / cpu, tmp_path / "exact" / f"x86_64-other-{index}")
    result = CliRunner().invoke(cli, ["regress", "--only", "nope", "--against", str(tmp_path)])
    assert result.exit_code == 2 and "no reference named nope" in result.output
    known = result.output.split("known: ")[1].split()
    assert len(known) == len(set(known)) > 1


def test_regress_cli_usage_errors_exit_two(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(cli, ["regress", "--against", str(tmp_path / "nowhere")])
    assert result.exit_code == 2 and "no such folder" in result.output
    result = runner.invoke(cli, ["regress", "--tier", "stat", "--against", str(tmp_path)])
    assert result.exit_code == 2 and "tacbench regress --update --tier stat" in result.output
    # a folder that is not the references one is said to be so (before: "create them there")
    assert f"{tmp_path} holds no references (no exact/, theory/ or stat/ folder)" in result.output
    result = runner.invoke(cli, ["regress", "--update", "--only", "x"])
    assert result.exit_code == 2 and "--only selects what to check" in result.output
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "old").write_text("")
    result = runner.invoke(cli, ["regress", "--work", str(tmp_path / "work")])
    assert result.exit_code == 2 and "is not an empty folder" in result.output
    result = runner.invoke(cli, ["regress", "--only", "nope", "--against", str(REFERENCE)])
    assert result.exit_code == 2 and "no reference named nope" in result.output
    result = runner.invoke(
        cli, ["regress", "--tier", "theory", "--only", "x", "--against", str(REFERENCE)]
    )
    assert result.exit_code == 2 and "the theory tier compares all of its CSVs" in result.output
    (tmp_path / "afile").write_text("")
    below_a_file = str(tmp_path / "afile" / "ref")
    result = runner.invoke(
        cli, ["regress", "--update", "--tier", "theory", "--against", below_a_file]
    )
    assert result.exit_code == 2 and "choose one you can write with --against" in result.output
    work = ["--work", str(tmp_path / "afile" / "sub"), "--against", str(REFERENCE)]
    result = runner.invoke(cli, ["regress", "--tier", "theory", *work])
    assert result.exit_code == 2 and "choose one you can write with --work" in result.output


@pytest.mark.parametrize(
    ("damage", "says"),
    [
        (Path.unlink, ["the theory references lack", "a.csv"]),
        (lambda path: path.write_bytes(b"\xff\xfe step"), ["a.csv cannot be read as text"]),
    ],
    ids=["missing", "not text"],
)
def test_a_reference_file_missing_or_not_text_is_a_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage: Any, says: list[str]
) -> None:
    reference = tmp_path / "ref"
    _fake_theory(monkeypatch, {"a.csv": CSV})
    update = ["regress", "--update", "--tier", "theory", "--against", str(reference)]
    assert CliRunner().invoke(cli, update).exit_code == 0
    damage(reference / "theory" / "a.csv")
    result = CliRunner().invoke(cli, ["regress", "--tier", "theory", "--against", str(reference)])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert all(part in result.output for part in says)
    assert "tacbench regress --update --tier theory" in result.output


@pytest.mark.parametrize(
    ("tier", "change", "named"),
    [
        ("theory", {"files": []}, "'files'"),
        ("theory", {"files": None}, "'files'"),
        ("exact", {"runs": []}, "'runs'"),
        ("exact", {"runs": [{"args": []}]}, "'runs'"),
        ("stat", {"groups": []}, "'groups'"),
        ("stat", {"alpha": "0.05", "last": 0}, "'alpha', 'last'"),
        ("theory", {"created": None}, "'created'"),  # provenance_note: a KeyError
        ("exact", {"environment": {"torch": "2"}}, "'environment'"),  # no versions
        ("stat", {"test": ""}, "'test'"),
    ],
)
def test_a_damaged_manifest_is_refused_before_anything_is_compared(
    tmp_path: Path, tier: str, change: dict[str, Any], named: str
) -> None:
    """An emptied or damaged manifest list would make a check pass having compared nothing
    (or end in a traceback): it is refused, naming what is wrong."""
    source = REFERENCE / tier
    if tier == "exact":
        source = source / mf.recorded_cpu_classes(REFERENCE)[0]
    manifest = json.loads((source / mf.MANIFEST).read_text())
    folder = mf.tier_directory(tmp_path, tier, "x86_64-test")
    folder.mkdir(parents=True)
    (folder / mf.MANIFEST).write_text(json.dumps({**manifest, **change}))
    with pytest.raises(TacbenchError, match=f"is damaged: {named} missing, empty or of the wrong"):
        mf.read_manifest(tmp_path, tier, "x86_64-test")


def test_format_result_lists_rows_notes_and_verdict() -> None:
    result = TierResult(
        "exact",
        "ref/exact",
        (Row("run-a", "eval.csv", "match", "4 rows"), Row("run-b", "losses.csv", "drift", "x")),
        ("recorded ...",),
        seconds=3.2,
    )
    text = format_result(result)
    assert text.splitlines()[0] == "== exact tier against ref/exact"
    assert "run-b  losses.csv  DRIFT   x" in text
    assert text.splitlines()[-1] == "REGRESSION (1 match, 1 drift; 3 s)"


@pytest.mark.smoke
def test_update_records_this_cpu_class_and_keeps_the_others(tmp_path: Path) -> None:
    reference = tmp_path / "reference"
    other = reference / "exact" / "x86_64-SomeVendor-1-2-AVX2"
    shutil.copytree(REFERENCE / "exact" / mf.recorded_cpu_classes(REFERENCE)[0], other)
    args = ("--env", "Hopper-v4", "--q", "1.5", "--learning-starts", "100", "--steps", "300")
    args += ("--eval-every", "150", "--eval-episodes", "1", "--checkpoint-every", "0", "--quiet")
    tiny = ReferenceRun("tac-tiny", args)
    path = exact.update_exact(reference, tmp_path / "work", [tiny], log=lambda _: None)
    assert path == mf.tier_directory(reference, "exact") / mf.MANIFEST
    manifest = json.loads(path.read_text())
    assert manifest["environment"]["cpu"] == hardware.cpu_class()
    assert [run["name"] for run in manifest["runs"]] == ["tac-tiny"]
    assert (other / mf.MANIFEST).is_file()  # another CPU class's references are untouched
    assert mf.recorded_cpu_classes(reference) == sorted([other.name, hardware.cpu_class()])
    result = exact.check_exact(reference, tmp_path / "check", log=lambda _: None)
    assert result.verdict == "PASS", format_result(result)
    assert [row.status for row in result.rows] == ["match"] * 4
    # a reference recorded before settings were added (their defaults keep its behaviour) was
    # said to differ from every fresh run ("density_cap: '(absent)' -> 'paper'; ..."); a
    # setting that really differs still is
    manifest["runs"][0]["config"].pop("matmul_precision")
    manifest["runs"][0]["config"].pop("density_cap")
    path.write_text(json.dumps(manifest))
    result = exact.check_exact(reference, tmp_path / "older", log=lambda _: None)
    assert not any("config differs" in note for note in result.notes), result.notes
    manifest["runs"][0]["config"]["alpha"] = 0.3
    path.write_text(json.dumps(manifest))
    result = exact.check_exact(reference, tmp_path / "other", log=lambda _: None)
    assert [n for n in result.notes if "config differs" in n] == [
        "tac-tiny: config differs from the reference's: alpha: 0.3 -> 0.2"
    ]


def test_a_cpu_class_without_references_fails_loudly_with_exit_three(tmp_path: Path) -> None:
    """Under a forced other ATen CPU capability this machine is a class without exact
    references: the tier compares nothing, so the command fails (exit 3) and says how to record
    that class's set, instead of passing."""
    env = {**os.environ, "ATEN_CPU_CAPABILITY": "default"}
    args = ["regress", "--tier", "exact", "--only", "tac-Hopper-v4-q2", "--against", str(REFERENCE)]
    done = subprocess.run(
        [sys.executable, "-m", "tacbench", *args], capture_output=True, text=True, env=env
    )
    assert done.returncode == 3, done.stdout + done.stderr
    assert "no exact references for this machine's CPU class" in done.stdout
    assert "-DEFAULT" in done.stdout and "tacbench regress --update --tier exact" in done.stdout


def test_a_second_update_of_the_same_references_is_refused_before_it_touches_them(
    tmp_path: Path,
) -> None:
    """Two ``regress --update`` at once would each delete the other's staging folder; the
    second is refused (exit 2 through the CLI), naming the holder, and the first's files stay."""
    reference = tmp_path / "reference"
    (reference / "theory").mkdir(parents=True)
    (reference / "theory" / "kept.csv").write_text("a\n1\n")
    with (
        locks.writing([reference], hint=""),
        pytest.raises(TacbenchError, match=f"{reference} is being written .*PID {os.getpid()}"),
    ):
        regress.update(reference, "theory", work=tmp_path / "work")
    assert [p.name for p in reference.rglob("*")] == ["theory", "kept.csv"]


def test_update_refuses_to_replace_a_folder_that_holds_no_references(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--update deleted whatever <against>/<tier> held: a results folder given as --against
    lost its theory/ folder."""
    _fake_theory(monkeypatch, {"a.csv": CSV})
    mine = tmp_path / "project" / "theory"
    mine.mkdir(parents=True)
    (mine / "notes.md").write_text("mine")
    args = ["regress", "--update", "--tier", "theory", "--against", str(mine.parent)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2, result.output
    assert f"{mine} holds no theory references (no manifest.json)" in result.output
    assert [p.name for p in mine.parent.rglob("*")] == ["theory", "notes.md"]

    def must_not_train(args: Any, out: Path) -> mf.CommandResult:
        raise AssertionError("trained before refusing")

    with pytest.raises(TacbenchError, match="holds no theory references"):  # before training
        regress.update(mine.parent, "exact", work=tmp_path / "work", runner=must_not_train)


def _stopped_runner(status: int) -> mf.Runner:
    """A runner whose command a stop signal ended (its exit status ``status``)."""
    return lambda args, out: mf.finished(status, "interrupted at step 100", out)


def test_an_interrupted_update_leaves_the_references_as_they_were(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C in the exact runs had already replaced the theory references, and left a
    half-filled staging folder beside the exact ones."""
    reference, _ = _copy_exact_reference(tmp_path)
    _fake_theory(monkeypatch, {"a.csv": CSV})
    regress.update(reference, "theory", work=tmp_path / "w1")
    before = {p: p.read_bytes() for p in reference.rglob("*") if p.is_file()}
    _fake_theory(monkeypatch, {"a.csv": CSV.replace("0.25", "0.5")})
    with pytest.raises(mf.RunStopped):
        regress.update(reference, "exact", work=tmp_path / "w2", runner=_stopped_runner(130))
    assert {p: p.read_bytes() for p in reference.rglob("*") if p.is_file()} == before
    assert not [p for p in reference.rglob(".*.new")]


@pytest.mark.parametrize(("status", "name"), [(130, "Ctrl-C"), (143, "SIGTERM")])
def test_a_check_whose_run_a_signal_stopped_stops_with_its_status(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, status: int, name: str
) -> None:
    """The interrupted run was counted as drift (exit 1, "REGRESSION") and the next run
    trained on."""
    reference, _ = _copy_exact_reference(tmp_path)
    ran: list[str] = []

    def stopped(args: Any, out: Path) -> mf.CommandResult:
        ran.append(out.name)
        return _stopped_runner(status)(args, out)

    monkeypatch.setattr(sys.modules["tacbench.cli.regress"], "in_process", lambda group: stopped)
    names = [e.name for e in EXACT_RUNS[:2]]
    args = ["regress", "--against", str(reference), "--only", names[0], "--only", names[1]]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == status, result.output
    assert f"interrupted by {name}" in result.output and "REGRESSION" not in result.output
    assert ran == names[:1]


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("check_seeds", [5]),  # one seed: no test, and the check said PASS
        ("check_seeds", []),
        ("check_seeds", [5, 5]),
        ("scores", {"0": 400.0}),  # one score: a ValueError after the training
        ("scores", {"0": 400.0, "10": "x"}),
    ],
)
def test_a_statistical_group_that_cannot_be_tested_is_refused(
    tmp_path: Path, field: str, value: Any
) -> None:
    folder = tmp_path / "stat"
    shutil.copytree(REFERENCE / "stat", folder)
    manifest = json.loads((folder / mf.MANIFEST).read_text())
    manifest["groups"][0][field] = value
    (folder / mf.MANIFEST).write_text(json.dumps(manifest))
    name = manifest["groups"][0]["name"]
    with pytest.raises(TacbenchError, match=f"is damaged: {name!r} lacks {field!r}"):
        mf.read_manifest(tmp_path, "stat")


def test_a_manifest_entry_lacking_what_a_check_reads_is_refused(tmp_path: Path) -> None:
    """An entry without its args ended in a KeyError traceback (exit 1, read as a regression)."""
    reference, path = _copy_exact_reference(tmp_path)
    manifest = json.loads(path.read_text())
    del manifest["runs"][1]["args"]
    manifest["runs"][2]["step"] = "2000"
    path.write_text(json.dumps(manifest))
    first, second = manifest["runs"][1]["name"], manifest["runs"][2]["name"]
    with pytest.raises(TacbenchError) as refused:
        regress.check(reference, "exact", names=[manifest["runs"][0]["name"]])
    assert f"is damaged: {first!r} lacks 'args'; {second!r} lacks 'step'" in str(refused.value)


def test_an_update_whose_theory_step_fails_changes_neither_tier(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The exact tier was published before the theory figures were drawn: a failure there
    left new exact references beside the old theory ones."""
    reference, _ = _copy_exact_reference(tmp_path)
    _fake_theory(monkeypatch, {"a.csv": CSV})
    regress.update(reference, "theory", work=tmp_path / "w1")
    before = {p: p.read_bytes() for p in reference.rglob("*") if p.is_file()}

    def drawing_fails(work: Path) -> dict[str, str]:
        raise KeyboardInterrupt

    monkeypatch.setattr(exact, "_theory_csvs", drawing_fails)
    with pytest.raises(KeyboardInterrupt):
        regress.update(reference, "exact", work=tmp_path / "w2", runner=_stopped_runner(0))
    assert {p: p.read_bytes() for p in reference.rglob("*") if p.is_file()} == before
    assert not [p for p in reference.rglob(".*")]


def test_a_swap_that_fails_puts_the_old_references_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The old references were deleted before the new ones were renamed into place: a failed
    rename lost both."""
    reference = tmp_path / "reference"
    _fake_theory(monkeypatch, {"a.csv": CSV})
    regress.update(reference, "theory", work=tmp_path / "w1")
    before = (reference / "theory" / "a.csv").read_text()
    real_rename = Path.rename

    def rename(self: Path, target: Any) -> Any:
        if self.name == ".theory.new":
            raise OSError("the disk went away")
        return real_rename(self, target)

    monkeypatch.setattr(Path, "rename", rename)
    _fake_theory(monkeypatch, {"a.csv": CSV.replace("0.25", "0.5")})
    with pytest.raises(OSError, match="the disk went away"):
        regress.update(reference, "theory", work=tmp_path / "w2")
    assert (reference / "theory" / "a.csv").read_text() == before
    assert sorted(p.name for p in reference.iterdir()) == ["theory"]
    monkeypatch.setattr(Path, "rename", real_rename)  # a swap that works leaves nothing beside
    regress.update(reference, "theory", work=tmp_path / "w3")
    assert (reference / "theory" / "a.csv").read_text() != before
    assert sorted(p.name for p in reference.iterdir()) == ["theory"]
