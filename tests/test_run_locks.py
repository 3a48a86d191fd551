"""One writer per run directory: a second process (or a second group in this one) that would
write a locked run directory is refused with the holder's PID, and the first run's results are
those of a lone run."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tacbench.errors import TacbenchError
from tacbench.runs import run_directory
from tacbench.runs.locks import lock_path, writing
from tests.helpers import assert_same_results, run_cli, start_cli, tiny_configs, train, wait_for

pytestmark = pytest.mark.unit


def test_a_held_run_directory_refuses_a_second_writer_and_names_the_holder(
    tmp_path: Path,
) -> None:
    configs = tiny_configs("tac", seeds=(0, 10))
    locked = run_directory(tmp_path, "tac", configs[1].env, configs[1].variant, 10)
    first = run_directory(tmp_path, "tac", configs[0].env, configs[0].variant, 0)
    with writing([locked]):
        with pytest.raises(TacbenchError, match=f"being written by .*PID {os.getpid()} on "):
            train(tmp_path, configs)
        assert not first.exists()
    train(tmp_path, configs[:1])  # seed 0 trained alone

    def files() -> dict[str, bytes]:
        return {str(p.relative_to(first)): p.read_bytes() for p in first.rglob("*") if p.is_file()}

    before = files()
    with writing([locked]), pytest.raises(TacbenchError, match="being written"):
        # the group locks all its members before it touches any: --force does not start
        # seed 0 over (deleting it) before it finds seed 10 held
        train(tmp_path, configs, force=True)
    assert files() == before
    outcomes = train(tmp_path, configs, force=True)  # released: trains
    assert [o.state for o in outcomes] == ["complete", "complete"]
    assert lock_path(locked).is_file()  # kept: deleting it could let two writers in


def test_force_cannot_take_a_run_from_its_writer(tmp_path: Path) -> None:
    configs = tiny_configs("ddpg")
    train(tmp_path, configs)
    directory = run_directory(tmp_path, "ddpg", configs[0].env, configs[0].variant, 0)
    before = (directory / "eval.csv").read_text()
    with writing([directory]), pytest.raises(TacbenchError, match="being written"):
        train(tmp_path, configs, force=True)
    assert (directory / "eval.csv").read_text() == before


def test_two_processes_on_one_run_one_refused_the_other_as_a_lone_run(tmp_path: Path) -> None:
    args = [
        "run",
        "--env",
        "Hopper-v4",
        "--q",
        "1.5",
        "--steps",
        "3000",
        "--learning-starts",
        "500",
        "--eval-every",
        "1000",
        "--eval-episodes",
        "1",
        "--hidden-sizes",
        "16",
        "--batch-size",
        "16",
        "--compile",
        "off",
        "--quiet",
    ]
    first = start_cli([*args, "--out", str(tmp_path / "both")])
    wait_for(
        lambda: any((tmp_path / "both").glob("runs/tac/*/*/seed0/status.json")),
        timeout=60,
        proc=first,
        what="the first run's status.json",
    )
    second = run_cli([*args, "--out", str(tmp_path / "both")])
    assert second.returncode == 2, second.stdout + second.stderr
    assert f"PID {first.pid} on" in second.stdout + second.stderr
    assert "Traceback" not in second.stdout + second.stderr
    assert first.wait(timeout=300) == 0
    lone = run_cli([*args, "--out", str(tmp_path / "lone")])
    assert lone.returncode == 0, lone.stdout + lone.stderr
    run = next((tmp_path / "both").glob("runs/tac/*/*/seed0"))
    assert_same_results(run, next((tmp_path / "lone").glob("runs/tac/*/*/seed0")))


def test_a_file_where_a_folder_of_the_run_path_goes_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "runs").write_text("mine")
    (config,) = tiny_configs("tac")
    with pytest.raises(TacbenchError, match="lock: a file stands where a folder of "):
        train(tmp_path, [config])
    assert (tmp_path / "runs").read_text() == "mine"


@pytest.mark.parametrize("what", ["a folder", "a link"])
def test_a_folder_or_link_where_the_lock_file_goes_is_refused_untouched(
    tmp_path: Path, what: str
) -> None:
    """A folder there was a traceback; a link was followed and its target overwritten."""
    (config,) = tiny_configs("tac")
    lock = lock_path(run_directory(tmp_path, config.algo, config.env, config.variant, config.seed))
    lock.parent.mkdir(parents=True)
    target = tmp_path / "someone's file"
    target.write_text("mine")
    if what == "a folder":
        lock.mkdir()
    else:
        lock.symlink_to(target)
    with pytest.raises(TacbenchError, match=f"lock is {what}, where tacbench keeps a lock file"):
        train(tmp_path, [config])
    assert target.read_text() == "mine"
    assert not (lock.parent / f"seed{config.seed}").exists()
