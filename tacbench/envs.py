"""The task suite, environment creation and checks, exact env state for resume, and evaluation.

The paper's six MuJoCo tasks and their Gymnasium ids are :data:`tacbench.paper.ENV_IDS`; any
other registered Gymnasium environment with a bounded, flat ``Box`` action space works too.

No torch here: the evaluation protocol (:func:`evaluate`) takes any policy callable, so the
baselines use it as TAC does.
"""

from __future__ import annotations

import difflib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import numpy.typing as npt
from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

from tacbench.errors import TacbenchError
from tacbench.paper import DEFAULT_SUITE, ENV_IDS, SUITES, paper_task, suite_task

FloatArray = npt.NDArray[np.float64]
Policy = Callable[[FloatArray], FloatArray]


@dataclass(frozen=True)
class EnvInfo:
    """What a learner needs to know about a task."""

    env_id: str
    task: str | None  # the paper's name for it, None if the paper did not run it
    obs_dim: int
    act_dim: int
    low: tuple[float, ...]
    high: tuple[float, ...]
    max_episode_steps: int


def resolve_env_id(name: str) -> str:
    """A Gymnasium id for ``name``: a paper task name (``Ant``) or any registered id.

    Unknown names raise :class:`TacbenchError` listing the suite and the closest registered ids.
    """
    task = suite_task(name)
    if task is not None:
        return ENV_IDS[task]
    if name in gym.registry:
        return name
    # ids registered with a module path: Gymnasium's moved ones (MuJoCo v2 and v3) register a
    # function that only raises, and are no use as a suggestion
    usable = [env_id for env_id, spec in gym.registry.items() if isinstance(spec.entry_point, str)]
    close = difflib.get_close_matches(name, [*ENV_IDS, *usable], n=4, cutoff=0.5)
    suite = ", ".join(f"{task} ({env_id})" for task, env_id in ENV_IDS.items())
    hint = f" Closest registered names: {', '.join(close)}." if close else ""
    raise TacbenchError(
        f"unknown environment {name!r}.{hint} The paper's suite: {suite}. "
        "`tacbench envs` lists it; any registered continuous-action Gymnasium id also works."
    )


# evaluation envs kept per member (about 1.1 MB each for the MuJoCo tasks): the reference code's
# 10 episodes run at once, more run in waves of this many, so memory does not grow with
# --eval-episodes
EVAL_POOL = 10
# from this many envs on, a run says it is making them (member_envs): about 5 s at 4-5 ms each
# (Hopper, HalfCheetah, Ant and Humanoid on the AMD EPYC AVX2 class)
MANY_ENVS = 1_000

# MuJoCo 4 deprecates the compiler attribute that Gymnasium's v4 HalfCheetah model sets; the
# attribute still works and the suite keeps v4 on purpose (module docstring)
_SILENCED_MUJOCO_WARNINGS = ("compiler attribute 'settotalmass' is deprecated",)


def _mujoco_warning(message: str) -> None:
    """MuJoCo's warning handler: a Python warning (shown on the console once per message),
    instead of MuJoCo's default of printing it and appending it to ``MUJOCO_LOG.TXT`` in the
    working folder; the deprecations in :data:`_SILENCED_MUJOCO_WARNINGS` are dropped."""
    if not message.startswith(_SILENCED_MUJOCO_WARNINGS):
        warnings.warn(f"MuJoCo: {message}", RuntimeWarning, stacklevel=1)


def quiet_mujoco() -> None:
    """Route MuJoCo's warnings through :func:`_mujoco_warning` (idempotent; leaves a handler that
    someone else installed alone). Changes no simulation: only where warnings go."""
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_mujoco_warning)


def make_env(env_id: str, **make_kwargs: Any) -> gym.Env[Any, Any]:
    """Create ``env_id`` (``make_kwargs`` go to ``gym.make``, e.g. ``render_mode``); check that
    TAC can drive it (bounded flat Box actions, a time limit)."""
    quiet_mujoco()
    try:
        with warnings.catch_warnings():  # v4 is the suite's deliberate choice (module docstring)
            warnings.filterwarnings("ignore", message=".*is out of date.*")
            env = gym.make(env_id, **make_kwargs)
    except (ImportError, gym.error.Error) as err:
        alternative = ENV_IDS.get(paper_task(env_id) or "", "")
        hint = f" Use {alternative} instead." if alternative and alternative != env_id else ""
        raise TacbenchError(f"cannot create {env_id}: {str(err).rstrip('.')}.{hint}") from None
    action_space, obs_space = env.action_space, env.observation_space
    if not isinstance(action_space, gym.spaces.Box):
        env.close()
        raise TacbenchError(
            f"{env_id} has a {type(action_space).__name__} action space; TAC needs continuous "
            "(Box) actions. Pick a continuous-control task, e.g. from `tacbench envs`."
        )
    if (
        len(action_space.shape) != 1
        or not np.all(np.isfinite(action_space.low))
        or not np.all(np.isfinite(action_space.high))
    ):
        env.close()
        raise TacbenchError(f"{env_id}: TAC needs a flat action Box with finite bounds.")
    if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) != 1:
        env.close()
        raise TacbenchError(f"{env_id}: TAC needs a flat Box observation space.")
    if env.spec is None or env.spec.max_episode_steps is None:
        env.close()
        raise TacbenchError(f"{env_id} has no time limit; register it with max_episode_steps.")
    return env


def env_info(env_id: str) -> EnvInfo:
    """Check ``env_id`` (see :func:`make_env`) and describe it."""
    env = make_env(env_id)
    space = env.action_space
    assert isinstance(space, gym.spaces.Box) and env.spec and env.spec.max_episode_steps
    info = EnvInfo(
        env_id=env_id,
        task=paper_task(env_id),
        obs_dim=int(np.prod(env.observation_space.shape or (1,))),
        act_dim=int(space.shape[0]),
        low=tuple(float(x) for x in space.low),
        high=tuple(float(x) for x in space.high),
        max_episode_steps=int(env.spec.max_episode_steps),
    )
    env.close()
    return info


def to_env_action(squashed: npt.ArrayLike, info: EnvInfo) -> FloatArray:
    """Map actions in [-1, 1] (tanh output) affinely onto the env's bounds [low, high]."""
    low, high = np.asarray(info.low), np.asarray(info.high)
    return low + (np.asarray(squashed, dtype=np.float64) + 1.0) * 0.5 * (high - low)


def suite_table(suite: str = DEFAULT_SUITE) -> list[dict[str, Any]]:
    """One row per paper task of ``suite`` (:data:`tacbench.paper.SUITES`): its id, sizes,
    episode limit and whether it loads here."""
    rows = []
    for task, env_id in SUITES[suite].items():
        row: dict[str, Any] = {"task": task, "env": env_id}
        try:
            info = env_info(env_id)
            row.update(obs=info.obs_dim, act=info.act_dim, limit=info.max_episode_steps, ok="yes")
        except TacbenchError as err:
            row.update(obs="-", act="-", limit="-", ok=f"no: {err}")
        rows.append(row)
    return rows


# --- exact state for resume -----------------------------------------------------------------


def _time_limit(env: gym.Env[Any, Any]) -> Any:
    wrapper: Any = env
    while not isinstance(wrapper, gym.wrappers.TimeLimit):
        wrapper = wrapper.env
    return wrapper


# The kinematics MuJoCo computed at the start of the last physics step (mj_kinematics and
# mj_comPos), which envs read before they step: Ant's torso (xpos) and Humanoid's centre of mass
# (xipos) for the reward. mj_setState restores none of them, and mj_forward would compute them
# for the state after the step, not before it, so they are kept as they were.
KINEMATICS = (
    "xpos", "xquat", "xmat", "xipos", "ximat", "geom_xpos", "geom_xmat", "site_xpos",
    "site_xmat", "subtree_com",
)  # fmt: skip


def get_env_state(env: gym.Env[Any, Any]) -> dict[str, Any] | None:
    """Everything needed to continue ``env`` bit-exactly, or None when it cannot be captured.

    For MuJoCo tasks: the simulator's integration state (positions, velocities, actuator state,
    solver warm start, time), the kinematics of :data:`KINEMATICS`, the env's random generator
    and the time-limit counter.
    """
    base = env.unwrapped
    if not isinstance(base, MujocoEnv):
        return None
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    physics = np.empty(mujoco.mj_stateSize(base.model, spec))
    mujoco.mj_getState(base.model, base.data, physics, spec)
    return {
        "physics": physics.tolist(),
        "kinematics": {name: getattr(base.data, name).tolist() for name in KINEMATICS},
        "np_random": base.np_random.bit_generator.state,
        "elapsed_steps": int(_time_limit(env)._elapsed_steps),
    }


def set_env_state(env: gym.Env[Any, Any], state: dict[str, Any]) -> None:
    """Restore a state from :func:`get_env_state` into an env of the same id that was reset (a
    state saved before the kinematics were kept restores without them, as it did then)."""
    base = env.unwrapped
    assert isinstance(base, MujocoEnv)
    physics = np.asarray(state["physics"], dtype=np.float64)
    mujoco.mj_setState(base.model, base.data, physics, mujoco.mjtState.mjSTATE_INTEGRATION)
    for name, values in state.get("kinematics", {}).items():
        field = getattr(base.data, name)
        field[...] = np.asarray(values, dtype=np.float64).reshape(field.shape)
    base.np_random.bit_generator.state = state["np_random"]
    _time_limit(env)._elapsed_steps = state["elapsed_steps"]


# --- evaluation protocol (reference code: deterministic episodes on separate env instances) ---


def eval_seeds(seed: int, step: int, n: int) -> list[int]:
    """Episode seeds for the evaluation at ``step`` of the run with ``seed``: distinct per
    evaluation, independent of the training env and of any other run."""
    sequence = np.random.SeedSequence([seed, step, 0x5EED])
    return [int(s) for s in sequence.generate_state(n, dtype=np.uint32)]


def eval_pool_size(episodes: int) -> int:
    """How many evaluation envs a run keeps for ``episodes`` episodes per evaluation: one per
    episode up to :data:`EVAL_POOL`, then the pool is reused in waves (:func:`waves`)."""
    return min(episodes, EVAL_POOL)


def member_envs(
    env_id: str, members: int, eval_episodes: int, say: Callable[[str], object]
) -> tuple[list[gym.Env[Any, Any]], list[list[gym.Env[Any, Any]]]]:
    """Each member's training env and, where ``eval_episodes`` > 0, its pool of evaluation envs
    (:func:`eval_pool_size`; none at all without evaluation). Each takes a few milliseconds (a
    MuJoCo task parses its model), so where they are :data:`MANY_ENVS` or more, ``say`` is told
    first: a thousand members' start-up is otherwise a minute of silence."""
    pool = eval_pool_size(eval_episodes)
    if members * (1 + pool) >= MANY_ENVS:
        say(f"making {members * (1 + pool):,} {env_id} environments ({1 + pool} per member) ...")
    training = [make_env(env_id) for _ in range(members)]
    evaluation = [[make_env(env_id) for _ in range(pool)] for _ in range(members if pool else 0)]
    return training, evaluation


def waves(episodes: int, pool: int) -> list[slice]:
    """The episodes of one evaluation in waves of at most ``pool``, in order."""
    return [slice(start, min(start + pool, episodes)) for start in range(0, episodes, pool)]


def evaluate_members(
    policy: Policy, pools: Sequence[Sequence[gym.Env[Any, Any]]], seeds: Sequence[Sequence[int]]
) -> tuple[FloatArray, FloatArray]:
    """Member m's episodes (one per seed of ``seeds[m]``) on its ``pools[m]`` of envs, in waves
    (:func:`waves`), every member's wave at once: ``policy`` gets the wave's rows member by
    member. Returns ``(members, episodes)`` returns and lengths."""
    members, episodes = len(seeds), len(seeds[0])
    returns, lengths = np.zeros((members, episodes)), np.zeros((members, episodes))
    for wave in waves(episodes, min(len(pool) for pool in pools)):
        width = wave.stop - wave.start
        returns[:, wave], lengths[:, wave] = (
            result.reshape(members, width)
            for result in evaluate(
                policy,
                [env for pool in pools for env in pool[:width]],
                [int(s) for member in seeds for s in member[wave]],
            )
        )
    return returns, lengths


def evaluate(
    policy: Policy, envs: Sequence[gym.Env[Any, Any]], seeds: Sequence[int]
) -> tuple[FloatArray, FloatArray]:
    """One episode on each of ``envs``, reset with its seed, all stepped in lockstep (more
    episodes than envs: :func:`evaluate_members`, in waves).

    ``policy`` maps an ``(n, obs_dim)`` array (one row per env, finished ones included) to
    ``(n, act_dim)`` actions in the env's units; it should be deterministic. Returns the
    episode returns and lengths. The envs are evaluation-only instances: training is unaffected.
    """
    if len(envs) != len(seeds):
        raise ValueError("evaluate needs one seed per env")
    obs = np.stack(
        [
            np.asarray(env.reset(seed=int(s))[0], dtype=np.float64)
            for env, s in zip(envs, seeds, strict=True)
        ]
    )
    returns = np.zeros(len(envs))
    lengths = np.zeros(len(envs))
    active = np.ones(len(envs), dtype=bool)
    while active.any():
        actions = policy(obs)
        for i in np.flatnonzero(active).tolist():
            next_obs, reward, terminated, truncated, _ = envs[i].step(actions[i])
            obs[i] = next_obs
            returns[i] += float(reward)
            lengths[i] += 1
            active[i] = not (terminated or truncated)
    return returns, lengths
