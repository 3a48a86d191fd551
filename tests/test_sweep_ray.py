"""``tacbench sweep --executor ray`` on a local Ray with 2 CPUs: the tasks write into a scratch
folder (as on a cluster without a shared filesystem) and return the small files, which the
driver writes into --out; checkpoints stay in the scratch folder."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.cli import cli

ray = pytest.importorskip("ray")

# a Ray test starts a local Ray and checks that its raylet and GCS processes are gone at the end:
# Ray tests run one after another on one xdist worker, so that no other test's Ray is counted
pytestmark = [pytest.mark.smoke, pytest.mark.xdist_group("ray")]


def _ray_processes() -> set[int]:
    """Ids of this machine's raylet and GCS server processes."""
    found = set()
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            text = cmdline.read_bytes().decode(errors="replace")
        except OSError:
            continue
        if "raylet" in text or "gcs_server" in text:
            found.add(int(cmdline.parent.name))
    return found


def test_ray_executor_returns_small_files_and_keeps_checkpoints_on_the_node(
    tmp_path: Path,
) -> None:
    before = _ray_processes()
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--algo", "ppo", "--seed", "0"]
    args += ["--executor", "ray", "--workers", "2", "--scratch", str(scratch), "--out", str(out)]
    runner = CliRunner()
    result = runner.invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "3 runs: 3 complete, 0 failed" in result.output
    assert not ray.is_initialized()

    run_dirs = sorted(out.glob("runs/*/Hopper-v4/*/seed0"))
    assert [d.parts[-4] for d in run_dirs] == ["ppo", "tac", "tac"]
    (node_root,) = scratch.iterdir()  # <scratch>/<digest of --out>
    history = json.loads((out / "sweep" / "state.json").read_text())["runs"]
    for run in run_dirs:
        key = run.relative_to(out).as_posix()
        assert sorted(p.name for p in run.iterdir()) == [
            "config.json",
            "eval.csv",
            "losses.csv",
            "status.json",
            "train.csv",
        ]
        assert json.loads((run / "status.json").read_text())["state"] == "complete"
        assert pd.read_csv(run / "eval.csv")["step"].tolist() == [500, 1000]
        assert (run / "eval.csv").read_bytes() == (node_root / key / "eval.csv").read_bytes()
        assert list((node_root / key / "checkpoint").glob("manifest-*.json"))
        assert len(history[key]["node"]) > 10  # the Ray node holding its checkpoint
    logs = sorted((out / "sweep" / "logs").glob("*.log"))
    assert len(logs) == 3 and all("1000/1000" in log.read_text() for log in logs)

    # the driver's copy lost: the task finds the run complete on its node and sends it back
    shutil.rmtree(run_dirs[0])
    again = runner.invoke(cli, args)
    assert again.exit_code == 0, again.output
    assert pd.read_csv(run_dirs[0] / "eval.csv")["step"].tolist() == [500, 1000]
    assert _ray_processes() <= before  # ray.shutdown() stopped the local Ray
