"""Synthetic results trees in the run-directory contract, shared by the report tests and bench.

:func:`write_run` writes one run directory exactly as the trainers do; :func:`synthetic_tree`
writes a whole sweep whose learning curves have known levels, so the best q is known.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

BASELINES = ("ddpg", "td3", "ppo", "trpo", "sac-sb3")


def write_run(
    root: Path,
    *,
    algo: str,
    env: str,
    variant: str,
    seed: int,
    steps: Sequence[float],
    returns: Sequence[float],
    q: float | None = None,
    alpha: float | None = None,
    total_steps: int | None = None,
    state: str = "complete",
    status_step: int | None = None,
    reason: str = "",
    train: tuple[Sequence[float], Sequence[float]] | None = None,
    settings: dict[str, Any] | None = None,
) -> Path:
    """Write ``root/runs/<algo>/<env>/<variant>/seed<k>/`` with config, status, eval and train.

    ``train`` defaults to one training episode per evaluation step with the same return;
    ``settings`` (the run's whole config, as a sweep compares it) to algo, env and seed.
    """
    path = root / "runs" / algo / env / variant / f"seed{seed}"
    path.mkdir(parents=True, exist_ok=True)
    planned = int(steps[-1]) if total_steps is None else total_steps
    command = f"tacbench run --algo {algo} --env {env} --variant {variant} --seed {seed}"
    config = {
        "algo": algo,
        "env": env,
        "variant": variant,
        "seed": seed,
        "q": q,
        "alpha": alpha,
        "total_steps": planned,
        "command": command,
        "versions": {"python": "3.11.9", "tacbench": "0.1.0", "torch": "2.13.0"},
        "git_commit": "abc1234",
        "host": "testhost",
        "created": f"2025-01-01T00:00:{seed % 60:02d}",
        "config": settings or {"algo": algo, "env": env, "seed": seed},
    }
    (path / "config.json").write_text(json.dumps(config))
    status = {
        "state": state,
        "step": int(steps[-1]) if status_step is None else status_step,
        "reason": reason,
        "updated": "2025-01-01T01:00:00",
    }
    (path / "status.json").write_text(json.dumps(status))
    steps_a = np.asarray(steps, dtype=float)
    returns_a = np.asarray(returns, dtype=float)
    eval_rows = ["step,wall_s,return_mean,return_std,length_mean"]
    eval_rows += [
        f"{int(s)},{s / 100:.3f},{float(r)!r},1.0,1000"
        for s, r in zip(steps_a, returns_a, strict=True)
    ]
    (path / "eval.csv").write_text("\n".join(eval_rows) + "\n")
    train_steps, train_returns = (steps_a, returns_a) if train is None else train
    train_rows = ["step,wall_s,return,length"]
    train_rows += [
        f"{int(s)},{s / 100:.3f},{float(r)!r},1000"
        for s, r in zip(train_steps, train_returns, strict=True)
    ]
    (path / "train.csv").write_text("\n".join(train_rows) + "\n")
    return path


def q_level(q: float) -> float:
    """Known final level of TAC with entropic index q: highest at q = 1.5, q = 1 second."""
    return 1000.0 - 600.0 * abs(np.log(q / 1.5)) - (0.0 if q != 1.0 else 50.0)


BASELINE_LEVEL = {"ddpg": 400.0, "td3": 700.0, "ppo": 300.0, "trpo": 250.0, "sac-sb3": 650.0}


def synthetic_tree(
    root: Path,
    *,
    tasks: Sequence[str] = ("HalfCheetah-v4", "Hopper-v4"),
    qs: Sequence[float] = (0.5, 1.0, 1.5, 2.0),
    baselines: Sequence[str] = ("ddpg", "td3"),
    seeds: int = 3,
    n_eval: int = 20,
    interval: int = 5000,
    noise: float = 20.0,
    spread: float = 0.0,
    rng_seed: int = 0,
) -> Path:
    """A sweep of complete runs: return(t) = level * (1 - exp(-3 t / T)) + Gaussian noise.

    Task ``i`` scales every level by ``i + 1``, so tasks have different return scales; each run's
    level is further multiplied by ``1 + spread * N(0, 1)`` (seed-to-seed variation).
    """
    rng = np.random.default_rng(rng_seed)
    steps = interval * np.arange(1, n_eval + 1)
    shape = 1.0 - np.exp(-3.0 * steps / steps[-1])
    for i, env in enumerate(tasks):
        methods = [("tac", f"q{q:g}-a0.2", q, 0.2, q_level(q)) for q in qs]
        methods += [(b, "default", None, None, BASELINE_LEVEL[b]) for b in baselines]
        for algo, variant, q, alpha, level in methods:
            for seed in range(seeds):
                run_level = (i + 1) * level * (1.0 + spread * rng.normal())
                returns = run_level * shape + rng.normal(0.0, noise, len(steps))
                write_run(
                    root,
                    algo=algo,
                    env=env,
                    variant=variant,
                    seed=10 * seed,
                    steps=steps,
                    returns=returns,
                    q=q,
                    alpha=alpha,
                )
    return root
