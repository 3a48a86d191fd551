"""``--matmul-precision bf16``: bfloat16 products with float32 accumulation in the update only,
within bfloat16 rounding of the float32 update, the same in the compiled and the eager path,
its own variant, and refused, before anything is written, where the device would emulate it."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch

from tacbench import hardware
from tacbench.errors import TacbenchError
from tacbench.tac.maths import METRICS, Coefficients, coefficients
from tacbench.tac.networks import linear
from tacbench.tac.update import gradients
from tests.helpers import (
    assert_close_per_member,
    random_batch,
    run_cli,
    tac_agent,
    tiny_configs,
    train,
)

pytestmark = pytest.mark.unit

OBS, ACT, SEEDS = 5, 3, [3, 4, 5]
NATIVE_BF16 = bool(hardware.bf16_instructions())
INTEL_FLAGS = "processor\t: 0\nvendor_id\t: GenuineIntel\nflags\t\t: fpu avx2 avx512f {}\n\n"


def test_bf16_instructions_are_read_from_the_cpu_flags() -> None:
    assert hardware.bf16_instructions(INTEL_FLAGS.format("avx512_bf16 amx_bf16")) == [
        "avx512_bf16",
        "amx_bf16",
    ]
    assert hardware.bf16_instructions(INTEL_FLAGS.format("avx512_vnni")) == []
    arm = "processor\t: 0\nFeatures\t: fp asimd bf16 i8mm\n\n"
    assert hardware.bf16_instructions(arm) == ["bf16"]


def test_a_cpu_without_bf16_instructions_refuses_before_anything_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(hardware, "bf16_instructions", lambda cpuinfo=None: [])
    hardware.check_matmul_precision("float32", "cpu")  # float32 is never refused
    with pytest.raises(TacbenchError, match="--matmul-precision float32") as refused:
        train(tmp_path / "out", tiny_configs("tac", matmul_precision="bf16"))
    assert "no native bfloat16" in str(refused.value)
    assert not (tmp_path / "out").exists()


def test_the_command_line_refuses_an_unknown_precision_with_its_choices(tmp_path: Path) -> None:
    refused = run_cli(["run", "--env", "Hopper-v4", "--matmul-precision", "fp8", "--out", "x"])
    assert refused.returncode == 2
    assert "float32" in refused.stderr and "bf16" in refused.stderr


def test_bf16_products_round_their_inputs_and_return_float32() -> None:
    g = torch.Generator().manual_seed(0)
    x, w, b = (
        torch.randn(2, 7, 33, generator=g),
        torch.randn(2, 33, 9, generator=g),
        torch.ones(2, 1, 9),
    )
    out = linear(x, w, b, bf16=True)
    assert out.dtype == torch.float32
    expected = (x.bfloat16().double() @ w.bfloat16().double()).bfloat16().double() + 1.0
    assert torch.allclose(out.double(), expected, rtol=0, atol=1e-6)
    exact = x.double() @ w.double() + 1.0
    assert not torch.allclose(out.double(), exact, rtol=1e-5)  # it did round
    assert torch.allclose(out.double(), exact, rtol=2e-2, atol=2e-2 * exact.abs().max().item())
    head = torch.randn(2, 33, 1, generator=g)  # a value head stays float32
    assert torch.equal(linear(x, head, b[..., :1], bf16=True), linear(x, head, b[..., :1]))


@pytest.mark.parametrize("hidden", [(16,), (64, 64)])
def test_the_bf16_update_is_the_float32_one_within_bfloat16_rounding(
    hidden: tuple[int, ...],
) -> None:
    """The same members on the same minibatch: every member's every metric within 2% of its
    float32 value (the largest difference here, 1.3%, is a std of 0.001 whose log-std came
    through bfloat16 products), every member's gradient of every tensor pointing the same way
    (cosine above 0.99), and not identical (the products did run in bfloat16)."""
    float32 = tac_agent(OBS, ACT, SEEDS, hidden_sizes=hidden)
    bf16 = tac_agent(OBS, ACT, SEEDS, hidden_sizes=hidden, matmul_precision="bf16")
    batch, eps = random_batch(len(SEEDS), 64, OBS, ACT, seed=0, terminal=0.2)
    c = _coefficients()
    expected, expected_grads = gradients(float32, batch, eps, c)
    metrics, grads = gradients(bf16, batch, eps, c)
    assert not torch.equal(metrics, expected)
    for i, name in enumerate(METRICS):
        assert_close_per_member(metrics[:, i], expected[:, i], 2e-2, name)
    for name, grad in expected_grads.items():
        cosine = torch.nn.functional.cosine_similarity(
            grads[name].flatten(1), grad.flatten(1), dim=1
        )
        assert cosine.min().item() > 0.99, (name, cosine)


@pytest.mark.compile
def test_the_compiled_bf16_update_equals_the_eager_bf16_one() -> None:
    """Inductor keeps the casts where the eager path has them: the two agree to float32
    rounding (1e-5 of the largest magnitude), as the float32 paths do. It did compile: a
    failed compilation falls back to the eager update with a warning, which compared eager
    with eager."""
    compiled = tac_agent(OBS, ACT, SEEDS, matmul_precision="bf16", compile="on")
    eager = tac_agent(OBS, ACT, SEEDS, matmul_precision="bf16")
    batch, eps = random_batch(len(SEEDS), 64, OBS, ACT, seed=1, terminal=0.2)
    expected, expected_grads = gradients(eager, batch, eps, _coefficients())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        metrics, grads = gradients(compiled, batch, eps, _coefficients())
    assert not [w for w in caught if "torch.compile of TAC's update" in str(w.message)]
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] >= 1
    for i, name in enumerate(METRICS):
        assert_close_per_member(metrics[:, i], expected[:, i], 1e-5, name)
    for name, grad in expected_grads.items():
        assert_close_per_member(grads[name], grad, 1e-5, name)


@pytest.mark.skipif(not NATIVE_BF16, reason="this CPU has no native bfloat16 instructions")
def test_a_bf16_run_trains_into_its_own_variant(tmp_path: Path) -> None:
    (outcome,) = train(tmp_path / "out", tiny_configs("tac", matmul_precision="bf16"))
    assert outcome.state == "complete"
    assert outcome.directory.parent.name.endswith("-bf16")


def _coefficients() -> Coefficients:
    return coefficients([1.0, 1.5, 3.0], [0.2, 0.1, 0.05], torch.device("cpu"))
