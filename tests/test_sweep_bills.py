"""What a study's sweeps took against the dry run's price (tacbench.sweep.bills, ``tacbench study
bills``): bills and run records, the repricing of a recorded command, and the verdict."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.cli.sweep import recorded_sweep
from tacbench.errors import TacbenchError
from tacbench.sweep import bills, calibration
from tacbench.sweep.calibration import Calibration
from tests.helpers import smoke_tac_unit

pytestmark = pytest.mark.unit

STUDY = Path("results/studies/authors-versions-100k/authors-2019-01-16c-h400x300")
SMOKE = "tacbench sweep --preset smoke --algo tac --workers 1 --out /elsewhere"
AGAIN = SMOKE.replace("/elsewhere", "/again")  # the same sweep into another folder
SMOKE_RUNS = [  # its plan: TAC at two q and two seeds on Hopper
    f"runs/tac/Hopper-v4/q{q}-a0.2-ls500-bs32/seed{seed}" for q in (1, 2) for seed in (0, 10)
]


@pytest.fixture(autouse=True)
def _own_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACBENCH_CALIBRATION", str(tmp_path / "calibration"))


def _run(folder: Path, command: str, created: str, updated: str) -> None:
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"command": command, "created": created}))
    (folder / "status.json").write_text(json.dumps({"state": "complete", "updated": updated}))


def _calibrate_smoke() -> float:
    """Store a calibration of the smoke preset's TAC unit; return what one of its runs costs."""
    configs = smoke_tac_unit()
    calibration.save({calibration.unit_key(configs): Calibration(1e-4, 2e-3, 5e-5, "-", 4)})
    return 500 * 1e-4 + 500 * 2e-3 + 2 * 2 * 1_000 * 5e-5  # random, learning, evaluation


def test_run_records_give_a_sweeps_wall_time_and_leave_out_single_runs(tmp_path: Path) -> None:
    first = "tacbench sweep --preset smoke --q 1.0"
    _run(tmp_path / "a", first, "2026-12-05T01:00:00+00:00", "2026-12-05T01:40:00+00:00")
    _run(tmp_path / "b", first, "2026-12-05T01:00:05+00:00", "2026-12-05T02:00:00+00:00")
    later = "tacbench sweep --preset smoke --q 2.0"
    _run(tmp_path / "c", later, "2026-12-05T03:00:00+00:00", "2026-12-05T03:10:00+00:00")
    _run(tmp_path / "d", "tacbench run --q 2", "2026-12-05T00:00:00+00:00", "2026-12-05T09:00Z")
    took = bills.sweeps(tmp_path)
    assert [(t.command, t.runs, t.wall_s) for t in took] == [(first, 2, 3600.0), (later, 1, 600.0)]
    assert {(t.source, t.cpu_class) for t in took} == {(bills.RUN_RECORDS, None)}
    assert took[1].keys == {(tmp_path / "c").as_posix()}  # not under a runs folder: its path


def test_a_whole_sweeps_bill_comes_before_its_run_records(tmp_path: Path) -> None:
    command = "tacbench sweep --preset smoke --q 1.0"
    _run(tmp_path / "runs" / "a", command, "2026-12-05T01:00:03+00:00", "2026-12-05T02:00:00Z")
    bill = {"cpu_class": "some-class", "workers": 2, "wall_s": 3000.0, "priced_wall_s": 2900.0}
    summary = {  # the sweep started at 01:00:00, before it created its run
        "command": command,
        "interrupted": False,
        "finished": "2026-12-05T01:50:00+00:00",
        "bill": bill,
    }
    (tmp_path / "sweep").mkdir()
    (tmp_path / "sweep" / "q1-summary.json").write_text(json.dumps(summary))
    (tmp_path / "sweep" / "stopped-summary.json").write_text(
        json.dumps({**summary, "command": "other", "interrupted": True})
    )
    [took] = bills.sweeps(tmp_path)
    assert (took.wall_s, took.cpu_class, took.source) == (3000.0, "some-class", bills.BILL)
    assert (took.priced_at_start_s, took.workers) == (2900.0, 2)
    shown = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert "took 50m00s (bill; some-class; priced at its start 48m20s)" in shown.output
    assert "on 2 workers" in shown.output  # the bill's, not this machine's
    assert "while it ran" not in shown.output  # this bill records no load
    bill.update(load_average=4.5, cores=4)
    (tmp_path / "sweep" / "q1-summary.json").write_text(json.dumps(summary))
    [took] = bills.sweeps(tmp_path)
    assert (took.load_average, took.cores) == (4.5, 4)
    shown = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert "\n  while it ran, the load averaged 4.5 on 4 cores, 2.5 above its workers: other" in (
        shown.output
    )


def test_the_bill_of_a_sweep_that_resumed_runs_is_not_the_whole_sweeps(tmp_path: Path) -> None:
    command = "tacbench sweep --preset smoke --q 1.0"
    _run(tmp_path / "runs" / "a", command, "2026-12-05T00:00:00+00:00", "2026-12-05T01:50:00Z")
    bill = {"cpu_class": "some-class", "workers": 1, "wall_s": 600.0, "priced_wall_s": 550.0}
    summary = {  # a rerun from 01:40 that finished the run a stopped sweep had started
        "command": command,
        "interrupted": False,
        "finished": "2026-12-05T01:50:00+00:00",
        "bill": bill,
    }
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    [took] = bills.sweeps(tmp_path)
    assert (took.source, took.wall_s, took.workers) == (bills.RUN_RECORDS, 6600.0, None)


def test_a_committed_studys_sweeps_from_their_run_records() -> None:
    took = bills.sweeps(STUDY)
    assert [t.runs for t in took] == [10, 10, 5]  # q = 1 and 1.5, then 2 and 3, then 5
    assert took[1].wall_s == 66 * 60 + 48  # 02:01:56 to 03:08:44 on 5 December
    assert "runs/tac/HalfCheetah-v4/q5-a0.2-authors20190116c/seed40" in took[2].keys


def test_a_recorded_command_is_repriced_from_scratch_as_the_dry_run_prices_it(
    tmp_path: Path,
) -> None:
    grid, options = recorded_sweep(SMOKE, tmp_path / "ignored")
    assert not bills.reprice(bills.fresh_plan(grid, options), options).calibrated  # none yet
    per_run = _calibrate_smoke()
    priced = bills.reprice(bills.fresh_plan(grid, options), options)
    assert priced.calibrated and priced.workers == 1
    assert priced.wall_s == pytest.approx(4 * per_run)  # one unit: two q times two seeds
    assert priced.core_hours == pytest.approx(4 * per_run / 3600)
    assert priced.runs == 4


def test_only_a_sweep_command_is_repriced() -> None:
    with pytest.raises(TacbenchError, match="not a tacbench sweep command"):
        recorded_sweep("tacbench run --q 2", Path("x"))


def test_within_is_the_price_against_the_wall_time() -> None:
    assert bills.within(100.0, 125.0) and bills.within(100.0, 75.0)
    assert not bills.within(100.0, 126.0) and not bills.within(100.0, 74.0)


def test_the_bills_command_gives_each_sweeps_ratio_once_calibrated(tmp_path: Path) -> None:
    on_time, late = tmp_path / "on-time", tmp_path / "late"
    for key in SMOKE_RUNS:
        _run(on_time / key, SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:05+00:00")
        _run(late / key, AGAIN, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:10+00:00")
    before = CliRunner().invoke(cli, ["study", "bills", str(on_time)])
    assert before.exit_code == 0, before.output
    assert "4 runs\n  took 0m05s (run records; CPU class not recorded)" in before.output
    assert "not calibrated: give --calibrate" in before.output
    _calibrate_smoke()  # four runs of 1.25 s in one unit: priced 5 s, the on-time sweep's wall
    after = CliRunner().invoke(cli, ["study", "bills", str(on_time), str(late)])
    assert "took 1.00x the price, the price within 25 % of it" in after.output
    assert "took 2.00x the price, the price outside 25 % of it" in after.output
    assert "CPU time" not in after.output  # runs begun before eval.csv logged cpu_s


def test_the_runs_cpu_time_is_set_beside_the_price_where_every_run_records_it(
    tmp_path: Path,
) -> None:
    """The late sweep shared the machine: twice its price in wall time, but its runs' CPU
    seconds (1.5 s each) show the price's rates 1.2x short, not 2x."""
    header = "step,wall_s,cpu_s,return_mean,return_std,length_mean\n"
    for key in SMOKE_RUNS:
        _run(tmp_path / key, SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:10+00:00")
        (tmp_path / key / "eval.csv").write_text(header + "500,4,0.5,1,0,1\n1000,9,1.5,1,0,1\n")
    _calibrate_smoke()
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "took 2.00x the price" in result.output
    assert "its runs' CPU time (eval.csv cpu_s): 0m06s of one core, 1.20x the price's 0m05s" in (
        result.output
    )
    copy = tmp_path / "copy" / SMOKE_RUNS[0]  # one run found twice counts once
    copy.parent.mkdir(parents=True)
    shutil.copytree(tmp_path / SMOKE_RUNS[0], copy)
    twice = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)]).output
    assert "0m06s of one core, 1.20x the price's 0m05s" in twice
    shutil.rmtree(tmp_path / "copy")
    for key in SMOKE_RUNS:  # runs that say their cpu_s is their share: never divided
        config = json.loads((tmp_path / key / "config.json").read_text())
        shared = {**config, "members": [0, 10], "cpu_clock": "share"}
        (tmp_path / key / "config.json").write_text(json.dumps(shared))
    assert "0m06s of one core" in CliRunner().invoke(cli, ["study", "bills", str(tmp_path)]).output
    for key in SMOKE_RUNS:  # begun before members split cpu_s: each logged its pair's
        config = json.loads((tmp_path / key / "config.json").read_text())
        del config["cpu_clock"]
        (tmp_path / key / "config.json").write_text(json.dumps(config))
    halved = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)]).output
    assert "its runs' CPU time (eval.csv cpu_s): 0m03s of one core, 0.60x the price's" in halved
    (tmp_path / SMOKE_RUNS[0] / "eval.csv").write_text(
        header.replace(",cpu_s", "") + "500,4,1,0,1\n"
    )
    assert "CPU time" not in CliRunner().invoke(cli, ["study", "bills", str(tmp_path)]).output
    (tmp_path / SMOKE_RUNS[0] / "eval.csv").write_text(header + "500,4,x,1,0,1\n")
    damaged = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert damaged.exit_code == 2 and "eval.csv cannot be read" in damaged.output
    # cut short: its last row was an earlier step's CPU time, taken without a word
    status = tmp_path / SMOKE_RUNS[0] / "status.json"
    status.write_text(json.dumps({**json.loads(status.read_text()), "step": 1000}))
    for cut, said in (
        ("500,4,0.5,1,0,1\n", "ends at step 500, where the complete run reached 1000"),
        ("500,4,0.5,1,0,1\n1000,9,1.", "its last line is torn"),
    ):
        (tmp_path / SMOKE_RUNS[0] / "eval.csv").write_text(header + cut)
        damaged = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
        assert damaged.exit_code == 2 and said in damaged.output, damaged.output


def test_runs_the_recorded_command_does_not_plan_are_not_compared(tmp_path: Path) -> None:
    _run(tmp_path / SMOKE_RUNS[0], SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:05Z")
    _run(
        tmp_path / "runs/tac/Hopper-v4/q3-a0.2/seed0",
        SMOKE,
        "2026-12-05T01:00:00Z",
        "2026-12-05T01:00:09Z",
    )
    _calibrate_smoke()
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert "2 runs, of which the command's plan names 1" in result.output
    assert "not comparable" in result.output and "the price" not in result.output


def test_part_of_a_sweep_is_priced_whole_from_its_bill_and_not_from_run_records(
    tmp_path: Path,
) -> None:
    """A study may keep part of a sweep. Its price was the part's, in smaller units than the
    sweep trained, and its wall time the whole sweep's (from run records: the part's span, with
    the other runs trained in it): the comparison study's two q of the paper's grid got a tenth
    of what they took. From a bill the whole sweep is priced; from run records it is not
    comparable."""
    for key in SMOKE_RUNS[:2]:
        _run(tmp_path / key, SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:05+00:00")
    per_run = _calibrate_smoke()
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "\n  2 runs of the 4 its command plans\n" in result.output
    assert "not comparable: only part of the sweep lies here" in result.output
    assert "x the price" not in result.output
    bill = {"cpu_class": "c", "workers": 1, "wall_s": 4 * per_run, "priced_wall_s": 5.0}
    summary = {"command": SMOKE, "interrupted": False, "finished": "2026-12-05T01:00:05Z"}
    (tmp_path / "summary.json").write_text(json.dumps({**summary, "bill": bill}))
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert "2 runs of the 4 its command plans" in result.output
    assert "took 1.00x the price, the price within 25 % of it" in result.output


def test_a_sweeps_runs_kept_by_two_studies_are_one_sweep(tmp_path: Path) -> None:
    """The comparison study keeps copies of two q of the paper's q grid, whose study keeps all of
    them: named together, the sweep is whole (each folder alone gave a part)."""
    whole, copies = tmp_path / "q-grid", tmp_path / "comparison"
    for key in SMOKE_RUNS:
        _run(whole / key, SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:05+00:00")
    status = whole / SMOKE_RUNS[0] / "status.json"
    complete = status.read_text()
    status.write_text(json.dumps({"state": "failed", "updated": "2026-12-05T01:00:01Z"}))
    for key in SMOKE_RUNS[:2]:
        shutil.copytree(whole / key, copies / key)
    [took] = bills.sweeps(whole, copies)
    assert (took.runs, took.wall_s, took.unfinished) == (4, 5.0, {"failed": 1})  # counted once
    _calibrate_smoke()
    for folder in (whole, copies):
        (folder / SMOKE_RUNS[0] / "status.json").write_text(complete)
    result = CliRunner().invoke(cli, ["study", "bills", str(copies), str(whole)])
    assert result.output.count(SMOKE) == 1 and "\n  4 runs\n" in result.output
    assert "took 1.00x the price, the price within 25 % of it" in result.output


@pytest.mark.parametrize(
    ("states", "said"),
    [(("failed",), "1 failed"), (("interrupted", "running"), "1 interrupted, 1 running")],
)
def test_a_sweep_with_a_run_short_of_its_budget_is_not_compared_with_its_price(
    tmp_path: Path, states: tuple[str, ...], said: str
) -> None:
    """A failed run stops before its budget; so does an interrupted one, and a sweep still
    running has not finished: none is a test of a price that trains every run to its budget
    (interrupted and running runs used to get a verdict)."""
    for key in SMOKE_RUNS:
        _run(tmp_path / key, SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:05+00:00")
    for key, state in zip(SMOKE_RUNS, states, strict=False):
        status = tmp_path / key / "status.json"
        status.write_text(json.dumps({"state": state, "updated": "2026-12-05T01:00:01+00:00"}))
    [took] = bills.sweeps(tmp_path)
    assert not took.comparable
    assert ", ".join(f"{n} {state}" for state, n in took.unfinished.items()) == said
    _calibrate_smoke()
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert f"4 runs, of which {said}\n" in result.output
    assert "not comparable: a run that stopped before its budget" in result.output
    assert "x the price" not in result.output


def test_a_folder_named_with_one_inside_it_counts_each_sweep_once(tmp_path: Path) -> None:
    for key in SMOKE_RUNS:
        _run(tmp_path / key, SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:05+00:00")
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path / "runs"), str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert result.output.count(SMOKE) == 1 and "4 runs\n" in result.output


BILL = {
    "wall_s": 5.0,
    "cpu_class": "x86_64-SomeVendor-1-2-AVX2",
    "priced_wall_s": 4.0,
    "workers": 1,
}


@pytest.mark.parametrize(
    ("file", "record", "message"),
    [
        ("config.json", {"command": SMOKE}, "'created' is None, not an ISO 8601 time"),
        ("status.json", {"state": "complete", "updated": "yesterday"}, "'updated' is 'yesterday'"),
        ("summary.json", {"command": SMOKE, "bill": {"wall_s": 5}}, "its bill lacks one of"),
        ("summary.json", {"command": SMOKE, "bill": BILL}, "'finished' is None"),
        (
            "summary.json",
            {"bill": BILL, "finished": "2026-12-05T01:00:00Z"},
            "records no sweep command",
        ),
        (  # a TypeError traceback
            "summary.json",
            {"command": SMOKE, "bill": {**BILL, "wall_s": "5"}, "finished": "2026-12-05T01:00Z"},
            "holds one of another type",
        ),
        (  # "can't compare offset-naive and offset-aware datetimes"
            "summary.json",
            {"command": SMOKE, "bill": BILL, "finished": "2026-12-05T01:00:00"},
            "a time without its UTC offset",
        ),
        (  # the same TypeError, from a run's record
            "config.json",
            {"command": SMOKE, "created": "2026-12-05T01:00:00"},
            "'created' is '2026-12-05T01:00:00', a time without its UTC offset",
        ),
        (  # a ValueError traceback
            "summary.json",
            {
                "command": SMOKE,
                "bill": {**BILL, "load_average": "2.1"},
                "finished": "2026-12-05T01:00Z",
            },
            "holds one of another type",
        ),
        (  # "--workers must be at least 1", which the user never gave
            "summary.json",
            {"command": SMOKE, "bill": {**BILL, "workers": 0}, "finished": "2026-12-05T01:00Z"},
            "holds one of another type",
        ),
    ],
)
def test_damaged_records_are_a_one_line_error(
    tmp_path: Path, file: str, record: dict, message: str
) -> None:
    for key in SMOKE_RUNS:
        _run(tmp_path / key, SMOKE, "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:05+00:00")
    path = tmp_path / (file if file == "summary.json" else f"{SMOKE_RUNS[0]}/{file}")
    path.write_text(json.dumps(record))
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert str(path) in result.output and message in result.output
    assert "restore it from the study's copy" in result.output
    assert "Traceback" not in result.output


def test_the_bills_command_says_when_no_sweep_trained_the_runs(tmp_path: Path) -> None:
    _run(tmp_path / "a", "tacbench run", "2026-12-05T01:00:00+00:00", "2026-12-05T01:00:10Z")
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path)])
    assert result.exit_code == 2 and "was trained by a tacbench sweep" in result.output


def test_a_recorded_command_this_tacbench_refuses_does_not_hide_the_other_bills(
    tmp_path: Path,
) -> None:
    bogus = "tacbench sweep --preset bogus --out /elsewhere"
    _run(
        tmp_path / "old/runs/tac/Hopper-v4/q1-a0.2/seed0",
        bogus,
        "2026-12-05T01:00:00Z",
        "2026-12-05T01:00:05Z",
    )
    for key in SMOKE_RUNS:
        _run(tmp_path / "new" / key, SMOKE, "2026-12-05T02:00:00Z", "2026-12-05T02:00:05Z")
    folders = [str(tmp_path / "old"), str(tmp_path / "new"), str(tmp_path / "new")]
    result = CliRunner().invoke(cli, ["study", "bills", *folders])
    assert result.exit_code == 0, result.output
    assert f"{bogus}\n  cannot be priced here: this tacbench does not accept" in result.output
    assert result.output.count(SMOKE) == 1  # a folder given twice is read once


def test_recalibrate_measures_each_kind_of_unit_once_for_every_sweep(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two sweeps of one kind of unit: measured again once, replacing the stored calibration,
    and both priced by the new one."""
    _calibrate_smoke()
    measured: list[int] = []

    def measure(configs: Any) -> Calibration:
        measured.append(len(configs))
        return Calibration(2e-4, 4e-3, 1e-4, "2026-12-07", len(configs))

    monkeypatch.setattr(calibration, "measure", measure)
    for folder, command in (("first", SMOKE), ("second", AGAIN)):
        for key in SMOKE_RUNS:
            _run(tmp_path / folder / key, command, "2026-12-05T01:00:00Z", "2026-12-05T01:00:10Z")
    args = ["study", "bills", str(tmp_path / "first"), str(tmp_path / "second")]
    result = CliRunner().invoke(cli, [*args, "--recalibrate"])
    assert result.exit_code == 0, result.output
    # the smoke preset's TAC units are of one kind: measured once a round for both sweeps
    assert len(measured) == calibration.ROUNDS
    assert result.output.count("took 1.00x the price, the price within 25 % of it") == 2


def test_calibrate_measures_no_unit_of_a_sweep_that_cannot_test_its_price(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It measured every sweep's units (minutes each), then called the sweep not comparable."""
    measured: list[int] = []

    def measure(configs: Any) -> Calibration:
        measured.append(len(configs))
        return Calibration(2e-4, 4e-3, 1e-4, "2026-12-07", len(configs))

    monkeypatch.setattr(calibration, "measure", measure)
    for key in SMOKE_RUNS:
        _run(tmp_path / key, SMOKE, "2026-12-05T01:00:00Z", "2026-12-05T01:00:10Z")
    status = tmp_path / SMOKE_RUNS[0] / "status.json"
    status.write_text(json.dumps({"state": "failed", "updated": "2026-12-05T01:00:01Z"}))
    result = CliRunner().invoke(cli, ["study", "bills", str(tmp_path), "--recalibrate"])
    assert result.exit_code == 0, result.output
    assert "4 runs, of which 1 failed\n" in result.output
    assert "not comparable: a run that stopped before its budget" in result.output
    assert measured == []
