"""The task suite, env checks, exact env state for resume, and the evaluation protocol."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from click.testing import CliRunner

from tacbench import envs, paper
from tacbench.cli import cli
from tacbench.errors import TacbenchError

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(
    ("name", "env_id"),
    [
        ("Ant", "Ant-v4"),
        ("hopper", "Hopper-v4"),
        ("Pusher", "Pusher-v5"),
        ("Humanoid", "Humanoid-v4"),
        ("Hopper-v5", "Hopper-v5"),
        ("Pendulum-v1", "Pendulum-v1"),
    ],
)
def test_resolve_env_id(name: str, env_id: str) -> None:
    assert envs.resolve_env_id(name) == env_id


def test_unknown_env_lists_the_suite_and_the_closest_names() -> None:
    with pytest.raises(TacbenchError) as err:
        envs.resolve_env_id("Hoper-v4")
    message = str(err.value)
    assert "Closest registered names: Hopper-v4" in message
    for env_id in paper.ENV_IDS.values():
        assert env_id in message
    assert "Hopper-v3" not in message  # registered, but moved out of Gymnasium: no suggestion


def test_a_moved_env_is_refused_in_one_sentence_with_its_successor() -> None:
    with pytest.raises(TacbenchError) as err:
        envs.make_env("Hopper-v3")
    assert "gymnasium-robotics).. " not in str(err.value)
    assert str(err.value).endswith("gymnasium-robotics). Use Hopper-v4 instead.")


def test_discrete_action_env_is_refused() -> None:
    with pytest.raises(TacbenchError, match="Discrete action space; TAC needs continuous"):
        envs.make_env("CartPole-v1")


def test_pusher_v4_points_to_pusher_v5() -> None:
    with pytest.raises(TacbenchError, match="Use Pusher-v5 instead"):
        envs.make_env("Pusher-v4")


def test_env_info_and_action_scaling() -> None:
    info = envs.env_info("Humanoid-v4")
    assert (info.obs_dim, info.act_dim, info.max_episode_steps) == (376, 17, 1000)
    assert info.low[0] == pytest.approx(-0.4)
    scaled = envs.to_env_action(np.array([[-1.0] * 17, [0.0] * 17, [1.0] * 17]), info)
    np.testing.assert_allclose(scaled[:, 0], [-0.4, 0.0, 0.4], atol=1e-7)
    pusher = envs.env_info("Pusher-v5")
    assert pusher.high[0] == pytest.approx(2.0)


@pytest.mark.parametrize("env_id", list(paper.SUITES[paper.DEFAULT_SUITE].values()))
def test_mujoco_state_restores_bit_exactly(env_id: str) -> None:
    """Every paper task; Ant and Humanoid read body positions computed at the last step's start
    for their reward, which the integration state alone did not bring back (the first resumed
    reward differed: Ant 0.069 against -14.12)."""
    env = envs.make_env(env_id)
    low, high = env.action_space.low, env.action_space.high  # type: ignore[attr-defined]
    actions = np.random.default_rng(0).uniform(low, high, size=(120, len(low)))
    env.reset(seed=3)
    for action in actions[:40]:
        env.step(action)
    state = envs.get_env_state(env)
    assert state is not None
    expected = [env.step(a) for a in actions[40:]]
    other = envs.make_env(env_id)
    other.reset(seed=99)
    envs.set_env_state(other, state)
    got = [other.step(a) for a in actions[40:]]
    for (o1, r1, t1, u1, _), (o2, r2, t2, u2, _) in zip(expected, got, strict=True):
        np.testing.assert_array_equal(o1, o2)
        assert (r1, t1, u1) == (r2, t2, u2)
    # the env's own generator (used at reset) comes back too
    np.testing.assert_array_equal(env.reset()[0], other.reset()[0])


def test_non_mujoco_env_has_no_exact_state() -> None:
    env = envs.make_env("Pendulum-v1")
    env.reset(seed=0)
    assert envs.get_env_state(env) is None


def test_eval_seeds_are_deterministic_distinct_and_per_run() -> None:
    first = envs.eval_seeds(0, 5000, 10)
    assert first == envs.eval_seeds(0, 5000, 10)
    assert len(set(first)) == 10
    assert set(first).isdisjoint(envs.eval_seeds(0, 10000, 10))
    assert set(first).isdisjoint(envs.eval_seeds(10, 5000, 10))


def test_evaluate_in_lockstep_equals_one_episode_at_a_time() -> None:
    info = envs.env_info("Hopper-v4")

    def policy(obs: np.ndarray) -> np.ndarray:
        return envs.to_env_action(np.tanh(obs[:, :3] * 3.0), info)

    seeds = [11, 12, 13]
    returns, lengths = envs.evaluate(policy, [envs.make_env("Hopper-v4") for _ in seeds], seeds)
    for seed, ret, length in zip(seeds, returns, lengths, strict=True):
        env = envs.make_env("Hopper-v4")
        obs, total, steps, done = env.reset(seed=seed)[0], 0.0, 0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs[None])[0])
            total, steps, done = total + float(reward), steps + 1, terminated or truncated
        assert (ret, length) == (total, steps)
    assert len(set(lengths.tolist())) > 1  # the episodes did end at different steps


def test_envs_command_lists_the_suite_with_the_papers_values() -> None:
    result = CliRunner().invoke(cli, ["envs"])
    assert result.exit_code == 0, result.output
    rows = {line.split()[0]: line.split() for line in result.output.splitlines()[1:7]}
    assert set(rows) == set(paper.ENV_IDS)
    assert rows["Humanoid"][1:7] == ["Humanoid-v4", "376", "17", "1000", "0.05", "1.2"]
    assert rows["Pusher"][1:7] == ["Pusher-v5", "23", "7", "100", "0.2", "1.2"]
    assert rows["Hopper"][6:9] == ["2", "(slightly", "better)"]
    header, *lines = result.output.splitlines()
    assert all(line.index(" yes") + 1 == header.index("loads") for line in lines[:6])  # aligned
    assert all(row[-1] == "yes" for row in rows.values())


def test_mujoco_is_quiet_and_leaves_no_log_file_in_the_working_folder(tmp_path: Path) -> None:
    # a fresh process: MuJoCo's default handler prints the v4 HalfCheetah model's deprecation
    # and appends it to ./MUJOCO_LOG.TXT unless make_env routed the warnings
    code = "from tacbench import envs; envs.make_env('HalfCheetah-v4').reset(seed=0)"
    done = subprocess.run(
        [sys.executable, "-W", "error::RuntimeWarning", "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        check=True,
    )
    assert "settotalmass" not in done.stdout + done.stderr
    assert list(tmp_path.iterdir()) == []


def test_other_mujoco_warnings_still_reach_the_user() -> None:
    envs.quiet_mujoco()
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='1'/></body></worldbody></mujoco>"
    )
    data = mujoco.MjData(model)
    data.qpos[:] = np.nan
    with pytest.warns(RuntimeWarning, match="MuJoCo: Nan, Inf or huge value in QPOS"):
        mujoco.mj_step(model, data)


def test_envs_command_lists_the_v5_suite_and_says_the_papers_values_are_carried_over() -> None:
    result = CliRunner().invoke(cli, ["envs", "--suite", "v5"])
    assert result.exit_code == 0, result.output
    rows = {line.split()[0]: line.split() for line in result.output.splitlines()[1:7]}
    assert {row[1] for row in rows.values()} == {f"{task}-v5" for task in paper.ENV_IDS}
    assert rows["Ant"][1:7] == ["Ant-v5", "105", "8", "1000", "0.2", "1.5"]
    assert all(row[-1] == "yes" for row in rows.values())
    assert "carried over to v5 unchanged" in result.output


def test_many_members_environments_are_announced_before_they_are_made(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Each member has a training env and a pool of evaluation envs; 900 members' 9,900 took
    47 s to make, in silence. From MANY_ENVS on, the start-up says so first."""
    said: list[str] = []
    training, evaluation = envs.member_envs("Pendulum-v1", 3, 12, said.append)
    assert (len(training), [len(pool) for pool in evaluation]) == (3, [10, 10, 10])
    assert said == []  # 33 environments: made before anyone would wonder
    assert envs.member_envs("Pendulum-v1", 2, 0, said.append)[1] == []  # no evaluation
    monkeypatch.setattr(envs, "MANY_ENVS", 33)
    envs.member_envs("Pendulum-v1", 3, 12, said.append)
    assert said == ["making 33 Pendulum-v1 environments (11 per member) ..."]
