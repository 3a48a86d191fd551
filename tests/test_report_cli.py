"""``tacbench report`` end to end on a small generated results tree."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tests.report_fixtures import synthetic_tree, write_run

pytestmark = pytest.mark.smoke

FIGURES = ("q_sweep", "comparison", "intervals", "intervals_per_task", "improvement", "profiles")


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = synthetic_tree(
        tmp_path_factory.mktemp("results"),
        tasks=("HalfCheetah-v4", "Hopper-v4"),
        qs=(1.0, 1.5, 2.0),
        baselines=("td3",),
        seeds=3,
        n_eval=10,
        spread=0.1,
    )
    write_run(
        root,
        algo="tac",
        env="Hopper-v4",
        variant="q1.5-a0.2",
        seed=99,
        q=1.5,
        alpha=0.2,
        steps=[5000, 10000],
        returns=[10.0, 20.0],
        total_steps=50000,
        state="running",
    )
    broken = write_run(
        root, algo="td3", env="Hopper-v4", variant="default", seed=98, steps=[1], returns=[1.0]
    )
    (broken / "config.json").write_text("{")
    return root


def _invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(cli, ["report", *args])
    return result.exit_code, result.output


@pytest.fixture(scope="module")
def report_dir(results: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("report")
    code, output = _invoke("--results", str(results), "--out", str(out), "--reps", "200")
    assert code == 0, output
    assert f"wrote {out / 'index.html'}" in output
    assert "25 runs loaded (1 partial), 1 skipped (see skipped.csv)" in output
    return out


def test_report_writes_every_file(report_dir: Path) -> None:
    out = report_dir
    for name in FIGURES:
        assert (out / f"{name}.png").stat().st_size > 10_000
    for table in ("runs", "skipped", "summary", "best_q", "stats_aggregate", "improvement"):
        assert (out / f"{table}.csv").exists()

    summary = pd.read_csv(out / "summary.csv")
    partial = summary[(summary["env"] == "Hopper-v4") & (summary["method"] == "TAC q=1.5")]
    assert partial["seeds"].item() == 4 and partial["partial"].item() == 1
    skipped = pd.read_csv(out / "skipped.csv")
    assert skipped["path"].tolist() == ["td3/Hopper-v4/default/seed98"]
    assert skipped["reason"].item().startswith("config.json unreadable")

    page = (out / "index.html").read_text()
    assert page.count("data:image/png;base64,") == len(FIGURES)
    assert 'src="http' not in page and "<link" not in page
    assert "How to read this" in page and "evaluation returns" in page
    assert "tacbench run --algo tac --env Hopper-v4 --variant q1.5-a0.2 --seed 99" in page
    assert "2.13.0" in page and "td3/Hopper-v4/default/seed98" in page
    markdown = (out / "report.md").read_text()
    assert "![" in markdown and "(q_sweep.png)" in markdown
    assert "| task | best q (final) |" in markdown


def test_train_metric_and_pdf_figures(results: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    args = ("--results", str(results), "--out", str(out), "--reps", "100")
    code, output = _invoke(*args, "--metric", "train", "--format", "pdf")
    assert code == 0, output
    assert (out / "q_sweep.pdf").read_bytes().startswith(b"%PDF")
    page = (out / "index.html").read_text()
    assert page.count("data:image/png;base64,") == len(FIGURES)
    assert "training-episode returns" in page


def test_svg_figures_are_embedded_as_svg(results: Path, tmp_path: Path) -> None:
    """And an earlier report's files that this one does not write (its figures in another
    format) are named in a caution, not deleted (a file of the user's is left alone too)."""
    out = tmp_path / "report"
    out.mkdir()
    (out / "report.md").write_text("# tacbench report\n")  # an earlier report's folder
    (out / "comparison.png").write_bytes(b"an earlier report's")
    (out / "notes.txt").write_text("mine")
    code, output = _invoke(
        "--results", str(results), "--out", str(out), "--reps", "100", "--format", "svg"
    )
    assert code == 0, output
    assert f"caution: {out} also holds comparison.png, which this report did not write" in output
    assert "notes.txt" not in output and (out / "comparison.png").exists()
    assert (out / "comparison.svg").read_text().lstrip().startswith("<?xml")
    assert (out / "index.html").read_text().count("data:image/svg+xml;base64,") == len(FIGURES)


def test_same_results_give_the_same_report(results: Path, report_dir: Path, tmp_path: Path) -> None:
    code, output = _invoke("--results", str(results), "--out", str(tmp_path), "--reps", "200")
    assert code == 0, output
    for name in ("stats_aggregate.csv", "improvement.csv", "summary.md", "q_sweep.png"):
        assert (tmp_path / name).read_bytes() == (report_dir / name).read_bytes()


def test_user_errors_exit_with_status_two(tmp_path: Path) -> None:
    code, output = _invoke("--results", str(tmp_path), "--out", str(tmp_path / "r"))
    assert code == 2 and "no run directories under" in output and "Traceback" not in output
    code, output = _invoke("--results", str(tmp_path / "nope"))
    assert code == 2 and "does not exist" in output
    code, output = _invoke("--results", "", "--out", str(tmp_path / "r"))  # not this folder
    assert code == 2 and "must name a folder (got an empty string)" in output
    write_run(tmp_path, algo="td3", env="Ant-v4", variant="d", seed=0, steps=[1], returns=[1.0])
    code, output = _invoke("--results", str(tmp_path), "--out", str(tmp_path / "r"), "--reps", "5")
    assert code == 2 and "--reps must be at least 100" in output
    assert not (tmp_path / "r").exists()
    (tmp_path / "afile").write_text("")  # an --out below a file: refused before any analysis
    code, output = _invoke("--results", str(tmp_path), "--out", str(tmp_path / "afile" / "r"))
    assert code == 2 and "cannot create or write the output folder" in output
    assert "choose one you can write with --out" in output and "Traceback" not in output


def test_a_folder_of_other_tables_is_refused_before_the_analysis(
    results: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A study's analysis folder as --out had its own summary.csv and curves.csv replaced."""
    import tacbench.report

    def analyse(options: object) -> None:
        raise AssertionError("analysed before refusing --out")

    monkeypatch.setattr(tacbench.report, "analyse", analyse)
    (tmp_path / "summary.csv").write_text("the study's own\n")
    (tmp_path / "notes.txt").write_text("mine")
    code, output = _invoke("--results", str(results), "--out", str(tmp_path), "--reps", "100")
    assert code == 2, output
    assert f"--out {tmp_path} holds summary.csv, which a report could overwrite" in output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "summary.csv"]
    assert (tmp_path / "summary.csv").read_text() == "the study's own\n"


def test_a_report_stopped_while_writing_leaves_the_earlier_one_whole(
    results: Path, report_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A Ctrl-C half-way through writing left the new report's tables beside the earlier
    report's page, which read as one report."""
    out = tmp_path / "report"
    shutil.copytree(report_dir, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    from tacbench.report import plots

    saved: list[object] = []
    real_save = plots.save

    def save_then_stop(fig: object, path: object, *args: object) -> None:
        saved.append(path)
        if len(saved) == 3:
            raise KeyboardInterrupt
        real_save(fig, path, *args)

    monkeypatch.setattr(plots, "save", save_then_stop)
    code, output = _invoke("--results", str(results), "--out", str(out), "--reps", "150")
    assert code == 130, output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no staging folder left


def test_config_provenance_reaches_the_page(results: Path, report_dir: Path) -> None:
    config = json.loads((results / "runs/td3/HalfCheetah-v4/default/seed0/config.json").read_text())
    page = (report_dir / "index.html").read_text()
    assert config["command"] in page and config["git_commit"] in page
    assert config["versions"]["torch"] in page


def test_runs_of_one_q_range_say_so_in_place_of_the_range_table(tmp_path: Path) -> None:
    """The page showed an empty table."""
    for seed in (0, 10):
        write_run(
            tmp_path, algo="tac", env="Hopper-v4", variant="q1-a0.2", seed=seed,
            steps=[1.0, 2.0], returns=[1.0, 2.0 + seed], q=1.0, alpha=0.2,
        )  # fmt: skip
    out = tmp_path / "report"
    code, output = _invoke("--results", str(tmp_path), "--out", str(out), "--reps", "100")
    assert code == 0, output
    page = (out / "report.md").read_text()
    assert "needs TAC runs at 1 <= q < 2 and in another range on one task" in page
    assert (out / "q_ranges.csv").read_text().count("\n") == 1  # the header only


def test_the_page_is_moved_into_place_last(
    results: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Until report.md and index.html are replaced the folder reads as the earlier report."""
    moved: list[str] = []
    real_replace = Path.replace

    def replace(self: Path, target: Any) -> Any:
        moved.append(self.name)
        return real_replace(self, target)

    monkeypatch.setattr(Path, "replace", replace)
    code, output = _invoke("--results", str(results), "--out", str(tmp_path), "--reps", "100")
    assert code == 0, output
    pages = [i for i, name in enumerate(moved) if name in ("report.md", "index.html")]
    assert len(moved) > 10 and pages == [len(moved) - 2, len(moved) - 1]


def test_a_report_of_one_run_counts_it_in_the_singular(tmp_path: Path) -> None:
    """ "1 run on 1 task", not "1 runs on 1 tasks", in the command's line and the page, whose
    empty comparison with q = 1 is a sentence, not a table's bare header."""
    write_run(
        tmp_path,
        algo="tac",
        env="Hopper-v4",
        variant="q1-a0.2",
        seed=0,
        q=1.0,
        alpha=0.2,
        steps=[5000, 10000],
        returns=[10.0, 20.0],
        total_steps=50000,
        state="running",
    )
    out = tmp_path / "report"
    code, output = _invoke("--results", str(tmp_path), "--out", str(out), "--reps", "100")
    assert code == 0, output
    assert "1 run loaded (1 partial), 0 skipped;" in output
    page = (out / "report.md").read_text()
    assert "- 1 run on 1 task (Hopper-v4) and 1 method, from" in page
    assert "- 1 partial run included (see Runs)." in page
    assert "The command that produced the runs:" in page
    assert "| P(method > q = 1) [95 % CI] |" not in page
    assert "The probability of improvement over q = 1 needs TAC runs at q = 1 and at" in page
