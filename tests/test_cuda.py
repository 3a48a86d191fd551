"""TAC on a GPU (skipped where none is visible, as in CI): the update on the GPU (its losses,
gradients and weights) equals the CPU's to float32 rounding, eager and compiled (CUDA graphs),
for members of several q; a short run with evaluation, losses and checkpoints completes, and so
does a local sweep whose workers share the GPU; a run stopped twice and resumed writes the CSVs
of an uninterrupted one; the bench's phases add up; and the update's profile names the GPU's
kernels."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from tacbench.bench import BenchOptions, run_bench
from tacbench.cli import cli
from tacbench.tac.agent import TacAgent
from tacbench.tac.maths import METRICS, Batch, coefficients
from tacbench.tac.update import gradients, update
from tests.helpers import (
    assert_close_per_member,
    assert_same_results,
    random_batch,
    tac_agent,
    tiny_configs,
    train,
)

pytestmark = [
    pytest.mark.smoke,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device visible"),
]

OBS, ACT, SEEDS, QS = 11, 3, [0, 10, 20], [1.0, 1.5, 3.0]


def _train_a_few(agent: TacAgent, updates: int = 5) -> list[dict[str, torch.Tensor]]:
    c = coefficients(QS, [0.2, 0.1, 0.05], agent.device)
    for step in range(updates):
        batch, _ = random_batch(len(SEEDS), 100, OBS, ACT, seed=step, terminal=0.1)
        metrics = update(agent, batch._asdict(), c)
        assert bool(torch.isfinite(metrics).all())
    return [agent.member_state(k)["params"] for k in range(len(SEEDS))]


@pytest.mark.parametrize("compile", ["off", "on"])
def test_the_update_on_the_gpu_equals_the_cpus(compile: str) -> None:
    """The noise comes from each member's CPU generator on every device, so the same seeds give
    the same numbers to float32 rounding (TF32 stays off: torch's default for float32
    products); the compiled GPU update runs as CUDA graphs."""
    on_cpu = _train_a_few(tac_agent(OBS, ACT, SEEDS, hidden_sizes=(64,)))
    on_gpu = _train_a_few(
        tac_agent(OBS, ACT, SEEDS, hidden_sizes=(64,), compile=compile, device="cuda")
    )
    for cpu_member, gpu_member in zip(on_cpu, on_gpu, strict=True):
        for name, value in cpu_member.items():
            torch.testing.assert_close(gpu_member[name], value, rtol=1e-4, atol=1e-5, msg=name)


@pytest.mark.parametrize("compile", ["off", "on"])
def test_the_gpu_gradients_equal_the_cpus(compile: str) -> None:
    """Each member's losses and gradients on one minibatch, to float32 rounding (1e-4 of each
    member's largest value: the GPU sums in another order). The weights after Adam steps
    cannot show a loss scaled per network: Adam's step does not change with the scale."""
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    on_cpu = tac_agent(OBS, ACT, SEEDS, hidden_sizes=(64,))
    on_gpu = tac_agent(OBS, ACT, SEEDS, hidden_sizes=(64,), compile=compile, device=cuda.type)
    batch, eps = random_batch(len(SEEDS), 100, OBS, ACT, seed=0, terminal=0.1)
    alphas = [0.2, 0.1, 0.05]
    expected, expected_grads = gradients(on_cpu, batch, eps, coefficients(QS, alphas, cpu))
    moved = Batch(*(t.to(cuda) for t in batch))
    metrics, grads = gradients(on_gpu, moved, eps.to(cuda), coefficients(QS, alphas, cuda))
    for i, name in enumerate(METRICS):
        assert_close_per_member(metrics[:, i].cpu(), expected[:, i], 1e-4, name)
    assert sorted(grads) == sorted(expected_grads)
    for name, grad in expected_grads.items():
        assert_close_per_member(grads[name].cpu(), grad, 1e-4, name)


def test_a_short_gpu_run_trains_evaluates_and_checkpoints(tmp_path: Path) -> None:
    (outcome,) = train(tmp_path, tiny_configs("tac", device="cuda", compile="on"))
    assert outcome.state == "complete"
    assert json.loads((outcome.directory / "config.json").read_text())["config"]["device"] == "cuda"
    for name in ("eval.csv", "losses.csv", "train.csv"):
        assert len((outcome.directory / name).read_text().splitlines()) > 1, name


def test_a_local_sweep_shares_the_gpu_between_its_workers(tmp_path: Path) -> None:
    args = ["sweep", "--preset", "smoke", "--algo", "tac", "--group", "seeds", "--steps", "600"]
    result = CliRunner().invoke(cli, [*args, "--gpus-per-run", "0.5", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    configs = sorted(tmp_path.glob("runs/tac/*/*/seed*/config.json"))
    assert len(configs) == 4  # two q, two seeds: one unit of two members per q, both at once
    for path in configs:
        assert json.loads(path.read_text())["config"]["device"] == "cuda"
    assert len(list((tmp_path / "sweep" / "logs").glob("*.log"))) == 2


def test_a_gpu_run_stopped_and_resumed_equals_an_uninterrupted_one(tmp_path: Path) -> None:
    configs = tiny_configs("tac", device="cuda")
    (whole,) = train(tmp_path / "whole", configs)
    for stop_at in (730, 1234):
        (stopped,) = train(
            tmp_path / "parts", configs, resume=True, stop=lambda s, at=stop_at: s >= at
        )
        assert (stopped.state, stopped.step) == ("interrupted", stop_at)
    (resumed,) = train(tmp_path / "parts", configs, resume=True)
    assert resumed.state == "complete"
    assert_same_results(whole.directory, resumed.directory)


def test_the_bench_on_the_gpu_splits_each_step_into_its_phases() -> None:
    options = BenchOptions(
        env="Hopper-v4", members=4, steps=40, rounds=2, learning_starts=20, sb3=False, device="cuda"
    )
    for result in run_bench(options, report=lambda line: None):
        shares = result.phase_shares
        assert min(shares.values()) > -0.05 and shares["update"] > 0, shares


def test_the_gpu_profile_splits_an_update_into_kernels_and_idle_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from tacbench import update_profile

    monkeypatch.setattr(update_profile, "PROFILED_UPDATES", 5)  # a profile, not a measurement
    result = update_profile.profile_update("Hopper-v4", 4, (64,), compile=False, device="cuda")
    rows = {row["what"]: row for row in result["rows"]}
    assert rows["matrix products"]["calls"] >= 1 and rows["matrix products"]["us"] > 0
    assert rows["Adam"]["calls"] >= 1
    assert sum(row["us"] for row in result["rows"]) == pytest.approx(result["profiled_update_us"])
    assert result["device"] == "cuda" and result["peak_gflops"] > 0
