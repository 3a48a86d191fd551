"""Where a run came from: the versions of Python and the main dependencies, the git commit and
the host, as config.json records them."""

from __future__ import annotations

import importlib.metadata
import platform
import socket
import subprocess
from pathlib import Path
from typing import Any, Protocol

from tacbench.runs.clock import CPU_CLOCK
from tacbench.runs.files import now_iso

VERSIONED_PACKAGES = ("torch", "gymnasium", "mujoco", "stable_baselines3", "sb3_contrib", "numpy")


def package_versions() -> dict[str, str | None]:
    """Python's and the main dependencies' versions (None for a package that is not installed)."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for package in VERSIONED_PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package.replace("_", "-"))
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    return versions


def git_commit() -> str | None:
    """The tacbench checkout's commit, with ``-dirty`` for uncommitted changes; None outside git."""
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return sha + ("-dirty" if dirty else "")


class RunIdentity(Protocol):
    """What config.json names a run by (a TAC or a baseline config)."""

    @property
    def algo(self) -> str: ...
    @property
    def env(self) -> str: ...
    @property
    def variant(self) -> str: ...
    @property
    def seed(self) -> int: ...
    @property
    def alpha(self) -> float | None: ...
    @property
    def total_steps(self) -> int: ...
    def to_dict(self) -> dict[str, Any]: ...


def run_metadata(
    config: RunIdentity, command: str, q: float | None, **fields: Any
) -> dict[str, Any]:
    """config.json's content: the run's identity (algo, env, variant, seed, q, alpha,
    total_steps), ``fields``, then command, versions, git commit, host, creation time and the
    full config."""
    return {
        "algo": config.algo,
        "env": config.env,
        "variant": config.variant,
        "seed": config.seed,
        "q": q,
        "alpha": config.alpha,
        "total_steps": config.total_steps,
        **fields,
        "cpu_clock": CPU_CLOCK,
        "command": command,
        "versions": package_versions(),
        "git_commit": git_commit(),
        "host": socket.gethostname(),
        "created": now_iso(),
        "config": config.to_dict(),
    }
