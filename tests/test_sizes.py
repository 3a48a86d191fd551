"""Sizes an argument can make arbitrarily large are refused before anything is written, with
the estimate: networks, minibatches, replay buffers, threads, bootstrap replications."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from baselines.trainer import check_sizes
from tacbench import envs, memory, trainers
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.paper import paper_task
from tests.helpers import TINY_HP, TINY_RUN, run_cli, tiny_configs, train
from tests.report_fixtures import write_run

pytestmark = pytest.mark.unit

TOO_BIG = [
    ("tac", {"hidden_sizes": (100_000, 100_000)}, "networks"),
    ("tac", {"batch_size": 10**11}, "an update's activations"),
    ("tac", {"buffer_size": 10**12, "total_steps": 10**12}, "the replay buffer"),
    ("tac", {"eval_episodes": 10**20}, "an evaluation"),
    ("ddpg", {"hp": ("batch_size=1000000000000",)}, "an update's activations"),
    ("ddpg", {"hp": ("buffer_size=1000000000000",), "total_steps": 10**12}, "the replay buffer"),
    ("ppo", {"hp": ("net_arch=[100000,100000]",)}, "networks"),
    ("td3", {"hp": (), "eval_episodes": 10**20}, "an evaluation"),
]


@pytest.mark.parametrize(("learner", "settings", "part"), TOO_BIG)
def test_a_run_too_big_for_the_machine_is_refused_before_anything_is_written(
    tmp_path: Path, learner: str, settings: dict, part: str
) -> None:
    if learner == "tac":
        configs = tiny_configs(learner, **settings)
    else:
        keys = {item.split("=")[0] for item in settings["hp"]}
        hp = (*(i for i in TINY_HP[learner] if i.split("=")[0] not in keys), *settings["hp"])
        run = {**TINY_RUN, **{k: v for k, v in settings.items() if k != "hp"}}
        configs, _ = trainers.make_configs(
            learner, "Hopper-v4", paper_task("Hopper-v4"), (0,), run, hp=hp
        )
    with pytest.raises(TacbenchError, match="more than this machine's") as refused:
        train(tmp_path / "out", configs)
    assert part in str(refused.value) and "smaller" in str(refused.value)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("learner", ["tac", "td3"])
def test_evaluation_episodes_count_only_where_the_run_evaluates(learner: str) -> None:
    """--eval-every 0 builds no evaluation envs: its --eval-episodes was counted all the same
    ("this run would need about 1,117.6 GiB (... an evaluation 1,117.6 GiB)")."""
    settings = {"eval_episodes": 10**10, "eval_every": 0}
    if learner == "tac":
        configs = tiny_configs("tac", seeds=(0,), **settings)
    else:
        run = {**TINY_RUN, **settings}
        hopper = paper_task("Hopper-v4")
        configs, _ = trainers.make_configs("td3", "Hopper-v4", hopper, (0,), run, hp=TINY_HP["td3"])
    trainers.check_sizes(configs, envs.env_info("Hopper-v4"))  # no error


def test_a_baselines_buffer_is_counted_as_built_never_above_the_runs_steps() -> None:
    """SB3's buffer is built with at most the run's steps (as TAC's), so a huge buffer_size on
    a short run fits: it used to be refused for memory it would never take."""
    configs, _ = trainers.make_configs(
        "td3", "Hopper-v4", "Hopper", (0,), TINY_RUN, hp=("buffer_size=100000000000",)
    )
    check_sizes(configs[0], envs.env_info("Hopper-v4"))  # no error


@pytest.mark.parametrize(
    ("learner", "buffer"), [("ddpg", "replay_buffer"), ("ppo", "rollout_buffer")]
)
def test_a_baselines_buffer_is_estimated_as_sb3_allocates_it(
    monkeypatch: pytest.MonkeyPatch, learner: str, buffer: str
) -> None:
    """SB3's replay buffer holds the observations as float32 (as baselines.algos casts them);
    the estimate counted them as float64 and could refuse a run that fits."""
    from baselines import algos

    estimated: dict[str, int] = {}
    monkeypatch.setattr(memory, "check_fits", lambda needs, advice: estimated.update(needs))
    (config,) = tiny_configs(learner)
    check_sizes(config, envs.env_info("Hopper-v4"))
    model = algos.build_model(config, algos.make_training_env(config)[0])
    arrays = [v for v in vars(getattr(model, buffer)).values() if isinstance(v, np.ndarray)]
    part = "the replay buffer" if buffer == "replay_buffer" else "the rollout"
    assert estimated[part] == sum(a.nbytes for a in arrays)


@pytest.mark.parametrize("dry_run", [True, False])
def test_a_sweep_refuses_units_too_big_before_anything_trains(
    tmp_path: Path, dry_run: bool
) -> None:
    """The dry run used to price such a sweep as fitting (its memory line counts buffers only),
    and the sweep failed every attempt of each unit with the same refusal, then gave it up."""
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--q", "1", "--seed", "0"]
    args += ["--hidden-sizes", "100000,100000", "--workers", "1", "--out", str(tmp_path)]
    result = run_cli([*args, "--dry-run"] if dry_run else args)
    assert result.returncode == 2, result.stdout + result.stderr
    unit = "runs/tac/Hopper-v4/q1-a0.2-ls500-h100000x100000-bs32/seed0"
    assert f"the unit {unit} (1 run): this run would need about" in result.stderr
    assert not (tmp_path / "runs").exists()


def test_more_threads_than_cores_are_refused(tmp_path: Path) -> None:
    cores = os.cpu_count() or 1
    with pytest.raises(TacbenchError, match=f"more than this machine's {cores} cores"):
        train(tmp_path / "out", tiny_configs("tac", threads=cores + 1))
    assert not (tmp_path / "out").exists()


def test_the_estimate_counts_parameters_and_activations() -> None:
    assert memory.mlp_parameters([3, 4, 2]) == 3 * 4 + 4 + 4 * 2 + 2
    needs = memory.actor_critic_bytes(11, 3, (300,), 100, members=2)
    parameters = (
        (11 * 300 + 300 + 300 * 6 + 6) + 2 * (14 * 300 + 300 + 301) + (11 * 300 + 300 + 301)
    )
    assert needs["networks"] == 2 * parameters * memory.PARAMETER_COPIES * 4
    # per member: the batch's widths (hidden, observation, action) through the four networks
    per_member = 100 * (300 + 11 + 3) * 4 * memory.ACTIVATION_COPIES
    assert needs["an update's activations"] == 2 * per_member * 4
    without_v = memory.actor_critic_bytes(11, 3, (300,), 100, value_network=False)
    assert without_v["an update's activations"] == per_member * 3 // 4 * 4


def test_too_many_bootstrap_replications_are_refused_before_anything_is_written(
    tmp_path: Path,
) -> None:
    for seed in (0, 10):
        write_run(
            tmp_path,
            algo="tac",
            env="Hopper-v4",
            variant="q1-a0.2",
            seed=seed,
            q=1.0,
            alpha=0.2,
            steps=[1000.0, 2000.0],
            returns=[1.0, 2.0],
        )
    args = ["report", "--results", str(tmp_path), "--out", str(tmp_path / "r")]
    refused = CliRunner().invoke(cli, [*args, "--reps", str(10**12)])
    assert refused.exit_code == 2 and "Traceback" not in refused.output
    assert "this report would need about" in refused.output
    assert "make --reps smaller" in refused.output and not (tmp_path / "r").exists()


def test_the_command_line_refuses_with_one_line_and_exit_2(tmp_path: Path) -> None:
    args = ["run", "--env", "Hopper-v4", "--hidden-sizes", "100000,100000", "--out", str(tmp_path)]
    refused = run_cli(args)
    assert refused.returncode == 2
    [line] = refused.stderr.strip().splitlines()
    assert line.startswith("Error: this run would need about") and "GiB" in line


def test_evaluation_reuses_its_pool_of_envs_in_waves() -> None:
    seeds = [11, 12, 13, 14, 15]

    def still(obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 1))

    pool = [envs.make_env("Pendulum-v1") for _ in range(2)]
    one_each = [envs.make_env("Pendulum-v1") for _ in seeds]
    waves = envs.evaluate_members(still, [pool], [seeds])
    at_once = envs.evaluate_members(still, [one_each], [seeds])
    np.testing.assert_array_equal(waves[0], at_once[0])
    np.testing.assert_array_equal(waves[1], at_once[1])
    assert envs.waves(25, 10) == [slice(0, 10), slice(10, 20), slice(20, 25)]


PEAK = """
import resource, sys, tempfile
from tacbench import trainers
from tacbench.paper import paper_task
run = dict(total_steps=200, learning_starts=1000, eval_every=200, checkpoint_every=0,
           eval_episodes=int(sys.argv[1]))
configs, _ = trainers.make_configs("tac", "Hopper-v4", paper_task("Hopper-v4"), (0,), run,
                                   qs=[1.5], alphas=[0.2])
trainers.trainer_for("tac").train(configs, tempfile.mkdtemp(), quiet=True)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


@pytest.mark.smoke
def test_fifty_evaluation_episodes_peak_like_one() -> None:
    def peak_kib(episodes: int) -> int:
        done = subprocess.run(
            [sys.executable, "-c", PEAK, str(episodes)], capture_output=True, text=True, check=True
        )
        return int(done.stdout.split()[-1])

    one, fifty = peak_kib(1), peak_kib(50)
    # an env is about 1.1 MB: fifty of them would add 55 MB, the pool of ten adds 10
    assert fifty - one < 25 * 1024, (one, fifty)
