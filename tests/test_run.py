"""TAC's ``tacbench run`` end to end on tiny budgets: every suite task, both ln_q forms, several
q, both update schedules, the q schedule, divergence, and the CLI's skip/refuse/force contract
(for TAC and a baseline). Resume, determinism and the run directory's schema are tested for
every learner in test_resume.py, test_determinism.py and test_run_directory.py."""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.paper import ENV_IDS, TASK_FACTS
from tacbench.runs import Outcome
from tests.helpers import assert_same_results, checkpoint_state, tiny_configs, train

pytestmark = pytest.mark.smoke

# ln_q of the joint density overflows float32 at the first update on several tasks at their
# paper q (docs/tac.md, Numerics); joint mode is smoke-tested where it stays finite.
JOINT_FINITE = ("Hopper", "Swimmer", "Pusher")


def _config(env: str = "Hopper-v4", q: float = 1.5, **settings: Any) -> RunConfig:
    (config,) = tiny_configs("tac", env, q=q, **settings)
    assert isinstance(config, RunConfig)
    return config


def _train(out: Path, *configs: RunConfig, **kw: Any) -> list[Outcome]:
    return train(out, configs, **kw)


@pytest.mark.parametrize(
    ("task", "lnq"), [(task, "per-dim") for task in ENV_IDS] + [(t, "joint") for t in JOINT_FINITE]
)
def test_every_suite_task_trains_into_a_run_directory(tmp_path: Path, task: str, lnq: str) -> None:
    config = _config(
        ENV_IDS[task], q=TASK_FACTS[task].best_q, alpha=TASK_FACTS[task].alpha, lnq=lnq
    )
    (outcome,) = _train(tmp_path, config)
    assert outcome.directory == tmp_path / "runs" / "tac" / ENV_IDS[task] / config.variant / "seed0"
    assert (outcome.state, outcome.step) == ("complete", 1500)
    metadata = json.loads((outcome.directory / "config.json").read_text())
    assert (metadata["env"], metadata["q"], metadata["alpha"]) == (
        ENV_IDS[task],
        config.q,
        config.alpha,
    )
    assert np.isfinite(pd.read_csv(outcome.directory / "eval.csv")["return_mean"]).all()
    losses = pd.read_csv(outcome.directory / "losses.csv")
    assert losses["updates"].tolist() == [1, 250, 250]
    assert np.isfinite(losses.drop(columns="step")).all().all()


def test_non_finite_loss_marks_the_run_failed_and_keeps_the_last_checkpoint(tmp_path: Path) -> None:
    # Humanoid at q = 1.2 with the joint ln_q: log pi ~ 270 at the first update overflows float32
    (outcome,) = _train(tmp_path, _config("Humanoid-v4", q=1.2, alpha=0.05, lnq="joint"))
    status = json.loads((outcome.directory / "status.json").read_text())
    assert (outcome.state, status["state"], status["step"]) == ("failed", "failed", 1000)
    assert status["reason"].startswith("non-finite loss_v")
    assert "--lnq per-dim" in status["reason"]
    assert status["reason"].endswith("; the last checkpoint is kept")
    checkpoint = checkpoint_state(outcome.directory)
    assert checkpoint["step"] == 500
    assert pd.read_csv(outcome.directory / "eval.csv")["step"].tolist() == [500]
    (again,) = _train(tmp_path, _config("Humanoid-v4", q=1.2, alpha=0.05, lnq="joint"), resume=True)
    assert again.state == "failed" and again.message.startswith("skipped: failed at step 1000")
    # without a checkpoint before the failure, the reason does not promise one
    config = _config("Humanoid-v4", q=1.2, alpha=0.05, lnq="joint", checkpoint_every=0)
    (unkept,) = _train(tmp_path / "unkept", config)
    assert unkept.state == "failed"
    assert unkept.message.endswith("; no checkpoint had been written yet")


@pytest.mark.parametrize("q", [0.5, 1.0, 1.5, 2.0, 5.0])
def test_q_values(tmp_path: Path, q: float) -> None:
    (outcome,) = _train(tmp_path, _config(q=q, eval_every=0))
    assert outcome.state == "complete"
    losses = pd.read_csv(outcome.directory / "losses.csv")
    assert (losses["q"] == q).all()
    assert np.isfinite(losses.drop(columns="step")).all().all()
    assert not (outcome.directory / "eval.csv").read_text().strip().count("\n")  # header only


def test_episode_schedule_updates_once_per_step_of_each_finished_episode(tmp_path: Path) -> None:
    config = _config(update_schedule="episode", lnq="per-dim", eval_every=0, log_every=100_000)
    (outcome,) = _train(tmp_path, config)
    assert outcome.state == "complete"
    episodes = pd.read_csv(outcome.directory / "train.csv")
    expected = episodes.loc[episodes["step"] >= config.learning_starts, "length"].sum()
    losses = pd.read_csv(outcome.directory / "losses.csv")
    assert losses["step"].tolist() == [1500]
    assert losses["updates"].item() == expected > 0


def test_linear_q_schedule_is_logged(tmp_path: Path) -> None:
    (outcome,) = _train(tmp_path, _config(q=2.0, q_schedule="linear", eval_every=0))
    q = pd.read_csv(outcome.directory / "losses.csv")["q"].tolist()
    assert q == pytest.approx([1 + (1000 / 1500 - 0.1) / 0.8, 1 + (1250 / 1500 - 0.1) / 0.8, 2.0])


CLI_TINY = ["--env", "Hopper-v4", "--steps", "300", "--learning-starts", "200"]
CLI_TINY += ["--eval-every", "100", "--eval-episodes", "1", "--quiet"]


def test_cli_run_skip_refuse_and_force(tmp_path: Path) -> None:
    args = [*CLI_TINY, "--out", str(tmp_path)]
    runner = CliRunner()
    first = runner.invoke(cli, ["run", *args])
    assert first.exit_code == 0, first.output
    assert "q = 2: the paper's best q for Hopper" in first.output
    assert "seed 0: complete" in first.output
    progress = [line for line in first.output.splitlines() if "| ETA " in line]
    assert progress[0].endswith("ETA - (warm-up)") and "step 100/300" in progress[0]
    assert not progress[1].endswith("(warm-up)")  # learning from step 200
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200" / "seed0"
    metadata = json.loads((run / "config.json").read_text())
    assert sorted(shlex.split(metadata["command"])) == sorted(["tacbench", "run", *args])
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [100, 200, 300]

    again = runner.invoke(cli, ["run", *args])
    assert again.exit_code == 0
    assert "seed 0: skipped" in again.output and "already complete (300 steps)" in again.output

    changed = runner.invoke(cli, ["run", *args, "--eval-every", "150"])
    assert changed.exit_code == 2
    assert "eval_every: 100 -> 150" in changed.output

    forced = runner.invoke(cli, ["run", *args, "--eval-every", "150", "--force"])
    assert forced.exit_code == 0, forced.output
    assert pd.read_csv(run / "eval.csv")["step"].tolist() == [150, 300]


def test_a_resume_without_a_checkpoint_says_it_trains_again_from_step_0(tmp_path: Path) -> None:
    """A run killed (kill -9, out of memory) before its first checkpoint resumed from step 0
    without a word, writing its CSVs again."""
    args = [*CLI_TINY, "--checkpoint-every", "0", "--out", str(tmp_path)]
    runner = CliRunner()
    assert runner.invoke(cli, ["run", *args]).exit_code == 0
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200" / "seed0"
    rows = (run / "eval.csv").read_text()
    shutil.rmtree(run / "checkpoint")  # as a run killed before its first checkpoint leaves it
    (run / "status.json").write_text('{"state": "running", "step": 0}')
    resumed = runner.invoke(cli, ["run", *args, "--resume"])
    assert resumed.exit_code == 0, resumed.output
    said = f"seed 0: {run} has no checkpoint yet (it stopped before its first, --checkpoint-every"
    assert said in resumed.output
    assert (run / "eval.csv").read_text().count("\n") == rows.count("\n")
    again = runner.invoke(cli, ["run", *args, "--resume"])  # complete: skipped, nothing said
    assert again.exit_code == 0 and "no checkpoint yet" not in again.output


def test_a_run_that_failed_before_is_not_trained_again_and_still_exits_1(tmp_path: Path) -> None:
    """A rerun skipped a failed run and exited 0, so a script saw success."""
    args = [*CLI_TINY, "--out", str(tmp_path)]
    runner = CliRunner()
    assert runner.invoke(cli, ["run", *args]).exit_code == 0
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200" / "seed0"
    status = {"state": "failed", "step": 300, "reason": "non-finite loss_v"}
    (run / "status.json").write_text(json.dumps(status))
    for extra in ([], ["--resume"]):
        again = runner.invoke(cli, ["run", *args, *extra])
        assert again.exit_code == 1, again.output
        assert f"seed 0: failed, {run} (skipped: failed at step 300: non-finite" in again.output


def test_a_lost_checkpoint_is_refused_without_first_saying_the_run_trains_again(
    tmp_path: Path,
) -> None:
    args = [*CLI_TINY, "--checkpoint-every", "100", "--out", str(tmp_path)]
    runner = CliRunner()
    assert runner.invoke(cli, ["run", *args]).exit_code == 0
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200" / "seed0"
    shutil.rmtree(run / "checkpoint")
    (run / "status.json").write_text('{"state": "interrupted", "step": 200}')
    resumed = runner.invoke(cli, ["run", *args, "--resume"])
    assert resumed.exit_code == 2, resumed.output
    assert "status.json records step 200, but" in resumed.output
    assert "no checkpoint yet" not in resumed.output and "trains again" not in resumed.output


def test_a_new_member_beside_one_to_resume_is_refused_without_a_contrary_note(
    tmp_path: Path,
) -> None:
    """--resume said the new seed would start afresh, then refused the whole group; the
    refusal used to advise --force, which deletes the trained member's steps."""
    args = [*CLI_TINY, "--checkpoint-every", "100", "--out", str(tmp_path)]
    runner = CliRunner()
    assert runner.invoke(cli, ["run", *args]).exit_code == 0
    run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200" / "seed0"
    (run / "checkpoint" / "manifest-000000000300.json").unlink()  # as if stopped at 200
    (run / "status.json").write_text('{"state": "interrupted", "step": 200}')
    both = runner.invoke(cli, ["run", *args, "--seed", "0", "--seed", "10", "--resume"])
    assert both.exit_code == 2, both.output
    assert "seed10 has no checkpoint, and the other members have" in both.output
    assert "nothing to resume" not in both.output and "--force" not in both.output
    alone = runner.invoke(cli, ["run", *args, "--resume"])  # as the refusal advises
    assert alone.exit_code == 0 and "seed 0: complete" in alone.output


def test_a_group_stopped_during_its_first_checkpoint_starts_afresh(tmp_path: Path) -> None:
    """Members commit their checkpoints one after another: a group killed after seed 0's first
    and before seed 10's was refused as if seed 10 were a new member, with advice (resume seed
    0 alone) that trains other numbers. It starts afresh, says why, and ends as an
    uninterrupted group."""
    group = [*CLI_TINY, "--seed", "0", "--seed", "10", "--checkpoint-every", "100"]
    runner = CliRunner()
    assert runner.invoke(cli, ["run", *group, "--out", str(tmp_path / "whole")]).exit_code == 0
    out = tmp_path / "cut"
    assert runner.invoke(cli, ["run", *group, "--out", str(out)]).exit_code == 0
    variant = out / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200"
    (variant / "seed0" / "checkpoint" / "manifest-000000000300.json").unlink()  # only step 200
    shutil.rmtree(variant / "seed10" / "checkpoint")  # killed before it wrote its first
    (variant / "seed0" / "status.json").write_text('{"state": "running", "step": 200}')  # kill -9
    (variant / "seed10" / "status.json").write_text('{"state": "running", "step": 0}')
    again = [*group, "--checkpoint-every", "150", "--out", str(out), "--resume"]
    resumed = runner.invoke(cli, ["run", *again])
    assert resumed.exit_code == 0, resumed.output
    assert "the group's first checkpoint (step 200) was cut short before" in resumed.output
    for seed in ("seed0", "seed10"):  # the cut-short generation at step 200 is forgotten
        kept = sorted(p.name for p in (variant / seed / "checkpoint").glob("manifest-*"))
        assert kept == ["manifest-000000000150.json", "manifest-000000000300.json"], seed
    for seed in ("seed0", "seed10"):
        assert_same_results(variant / seed, tmp_path / "whole" / variant.relative_to(out) / seed)


def test_a_group_resumes_in_the_order_it_trained_in_whatever_the_commands(
    tmp_path: Path,
) -> None:
    """The order of a group's members is part of its rounding: `--seed 10 --seed 0` resumed a
    group trained as `--seed 0 --seed 10` in the other order, to other numbers and without a
    note. It resumes in the order config.json records."""
    first = [*CLI_TINY, "--seed", "0", "--seed", "10", "--checkpoint-every", "100"]
    runner = CliRunner()
    assert runner.invoke(cli, ["run", *first, "--out", str(tmp_path / "whole")]).exit_code == 0
    out = tmp_path / "stopped"
    assert runner.invoke(cli, ["run", *first, "--out", str(out)]).exit_code == 0
    variant = out / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ls200"
    for seed in ("seed0", "seed10"):  # as if stopped at step 200
        (variant / seed / "checkpoint" / "manifest-000000000300.json").unlink()
        (variant / seed / "status.json").write_text('{"state": "interrupted", "step": 200}')
    swapped = [*CLI_TINY, "--seed", "10", "--seed", "0", "--checkpoint-every", "100"]
    resumed = runner.invoke(cli, ["run", *swapped, "--out", str(out), "--resume"])
    assert resumed.exit_code == 0, resumed.output
    for seed in ("seed0", "seed10"):
        whole = tmp_path / "whole" / variant.relative_to(out) / seed
        assert_same_results(variant / seed, whole)
        # the weights and Adam moments to the last bit (the order's rounding: about 1e-8)
        trained = checkpoint_state(variant / seed)["agent"]
        uninterrupted = checkpoint_state(whole)["agent"]
        for part in ("params", "adam"):
            pairs = zip(_tensors(trained[part]), _tensors(uninterrupted[part]), strict=True)
            assert all(torch.equal(a, b) for a, b in pairs), (seed, part)


def _tensors(tree: Any) -> list[torch.Tensor]:
    """The tensors of a checkpoint's nested dicts, in their order."""
    if isinstance(tree, torch.Tensor):
        return [tree]
    values = tree.values() if isinstance(tree, dict) else []
    return [tensor for value in values for tensor in _tensors(value)]


def test_cli_user_errors_and_failed_run(tmp_path: Path) -> None:
    runner = CliRunner()
    for env, message in [("Hoper-v4", "Closest registered names"), ("CartPole-v1", "Discrete")]:
        result = runner.invoke(cli, ["run", "--env", env, "--out", str(tmp_path)])
        assert (result.exit_code, message in result.output) == (2, True), result.output
    args = ["--env", "Humanoid-v4", "--lnq", "joint", "--steps", "300", "--learning-starts", "200"]
    failed = runner.invoke(cli, ["run", *args, "--eval-every", "0", "--out", str(tmp_path)])
    assert failed.exit_code == 1, failed.output
    assert "seed 0: failed" in failed.output


def test_twin_q_critic_target_has_no_v_loss_and_names_its_variant(tmp_path: Path) -> None:
    (outcome,) = _train(tmp_path, _config(critic_target="twin-q"))
    assert outcome.state == "complete"
    assert outcome.directory.parent.name == "q1.5-a0.2-twinq-ls1000-bs32"
    losses = pd.read_csv(outcome.directory / "losses.csv")
    assert (losses["loss_v"] == 0).all() and losses["loss_q1"].gt(0).all()


def test_members_of_two_q_and_two_seeds_write_the_runs_they_would_write_alone(
    tmp_path: Path,
) -> None:
    settings = {"total_steps": 1000, "learning_starts": 500, "eval_every": 500}
    group = tiny_configs("tac", seeds=[0, 10], qs=[1.0, 2.0], **settings)
    outcomes = _train(tmp_path / "group", *group)  # type: ignore[arg-type]
    assert {o.state for o in outcomes} == {"complete"}
    directories = {(o.directory.parent.name, o.seed): o.directory for o in outcomes}
    assert sorted(directories) == [
        (f"q{q}-a0.2-ls500-bs32", seed) for q in (1, 2) for seed in (0, 10)
    ]
    for config in group:
        member = directories[(config.variant, config.seed)]
        (alone,) = _train(tmp_path / f"alone-{config.variant}", config)  # type: ignore[arg-type]
        ours = json.loads((member / "config.json").read_text())
        theirs = json.loads((alone.directory / "config.json").read_text())
        assert ours["config"] == theirs["config"]  # only the members list differs
        assert (len(ours["members"]), len(theirs["members"])) == (4, 1)
        # the evaluation before learning: the same initial weights and warm-up as alone
        before = [pd.read_csv(d / "eval.csv").iloc[0] for d in (member, alone.directory)]
        assert before[0]["step"] == 500 and before[0]["return_mean"] == before[1]["return_mean"]
        assert (pd.read_csv(member / "losses.csv")["q"] == config.q).all()
    from tacbench.report import ReportOptions, analyse

    report = analyse(ReportOptions(results=tmp_path / "group", out=tmp_path / "report"))
    runs = report.runset.runs
    assert len(runs) == 4 and sorted(runs["q"].unique()) == [1.0, 2.0]


def test_a_member_that_diverges_is_retired_and_the_others_finish(tmp_path: Path) -> None:
    # Humanoid with the joint ln_q: q = 1.2 overflows float32 at the first update, q = 1 does not
    configs = tiny_configs("tac", "Humanoid-v4", q=None, qs=[1.0, 1.2], alpha=0.05, lnq="joint")
    by_q = {o.directory.parent.name.split("-")[0]: o for o in _train(tmp_path, *configs)}  # type: ignore[arg-type]
    assert (by_q["q1.2"].state, by_q["q1.2"].step) == ("failed", 1000)
    assert by_q["q1"].state == "complete"
    assert pd.read_csv(by_q["q1"].directory / "eval.csv")["step"].tolist() == [500, 1000, 1500]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--q", "1", "--q", "1"], "--q values must differ (got [1.0, 1.0])"),
        (["--alpha", "0.2", "--alpha", "0.2"], "--alpha values must differ"),
        (["--q", "1", "--q", "1.0000001"], "would share the run directory q1-a0.2/seed0"),
        (["--alpha", "0.2", "--alpha", "0.2000001"], "alpha 0.2 and 0.2000001 differ only"),
        (["--algo", "td3", "--alpha", "0.1", "--alpha", "0.2"], "repeatable for TAC only"),
    ],
)
def test_repeated_values_are_refused_and_nothing_is_written(
    tmp_path: Path, args: list[str], message: str
) -> None:
    result = CliRunner().invoke(cli, ["run", "--env", "Hopper-v4", *args, "--out", str(tmp_path)])
    assert result.exit_code == 2 and message in result.output, result.output
    assert not (tmp_path / "runs").exists()


def test_members_that_differ_in_more_than_q_alpha_and_seed_are_refused(tmp_path: Path) -> None:
    (a,) = tiny_configs("tac", lnq="joint")
    (b,) = tiny_configs("tac", seeds=[1])
    (c,) = tiny_configs("tac", "Ant-v4", seeds=[2])
    with pytest.raises(
        TacbenchError, match="differ only in q, alpha and the seed; these differ: lnq"
    ):
        _train(tmp_path, a, b)  # type: ignore[arg-type]
    with pytest.raises(TacbenchError, match="these differ: env: 'Hopper-v4' -> 'Ant-v4'"):
        _train(tmp_path, b, c)  # type: ignore[arg-type]
    with pytest.raises(TacbenchError, match="the same run"):
        _train(tmp_path, b, b)  # type: ignore[arg-type]
    assert not (tmp_path / "runs").exists()


def test_the_reference_profile_trains_as_the_authors_code_did(tmp_path: Path) -> None:
    """Two members with (400, 300) networks, updates from each one's first episode end during
    the random warm-up, in bursts at episode ends."""
    args = ["run", "--env", "Hopper-v4", "--profile", "reference", "--seed", "0", "--seed", "1"]
    args += ["--steps", "600", "--eval-every", "0", "--log-every", "300", "--quiet"]
    result = CliRunner().invoke(cli, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    for seed in (0, 1):
        run = tmp_path / "runs" / "tac" / "Hopper-v4" / "q2-a0.2-ref" / f"seed{seed}"
        config = json.loads((run / "config.json").read_text())["config"]
        assert config["hidden_sizes"] == [400, 300] and config["profile"] == "reference"
        losses = pd.read_csv(run / "losses.csv")
        episodes = pd.read_csv(run / "train.csv")
        # every step of every finished episode earned one update, all before learning_starts
        assert losses["updates"].sum() == episodes["length"].sum() > 500
        assert episodes["step"].max() < config["learning_starts"]
        state = checkpoint_state(run)
        assert state["agent"]["params"]["q1.weights.1"].shape == (400, 300)


def test_the_reference_profile_stores_pushers_time_limit_as_terminal_and_scaled_actions(
    tmp_path: Path,
) -> None:
    (config,) = tiny_configs("tac", "Pusher-v5", q=1.2, profile="reference", hidden_sizes=(16,))
    (outcome,) = _train(tmp_path, config)  # type: ignore[arg-type]
    assert outcome.state == "complete"
    chunk = sorted((outcome.directory / "checkpoint" / "replay").glob("*.npz"))[0]
    with np.load(chunk) as replay:
        terminated, action = replay["terminated"], replay["action"]
    assert (
        terminated.reshape(-1, 100)[:, -1].all() and not terminated.reshape(-1, 100)[:, :-1].any()
    )
    assert np.abs(action).max() > 1.0 and np.abs(action).max() <= 2.0  # times Pusher's bound 2
    (paper,) = tiny_configs("tac", "Pusher-v5", q=1.2, hidden_sizes=(16,))
    (outcome,) = _train(tmp_path / "paper", paper)  # type: ignore[arg-type]
    chunk = sorted((outcome.directory / "checkpoint" / "replay").glob("*.npz"))[0]
    with np.load(chunk) as replay:
        assert not replay["terminated"].any() and np.abs(replay["action"]).max() <= 1.0
