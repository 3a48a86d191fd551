"""The one place where tacbench chooses a trainer: TAC's (:mod:`tacbench.training`) or a
baseline's (the top-level ``baselines`` package, stable-baselines3 and sb3-contrib).

Both trainers have the same interface: configs in, run directories and
:class:`tacbench.runs.Outcome` out. Everything heavy is imported when a function here runs,
so the CLI can import this module at start-up.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from baselines import ALGOS as BASELINES
from tacbench.config import RunConfig, RunSettings
from tacbench.members import make_run_configs
from tacbench.settings import settings_of

if TYPE_CHECKING:
    from baselines.config import BaselineConfig
    from tacbench.interrupts import StopCheck
    from tacbench.runs import Outcome

    AnyConfig = RunConfig | BaselineConfig

ALGOS = ("tac", *BASELINES)
# TAC's settings that a baseline does not have (``tacbench run --algo td3 --lnq joint`` is
# refused, or mapped to the baseline's hyperparameter where there is one)
TAC_ONLY = tuple(name for name in settings_of(RunConfig) if name not in settings_of(RunSettings))


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

    overrides = baseline_config.flags_as_overrides(algo, tac_settings_given or {})
    built, _, notes = baseline_config.make_configs(
        algo, env, task, seeds, [*overrides, *hp], **settings
    )
    return list(built), notes


def train(
    configs: Sequence[AnyConfig],
    out: Path,
    *,
    resume: bool = False,
    force: bool = False,
    quiet: bool = False,
    command: str = "",
    stop: StopCheck | None = None,
) -> list[Outcome]:
    """Train ``configs`` (one algorithm, one task) with their algorithm's trainer."""
    kwargs: dict[str, Any] = {
        "resume": resume,
        "force": force,
        "quiet": quiet,
        "command": command,
        "stop": stop,
    }
    if all(isinstance(c, RunConfig) for c in configs):
        from tacbench import training

        return training.train([c for c in configs if isinstance(c, RunConfig)], out, **kwargs)
    from baselines import trainer
    from baselines.config import BaselineConfig

    return trainer.train([c for c in configs if isinstance(c, BaselineConfig)], out, **kwargs)
