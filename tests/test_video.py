"""``tacbench video``: the rendered policy is the run's (its returns are the evaluation's at
that checkpoint), the file plays, and a machine or a request it cannot serve gets a clear
error. Needs an OpenGL backend for MuJoCo (EGL or OSMesa; .ci/run installs one)."""

from __future__ import annotations

import json
import tracemalloc
from pathlib import Path

import imageio.v3 as iio
import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench import video
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tests.helpers import tiny_configs, train

pytestmark = pytest.mark.smoke


@pytest.fixture(scope="module")
def backend() -> str:
    with pytest.MonkeyPatch.context() as patch:  # what choose_gl_backend sets is undone after
        patch.delenv("MUJOCO_GL", raising=False)
        patch.delenv("PYOPENGL_PLATFORM", raising=False)
        try:
            chosen = video.choose_gl_backend()
        except TacbenchError as err:
            pytest.skip(f"no OpenGL backend for MuJoCo here: {err}")
    return chosen  # each test sets it with its own monkeypatch


@pytest.mark.parametrize("learner", ["tac", "td3", "ppo"])  # ppo: with VecNormalize
def test_the_rendered_policy_is_the_one_the_run_evaluated(
    tmp_path: Path, backend: str, monkeypatch: pytest.MonkeyPatch, learner: str
) -> None:
    monkeypatch.setenv("MUJOCO_GL", backend)
    monkeypatch.setenv("PYOPENGL_PLATFORM", backend)
    # TAC's evaluation episodes are short: two, the second seeded as the evaluation's second;
    # one for the baselines, whose episodes take 100-150 frames at about 0.1 s each (software GL)
    episodes = 2 if learner == "tac" else 1
    configs = tiny_configs(learner, total_steps=1024, eval_every=1024, eval_episodes=episodes)
    (outcome,) = train(tmp_path, configs)
    policy = video.load_policy(outcome.directory)
    assert (policy.algo, policy.env, policy.seed, policy.step) == (
        outcome.directory.parts[-4],
        "Hopper-v4",
        0,
        1024,
    )
    returns: list[float] = []
    frames = list(video.episode_frames(policy, episodes, width=32, height=24, returns=returns))
    evaluation = pd.read_csv(outcome.directory / "eval.csv").iloc[-1]
    assert evaluation["step"] == 1024
    assert sum(returns) / episodes == pytest.approx(evaluation["return_mean"], rel=1e-5)
    # a frame per reset and per step
    assert len(frames) == episodes * (1 + evaluation["length_mean"])
    assert frames[0].shape == (24, 32, 3)


@pytest.mark.parametrize("suffix", [".mp4", ".gif", ".MP4"])  # any case
def test_the_command_writes_a_playable_video(
    tmp_path: Path, backend: str, monkeypatch: pytest.MonkeyPatch, suffix: str
) -> None:
    monkeypatch.setenv("MUJOCO_GL", backend)
    monkeypatch.setenv("PYOPENGL_PLATFORM", backend)
    (outcome,) = train(tmp_path, tiny_configs("tac", total_steps=500, eval_every=0))
    out = tmp_path / f"hopper{suffix}"
    args = ["video", str(outcome.directory), "--out", str(out), "--max-steps", "20"]
    result = CliRunner().invoke(cli, [*args, "--width", "64", "--height", "48", "--episodes", "2"])
    assert result.exit_code == 0, result.output
    frames = iio.imread(out, index=None)
    assert frames.shape[1:3] == (48, 64)
    assert f"({len(frames)} frames" in result.output
    assert frames.std() > 0  # a picture, not a blank
    assert [p.name for p in tmp_path.iterdir() if "partial" in p.name] == []
    if suffix == ".gif":  # a GIF keeps its frames: one that would not fit is refused
        from tacbench import memory

        monkeypatch.setattr(memory, "machine_memory", lambda: 10**6)
        result = CliRunner().invoke(cli, [*args, "--episodes", "2", "--out", str(out) + ".gif"])
        assert result.exit_code == 2 and "this GIF would need about" in result.output


def test_bad_requests_are_clear_errors(tmp_path: Path) -> None:
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", str(tmp_path / "x.avi")])
    assert result.exit_code == 2 and "must end in .mp4 or .gif" in result.output
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", str(tmp_path / "x.mp4")])
    assert result.exit_code == 2 and "is not a run directory" in result.output
    (tmp_path / "afile").write_text("")
    below_a_file = str(tmp_path / "afile" / "x.mp4")
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", below_a_file])
    assert result.exit_code == 2 and "cannot create or write the output folder" in result.output
    (tmp_path / "config.json").write_text("")
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", str(tmp_path / "x.mp4")])
    assert result.exit_code == 2 and "config.json is empty" in result.output
    assert "--force" not in result.output  # video has none; it says how to restore the file
    (tmp_path / "config.json").write_text('{"algo": "tac"}')
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", str(tmp_path / "x.mp4")])
    assert result.exit_code == 2 and "is not a run's config (no env, seed, config)" in result.output
    (tmp_path / "config.json").write_text(  # was a TypeError traceback (width)
        '{"algo": "tac", "env": "Pendulum-v1", "seed": 0, "config": {}}'
    )
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", str(tmp_path / "x.mp4")])
    assert result.exit_code == 2 and "Pendulum-v1 is not a MuJoCo task" in result.output
    (tmp_path / "config.json").write_text(
        '{"algo": "tac", "env": "Hopper-v4", "seed": 0, "config": {}}'
    )
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", str(tmp_path / "x.mp4")])
    assert result.exit_code == 2 and "has no checkpoint yet" in result.output
    (tmp_path / "checkpoint").mkdir()
    (tmp_path / "checkpoint" / "manifest-000000001000.json").write_text("{")
    result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", str(tmp_path / "x.mp4")])
    assert (
        result.exit_code == 2 and "has no intact checkpoint to render (step 1000:" in result.output
    )
    assert "resume" not in result.output and "--force" not in result.output


def test_a_machine_without_opengl_is_told_what_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setattr(video, "_backend_works", lambda backend: (False, "no library"))
    with pytest.raises(TacbenchError, match=r"apt-get install libegl1.*libosmesa6"):
        video.choose_gl_backend()


def test_a_video_streams_its_frames_so_five_episodes_peak_like_one(
    tmp_path: Path, backend: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MUJOCO_GL", backend)
    monkeypatch.setenv("PYOPENGL_PLATFORM", backend)
    (outcome,) = train(tmp_path, tiny_configs("tac", "HalfCheetah-v4", total_steps=500))
    policy = video.load_policy(outcome.directory)

    def peak(episodes: int) -> int:  # HalfCheetah never ends early: 31 frames an episode
        tracemalloc.start()
        frames = video.episode_frames(policy, episodes, width=96, height=72, max_steps=30)
        count = video.write_video(frames, tmp_path / f"{episodes}.mp4", fps=30)
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert count == episodes * 31
        return top

    one, five = peak(1), peak(5)
    frame = 96 * 72 * 3  # bytes; five episodes held whole would be 155 frames, 3.2 MB
    assert five < one + 20 * frame, (one, five)


def test_sizes_a_video_cannot_take_are_refused_before_anything_renders(tmp_path: Path) -> None:
    out = str(tmp_path / "x.mp4")
    for flags, says in (
        (["--width", "20000"], "20000 is not in the range 16<=x<=4096"),
        (["--episodes", "1000000000"], "is not in the range 1<=x<=1000"),
        (
            ["--width", "65"],
            "--width 65: an MP4's frame sides are multiples of 8 (H.264's blocks); use 64 or 72",
        ),
    ):
        result = CliRunner().invoke(cli, ["video", str(tmp_path), "--out", out, *flags])
        assert result.exit_code == 2 and says in result.output, result.output
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("learner", ["tac", "td3"])
def test_a_checkpoint_that_does_not_fit_its_runs_task_is_a_clear_error(
    tmp_path: Path, learner: str
) -> None:
    """Another run's checkpoint (here: config.json says Swimmer, the checkpoint is Hopper's),
    or an algorithm no trainer has, fails when the policy is loaded, with what to do, not as a
    traceback half-way into the video."""
    (outcome,) = train(tmp_path, tiny_configs(learner, total_steps=500, eval_every=0))
    config = outcome.directory / "config.json"
    data = json.loads(config.read_text())
    config.write_text(json.dumps({**data, "env": "Swimmer-v4"}))
    with pytest.raises(TacbenchError, match=r"does not act on Swimmer-v4 as config\.json says"):
        video.load_policy(outcome.directory)
    config.write_text(json.dumps({**data, "algo": "foo"}))
    with pytest.raises(TacbenchError, match="names the algorithm 'foo', not one of tac, "):
        video.load_policy(outcome.directory)
    config.write_text(json.dumps(data))
    assert video.load_policy(outcome.directory).step == 500
