"""The sweep presets against hand counts from the paper, and narrowing (tacbench.sweep.presets)."""

from __future__ import annotations

from collections import Counter

import pytest

from tacbench.errors import TacbenchError
from tacbench.paper import ENV_IDS, SEEDS, TASK_FACTS, TOTAL_STEPS
from tacbench.sweep.plan import build_runs
from tacbench.sweep.presets import PRESETS, Narrowing, get_preset, narrow

pytestmark = pytest.mark.unit

Q_GRID = {0.5, 0.7, 1.0, 1.2, 1.5, 1.7, 2.0, 3.0, 5.0}  # paper, line 797


def _runs(name: str, **by: object) -> list:
    preset = get_preset(name)
    return build_runs(narrow(preset, Narrowing(**by)) if by else preset)  # type: ignore[arg-type]


def test_paper_q_grid_is_9_q_by_6_tasks_by_10_seeds() -> None:
    runs = _runs("paper-q-grid")
    assert len(runs) == 9 * 6 * 10 == 540
    assert len({r.key for r in runs}) == 540
    configs = [r.config for r in runs]
    assert {c.algo for c in configs} == {"tac"}
    assert {c.q for c in configs} == Q_GRID
    assert {c.env for c in configs} == set(ENV_IDS.values())
    assert Counter(c.seed for c in configs) == dict.fromkeys(SEEDS, 54)
    assert {c.total_steps for c in configs} == {TOTAL_STEPS} == {1_000_000}
    for c in configs:
        task = c.env.split("-v")[0]
        assert c.alpha == TASK_FACTS[task].alpha == (0.05 if task == "Humanoid" else 0.2)
    assert runs[0].key == "runs/tac/HalfCheetah-v4/q0.5-a0.2/seed0"


def test_paper_comparison_is_tac_best_q_sac_four_baselines_and_sb3s_sac() -> None:
    runs = _runs("paper-comparison")
    assert len(runs) == 7 * 6 * 10 == 420
    by_algo = Counter(r.config.algo for r in runs)
    assert by_algo == {"tac": 120, "ddpg": 60, "td3": 60, "ppo": 60, "trpo": 60, "sac-sb3": 60}
    tac = [r for r in runs if r.config.algo == "tac"]
    sac = [r for r in tac if r.label == "SAC"]
    assert len(sac) == 60 and {r.config.q for r in sac} == {1.0}
    for r in tac:
        if r.label == "TAC":
            assert r.config.q == TASK_FACTS[r.config.env.split("-v")[0]].best_q
    assert {r.config.total_steps for r in runs} == {1_000_000}
    assert {r.config.seed for r in runs} == set(SEEDS)


def test_smoke_preset_is_small() -> None:
    runs = _runs("smoke")
    assert len(runs) == 8
    assert {r.config.total_steps for r in runs} == {1000}
    assert Counter(r.config.algo for r in runs) == {"tac": 4, "td3": 2, "ppo": 2}


def test_narrowing() -> None:
    assert len(_runs("paper-q-grid", tasks=("hopper",), q=(1.5,))) == 10
    assert len(_runs("paper-q-grid", tasks=("Ant-v4", "Humanoid"), seeds=(0, 90))) == 2 * 9 * 2
    sac = _runs("paper-comparison", q=(1.0,))
    assert len(sac) == 60 and {r.config.q for r in sac} == {1.0}
    best = _runs("paper-comparison", q=(1.5,))  # HalfCheetah's and Ant's best q
    assert {r.config.env for r in best} == {"HalfCheetah-v4", "Ant-v4"} and len(best) == 20
    ppo = _runs("paper-comparison", algos=("ppo",), seeds=(0,))
    assert len(ppo) == 6 and {r.config.env for r in ppo} == set(ENV_IDS.values())
    assert {r.config.algo for r in ppo} == {"ppo"} and {r.config.seed for r in ppo} == {0}
    short = _runs("smoke", algos=("tac",), settings={"total_steps": 400, "checkpoint_every": 100})
    assert {(r.config.total_steps, r.config.checkpoint_every) for r in short} == {(400, 100)}


def test_tac_flags_follow_one_rule_for_baselines_as_in_tacbench_run() -> None:
    """A TAC setting applies to TAC's entries; for a baseline's it becomes the baseline's
    equivalent hyperparameter (--learning-starts for the off-policy ones), and where there is
    none the sweep is refused, as tacbench run refuses it (exit 2 through the CLI)."""
    runs = _runs(
        "paper-comparison", seeds=(0,), algos=("tac",), settings={"critic_target": "twin-q"}
    )
    assert runs and {r.config.critic_target for r in runs} == {"twin-q"}  # type: ignore[union-attr]
    assert all(r.config.variant.endswith("-twinq") for r in runs)
    with pytest.raises(TacbenchError, match="--critic-target is a TAC option that ddpg does not"):
        _runs("paper-comparison", seeds=(0,), settings={"critic_target": "twin-q"})
    algos = ("tac", "td3", "ddpg")
    mapped = _runs("paper-comparison", seeds=(0,), algos=algos, settings={"learning_starts": 5000})
    off_policy = [r.config for r in mapped if r.config.algo in ("td3", "ddpg")]
    assert off_policy and {c.hyperparams["learning_starts"] for c in off_policy} == {5000}
    assert {c.learning_starts for c in (r.config for r in mapped) if c.algo == "tac"} == {5000}
    with pytest.raises(TacbenchError, match="--learning-starts is a TAC option that ppo does not"):
        _runs("paper-comparison", seeds=(0,), algos=("ppo",), settings={"learning_starts": 5000})
    smoke = _runs("smoke", algos=("td3",), settings={"learning_starts": 200})  # the preset has 500
    assert smoke and {r.config.hyperparams["learning_starts"] for r in smoke} == {200}


@pytest.mark.parametrize(
    ("by", "message"),
    [
        ({"tasks": ("Hopper-v5",)}, "Hopper-v5 is in suite v5: add --suite v5"),
        ({"tasks": ("Hopper-v4",), "suite": "v5"}, "here of suite v5: HalfCheetah .HalfCheetah-v5"),
        ({"suite": "v3"}, "--suite v3: choose one of v4, v5"),
        ({"q": (4.0,)}, "--q 4: not in this preset, which has 0.5, 0.7, 1, 1.2"),
        ({"q": (1.0000001,)}, "--q 1.0000001: not in"),  # was "--q 1", a q of the preset
        ({"seeds": (5,)}, "--seed 5: not in this preset"),
        ({"algos": ("sac-sb3",)}, "--algo sac-sb3: not in this preset"),
    ],
)
def test_narrowing_mistakes_say_what_exists(by: dict, message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        narrow(get_preset("paper-q-grid"), Narrowing(**by))


def test_narrowing_to_nothing_and_unknown_preset() -> None:
    with pytest.raises(TacbenchError, match="leave no run"):
        narrow(get_preset("paper-comparison"), Narrowing(q=(1.5,), tasks=("Hopper",)))
    with pytest.raises(TacbenchError, match="choose one of paper-q-grid"):
        get_preset("paper")
    assert list(PRESETS) == ["paper-q-grid", "paper-comparison", "smoke"]


def test_suite_v5_trains_every_task_on_its_v5_id_with_the_papers_values() -> None:
    v4 = _runs("paper-comparison", seeds=(0,))
    v5 = _runs("paper-comparison", seeds=(0,), suite="v5")
    assert sorted({r.config.env for r in v5}) == sorted(f"{task}-v5" for task in ENV_IDS)
    assert len(v5) == len(v4)
    for old, new in zip(v4, v5, strict=True):  # the same runs, task for task, on v5
        assert new.config.env == old.config.env.rsplit("-", 1)[0] + "-v5"
        assert getattr(new.config, "q", None) == getattr(old.config, "q", None)
        assert getattr(new.config, "alpha", None) == getattr(old.config, "alpha", None)
    hopper = _runs("paper-q-grid", tasks=("hopper-v5",), seeds=(0,), suite="v5")
    assert {r.config.env for r in hopper} == {"Hopper-v5"}
    assert {r.config.alpha for r in hopper} == {TASK_FACTS["Hopper"].alpha}


def test_sweep_command_takes_the_suite(tmp_path: object) -> None:
    from click.testing import CliRunner

    from tacbench.cli import cli

    args = ["sweep", "--preset", "smoke", "--suite", "v5", "--dry-run", "--out", str(tmp_path)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "tac Hopper-v5: 2 units" in result.output
    planned = [line.split()[:2] for line in result.output.splitlines()]
    assert ["tac", "Hopper-v5"] in planned and ["tac", "Hopper-v4"] not in planned
    # priced as Hopper-v4's default, the same task, and said so
    assert "tac Hopper-v5: no default of its own, priced at tac's on Hopper-v4;" in (result.output)
    refused = CliRunner().invoke(cli, [*args[:3], "--env", "Hopper-v5", "--dry-run"])
    assert refused.exit_code != 0 and "add --suite v5" in refused.output
