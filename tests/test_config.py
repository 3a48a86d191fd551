"""RunConfig: the paper's defaults, validation, variant names, the q schedule, JSON round trip."""

from __future__ import annotations

import json

import pytest
import torch

from tacbench import hardware
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.members import make_run_configs, paper_defaults, resolve_compile

pytestmark = pytest.mark.unit


def test_defaults_are_the_papers_and_the_reference_codes() -> None:
    config = RunConfig(env="Ant-v4", q=1.5, alpha=0.2)
    assert config.hidden_sizes == (300,)
    assert (config.learning_rate, config.batch_size, config.buffer_size) == (1e-3, 100, 1_000_000)
    assert (config.gamma, config.tau) == (0.99, 0.005)
    assert (config.log_std_min, config.log_std_max) == (-20.0, 2.0)
    assert (config.learning_starts, config.total_steps) == (10_000, 1_000_000)
    assert (config.eval_every, config.eval_episodes, config.checkpoint_every) == (5_000, 10, 50_000)
    assert (config.update_schedule, config.lnq, config.q_schedule) == (
        "step",
        "per-dim",
        "constant",
    )


@pytest.mark.parametrize(
    ("task", "q", "alpha"),
    [
        ("HalfCheetah", 1.5, 0.2),
        ("Ant", 1.5, 0.2),
        ("Hopper", 2.0, 0.2),
        ("Swimmer", 2.0, 0.2),
        ("Pusher", 1.2, 0.2),
        ("Humanoid", 1.2, 0.05),
        (None, 1.0, 0.2),
    ],
)
def test_paper_defaults_per_task(task: str | None, q: float, alpha: float) -> None:
    assert paper_defaults(task)[:2] == (q, alpha)


def test_make_run_configs_fills_in_the_papers_values_and_says_so() -> None:
    configs, notes = make_run_configs("Humanoid-v4", "Humanoid", [0, 10])
    assert [(c.q, c.alpha, c.seed) for c in configs] == [(1.2, 0.05, 0), (1.2, 0.05, 10)]
    assert any("q = 1.2" in note and "Humanoid" in note for note in notes)
    assert any("alpha = 0.05" in note for note in notes)
    configs, notes = make_run_configs("Hopper-v4", "Hopper", [0], [1.5], [0.3], compile="off")
    assert (configs[0].q, configs[0].alpha, notes) == (1.5, 0.3, ["compile: off (--compile off)"])


def test_members_are_the_cross_product_of_q_alpha_and_seed() -> None:
    configs, notes = make_run_configs("Hopper-v4", "Hopper", [0, 10], [0.5, 2.0], [0.1, 0.2])
    assert [(c.q, c.alpha, c.seed) for c in configs] == [
        (q, alpha, seed) for q in (0.5, 2.0) for alpha in (0.1, 0.2) for seed in (0, 10)
    ]
    assert {c.variant for c in configs} == {"q0.5-a0.1", "q0.5-a0.2", "q2-a0.1", "q2-a0.2"}
    assert any(note.startswith("q = 2: the policy density is capped") for note in notes)
    for flag, kwargs in (("--q", {"qs": [1, 1]}), ("--alpha", {"alphas": [0.2, 0.2]})):
        with pytest.raises(TacbenchError, match=f"{flag} values must differ"):
            make_run_configs("Hopper-v4", "Hopper", [0], **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("steps", "compiler", "expected", "note"),
    [
        (1_000_000, "g++", "on", "compile: on (--compile auto: 990,000 learning steps"),
        (29_999, "g++", "off", "compile: off (--compile auto: 19,999 learning steps, fewer"),
        (1_000_000, None, "off", "WARNING: compile: off (--compile auto found no C++ compiler"),
    ],
)
def test_compile_auto_compiles_long_runs_where_a_compiler_is_found(
    monkeypatch: pytest.MonkeyPatch, steps: int, compiler: str | None, expected: str, note: str
) -> None:
    monkeypatch.setattr(hardware, "cpp_compiler", lambda: compiler)
    configs, notes = make_run_configs("Hopper-v4", "Hopper", [0], total_steps=steps)
    assert configs[0].compile == "auto"  # decided where the run trains, not where it is planned
    resolved = resolve_compile(configs[0])
    assert resolved.compile == expected  # what is used is what config.json records
    assert any(n.startswith(note) for n in notes), notes
    assert RunConfig.from_dict(resolved.to_dict()) == resolved
    other = "off" if expected == "on" else "on"
    assert resolve_compile(configs[0], recorded=other).compile == other  # a resume keeps it
    forced, notes = make_run_configs("Hopper-v4", "Hopper", [0], total_steps=steps, compile="on")
    assert forced[0].compile == "on" and "compile: on (--compile on)" in notes


@pytest.mark.parametrize(
    ("steps", "settings", "warned"),
    [
        (5000, {}, True),
        (10_000, {}, True),
        (10_001, {}, False),
        (5000, {"warmup_updates": "on"}, False),  # updates from the first episode's end
    ],
)
def test_a_run_that_never_learns_is_warned_about(steps: int, settings: dict, warned: bool) -> None:
    _, notes = make_run_configs("Hopper-v4", "Hopper", [0], total_steps=steps, **settings)
    warning = f"WARNING: --learning-starts 10,000 is not below --steps {steps:,}"
    assert any(note.startswith(warning) for note in notes) == warned, notes
    if warned:  # the loop updates after step 10,000 itself: at --steps 10,000, once
        last = "updated once, after the last step" if steps == 10_000 else "never updated"
        assert any(note.endswith(f"the networks are {last}") for note in notes), notes


def test_a_population_that_never_exploits_is_warned_about() -> None:
    seeds = [0, 10, 20, 30]
    population = {"q_mode": "auto"}
    _, notes = make_run_configs("Hopper-v4", "Hopper", seeds, total_steps=20_000, **population)
    assert any(note.startswith("WARNING: --pbt-every 10,000 is not shorter") for note in notes)
    _, notes = make_run_configs("Hopper-v4", "Hopper", seeds, total_steps=20_001, **population)
    assert not any(note.startswith("WARNING: --pbt-every") for note in notes)


def test_the_density_cap_is_mentioned_where_its_rule_applies() -> None:
    _, notes = make_run_configs("Hopper-v4", "Hopper", [0])
    assert any("q = 2: the policy density is capped at 10^8 (" in note for note in notes)
    _, notes = make_run_configs("Hopper-v4", "Hopper", [0], [2.0], density_cap="off")
    assert not any("capped" in note for note in notes)
    _, notes = make_run_configs("Hopper-v4", "Hopper", [0], [1.5], density_cap="every-q")
    assert any("q = 1.5: the policy density is capped at 10^16 (" in note for note in notes)
    # near q = 1 the cap is far beyond a float (exp overflowed) or below its smallest (read 0)
    qs = [1.02, 0.98]
    _, notes = make_run_configs("Hopper-v4", "Hopper", [0], qs, density_cap="every-q")
    assert any("q = 1.02: the policy density is capped at 10^400 (" in note for note in notes)
    assert any("q = 0.98: the policy density is capped at 10^-400 (" in note for note in notes)


@pytest.mark.parametrize(
    ("field", "value", "fragment"),
    [
        ("q", 0.0, "q must be"),
        ("q", float("nan"), "q must be"),
        ("alpha", -0.1, "alpha must be"),
        ("total_steps", 0, "--steps"),
        ("batch_size", 2.5, "batch_size"),
        ("eval_episodes", 0, "--eval-episodes"),
        ("lnq", "log", "--lnq must be one of joint, per-dim, joint-batch-max"),
        ("density_cap", "always", "--density-cap must be one of paper, every-q, off"),
        ("update_schedule", "epoch", "--update-schedule"),
        ("device", "tpu", "--device"),
        ("gamma", 1.5, "--gamma must lie in"),
        ("gamma", float("nan"), "--gamma must lie in"),
        ("tau", 0.0, "--tau must lie in"),
        ("learning_rate", float("nan"), "--learning-rate must be a finite"),
        ("learning_rate", float("inf"), "--learning-rate must be a finite"),
        ("log_std_max", float("inf"), "--log-std-min and --log-std-max must be finite"),
        ("log_std_min", 3.0, "min < max"),
        ("target_entropy", float("nan"), "--target-entropy must be a finite"),
        ("target_entropy", 1e308, "a float32 holds"),
        ("log_std_max", 1e308, "finite float32 numbers"),
        ("q", 1e308, r"above 1000, where the density cap \(below 1.02\) makes ln_q flat"),
        ("hidden_sizes", (), "hidden_sizes"),
        ("q_schedule_start", 0.95, "q_schedule_start"),
        ("q_schedule_start", 0.5, "--q-schedule-start shapes the linear q schedule; add"),
        ("density_floor", 0.0, "--density-floor must lie in"),
        ("density_floor", 1e-320, r"float32's normal numbers \(got 9.99989e-321\)"),  # log: NaN
        ("alpha", 1e-40, r"--alpha 1e-40 is below float32's smallest normal number, 1.175e-38"),
        ("tau", 1e-40, "--tau 1e-40 is below float32's smallest normal number"),  # target fixed
        ("gamma", 1e-39, "--gamma 1e-39 is below float32's smallest normal number"),
        ("learning_rate", 1e-300, "--learning-rate 1e-300 is below float32's smallest normal"),
        # both were accepted and ended the run with a non-finite loss at its first update
        ("alpha", 1e40, r"--alpha 1e\+40 is above float32's largest number, 3.403e\+38"),
        ("learning_rate", 1e40, r"--learning-rate 1e\+40 is above float32's largest number"),
        ("jacobian_clip", 1.0, "--jacobian-clip must lie in"),
        ("gaussian_eps", -1e-8, "--gaussian-eps must lie in"),
        ("compile", True, "--compile must be one of auto, on, off"),
    ],
)
def test_invalid_values_are_refused_with_what_to_do(
    field: str, value: object, fragment: str
) -> None:
    with pytest.raises(TacbenchError, match=fragment):
        RunConfig(**{"env": "Hopper-v4", "q": 1.5, "alpha": 0.2, field: value})  # type: ignore[arg-type]


def test_the_density_settings_refuse_what_they_cannot_mean() -> None:
    with pytest.raises(TacbenchError, match="--density-floor applies to --lnq per-dim"):
        RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, lnq="joint", density_floor=1e-8)
    with pytest.raises(TacbenchError, match="--alpha auto needs --lnq per-dim or joint"):
        RunConfig(env="Hopper-v4", q=1.5, alpha=0.2, lnq="joint-batch-max", alpha_mode="auto")
    ramp = {"q_schedule": "linear", "q_schedule_start": 0.5}
    assert (
        RunConfig(env="Hopper-v4", q=2.0, alpha=0.2, **ramp).variant == "q2-a0.2-qlinear-qstart0.5"
    )


def test_members_must_have_distinct_seeds_and_the_episode_schedule_takes_several() -> None:
    with pytest.raises(TacbenchError, match="must differ"):
        make_run_configs("Hopper-v4", "Hopper", [0, 0])
    configs, _ = make_run_configs("Hopper-v4", "Hopper", [0, 10], update_schedule="episode")
    assert [c.update_schedule for c in configs] == ["episode", "episode"]
    assert all(c.per_member_updates for c in configs)


def test_the_reference_profile_sets_what_the_authors_code_did_and_each_item_can_change() -> None:
    paper = RunConfig(env="Pusher-v5", q=1.2, alpha=0.2)
    reference = RunConfig(env="Pusher-v5", q=1.2, alpha=0.2, profile="reference")
    assert (paper.update_schedule, paper.warmup_updates, paper.hidden_sizes) == (
        "step",
        "off",
        (300,),
    )
    assert (paper.time_limits, paper.action_scale) == ("not-terminal", "unit")
    assert (reference.update_schedule, reference.warmup_updates, reference.hidden_sizes) == (
        "episode",
        "on",
        (400, 300),
    )
    assert (reference.time_limits, reference.action_scale) == ("terminal-below-1000", "bound")
    assert reference.variant == "q1.2-a0.2-ref"
    ablation = RunConfig(
        env="Pusher-v5", q=1.2, alpha=0.2, profile="reference", hidden_sizes=(300,)
    )
    assert ablation.variant == "q1.2-a0.2-ref-h300"
    one_item = RunConfig(env="Pusher-v5", q=1.2, alpha=0.2, warmup_updates="on")
    assert one_item.variant == "q1.2-a0.2-wu" and one_item.per_member_updates
    assert RunConfig.from_dict(reference.to_dict()) == reference
    with pytest.raises(TacbenchError, match="--profile must be one of paper, reference"):
        RunConfig(env="Pusher-v5", q=1.2, alpha=0.2, profile="authors")
    with pytest.raises(TacbenchError, match="--time-limits must be one of"):
        RunConfig(env="Pusher-v5", q=1.2, alpha=0.2, time_limits="always")


@pytest.mark.parametrize(
    ("overrides", "variant"),
    [
        ({}, "q1.5-a0.2"),
        ({"lnq": "joint"}, "q1.5-a0.2-joint"),
        ({"profile": "authors-2019-01-11b"}, "q1.5-a0.2-authors20190111b"),
        (
            {"profile": "authors-2019-01-11b", "density_cap": "paper"},
            "q1.5-a0.2-authors20190111b-cappaper",
        ),
        ({"density_floor": 1e-8, "jacobian_clip": 1e-3}, "q1.5-a0.2-floor1e-08-jclip0.001"),
        ({"update_schedule": "episode", "q_schedule": "linear"}, "q1.5-a0.2-episode-qlinear"),
        ({"learning_starts": 100_000}, "q1.5-a0.2-ls100000"),
        ({"matmul_precision": "bf16"}, "q1.5-a0.2-bf16"),
        ({"hidden_sizes": (400, 300), "learning_rate": 3e-4}, "q1.5-a0.2-h400x300-lr0.0003"),
        # neither evaluation, logging, hardware nor length change what is learned
        ({"eval_every": 1000, "threads": 4, "total_steps": 30_000, "seed": 3}, "q1.5-a0.2"),
    ],
)
def test_variant_names_each_non_default_training_choice(overrides: dict, variant: str) -> None:
    assert RunConfig(env="Ant-v4", q=1.5, alpha=0.2, **overrides).variant == variant


def test_linear_q_schedule_goes_from_one_to_q_between_ten_and_ninety_percent() -> None:
    config = RunConfig(env="Ant-v4", q=2.0, alpha=0.2, total_steps=1000, q_schedule="linear")
    assert [config.q_at(s) for s in (0, 100, 500, 900, 1000)] == pytest.approx(
        [1.0, 1.0, 1.5, 2.0, 2.0]
    )
    assert RunConfig(env="Ant-v4", q=0.5, alpha=0.2, q_schedule="linear").q_at(500_000) == 0.75
    assert RunConfig(env="Ant-v4", q=2.0, alpha=0.2).q_at(0) == 2.0


def test_json_round_trip_and_unknown_fields() -> None:
    config = RunConfig(env="Ant-v4", q=1.5, alpha=0.2, hidden_sizes=(400, 300), seed=20)
    data = json.loads(json.dumps(config.to_dict()))
    assert RunConfig.from_dict(data) == config
    with pytest.raises(TacbenchError, match="unknown RunConfig fields"):
        RunConfig.from_dict({**data, "epochs": 3})


def test_device_resolution() -> None:
    from tacbench.training import resolve_device

    assert resolve_device("cpu") == "cpu"
    assert resolve_device("auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    if not torch.cuda.is_available():
        with pytest.raises(TacbenchError, match="no CUDA device"):
            resolve_device("cuda")


def test_q_auto_notes_the_cap_once_and_not_for_its_starting_qs() -> None:
    """A --q auto population's q moves during training: one note about the q >= 2 cap when the
    range reaches 2, none per starting q; none at all for a range below 2."""
    seeds = [0, 10, 20, 30]
    configs, notes = make_run_configs("Hopper-v4", "Hopper", seeds, alphas=[0.2], q_mode="auto")
    assert max(c.q for c in configs) >= 2  # the default range 0.5,5 starts members above 2
    assert not any(note.startswith("q = 5 >= 2") for note in notes)
    assert sum("policy density is capped" in note for note in notes) == 1
    _, low = make_run_configs(
        "Hopper-v4", "Hopper", seeds, alphas=[0.2], q_mode="auto", q_range=(0.5, 1.5)
    )
    assert not any("capped" in note for note in low)


def test_another_version_of_a_paper_task_says_its_q_and_alpha_are_carried_over() -> None:
    configs, notes = make_run_configs("Hopper-v5", "Hopper", [0])
    assert (configs[0].q, configs[0].alpha) == (2.0, 0.2)
    carried = "tuned on Hopper-v2 and carried over to Hopper-v5 unchanged"
    assert notes[0].startswith("q = 2: the paper's best q for Hopper") and carried in notes[0]
    assert notes[1].startswith("alpha = 0.2:") and carried in notes[1]
    _, suite_notes = make_run_configs("Hopper-v4", "Hopper", [0])
    assert not any("carried over" in note for note in suite_notes)
