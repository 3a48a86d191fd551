"""``tacbench bench --profile``: where one TAC update's time goes, and how close its matrix
products run to this core's rate.

The update is run on a synthetic minibatch (no environment) with the members, networks and
compile setting asked for, then profiled with ``torch.profiler``. Its time is split into the
matrix products, by shape, each with its achieved GFLOP/s; the compiled graph's fused
elementwise kernels; Adam; the target average; and the rest (Python, dispatch, Dynamo's guards
and the kernels too small to name). The peak it is compared with is a large square product on
one thread, measured in the same process.

Inductor's kernels are only visible to the profiler through its Python wrapper, so the compiled
update is profiled without the C++ wrapper (``cpp_wrapper``) that training uses; the update's
time without the profiler is measured with the wrapper, as training runs it, and both are shown.

On a GPU (``--device cuda``) the update is timed to its completion and its time is split by the
GPU's kernels (matrix products, compiled elementwise kernels, Adam, copies, others) and the time
the GPU waits for the host; the peak is a large square product on the GPU.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from tacbench.hardware import configure_process

PEAK_SIZE = 2048  # the square product whose rate stands for the core's peak
PROFILED_UPDATES = 50  # updates timed, and then profiled
ELEMENTWISE = "elementwise (compiled kernels)"  # Inductor's fused kernels, graph_*_cpp_fused_*
KINDS = {"aten::_fused_adam_": "Adam", "aten::lerp_": "target average"}  # ops named by kind
BATCH = 100  # the paper's minibatch


@dataclass(frozen=True)
class Row:
    """One line of the profile: what, how many calls per update, microseconds per update and,
    for a product, its GFLOP/s."""

    what: str
    calls: float
    us: float
    gflops: float | None = None


KERNEL_KINDS = ("matrix products", ELEMENTWISE, "Adam", "copies", "other kernels")
GPU_IDLE = "GPU idle (waiting for the host: Python, launches, noise draws)"


def best_seconds(fn: Callable[[], Any], repeats: int, rounds: int = 5) -> float:
    """The fastest of ``rounds`` means of ``repeats`` calls of ``fn``, in seconds per call."""
    for _ in range(min(repeats, 5)):
        fn()
    best = math.inf
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(repeats):
            fn()
        best = min(best, (time.perf_counter() - start) / repeats)
    return best


def _finished(fn: Callable[[], Any], device: str) -> Callable[[], Any]:
    """``fn``, waited for on a GPU (its kernels run after the call returns)."""
    if device == "cpu":
        return fn

    def waited() -> Any:
        out = fn()
        torch.cuda.synchronize()
        return out

    return waited


def peak_gflops(
    size: int | None = None, dtype: torch.dtype = torch.float32, device: str = "cpu"
) -> float:
    """GFLOP/s of one ``size`` x ``size`` (default :data:`PEAK_SIZE`) product of ``dtype``
    (float32, or bfloat16 with float32 accumulation) on this process's threads or the GPU."""
    size = size or PEAK_SIZE
    a, b = (torch.randn(size, size, dtype=dtype, device=device) for _ in range(2))
    return 2 * size**3 / best_seconds(_finished(lambda: a @ b, device), repeats=3) / 1e9


def _minibatch(k: int, obs_dim: int, act_dim: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    shape = (k, BATCH)
    return {
        "obs": rng.standard_normal((*shape, obs_dim), dtype=np.float32),
        "action": rng.uniform(-1, 1, (*shape, act_dim)).astype(np.float32),
        "reward": rng.standard_normal(shape, dtype=np.float32),
        "next_obs": rng.standard_normal((*shape, obs_dim), dtype=np.float32),
        "terminated": np.zeros(shape, dtype=np.float32),
    }


def _update(
    env: str,
    members: int,
    hidden_sizes: Sequence[int],
    compile: bool,
    bf16: bool,
    device: str = "cpu",
) -> Callable[[], Any]:
    """One update of ``members`` fresh TAC members of ``env``'s dimensions, as a closure that
    returns when the update is done."""
    from tacbench import envs, paper
    from tacbench.members import make_run_configs
    from tacbench.tac.agent import TacAgent
    from tacbench.tac.maths import coefficients
    from tacbench.tac.update import update

    info = envs.env_info(env)
    configs, _ = make_run_configs(
        env,
        paper.paper_task(env),
        list(range(0, 10 * members, 10)),
        hidden_sizes=tuple(hidden_sizes),
        compile="on" if compile else "off",
        matmul_precision="bf16" if bf16 else "float32",
        device=device,
    )
    where = torch.device(device)
    agent = TacAgent(info.obs_dim, info.act_dim, configs[0], [c.seed for c in configs], where)
    c = coefficients([x.q for x in configs], [x.alpha for x in configs], where)
    minibatch = _minibatch(members, info.obs_dim, info.act_dim)
    return _finished(lambda: update(agent, minibatch, c), device)


def _product_flops(shapes: Sequence[Sequence[int]]) -> int:
    """FLOPs of a ``bmm`` of ``(M, n, k) @ (M, k, m)``."""
    (m, n, k), (_, _, cols) = shapes[0], shapes[1]
    return 2 * m * n * k * cols


def profile_rows(
    step: Callable[[], Any], updates: int, compiled: bool = True
) -> tuple[list[Row], float]:
    """The profile of ``updates`` calls of ``step``: rows per update, and the profiled
    microseconds per update. An eager (not ``compiled``) update has no compiled kernels: its
    elementwise operations are counted in the rest."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
        start = time.perf_counter()
        for _ in range(updates):
            step()
        wall_us = (time.perf_counter() - start) / updates * 1e6
    products: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0.0])
    kinds = {kind: [0.0, 0.0] for kind in (ELEMENTWISE, *KINDS.values())}
    for event in prof.key_averages(group_by_input_shape=True):
        name, us, calls = event.key, event.self_cpu_time_total / updates, event.count / updates
        if name in ("aten::bmm", "aten::mm", "aten::baddbmm", "aten::addmm"):
            shapes = [s for s in event.input_shapes if s][:2]
            if name in ("aten::baddbmm", "aten::addmm"):
                shapes = [s for s in event.input_shapes if s][1:3]
            if len(shapes[0]) == 2:
                shapes = [[1, *s] for s in shapes]
            label = "x".join(map(str, shapes[0])) + " @ " + "x".join(map(str, shapes[1]))
            entry = products[label]
            entry[0] += calls
            entry[1] += us
            entry[2] += _product_flops(shapes) * calls
        else:
            fused = name.startswith("graph_") and "cpp_fused" in name
            kind = ELEMENTWISE if fused else KINDS.get(name)
            if kind is not None:
                kinds[kind][0] += calls
                kinds[kind][1] += us
    rows = [
        Row(f"product {label}", calls, us, flops / us / 1e3)
        for label, (calls, us, flops) in sorted(products.items(), key=lambda kv: -kv[1][1])
    ]
    rows += [
        Row(what, calls, us)
        for what, (calls, us) in kinds.items()
        if compiled or what != ELEMENTWISE
    ]
    named = sum(r.us for r in rows)
    rest = (
        "Python, dispatch, guards, small ops" if compiled else "elementwise ops, Python, dispatch"
    )
    rows.append(Row(f"the rest ({rest})", 0, wall_us - named))
    return rows, wall_us


def _kernel_kind(name: str) -> str:
    """Which of :data:`KERNEL_KINDS` a GPU kernel (or copy) of this name is."""
    lower = name.lower()
    if "memcpy" in lower or "memset" in lower:
        return "copies"
    if any(part in lower for part in ("gemm", "xmma", "cutlass", "cublas")):
        return "matrix products"
    if lower.startswith("triton"):
        return ELEMENTWISE
    if "adam" in lower or "multi_tensor_apply" in lower:
        return "Adam"
    return "other kernels"


def kernel_rows(step: Callable[[], Any], updates: int) -> tuple[list[Row], float]:
    """The GPU profile of ``updates`` calls of ``step``: the kernels' time per update by
    :data:`KERNEL_KINDS`, then the time the GPU waited (the wall time not covered by kernels),
    and the profiled microseconds per update."""
    from torch.autograd import DeviceType
    from torch.profiler import ProfilerActivity, profile

    activities = [ProfilerActivity.CPU, ProfilerActivity.CUDA]
    with profile(activities=activities) as prof:
        start = time.perf_counter()
        for _ in range(updates):
            step()
        wall_us = (time.perf_counter() - start) / updates * 1e6
    kinds = {kind: [0.0, 0.0] for kind in KERNEL_KINDS}
    for event in prof.key_averages():
        if event.device_type == DeviceType.CUDA:
            entry = kinds[_kernel_kind(event.key)]
            entry[0] += event.count / updates
            entry[1] += event.self_device_time_total / updates
    rows = [Row(kind, calls, us) for kind, (calls, us) in kinds.items()]
    rows.append(Row(GPU_IDLE, 0, wall_us - sum(r.us for r in rows)))
    return rows, wall_us


def profile_update(
    env: str,
    members: int,
    hidden_sizes: Sequence[int],
    compile: bool,
    bf16: bool = False,
    device: str = "cpu",
) -> dict[str, Any]:
    """Peak, the update's unprofiled time (as training runs it) and its profile over
    :data:`PROFILED_UPDATES` updates, for one thread (or, with ``device`` ``cuda``, by the GPU's
    kernels: :func:`kernel_rows`); with ``bf16`` of the update with bfloat16 products
    (``--matmul-precision bf16``), against a bfloat16 product's peak. The process is set up as
    training sets it up (:func:`tacbench.hardware.configure_process`: one thread, subnormals
    flushed)."""
    from tacbench.tac import gradient

    configure_process(1)
    updates = PROFILED_UPDATES
    step = _update(env, members, hidden_sizes, compile, bf16, device)
    unprofiled_us = best_seconds(step, repeats=max(10, updates)) * 1e6
    result = {
        "env": env,
        "members": members,
        "hidden_sizes": list(hidden_sizes),
        "compile": compile,
        "matmul_precision": "bf16" if bf16 else "float32",
        "device": device,
        "peak_size": PEAK_SIZE,
        "peak_gflops": peak_gflops(dtype=torch.bfloat16 if bf16 else torch.float32, device=device),
        "update_us": unprofiled_us,
    }
    if device != "cpu":  # the GPU's kernels are visible as training runs them
        rows, profiled_us = kernel_rows(step, updates)
        return {**result, "profiled_update_us": profiled_us, "rows": [vars(r) for r in rows]}
    wrapper = gradient.CPU_COMPILE_OPTIONS["cpp_wrapper"]
    kernel_profile = torch._inductor.config.cpp.enable_kernel_profile
    try:  # a second agent compiled with its kernels visible to the profiler
        gradient.CPU_COMPILE_OPTIONS["cpp_wrapper"] = False
        torch._inductor.config.cpp.enable_kernel_profile = True
        visible = _update(env, members, hidden_sizes, compile, bf16)
        best_seconds(visible, repeats=10, rounds=1)
        rows, profiled_us = profile_rows(visible, updates, compile)
    finally:
        gradient.CPU_COMPILE_OPTIONS["cpp_wrapper"] = wrapper
        torch._inductor.config.cpp.enable_kernel_profile = kernel_profile
    return {**result, "profiled_update_us": profiled_us, "rows": [vars(r) for r in rows]}


def profile_table(result: dict[str, Any]) -> str:
    """The profile as a Markdown table, with the peak and the products' share."""
    peak = result["peak_gflops"]
    total = result["profiled_update_us"]
    precision = result.get("matmul_precision", "float32")  # absent from older profiles
    lines = [
        f"{result['env']}, {result['members']} member(s), hidden layers "
        f"{tuple(result['hidden_sizes'])}, batch {BATCH}, "
        f"{'compiled' if result['compile'] else 'eager'}, "
        f"{precision} products, "
        f"{'one thread' if result.get('device', 'cpu') == 'cpu' else result['device']}. Update: "
        f"{result['update_us'] / 1e3:.2f} ms as training runs it, "
        f"{total / 1e3:.2f} ms profiled. Peak (a {result['peak_size']}x{result['peak_size']} "
        f"{precision} product): "
        f"{peak:.1f} GFLOP/s.",
        "",
        "| where | calls/update | us/update | share | GFLOP/s | of peak |",
        "|---|---|---|---|---|---|",
    ]
    for row in result["rows"]:
        rate = row["gflops"]
        lines.append(
            f"| {row['what']} | {row['calls']:.0f} | {row['us']:.0f} | "
            f"{row['us'] / total:.0%} | "
            + (f"{rate:.1f} | {rate / peak:.0%} |" if rate is not None else "- | - |")
        )
    product_rows = [r for r in result["rows"] if r["gflops"] is not None]
    flops = sum(r["gflops"] * r["us"] * 1e3 for r in product_rows)
    product_us = sum(r["us"] for r in product_rows)
    if product_us:
        lines += [
            "",
            f"products: {flops / 1e9:.3f} GFLOP per update in {product_us / 1e3:.2f} ms "
            f"({flops / product_us / 1e3:.1f} GFLOP/s, {flops / product_us / 1e3 / peak:.0%} of "
            f"peak); the whole update runs at {flops / total / 1e3:.1f} GFLOP/s.",
        ]
    return "\n".join(lines)
