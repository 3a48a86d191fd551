"""A baseline's ``checkpoint/``: generations (:mod:`tacbench.runs.checkpoints`) of everything its
exact continuation depends on.

- ``model-<step>.zip``: ``model.save`` (weights, optimiser states, counters, last observation,
  action-noise state, learning-rate schedule).
- ``replay/<from>-<to>.npz`` (off-policy): the replay transitions added since the previous
  checkpoint, so a checkpoint writes only what is new (SB3's ``save_replay_buffer`` would pickle
  the whole preallocated buffer each time). Loading the chunks in order rebuilds the buffer.
- ``state-<step>.pt``: the step, which model file belongs to it, the global random generators
  SB3 draws from (torch, NumPy, Python) and the action space's, the environment's exact state
  (:func:`tacbench.envs.get_env_state`), the episode in progress, the ``VecNormalize``
  statistics, the partial losses window and the run's clocks (wall and CPU seconds).

Each file is written durably; the generation's manifest (sizes and checksums) is written
last, so a crash mid-checkpoint leaves the previous generation usable, and a damaged file is
found on resume, which then continues from the previous generation.
"""

from __future__ import annotations

import io
import random
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize

from baselines import algos
from baselines.callbacks import LossLogger
from baselines.config import BaselineConfig
from tacbench import envs
from tacbench.runs import RunClock, checkpoints
from tacbench.runs.resume_checks import LogDigest
from tacbench.seeding import run_streams

REPLAY_FIELDS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def _rng_state(model: BaseAlgorithm) -> dict[str, Any]:
    # SB3 draws from the legacy global NumPy generator (replay sampling, action noise)
    kind, key, pos, has_gauss, cached = np.random.get_state(legacy=True)  # noqa: NPY002
    assert isinstance(key, np.ndarray)
    state = {
        "torch": torch.get_rng_state(),
        "numpy": [kind, torch.from_numpy(key.astype(np.int64)), pos, has_gauss, cached],
        "python": random.getstate(),
        "action_space": model.action_space.np_random.bit_generator.state,
    }
    if model.device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _set_rng_state(model: BaseAlgorithm, state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    kind, key, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((kind, key.numpy().astype(np.uint32), pos, has_gauss, cached))  # noqa: NPY002
    random.setstate(state["python"])
    model.action_space.np_random.bit_generator.state = state["action_space"]
    if "cuda" in state:
        torch.cuda.set_rng_state_all(state["cuda"])


def _statistics(venv: VecNormalize) -> tuple[RunningMeanStd, RunningMeanStd]:
    obs_rms, ret_rms = venv.obs_rms, venv.ret_rms
    assert isinstance(obs_rms, RunningMeanStd) and isinstance(ret_rms, RunningMeanStd)
    return obs_rms, ret_rms


def _normalizer_state(venv: VecEnv) -> dict[str, torch.Tensor] | None:
    if not isinstance(venv, VecNormalize):
        return None
    obs_rms, ret_rms = _statistics(venv)
    return {
        "obs_mean": torch.from_numpy(np.asarray(obs_rms.mean, dtype=np.float64)),
        "obs_var": torch.from_numpy(np.asarray(obs_rms.var, dtype=np.float64)),
        "obs_count": torch.tensor(float(obs_rms.count), dtype=torch.float64),
        "ret_mean": torch.from_numpy(np.asarray(ret_rms.mean, dtype=np.float64)),
        "ret_var": torch.from_numpy(np.asarray(ret_rms.var, dtype=np.float64)),
        "ret_count": torch.tensor(float(ret_rms.count), dtype=torch.float64),
        "returns": torch.from_numpy(np.asarray(venv.returns, dtype=np.float64)),
    }


def set_normalizer_state(venv: VecEnv, state: dict[str, torch.Tensor] | None) -> None:
    """Give ``venv`` (a VecNormalize when ``state`` is not None) the statistics of a
    checkpoint's ``normalize`` entry."""
    if state is None:
        return
    assert isinstance(venv, VecNormalize)
    obs_rms, ret_rms = _statistics(venv)
    obs_rms.mean, obs_rms.var = state["obs_mean"].numpy(), state["obs_var"].numpy()
    obs_rms.count = float(state["obs_count"])
    ret_rms.mean, ret_rms.var = state["ret_mean"].numpy(), state["ret_var"].numpy()
    ret_rms.count = float(state["ret_count"])
    venv.returns = state["returns"].numpy().copy()


def _replay_buffer(model: BaseAlgorithm) -> ReplayBuffer | None:
    buffer = getattr(model, "replay_buffer", None)
    return buffer if isinstance(buffer, ReplayBuffer) else None


def _chunk_end(path: Path) -> int:
    return int(path.stem.split("-")[1])


def save(
    directory: Path,
    step: int,
    since: int,
    model: BaseAlgorithm,
    dummy: DummyVecEnv,
    venv: VecEnv,
    losses: LossLogger,
    clock: RunClock,
    chunks: list[Path],
    logs: Mapping[str, LogDigest],
) -> list[Path]:
    """Write the checkpoint generation at ``step`` (``since``: the previous checkpoint's step, 0
    if none; ``chunks``: the replay chunks the previous generation lists; ``logs``: what the
    run's CSVs hold, for the manifest) and return the chunks this one lists."""
    buffer = _replay_buffer(model)
    listed = []
    if buffer is not None:
        replay = directory / "replay"
        replay.mkdir(exist_ok=True)
        listed = [c for c in chunks if _chunk_end(c) >= step - buffer.buffer_size]
        if step > since:
            start = max(since, step - buffer.buffer_size)
            positions = np.arange(start, step) % buffer.buffer_size
            fields = {name: getattr(buffer, name)[positions] for name in REPLAY_FIELDS}
            chunk = replay / f"{since:012d}-{step:012d}.npz"
            checkpoints.write_durably(chunk, lambda handle: np.savez(handle, start=start, **fields))
            listed.append(chunk)
    model_file = directory / f"model-{step:012d}.zip"
    checkpoints.write_durably(model_file, lambda handle: model.save(handle))  # type: ignore[arg-type]
    recorder = algos.recorder(dummy)
    state = {
        "step": step,
        "model": model_file.name,
        "rng": _rng_state(model),
        "env": envs.get_env_state(dummy.envs[0]),
        "episode": [recorder.episode_return, recorder.episode_length],
        "normalize": _normalizer_state(venv),
        "losses": losses.state(),
        "wall_s": clock.wall_s,
        "cpu_s": clock.cpu_s,
    }
    data = io.BytesIO()
    torch.save(state, data)
    state_file = directory / f"state-{step:012d}.pt"
    checkpoints.write_durably(state_file, lambda handle: handle.write(data.getbuffer()))
    checkpoints.commit(directory, step, [state_file, model_file, *listed], logs)
    return listed


def load(directory: Path) -> tuple[dict[str, Any] | None, list[Path], list[str]]:
    """The state of the newest intact checkpoint generation under ``directory``, the replay
    chunks it lists and notes on damaged generations passed over; ``(None, [], [])`` without
    a checkpoint. A TacbenchError when there are checkpoints but none is intact. Newer
    generations stay until the caller discards them (:func:`checkpoints.discard_after`), once
    the run's CSVs are checked."""
    step, notes = checkpoints.choose([directory])
    if step is None:
        return None, [], []
    state = torch.load(directory / f"state-{step:012d}.pt", weights_only=True)
    files = checkpoints.files_of(directory, step)
    return state, sorted(p for p in files if p.parent.name == "replay"), notes


def restore(
    config: BaselineConfig,
    directory: Path,
    state: dict[str, Any],
    chunks: list[Path],
    dummy: DummyVecEnv,
    venv: VecEnv,
    losses: LossLogger,
) -> BaseAlgorithm:
    """The model, its replay buffer (from the generation's ``chunks``), the environment and the
    generators as they were at the checkpoint ``state`` (from :func:`load`)."""
    step = int(state["step"])
    env = dummy.envs[0]
    env_seed = run_streams(config.seed).env_seed
    env.reset(seed=env_seed)
    set_normalizer_state(venv, state["normalize"])
    model = algos.ALGORITHMS[config.algo].load(
        directory / state["model"], env=venv, device=config.device, force_reset=False
    )
    if state["env"] is not None:
        envs.set_env_state(env, state["env"])
        recorder = algos.recorder(dummy)
        recorder.episode_return, recorder.episode_length = state["episode"]
    else:  # no exact env state (not MuJoCo): continue with a fresh episode, as TAC does
        venv.seed(env_seed + step)
        obs = venv.reset()
        assert isinstance(obs, np.ndarray)
        model._last_obs = obs
        model._last_episode_starts = np.ones((1,), dtype=bool)
    buffer = _replay_buffer(model)
    if buffer is not None:
        for chunk in chunks:
            with np.load(chunk) as data:
                start, count = int(data["start"]), len(data["rewards"])
                positions = np.arange(start, start + count) % buffer.buffer_size
                for name in REPLAY_FIELDS:
                    getattr(buffer, name)[positions] = data[name]
        buffer.pos, buffer.full = step % buffer.buffer_size, step >= buffer.buffer_size
    losses.load_state(state["losses"])
    _set_rng_state(model, state["rng"])
    return model
