"""The one place where tacbench chooses a trainer: TAC's (:mod:`tacbench.training`) or a
baseline's (the top-level ``baselines`` package, stable-baselines3 and sb3-contrib).

Both implement :class:`Trainer`: configs in, run directories and :class:`tacbench.runs.Outcome`
out; :func:`trainer_for` picks one. Everything heavy is imported when a function here runs,
so the CLI can import this module at start-up.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from baselines import ALGOS as BASELINES
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.members import make_run_configs

if TYPE_CHECKING:
    import numpy as np

    from baselines.config import BaselineConfig
    from tacbench.envs import EnvInfo
    from tacbench.interrupts import StopCheck
    from tacbench.runs import Outcome

    AnyConfig = RunConfig | BaselineConfig

ALGOS = ("tac", *BASELINES)


def make_configs(
    algo: str,
    env: str,
    task: str | None,
    seeds: Sequence[int],
    settings: Mapping[str, Any],
    *,
    qs: Sequence[float] = (),
    alphas: Sequence[float] = (),
    tac_settings_given: Mapping[str, Any] | None = None,
    hp: Sequence[str] = (),
) -> tuple[list[AnyConfig], list[str]]:
    """One config per member for ``algo`` on ``env`` (``task``: its paper name; TAC: the cross
    product of ``qs``, ``alphas`` and ``seeds``, empty ones the paper's) and notes on the
    defaults chosen. ``settings``: config fields (TAC's, or the run settings for a baseline).
    For a baseline, ``tac_settings_given`` (TAC settings the user gave, q and alpha included)
    become its hyperparameters where it has an equivalent, and ``hp`` holds ``KEY=VALUE``
    overrides of its table."""
    if algo == "tac":
        configs, notes = make_run_configs(env, task, seeds, qs, alphas, **settings)
        return list(configs), notes
    from baselines import config as baseline_config  # torch and SB3 only when this runs

    given = dict(tac_settings_given or {})
    overrides = tac_flags_for_baseline(algo, given)
    for item in hp:
        key = item.partition("=")[0].strip()
        flags = [
            f"--{name.replace('_', '-')} {value}"
            for name, value in given.items()
            if baseline_config.flag_key(algo, name) == key
        ]
        if flags:
            raise TacbenchError(
                f"--hp {item} sets {key}, which {' and '.join(flags)} set"
                f"{'s' if len(flags) == 1 else ''} too; give one of the two."
            )
    built, _, notes = baseline_config.make_configs(
        algo, env, task, seeds, [*overrides, *hp], **settings
    )
    return list(built), notes


class Trainer(Protocol):
    """What ``tacbench run`` and the sweep call to train runs: TAC's (:mod:`tacbench.training`)
    and the baselines' (``baselines.trainer``) implement it as a module-level ``train``."""

    def train(
        self,
        configs: Sequence[Any],
        out: Path,
        *,
        resume: bool = False,
        force: bool = False,
        quiet: bool = False,
        command: str = "",
        stop: StopCheck | None = None,
    ) -> list[Outcome]:
        """Train ``configs`` (one algorithm, one task, different seeds; for TAC the members of
        one group, which may also differ in q and alpha) into their run directories under
        ``out``, planned first (start, resume, skip or refuse:
        :func:`tacbench.runs.planned_runs`) and locked against other writers until it returns.

        ``stop`` is polled with the step count; when it, Ctrl-C or SIGTERM says stop, every run
        in progress is checkpointed and left "running", to be continued with ``resume=True``.
        Complete and failed runs are skipped unless ``force``. ``command`` is recorded in
        config.json. A full disk or an unwritable folder raises
        :class:`tacbench.runs.checkpoints.DiskError`; what was written up to the last checkpoint
        stays resumable. Returns one :class:`~tacbench.runs.Outcome` per run, by seed.
        """
        ...

    def policy(
        self, config_data: dict[str, Any], folder: Path, state: dict[str, Any]
    ) -> Callable[[np.ndarray], np.ndarray]:
        """The deterministic policy of a run whose ``config.json`` holds ``config_data`` and
        whose newest intact checkpoint (in ``folder``) holds ``state``: one observation in, one
        action in the env's units out (``tacbench video``)."""
        ...


def trainer_for(algo: str) -> Trainer:
    """The trainer of ``algo``: TAC's or the baselines' (imported only when asked for)."""
    if algo == "tac":
        from tacbench import training

        return training
    from baselines import trainer

    return trainer


def check_sizes(configs: Sequence[AnyConfig], info: EnvInfo) -> None:
    """Refuse, before anything is written, runs on the task ``info`` describes that would not
    fit this machine's memory or cores, as their trainer does when it starts: TAC's as one
    group, a baseline's one by one."""
    if configs[0].algo == "tac":
        from tacbench import training

        training.check_sizes(configs, info)  # type: ignore[arg-type]
        return
    from baselines import trainer

    for config in configs:
        trainer.check_sizes(config, info)  # type: ignore[arg-type]


def tac_flags_for_baseline(algo: str, given: Mapping[str, Any]) -> list[str]:
    """The one rule for TAC's flags on a baseline's runs, in ``tacbench run`` and ``tacbench
    sweep`` alike: a flag the baseline has an equivalent for becomes that hyperparameter, as an
    ``--hp`` item (``--learning-starts`` for the off-policy baselines; ``--alpha`` and
    ``--target-entropy`` for sac-sb3); any other is refused with a TacbenchError (exit 2)."""
    from baselines import config as baseline_config

    return baseline_config.flags_as_overrides(algo, given)
