"""The baselines' hyperparameter tables, --hp parsing, variants and configs."""

from __future__ import annotations

import re
from importlib import resources

import pytest
import yaml

from baselines import hyperparams
from baselines.config import BaselineConfig, flags_as_overrides, make_configs
from tacbench import config as tac_config
from tacbench.errors import TacbenchError
from tacbench.paper import ENV_IDS, TASK_FACTS, paper_task

pytestmark = pytest.mark.unit


def _table_text(algo: str) -> str:
    return resources.files("baselines").joinpath("hyperparams", f"{algo}.yaml").read_text()


@pytest.mark.parametrize("algo", hyperparams.ALGOS)
def test_every_value_in_a_table_names_its_source(algo: str) -> None:
    values = [line for line in _table_text(algo).splitlines() if re.match(r"^\s+\w+:", line)]
    assert values
    for line in values:
        value, _, comment = line.partition("  # ")
        assert comment.strip(), f"{algo}.yaml: no source for {value.strip()!r}"


@pytest.mark.parametrize("algo", hyperparams.ALGOS)
@pytest.mark.parametrize("env", sorted(ENV_IDS.values()))
def test_tables_resolve_to_every_key_for_every_suite_task(algo: str, env: str) -> None:
    values, sections = hyperparams.resolve(algo, env, paper_task(env))
    assert set(values) == set(hyperparams.ALGO_KEYS[algo])
    assert sections[0] == "default"
    table = yaml.safe_load(_table_text(algo))
    assert set(table) - {"default"} <= {*ENV_IDS, *ENV_IDS.values()}  # no misspelt section names


def test_networks_are_the_papers() -> None:
    def net(algo: str) -> tuple[list[int], str]:
        values, _ = hyperparams.resolve(algo, "Hopper-v4", "Hopper")
        return values["net_arch"], values["activation_fn"]

    assert net("ddpg") == ([300], "relu")  # paper: SAC, TAC and DDPG share 1 x 300
    assert net("sac-sb3") == ([300], "relu")
    assert net("td3") == ([400, 300], "relu")  # TD3's authors
    assert net("ppo") == ([64, 64], "tanh")  # paper: 64 units; Spinning Up: two layers, tanh
    assert net("trpo") == ([64, 64], "tanh")


@pytest.mark.parametrize("env", sorted(ENV_IDS.values()))
def test_sac_sb3_is_configured_like_tac_at_q1(env: str) -> None:
    values, _ = hyperparams.resolve("sac-sb3", env, paper_task(env))
    tac = tac_config.RunConfig(env=env, q=1.0, alpha=TASK_FACTS[paper_task(env)].alpha)
    assert values["net_arch"] == list(tac.hidden_sizes)
    assert values["learning_rate"] == tac.learning_rate
    assert values["batch_size"] == tac.batch_size
    assert values["buffer_size"] == tac.buffer_size
    assert values["learning_starts"] == tac.learning_starts
    assert values["gamma"] == tac.gamma
    assert values["tau"] == tac.tau
    assert values["ent_coef"] == tac.alpha  # a constant alpha, 0.05 on Humanoid
    assert (values["train_freq"], values["gradient_steps"]) == (1, 1)


def test_zoo_values_are_applied_per_environment() -> None:
    swimmer, sections = hyperparams.resolve("ppo", "Swimmer-v4", "Swimmer")
    assert sections == ["default", "Swimmer-v4"]
    assert (swimmer["n_steps"], swimmer["batch_size"], swimmer["gamma"]) == (4096, 256, 0.9999)
    # the zoo's HalfCheetah, Hopper and Humanoid entries were tuned for another network
    for task in ("HalfCheetah", "Hopper", "Humanoid", "Ant"):
        values, sections = hyperparams.resolve("ppo", f"{task}-v4", task)
        assert sections == ["default"]
        assert (values["n_steps"], values["learning_rate"], values["normalize"]) == (
            2048,
            3e-4,
            True,
        )
    # RL Zoo's v4 TD3 entries keep 1e-3 on Hopper (its 3e-4 override was the v3 era's)
    assert hyperparams.resolve("td3", "Hopper-v4", "Hopper")[0]["learning_rate"] == 1e-3
    assert hyperparams.resolve("td3", "Swimmer-v4", "Swimmer")[0]["gamma"] == 0.9999
    assert hyperparams.resolve("trpo", "HalfCheetah-v4", "HalfCheetah")[0]["target_kl"] == 0.04
    humanoid, sections = hyperparams.resolve("sac-sb3", "Humanoid-v5", "Humanoid")
    assert sections == ["default", "Humanoid"] and humanoid["ent_coef"] == 0.05


def test_another_version_of_a_task_takes_the_suites_section_and_says_so() -> None:
    v4, _ = hyperparams.resolve("ppo", "Swimmer-v4", "Swimmer")
    v5, sections = hyperparams.resolve("ppo", "Swimmer-v5", "Swimmer")
    assert v5 == v4
    assert sections == ["default", "Swimmer-v4 (carried over to Swimmer-v5)"]
    configs, _, notes = make_configs("td3", "Swimmer-v5", "Swimmer", [0])
    assert configs[0].hyperparams["gamma"] == 0.9999  # the zoo's Swimmer value
    assert "Swimmer-v4 (carried over to Swimmer-v5)" in notes[0]
    # a task the paper did not run has no suite section to take
    assert hyperparams.resolve("ppo", "Walker2d-v5", None)[1] == ["default"]


def test_overrides_are_parsed_as_yaml_and_checked() -> None:
    parsed = hyperparams.parse_overrides(
        "td3",
        ["learning_rate=3e-4", "net_arch=[64, 64]", "train_freq=[1, episode]", "batch_size=1e2"],
    )
    assert parsed == {
        "learning_rate": 3e-4,
        "net_arch": [64, 64],
        "train_freq": [1, "episode"],
        "batch_size": 100,
    }
    assert hyperparams.parse_overrides("ppo", ["target_kl=null", "normalize=false"]) == {
        "target_kl": None,
        "normalize": False,
    }
    assert hyperparams.parse_overrides("sac-sb3", ["ent_coef=auto_0.1"]) == {"ent_coef": "auto_0.1"}


def test_a_bad_key_names_the_valid_keys() -> None:
    with pytest.raises(TacbenchError) as err:
        hyperparams.parse_overrides("ppo", ["lr=3e-4"])
    message = str(err.value)
    assert "unknown hyperparameter 'lr' for ppo" in message
    assert "Valid keys: activation_fn, batch_size, clip_range" in message
    with pytest.raises(TacbenchError, match="Did you mean n_steps"):
        hyperparams.parse_overrides("ppo", ["steps=10"])
    with pytest.raises(TacbenchError, match=r"write key=value.*Valid keys for ddpg"):
        hyperparams.parse_overrides("ddpg", ["learning_rate"])
    with pytest.raises(TacbenchError, match="given twice"):
        hyperparams.parse_overrides("ddpg", ["gamma=0.9", "gamma=0.8"])
    with pytest.raises(TacbenchError, match="unknown baseline 'sac'"):
        hyperparams.parse_overrides("sac", ["gamma=0.9"])


@pytest.mark.parametrize(
    ("algo", "item", "expected"),
    [
        ("ppo", "n_steps=abc", "n_steps for ppo must be an integer >= 2"),
        ("ppo", "n_steps=2.5", "an integer >= 2"),
        ("td3", "gamma=1.5", "gamma for td3 must be a number > 0 and <= 1"),
        ("td3", "learning_rate=0", "a number > 0"),
        ("td3", "learning_rate=nan", "a number > 0"),
        ("ddpg", "net_arch=300", "a list of layer widths"),
        ("ddpg", "net_arch=[300, 0]", "a list of layer widths"),
        ("ddpg", "activation_fn=sigmoid", "one of relu, tanh, elu, leaky_relu"),
        ("ddpg", "noise_type=ornstein-uhlenbeck", "one of normal, none"),
        ("ppo", "normalize=yes please", "true or false"),
        ("ppo", "ent_coef=auto", "ent_coef for ppo must be a number >= 0"),
        ("sac-sb3", "ent_coef=automatic", '"auto" or "auto_<initial value>"'),
        ("sac-sb3", "ent_coef=auto_inf", '"auto" or "auto_<initial value>"'),
        ("sac-sb3", "ent_coef=auto_nan", '"auto" or "auto_<initial value>"'),
        ("sac-sb3", "ent_coef=auto_0", "with an initial value of at least"),  # it said ">= 0"
        # SB3 starts auto_1_0 at 1 (the text up to a second _); the check read 10
        ("sac-sb3", "ent_coef=auto_1_0", "written without _"),
        ("sac-sb3", "ent_coef=auto_1e-40", "with an initial value of at least"),
        # flush-to-zero trained these as 0 (config.json said 1e-40)
        ("sac-sb3", "ent_coef=1e-40", "below float32's smallest normal number, 1.175e-38"),
        ("td3", "tau=1e-40", "below float32's smallest normal number"),
        ("td3", "learning_rate=1e-300", "below float32's smallest normal number"),
        ("td3", "train_freq=[1, day]", 'an integer >= 1, or [n,"step"]'),
        # TRPO's line search steps by 2 target_kl: null (PPO's "no limit") crashed its update
        ("trpo", "target_kl=null", "target_kl for trpo must be a number > 0"),
        # YAML reads dates, bytes and base 60: a date crashed the message, 12:30:00 ran as 45000
        ("ddpg", "learning_rate=2020-01-01", "--hp learning_rate=2020-01-01: learning_rate"),
        ("ddpg", "learning_rate=12:30:00", "learning_rate for ddpg must be a number > 0"),
        ("ddpg", "noise_type=!!binary aGVsbG8=", "one of normal, none"),
        ("ddpg", "net_arch=[64, 2020-01-01]", "a list of layer widths"),
        ("ddpg", "net_arch=[1:30, 300]", "a list of layer widths"),  # it ran [90, 300]
        ("ppo", "n_steps=0x800", "an integer >= 2"),  # it ran 2048
        ("ddpg", "net_arch=[010, 300]", "a list of layer widths"),
    ],
)
def test_a_bad_value_says_what_is_expected(algo: str, item: str, expected: str) -> None:
    with pytest.raises(TacbenchError, match=re.escape(expected)):
        hyperparams.parse_overrides(algo, [item])


def test_a_number_yaml_1_1_reads_as_octal_is_read_as_written() -> None:
    assert hyperparams.parse_overrides("ppo", ["n_steps=010"]) == {"n_steps": 10}  # it ran 8
    with pytest.raises(TacbenchError, match=re.escape("a list of layer widths, e.g. [400,300]")):
        hyperparams.parse_overrides("td3", ["net_arch=[010]"])  # not [8], as YAML 1.1 reads it


def test_ppo_may_leave_target_kl_unlimited() -> None:
    assert hyperparams.parse_overrides("ppo", ["target_kl=null"]) == {"target_kl": None}


def test_variant_names_what_differs_and_hashes_it() -> None:
    table, _ = hyperparams.resolve("td3", "Hopper-v4", "Hopper")
    assert hyperparams.variant(table, dict(table)) == "default"
    a = hyperparams.variant(table, {**table, "learning_rate": 3e-4, "net_arch": [64, 64]})
    b = hyperparams.variant(table, {**table, "net_arch": [64, 64], "learning_rate": 3e-4})
    c = hyperparams.variant(table, {**table, "learning_rate": 1e-4, "net_arch": [64, 64]})
    assert a == b != c
    assert re.fullmatch(r"learning_rate0\.0003-net_arch64x64-[0-9a-f]{8}", a)
    signed = hyperparams.variant(table, {**table, "learning_rate": 1e-5, "tau": -2.0})
    assert re.fullmatch(r"learning_rate1e-05-tau-2-[0-9a-f]{8}", signed)


def test_spellings_sb3_reads_alike_share_one_value_and_one_variant_folder() -> None:
    """train_freq=[1,step] is the table's 1 and auto_1e-3 is --alpha-mode auto --alpha 0.001:
    each trained alike and got a folder of its own, so a resume with the other found nothing."""
    same = [
        ("td3", ["train_freq=[1, step]"], ["train_freq=1"]),
        ("td3", ["train_freq=[4,step]"], ["train_freq=4"]),
        (
            "sac-sb3",
            ["ent_coef=auto_1e-3"],
            flags_as_overrides("sac-sb3", {"alpha_mode": "auto", "alpha": 0.001}),
        ),
        ("sac-sb3", ["ent_coef=auto_1"], ["ent_coef=auto"]),  # SB3's auto starts at 1
    ]
    for algo, one, other in same:
        first = make_configs(algo, "Hopper-v4", "Hopper", [0], one)[0][0]
        second = make_configs(algo, "Hopper-v4", "Hopper", [0], other)[0][0]
        assert first.variant == second.variant and first.hyperparams == second.hyperparams
    assert make_configs("td3", "Hopper-v4", "Hopper", [0], ["train_freq=[1,step]"])[1] == {}
    parsed = hyperparams.parse_overrides("sac-sb3", ["ent_coef=auto_1e-3", "train_freq=[2,step]"])
    assert parsed == {"ent_coef": "auto_0.001", "train_freq": 2}
    episodes = hyperparams.parse_overrides("td3", ["train_freq=[1,episode]"])
    assert episodes == {"train_freq": [1, "episode"]}  # not the step count 1


def test_make_configs_applies_overrides_and_run_settings() -> None:
    configs, changed, notes = make_configs(
        "sac-sb3",
        "Humanoid-v4",
        "Humanoid",
        [0, 10],
        ["learning_rate=1e-3", "batch_size=256"],
        total_steps=5000,
    )
    assert [c.seed for c in configs] == [0, 10]
    assert changed == {"batch_size": 256}  # learning_rate=1e-3 is the table's value
    assert configs[0].hyperparams["batch_size"] == 256
    assert configs[0].alpha == 0.05 and configs[0].total_steps == 5000
    assert configs[0].variant.startswith("batch_size256-")
    assert "sections default + Humanoid; overridden: {'batch_size': 256}" in notes[0]
    data = configs[1].to_dict()
    assert data["hyperparams"]["ent_coef"] == 0.05 and data["seed"] == 10
    assert any(note.startswith("WARNING: sac-sb3's learning_starts 10,000") for note in notes)
    _, _, notes = make_configs("sac-sb3", "Humanoid-v4", "Humanoid", [0], total_steps=10_001)
    assert not any(note.startswith("WARNING") for note in notes)
    _, _, notes = make_configs("ppo", "Hopper-v4", "Hopper", [0], total_steps=2048)
    assert not any(note.startswith("WARNING") for note in notes)  # one rollout: one update
    _, _, notes = make_configs("trpo", "Hopper-v4", "Hopper", [0], total_steps=2047)
    assert "WARNING: trpo's n_steps 2,048 is above --steps 2,047" in notes[-1]
    # SB3 trains after each train_freq steps: one above --steps never trains (it was unsaid)
    for freq in ("train_freq=2000", "train_freq=[2000, step]"):
        _, _, notes = make_configs("ddpg", "Hopper-v4", "Hopper", [0], [freq], total_steps=1000)
        assert "WARNING: ddpg's train_freq 2,000 steps is above --steps 1,000" in notes[-1]
    _, _, notes = make_configs(
        "ddpg", "Hopper-v4", "Hopper", [0], ["train_freq=1000"], total_steps=1000
    )
    assert not any(note.startswith("WARNING: ddpg's train_freq") for note in notes)
    with pytest.raises(TacbenchError, match="PPO normalises the advantages over each minibatch"):
        make_configs("ppo", "Hopper-v4", "Hopper", [0], ["batch_size=1"])
    make_configs("ppo", "Hopper-v4", "Hopper", [0], ["batch_size=1", "normalize_advantage=false"])
    # TRPO's policy step takes every factor-th sample: one left made its advantages NaN
    with pytest.raises(TacbenchError, match=r"take 1 sample of its 256-step rollout"):
        make_configs("trpo", "Hopper-v4", "Hopper", [0], ["n_steps=256", "sub_sampling_factor=256"])
    make_configs("trpo", "Hopper-v4", "Hopper", [0], ["n_steps=256", "sub_sampling_factor=255"])
    # a noise scale without noise only renamed the run (another variant folder, the same runs)
    with pytest.raises(TacbenchError, match="with noise_type=none td3 adds no exploration"):
        make_configs("td3", "Hopper-v4", "Hopper", [0], ["noise_type=none", "noise_std=0.3"])
    make_configs("td3", "Hopper-v4", "Hopper", [0], ["noise_type=normal", "noise_std=0.3"])
    make_configs("td3", "Hopper-v4", "Hopper", [0], ["noise_type=none"])
    with pytest.raises(TacbenchError, match="must differ"):
        make_configs("ppo", "Hopper-v4", "Hopper", [0, 0])
    with pytest.raises(TacbenchError, match="total_steps must be an integer >= 1"):
        make_configs("ppo", "Hopper-v4", "Hopper", [0], total_steps=0)


def test_config_checks_its_hyperparameters() -> None:
    values, _ = hyperparams.resolve("ppo", "Hopper-v4", "Hopper")
    assert BaselineConfig(algo="ppo", env="Hopper-v4", hyperparams=values).alpha is None
    with pytest.raises(TacbenchError, match="lacks hyperparameters"):
        BaselineConfig(algo="ppo", env="Hopper-v4", hyperparams={})
    with pytest.raises(TacbenchError, match="n_epochs for ppo"):
        BaselineConfig(algo="ppo", env="Hopper-v4", hyperparams={**values, "n_epochs": 0})


def test_tac_flags_map_to_hyperparameters_or_are_refused() -> None:
    assert flags_as_overrides("sac-sb3", {"alpha": 0.1, "learning_starts": 500}) == [
        "ent_coef=0.1",
        "learning_starts=500",
    ]
    assert flags_as_overrides("td3", {"learning_starts": 500}) == ["learning_starts=500"]
    learned = [
        flags_as_overrides("sac-sb3", given)
        for given in (
            {"alpha": "auto"},
            {"alpha_mode": "auto"},
            {"alpha_mode": "auto", "alpha": 0.1},
        )
    ]
    assert learned == [["ent_coef=auto"], ["ent_coef=auto"], ["ent_coef=auto_0.1"]]
    started = flags_as_overrides("sac-sb3", {"alpha_mode": "auto", "alpha": 0.1234567})
    assert started == ["ent_coef=auto_0.1234567"]  # it was rounded to auto_0.123457
    # a bad value is named by the flag given, not as an --hp the user never typed
    with pytest.raises(TacbenchError, match=r"^--learning-starts -5: learning_starts for ddpg"):
        flags_as_overrides("ddpg", {"learning_starts": -5})
    with pytest.raises(TacbenchError, match=r"^--alpha-mode auto --alpha 0: ent_coef for sac"):
        flags_as_overrides("sac-sb3", {"alpha_mode": "auto", "alpha": 0})
    assert flags_as_overrides("sac-sb3", {"alpha_mode": "fixed", "alpha": 0.1}) == ["ent_coef=0.1"]
    assert flags_as_overrides("sac-sb3", {"alpha_mode": "fixed"}) == []  # the table's alpha
    with pytest.raises(TacbenchError, match="--alpha auto learns alpha; it does not mix with"):
        flags_as_overrides("sac-sb3", {"alpha_mode": "fixed", "alpha": "auto"})
    with pytest.raises(TacbenchError, match="--alpha-mode is a TAC option that td3 does not use"):
        flags_as_overrides("td3", {"alpha_mode": "auto"})
    with pytest.raises(TacbenchError, match="--learning-starts is a TAC option that ppo"):
        flags_as_overrides("ppo", {"learning_starts": 500})
    with pytest.raises(TacbenchError, match="--q is a TAC option that td3 does not use"):
        flags_as_overrides("td3", {"q": 1.5})
    # a TAC flag named as the baseline's hyperparameter: told the --hp that sets it
    with pytest.raises(TacbenchError, match="set with tacbench run --algo td3 --hp batch_size=64"):
        flags_as_overrides("td3", {"batch_size": 64})


def test_learning_steps_are_those_after_the_random_warm_up() -> None:
    """What the sweep's ETA times (tacbench.sweep.progress): on-policy runs learn throughout."""
    (td3,), _, _ = make_configs("td3", "Hopper-v4", "Hopper", [0], total_steps=25_000)
    assert td3.learning_steps == 25_000 - 10_000
    (short,), _, _ = make_configs("td3", "Hopper-v4", "Hopper", [0], ["learning_starts=900"])
    assert short.learning_steps == short.total_steps - 900
    (ppo,), _, _ = make_configs("ppo", "Hopper-v4", "Hopper", [0], total_steps=25_000)
    assert ppo.learning_steps == 25_000
    (random,), _, _ = make_configs("ddpg", "Hopper-v4", "Hopper", [0], total_steps=5_000)
    assert random.learning_steps == 0
