"""``tacbench video``: episodes of a run's latest deterministic policy, rendered offscreen.

The policy is the one in the run's newest intact checkpoint generation (TAC's member weights, or
a baseline's SB3 model with its observation normaliser), acting as in evaluation: tanh(mu) for
TAC, ``predict(deterministic=True)`` for the baselines. Episodes are reset with the evaluation
seeds of that step (:func:`tacbench.envs.eval_seeds`), so the first episode is the first one the
run's evaluation at that step saw. Nothing in the run directory is changed.

MuJoCo renders through EGL or OSMesa; :func:`choose_gl_backend` picks the first that works on
this machine (or keeps ``MUJOCO_GL`` when it is set) before anything renders.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tacbench import envs
from tacbench.errors import TacbenchError
from tacbench.runs import checkpoints, read_json
from tacbench.trainers import ALGOS, trainer_for

GL_BACKENDS = ("egl", "osmesa")  # MuJoCo's offscreen backends, GPU-capable first
FORMATS = (".mp4", ".gif")
MP4_BLOCK = 8  # an MP4's frame sides are multiples of this (imageio would rescale the frames)
# what a Debian or Ubuntu machine installs for each backend
GL_PACKAGES = {"egl": "libegl1", "osmesa": "libosmesa6"}
_PROBE = (
    "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); "
    "r = mujoco.Renderer(m, 16, 16); r.render()"
)

Frame = npt.NDArray[np.uint8]
Policy = Callable[[np.ndarray], np.ndarray]


def _backend_works(backend: str) -> tuple[bool, str]:
    """Whether MuJoCo renders a frame with ``backend``, tried in a child process (a failed
    OpenGL start can leave a process unable to try another); and the error if not."""
    env = {**os.environ, "MUJOCO_GL": backend, "PYOPENGL_PLATFORM": backend}
    done = subprocess.run(
        [sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=False
    )
    last = (done.stderr.strip().splitlines() or ["exit status " + str(done.returncode)])[-1]
    return done.returncode == 0, last


def choose_gl_backend() -> str:
    """Set ``MUJOCO_GL`` (and PyOpenGL's platform) to the first backend of :data:`GL_BACKENDS`
    that renders here, unless ``MUJOCO_GL`` is already set; a TacbenchError naming what to
    install when none does."""
    chosen = os.environ.get("MUJOCO_GL")
    if chosen:
        os.environ.setdefault("PYOPENGL_PLATFORM", chosen)
        return chosen
    failures = []
    for backend in GL_BACKENDS:
        works, error = _backend_works(backend)
        if works:
            os.environ["MUJOCO_GL"] = os.environ["PYOPENGL_PLATFORM"] = backend
            return backend
        failures.append(f"{backend}: {error}")
    packages = " or ".join(f"`apt-get install {p}`" for p in GL_PACKAGES.values())
    raise TacbenchError(
        "MuJoCo cannot render offscreen on this machine (" + "; ".join(failures) + "). Install "
        f"an OpenGL backend (Debian/Ubuntu: {packages}), or set MUJOCO_GL to one that works."
    )


@dataclass(frozen=True)
class LoadedPolicy:
    """A run's policy at its newest checkpoint: what acts, on which task, from which step."""

    algo: str
    env: str
    seed: int
    step: int
    act: Policy  # one observation -> one action in the env's units


_RESTORE = "restore it from the run's sweep, or train the run again"


def _check_renderable(env_id: str) -> None:
    """Refuse a task that MuJoCo does not simulate (a classic-control one: Pendulum-v1): its
    frames are another renderer's (pygame), which takes no --width and --height."""
    from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

    env = envs.make_env(env_id)
    try:
        simulated = isinstance(env.unwrapped, MujocoEnv)
    finally:
        env.close()
    if not simulated:
        raise TacbenchError(
            f"{env_id} is not a MuJoCo task, and tacbench video renders with MuJoCo's offscreen "
            "renderer; record it with gymnasium's own wrappers (RecordVideo)."
        )


def load_policy(run: Path) -> LoadedPolicy:
    """The deterministic policy of run directory ``run`` at its newest intact checkpoint."""
    import torch

    if not (run / "config.json").is_file():
        raise TacbenchError(
            f"{run} is not a run directory (no config.json); give a folder like "
            "results/runs/tac/Hopper-v4/q2-a0.2/seed0."
        )
    metadata = read_json(run / "config.json", advice=_RESTORE)
    missing = [key for key in ("algo", "env", "seed", "config") if key not in metadata]
    if missing or not isinstance(metadata["config"], dict):
        raise TacbenchError(
            f"{run / 'config.json'} is not a run's config (no {', '.join(missing) or 'config'}); "
            f"{_RESTORE}."
        )
    _check_renderable(str(metadata["env"]))
    folder = run / "checkpoint"
    steps, damaged = checkpoints.usable_steps(folder) if folder.is_dir() else ([], {})
    if damaged and not steps:
        found = "; ".join(f"step {step}: {', '.join(why)}" for step, why in damaged.items())
        raise TacbenchError(f"{run} has no intact checkpoint to render ({found}).")
    if not steps:
        raise TacbenchError(f"{run} has no checkpoint yet: a policy is saved at each checkpoint.")
    if metadata["algo"] not in ALGOS:
        raise TacbenchError(
            f"{run / 'config.json'} names the algorithm {metadata['algo']!r}, not one of "
            f"{', '.join(ALGOS)}; {_RESTORE}."
        )
    info = envs.env_info(str(metadata["env"]))
    step = steps[0]
    state = torch.load(folder / f"state-{step:012d}.pt", weights_only=True)
    config_data = dict(metadata["config"])
    try:  # a checkpoint of another task (or algorithm) fails here, not half-way into a video
        act = trainer_for(metadata["algo"]).policy(config_data, folder, state)
        action = np.shape(act(np.zeros(info.obs_dim, dtype=np.float32)))
        if action != (info.act_dim,):
            raise ValueError(f"actions of shape {action}, not ({info.act_dim},)")
    except (RuntimeError, ValueError, TypeError, KeyError) as err:
        raise TacbenchError(
            f"the checkpoint at step {step} of {run} does not act on {info.env_id} as "
            f"config.json says ({type(err).__name__}: {str(err).splitlines()[0]}); it holds "
            f"another run's policy: {_RESTORE}."
        ) from None
    return LoadedPolicy(metadata["algo"], metadata["env"], int(metadata["seed"]), step, act)


def episode_frames(
    policy: LoadedPolicy,
    episodes: int,
    width: int,
    height: int,
    max_steps: int | None = None,
    returns: list[float] | None = None,
) -> Iterator[Frame]:
    """The frames of ``episodes`` episodes (each at most ``max_steps`` steps), one after
    another, made as they are asked for, so that only one is held at a time; each episode's
    return is appended to ``returns`` when it ends."""
    env = envs.make_env(policy.env, render_mode="rgb_array", width=width, height=height)
    try:
        for seed in envs.eval_seeds(policy.seed, policy.step, episodes):
            obs, _ = env.reset(seed=int(seed))
            yield np.asarray(env.render(), dtype=np.uint8)
            done, steps, total = False, 0, 0.0
            while not done and (max_steps is None or steps < max_steps):
                obs, reward, terminated, truncated, _ = env.step(policy.act(np.asarray(obs)))
                yield np.asarray(env.render(), dtype=np.uint8)
                done, steps, total = terminated or truncated, steps + 1, total + float(reward)
            if returns is not None:
                returns.append(total)
    finally:
        env.close()


def write_video(frames: Iterable[Frame], out: Path, fps: int) -> int:
    """An MP4 (H.264 through imageio's ffmpeg pipe; each frame is sent to the encoder as it
    comes, so memory does not grow with the video's length) or a looping GIF (Pillow writes a
    GIF at the end, so its frames are kept, as 256-colour images: a third of their RGB size),
    by ``out``'s suffix (in any case). Returns the number of frames."""
    count = 0
    if out.suffix.lower() == ".gif":
        from PIL import Image

        kept = [Image.fromarray(frame).quantize(colors=256) for frame in frames]
        kept[0].save(
            out, format="GIF", save_all=True, append_images=kept[1:], duration=1000 / fps, loop=0
        )
        return len(kept)
    import imageio.v2 as imageio

    writer: Any = imageio.get_writer(out, format="FFMPEG", fps=fps, macro_block_size=MP4_BLOCK)
    try:
        for frame in frames:
            writer.append_data(frame)
            count += 1
    finally:
        writer.close()
    return count
