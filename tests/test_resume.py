"""Resume, for every learner: stopped any number of times (before the start, in warm-up, while
learning, mid-episode) and resumed, or crashed and resumed from its last checkpoint, a run
writes exactly the CSVs of an uninterrupted one, and TensorBoard shows exactly those rows;
Ctrl-C on the command line checkpoints and
exits 130, and ``--resume`` completes it."""

from __future__ import annotations

import json
import shutil
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from baselines import OFF_POLICY
from tacbench.runs.resume_checks import DamagedRun
from tests.helpers import (
    LEARNERS,
    assert_same_results,
    assert_tensorboard_matches_csvs,
    checkpoint_state,
    interrupt_cli,
    run_cli,
    tiny_configs,
    train,
)

pytestmark = pytest.mark.smoke

# where a stop asked for at 0, 730 and 1234 takes effect: at once for TAC and the off-policy
# baselines, at the end of the 512-step rollout in progress for PPO and TRPO
ON_POLICY_STOPS = {0: 0, 730: 1024, 1234: 1536}


@pytest.mark.parametrize("learner", LEARNERS)
def test_stop_and_resume_equals_an_uninterrupted_run(
    tmp_path: Path, uninterrupted: Callable[[str], Path], learner: str
) -> None:
    configs = tiny_configs(learner)
    on_policy = configs[0].algo in ("ppo", "trpo")
    for stop_at in (0, 730, 1234):
        (outcome,) = train(tmp_path, configs, resume=True, stop=lambda s, at=stop_at: s >= at)
        expected = ON_POLICY_STOPS[stop_at] if on_policy else stop_at
        if expected >= 1500:  # the stop came in the last rollout: the run simply completes
            assert outcome.state == "complete"
            break
        assert (outcome.state, outcome.step) == ("interrupted", expected)
        assert "resume with" in outcome.message
        status = json.loads((outcome.directory / "status.json").read_text())
        assert (status["state"], status["step"]) == ("interrupted", expected)
    else:
        (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete"
    assert_same_results(uninterrupted(learner), outcome.directory)
    assert_tensorboard_matches_csvs(outcome.directory)


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("learner", LEARNERS)
def test_a_stop_at_the_step_resumed_from_leaves_its_checkpoint_as_it_was(
    tmp_path: Path, uninterrupted: Callable[[str], Path], learner: str
) -> None:
    """A resumed run stopped before its first step rewrote the generation it resumed from, so
    a kill during that write left no intact checkpoint; now it writes nothing."""
    configs = tiny_configs(learner)
    (stopped,) = train(tmp_path, configs, resume=True, stop=lambda s: s >= 730)
    checkpoint = stopped.directory / "checkpoint"
    before = _files(checkpoint)
    (again,) = train(tmp_path, configs, resume=True, stop=lambda s: True)
    assert (again.state, again.step) == ("interrupted", stopped.step)
    assert _files(checkpoint) == before
    (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete"
    assert_same_results(uninterrupted(learner), outcome.directory)


@pytest.mark.parametrize("learner", ["tac", "ddpg"])
def test_resume_after_a_crash_drops_rows_past_the_last_checkpoint(
    tmp_path: Path, uninterrupted: Callable[[str], Path], learner: str
) -> None:
    def crash(step: int) -> bool:
        if step >= 1300:
            raise RuntimeError("simulated crash")
        return False

    configs = tiny_configs(learner)
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(tmp_path, configs, stop=crash)
    c = configs[0]
    run = tmp_path / "runs" / c.algo / "Hopper-v4" / c.variant / "seed0"
    assert json.loads((run / "status.json").read_text())["step"] == 1000  # last checkpoint
    assert pd.read_csv(run / "losses.csv")["step"].max() == 1250  # a row past it
    (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete"
    assert_same_results(uninterrupted(learner), run)
    assert_tensorboard_matches_csvs(run)  # the points past step 1000 of the crashed process hidden
    if c.algo in OFF_POLICY:
        assert not (run / "checkpoint" / "replay" / "000000001000-000000001300.npz").exists()


def test_a_file_where_the_event_files_go_stops_a_resume_before_anything_is_cut(
    tmp_path: Path,
) -> None:
    """It was a FileExistsError traceback after the CSVs had lost their rows past the
    checkpoint; now a clear refusal that changes nothing, and --no-tensorboard resumes."""

    def crash(step: int) -> bool:
        if step >= 1300:
            raise RuntimeError("simulated crash")
        return False

    configs = tiny_configs("tac")
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(tmp_path, configs, stop=crash)
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / configs[0].variant / "seed0"
    shutil.rmtree(run / "tensorboard")
    (run / "tensorboard").write_text("not a folder")
    before = _files(run)
    with pytest.raises(DamagedRun, match=r"tensorboard is a file .* --no-tensorboard"):
        train(tmp_path, configs, resume=True)
    assert _files(run) == before
    (outcome,) = train(tmp_path, [replace(c, tensorboard=False) for c in configs], resume=True)
    assert (outcome.state, outcome.step) == ("complete", 1500)


def test_resume_on_an_env_without_exact_state_starts_a_fresh_episode(tmp_path: Path) -> None:
    configs = tiny_configs("tac", "Pendulum-v1", q=1.0, eval_every=0)
    (first,) = train(tmp_path, configs, stop=lambda s: s >= 1100)
    assert (first.state, first.step) == ("interrupted", 1100)
    (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete"
    episodes = pd.read_csv(outcome.directory / "train.csv")
    # 200-step episodes; the one in progress at 1100 is dropped and a new one starts there
    assert episodes["step"].tolist() == [200, 400, 600, 800, 1000, 1300, 1500]
    assert (episodes["length"] == 200).all()


@pytest.mark.parametrize(
    ("args", "when", "rollout"),
    [
        (["--env", "Hopper-v4", "--steps", "2000", "--learning-starts", "1000"], "step 1000/", 1),
        (["--algo", "ppo", "--env", "Hopper-v4", "--steps", "2000"], "step 500/", 512),
    ],
    ids=["tac", "ppo"],
)
def test_ctrl_c_checkpoints_and_resume_completes(
    tmp_path: Path, args: list[str], when: str, rollout: int
) -> None:
    if rollout > 1:
        args = [*args, "--hp", "n_steps=512", "--hp", "n_epochs=1"]
    args = ["run", *args, "--eval-every", "500", "--eval-episodes", "1", "--out", str(tmp_path)]
    code, output = interrupt_cli(args, when)
    assert code == 130, output
    assert "interrupted at step" in output and "--resume" in output
    (run,) = (tmp_path / "runs").glob("*/Hopper-v4/*/seed0")
    status = json.loads((run / "status.json").read_text())
    assert status["state"] == "interrupted" and status["step"] < 2000
    assert status["step"] % rollout == 0  # PPO stops at the end of its rollout
    assert checkpoint_state(run)["step"] == status["step"]
    resumed = run_cli([*args, "--resume"])
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [500, 1000, 1500, 2000]
    train_steps = pd.read_csv(run / "train.csv")["step"]
    assert train_steps.is_monotonic_increasing and not train_steps.duplicated().any()


def _stopped_twice_then_resumed(
    out: Path, configs: list, stops: tuple[int, int] = (730, 1234)
) -> list:
    """Train ``configs`` into ``out`` stopped at steps ``stops``, then to the end."""
    for stop_at in stops:
        stopped = train(out, configs, resume=True, stop=lambda s, at=stop_at: s >= at)
        assert {(o.state, o.step) for o in stopped} == {("interrupted", stop_at)}
    return train(out, configs, resume=True)


@pytest.mark.parametrize("profile", ["paper", "reference"])
def test_a_mixed_group_stopped_and_resumed_continues_every_member_exactly(
    tmp_path: Path, profile: str
) -> None:
    """Members at q = 1 and 2 (q = 1 and the cap in one group) with two seeds each; in the
    reference profile each updates at its own episode ends, from its first one (every step
    of a finished episode is an update from the start: 600 steps, stopped at 260 and 430)."""
    settings: dict[str, Any] = {}
    stops = (730, 1234)  # in the warm-up and while learning
    if profile == "reference":
        settings = {"profile": profile, "hidden_sizes": (32,), "total_steps": 600}
        stops = (260, 430)
    configs = tiny_configs("tac", seeds=[0, 10], qs=[1.0, 2.0], **settings)
    reference = train(tmp_path / "reference", configs)
    resumed = _stopped_twice_then_resumed(tmp_path / "resumed", configs, stops)
    assert [o.state for o in resumed] == ["complete"] * 4
    for a, b in zip(reference, resumed, strict=True):
        assert a.directory.relative_to(tmp_path / "reference") == b.directory.relative_to(
            tmp_path / "resumed"
        )
        assert_same_results(a.directory, b.directory)


def test_updates_begun_in_the_warm_up_resume_exactly(tmp_path: Path) -> None:
    """The step schedule with --warmup-updates on: updates begin at a member's first episode
    end, in the warm-up, and go on every step; whether they have begun is checkpointed. The
    profiles above recompute it every step (warm-up updates off) or at each episode end (the
    episode schedule), so a resume that forgot it passed their tests and wrote other rows
    here."""
    settings: dict[str, Any] = {"update_schedule": "step", "warmup_updates": "on"}
    configs = tiny_configs("tac", seeds=[0, 10], total_steps=900, **settings)
    reference = train(tmp_path / "reference", configs)
    resumed = _stopped_twice_then_resumed(tmp_path / "resumed", configs, (300, 610))
    for a, b in zip(reference, resumed, strict=True):
        assert b.state == "complete"
        assert_same_results(a.directory, b.directory)


@pytest.mark.compile
def test_a_compiled_group_stopped_and_resumed_continues_exactly(tmp_path: Path) -> None:
    """Every study's runs compile (--compile auto from 20,000 learning steps), while the tests
    above train eagerly: a compiled group stopped twice (each resume compiles again) writes the
    CSVs of an uninterrupted compiled one."""
    configs = tiny_configs("tac", seeds=[0, 10], qs=[1.0, 2.0], compile="on")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reference = train(tmp_path / "reference", configs)
        resumed = _stopped_twice_then_resumed(tmp_path / "resumed", configs)
    assert not [w for w in caught if "torch.compile of TAC's update" in str(w.message)]
    for a, b in zip(reference, resumed, strict=True):
        assert b.state == "complete"
        assert_same_results(a.directory, b.directory)


def test_a_learned_alpha_stopped_and_resumed_continues_exactly(tmp_path: Path) -> None:
    configs = tiny_configs("tac", seeds=(0, 1), alpha_mode="auto")
    uninterrupted = train(tmp_path / "straight", configs)
    resumed = _stopped_twice_then_resumed(tmp_path / "resumed", configs)
    for a, b in zip(uninterrupted, resumed, strict=True):
        assert b.state == "complete"
        assert_same_results(a.directory, b.directory)
        losses = pd.read_csv(b.directory / "losses.csv")
        assert losses["alpha"].iloc[0] == pytest.approx(0.2)  # the paper's, its start
        assert losses["alpha"].nunique() == len(losses)  # learned: a new value every row


def test_a_resumed_run_keeps_the_compile_it_started_with(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--compile auto`` is decided where a run starts and recorded; resumed on a machine (or
    with a threshold) that would decide otherwise, the run keeps its recorded value."""
    from tacbench import hardware, members

    configs = tiny_configs("tac", total_steps=1200)
    assert configs[0].compile == "auto"
    train(tmp_path, configs, stop=lambda step: step >= 1100)
    config_json = next(tmp_path.rglob("config.json"))
    assert json.loads(config_json.read_text())["config"]["compile"] == "off"  # too short to pay
    monkeypatch.setattr(members, "COMPILE_AUTO_LEARNING_STEPS", 0)
    monkeypatch.setattr(hardware, "cpp_compiler", lambda: "g++")
    assert members.resolve_compile(configs[0]).compile == "on"  # a fresh start would compile
    [outcome] = train(tmp_path, configs, resume=True)
    assert (outcome.state, outcome.step) == ("complete", 1200)
    assert json.loads(config_json.read_text())["config"]["compile"] == "off"


@pytest.mark.parametrize("learner", ["tac", "td3"])
def test_a_run_resumed_on_other_hardware_says_so_and_config_json_keeps_the_first(
    tmp_path: Path, learner: str
) -> None:
    """Threads (and the device) may differ on resume, so that a run can move to other
    hardware, but the numbers from there round as on it: the resume says so in its notes and
    status.json, once however many members share the process, and config.json keeps the
    value the run started with."""
    seeds = [0, 10] if learner == "tac" else [0]
    train(tmp_path, tiny_configs(learner, seeds=seeds), stop=lambda step: step >= 1100)
    [outcome, *_] = train(tmp_path, tiny_configs(learner, seeds=seeds, threads=2), resume=True)
    assert (outcome.state, outcome.step) == ("complete", 1500)
    reason = json.loads((outcome.directory / "status.json").read_text())["reason"]
    assert reason.count("threads 1 -> 2 (config.json keeps 1; from here the numbers round") == 1
    config = json.loads((outcome.directory / "config.json").read_text())["config"]
    assert config["threads"] == 1


def test_a_resume_from_before_the_step_status_json_records_says_so(tmp_path: Path) -> None:
    """The newest generation's manifest deleted: the resume falls back to the one before, as it
    must, and says that the steps after it are trained again (it used to say nothing)."""
    configs = tiny_configs("tac")
    [stopped] = train(tmp_path, configs, stop=lambda step: step >= 1100)
    assert json.loads((stopped.directory / "status.json").read_text())["step"] == 1100
    (stopped.directory / "checkpoint" / "manifest-000000001100.json").unlink()
    [outcome] = train(tmp_path, configs, resume=True)
    assert (outcome.state, outcome.step) == ("complete", 1500)
    reason = json.loads((outcome.directory / "status.json").read_text())["reason"]
    assert "status.json records step 1,100, but the resume starts from step 1,000" in reason


def test_a_group_resumed_with_fewer_members_says_its_numbers_round_otherwise(
    tmp_path: Path,
) -> None:
    """A member that failed is not resumed, so the others train as a smaller group, whose
    batched products round otherwise than the group's: the resumed CSVs then differ from an
    uninterrupted run's without a word (and config.json still lists every member)."""
    train(tmp_path, tiny_configs("tac", seeds=[0, 10]), stop=lambda step: step >= 1100)
    [outcome] = train(tmp_path, tiny_configs("tac", seeds=[0]), resume=True)
    assert (outcome.state, outcome.step) == ("complete", 1500)
    reason = json.loads((outcome.directory / "status.json").read_text())["reason"]
    assert "the members resume in another group than they trained in" in reason
    # the whole group resumed together: nothing to say
    train(tmp_path / "whole", tiny_configs("tac", seeds=[0, 10]), stop=lambda s: s >= 1100)
    outcomes = train(tmp_path / "whole", tiny_configs("tac", seeds=[0, 10]), resume=True)
    for done in outcomes:
        assert "group" not in json.loads((done.directory / "status.json").read_text())["reason"]
