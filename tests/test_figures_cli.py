"""``tacbench figures`` end to end: every PNG and CSV is written and readable."""

from __future__ import annotations

import errno
import os
import struct
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.theory import figures

pytestmark = pytest.mark.smoke

EXPECTED_COLUMNS = {
    "qexp_qlog_entropy": ["function", "q", "x", "value"],
    "bandit_policies": ["q", "alpha", "action", "reward", "prob"],
    "q_max_bounds": ["q", "c", "q_max", "lower", "upper"],
    "error_bounds": ["q", "J", "lower_bound", "upper_bound"],
}


def _png_size(path: Path) -> tuple[int, int]:
    header = path.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    width, height = struct.unpack(">II", header[16:24])
    return width, height


def test_figures_command_writes_every_figure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # the default --out is relative: results/figures
    result = CliRunner().invoke(cli, ["figures"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "results" / "figures"
    for name, columns in EXPECTED_COLUMNS.items():
        png, csv = out / f"{name}.png", out / f"{name}.csv"
        assert f"wrote {Path('results/figures') / png.name}" in result.output
        assert f"wrote {Path('results/figures') / csv.name}" in result.output
        width, height = _png_size(png)
        assert width >= 1000 and height >= 400
        table = pd.read_csv(csv)
        assert list(table.columns) == columns and len(table) > 0
    assert len(result.output.splitlines()) == 2 * len(EXPECTED_COLUMNS)


def test_figures_command_rejects_a_file_as_out(tmp_path: Path) -> None:
    target = tmp_path / "file"
    target.write_text("x")
    result = CliRunner().invoke(cli, ["figures", "--out", str(target)])
    assert result.exit_code == 2
    assert "is a file" in result.output
    assert "Traceback" not in result.output


def test_a_folder_where_a_figure_goes_is_refused_before_any_is_written(tmp_path: Path) -> None:
    (tmp_path / "q_max_bounds.png").mkdir()
    result = CliRunner().invoke(cli, ["figures", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "holds q_max_bounds.png as a folder, where a figure's file goes" in result.output
    assert [p.name for p in tmp_path.iterdir()] == ["q_max_bounds.png"]


def test_an_out_that_takes_no_file_is_refused_before_any_figure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A read-only folder (root's /sys/kernel) gave a PermissionError traceback, at the first
    figure's write."""

    def read_only(**kwargs: object) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(kwargs["dir"]))

    monkeypatch.setattr(figures.tempfile, "TemporaryFile", read_only)
    result = CliRunner().invoke(cli, ["figures", "--out", str(tmp_path / "figs")])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "cannot create or write the output directory" in result.output
    assert "Read-only file system; pick another --out" in result.output
    assert list((tmp_path / "figs").iterdir()) == []
