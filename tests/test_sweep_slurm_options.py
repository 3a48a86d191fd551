"""The Slurm executor's options, checked without a cluster: time limits, sbatch arguments, which
flags go with which executor, and a clear error where Slurm is not installed."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.sweep import driver, slurm

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(
    ("text", "minutes"),
    [
        ("90", 90),
        ("1:30", 90),
        ("1:30:00", 90),
        ("0:00:01", 1),
        ("2-00:00", 2880),
        ("1-2:03:04", 1564),
    ],
)
def test_time_limits_in_slurms_formats(text: str, minutes: int) -> None:
    assert slurm.parse_time(text) == minutes


@pytest.mark.parametrize("text", ["", "abc", "1:2:3:4", "-5", "0", "0:00"])
def test_bad_time_limits_say_what_to_give(text: str) -> None:
    with pytest.raises(TacbenchError, match="--time"):
        slurm.parse_time(text)


def test_slurm_args_become_sbatch_options() -> None:
    parsed = slurm.parse_slurm_args(("mem=8G", "--qos=normal", "mail-type=END", "comment=a=b"))
    assert parsed == {"mem": "8G", "qos": "normal", "mail_type": "END", "comment": "a=b"}
    for bad in ("mem", "=8G"):
        with pytest.raises(TacbenchError, match="KEY=VALUE"):
            slurm.parse_slurm_args((bad,))


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"partition": "gpu"}, "Slurm options"),
        ({"executor": "ray", "time_limit": "10"}, "Slurm options"),
        ({"executor": "slurm", "shared_fs": True}, "Ray options"),
        ({"executor": "slurm", "address": "auto"}, "Ray options"),
        ({"executor": "slurm", "time_limit": "soon"}, "--time"),
        ({"executor": "slurm", "slurm_args": ("mem",)}, "KEY=VALUE"),
        ({"executor": "pbs"}, "--executor must be one of local, ray, slurm"),
    ],
)
def test_options_that_do_not_go_together_are_refused(options: dict, message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        driver.Options(**options)


def test_no_slurm_on_the_path_is_a_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("submitit")
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(TacbenchError, match="sbatch and squeue"):
        slurm.SlurmExecutor(
            tmp_path,
            workers=None,
            partition=None,
            time_limit="10",
            cpus=1,
            gpus=0,
            slurm_args={},
            command="",
        )


def test_the_cli_refuses_a_bad_time_with_status_2(tmp_path: Path) -> None:
    args = ["sweep", "--preset", "smoke", "--executor", "slurm", "--time", "soon"]
    result = CliRunner().invoke(cli, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert "--time 'soon'" in result.output
