"""Planning the run directories of one trainer call: where each run goes, and whether a new
command starts, resumes, skips or must refuse it, while it holds the directories' locks."""

from __future__ import annotations

import dataclasses
import os
import shutil
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args

from tacbench.config import RESULT_NEUTRAL_FIELDS
from tacbench.errors import TacbenchError, listing
from tacbench.interrupts import resume_command
from tacbench.runs import checkpoints
from tacbench.runs.files import CRASHED, RESTORE_OR_FORCE, State, ensure_writable, read_json
from tacbench.runs.locks import writing
from tacbench.runs.provenance import RunIdentity
from tacbench.runs.resume_checks import START_OVER


def run_directory(out: Path, algo: str, env: str, variant: str, seed: int) -> Path:
    """``<out>/runs/<algo>/<env>/<variant>/seed<seed>``."""
    return Path(out) / "runs" / algo / env / variant / f"seed{seed}"


def check_results_folder(out: Path) -> None:
    """Refuse an ``--out`` at or inside a run directory, or inside a results folder's ``runs/``
    tree (``runs/`` itself, an algorithm's or task's folder): the new runs would nest there,
    where a report of the folder above misses them, or loads them and sets the runs beside
    them aside as duplicates."""
    path = Path(os.path.abspath(out))
    for folder in (path, *path.parents):
        if folder.name.startswith("seed") and (folder / "config.json").is_file():
            raise TacbenchError(
                f"--out {out} is {'' if folder == path else 'inside '}the run directory "
                f"{folder}; give the results folder that holds its runs/ folder instead."
            )
        if folder.name == "runs" and next(folder.glob("*/*/*/seed*/config.json"), None):
            raise TacbenchError(
                f"--out {out} is {'' if folder == path else 'inside '}the runs/ folder of the "
                f"results folder {folder.parent}; give --out {folder.parent} (its runs go to "
                f"{folder}/<algo>/<env>/<variant>/seed<k>)."
            )


def differing_fields(
    old: Mapping[str, Any], new: Mapping[str, Any], ignore: Sequence[str] = ()
) -> list[str]:
    """``"name: old -> new"`` for every field that differs, ignoring the names in ``ignore``."""
    names = sorted((set(old) | set(new)) - set(ignore))
    return [
        f"{name}: {old.get(name, '(absent)')!r} -> {new.get(name, '(absent)')!r}"
        for name in names
        if old.get(name) != new.get(name)
    ]


def as_read_now(stored: Mapping[str, Any], config: Any) -> dict[str, Any]:
    """A run's stored config with each field of ``config``'s class that it lacks (a setting
    tacbench gained after the run was written) at the value its default takes beside
    ``config``'s other fields: a new setting's default keeps the behaviour before it, and the
    report reads an older config so too (:meth:`tacbench.config.RunConfig.from_dict`). A
    default that ``config``'s other fields refuse stays absent: the run differs."""
    filled = dict(stored)
    for field in dataclasses.fields(config):
        if field.name in filled or not field.init:
            continue
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            continue
        try:
            filled[field.name] = dataclasses.replace(config, **{field.name: default}).to_dict()[
                field.name
            ]
        except (TacbenchError, TypeError, ValueError):
            continue
    return filled


@dataclass(frozen=True)
class DirectoryPlan:
    """What to do with one run directory: start it, resume it, or skip it (with why)."""

    action: Literal["start", "resume", "skip"]
    message: str = ""
    failed: bool = False  # skipped because its status.json records a failure


def plan_run(
    directory: Path,
    config: Mapping[str, Any],
    *,
    resume: bool,
    force: bool,
    neutral: Sequence[str] = (),
    read_as: Any = None,
) -> DirectoryPlan:
    """Decide how a new command treats ``directory``; refuse (TacbenchError) when it must not
    touch it. Fields in ``neutral`` may differ between the stored config and the new one; with
    ``read_as`` (the new config object) a stored config's missing fields are read as its
    class's defaults (:func:`as_read_now`)."""
    check_resume_or_force(resume, force)
    _check_a_folder(directory)
    config_path = directory / "config.json"
    if force:
        return DirectoryPlan("start", "--force: starting over" if directory.exists() else "")
    if not config_path.exists():
        check_nothing_to_lose(directory)
        return DirectoryPlan("start")
    metadata = read_json(config_path)
    stored = metadata.get("config")
    if not isinstance(stored, dict):
        raise TacbenchError(f"{config_path} holds no run config; {RESTORE_OR_FORCE}.")
    if read_as is not None:
        stored = as_read_now(stored, read_as)
    differences = differing_fields(stored, config, neutral)
    if differences:
        recorded = metadata.get("command")
        command = recorded if isinstance(recorded, str) else ""
        how = {"tacbench run": "repeat its own command", "tacbench sweep": "run its sweep again"}
        made_by = how.get(" ".join(command.split()[:2]))
        again = (  # a setting left out of the resume, such as --steps
            f"To continue it, {made_by}: {resume_command(command, directory.parents[4])}; or pass "
            if resume and made_by and unfinished(directory)
            else "Pass "
        )
        raise TacbenchError(
            f"{directory} holds a run with another config ({'; '.join(differences)}). "
            f"{again}--force to replace it, or --out to write somewhere else."
        )
    status = read_status(directory)
    step = status["step"]
    if status.get("state") == "complete":
        return DirectoryPlan("skip", f"already complete ({step} steps); --force retrains it")
    if status.get("state") == "failed":
        reason = str(status.get("reason", ""))
        crashed = resumable(status)
        if crashed and resume:
            check_checkpoint(directory, step)
            return DirectoryPlan("resume", "resuming a crashed run from its last checkpoint")
        again = "--resume continues it, --force retrains it" if crashed else "--force retrains it"
        return DirectoryPlan("skip", f"failed at step {step}: {reason}; {again}", failed=True)
    if not resume:
        raise TacbenchError(
            f"{directory} holds an unfinished run (step {step}). Add --resume to continue it, "
            "or --force to start over."
        )
    check_checkpoint(directory, step)
    return DirectoryPlan("resume", "resuming from its last checkpoint")


def unfinished(directory: Path) -> bool:
    """Whether ``--resume`` would continue the run in ``directory`` (False where its status
    cannot be read: the refusal that names it says so)."""
    try:
        return resumable(read_status(directory))
    except (TacbenchError, OSError):
        return False


def resumable(status: Mapping[str, Any]) -> bool:
    """Whether ``--resume`` continues a run whose status.json holds ``status``: neither complete
    nor failed, or failed by a crash (not by its own numbers, which would fail again)."""
    crashed = str(status.get("reason", "")).startswith(CRASHED)
    return status.get("state") not in ("complete", "failed") or crashed


def read_status(directory: Path) -> dict[str, Any]:
    """The status.json of a run directory that has a config.json, its step checked; a run
    without one that has written no rows yet is ``running`` at step 0. TacbenchError, saying
    what to do, for a damaged status.json, or one missing under rows already written."""
    status_path = directory / "status.json"
    if not status_path.exists():
        _check_no_rows(directory)
    status: dict[str, Any] = (
        read_json(status_path) if status_path.exists() else {"state": "running", "step": 0}
    )
    step = status.get("step", 0)
    if not isinstance(step, int) or isinstance(step, bool) or step < 0:
        raise TacbenchError(
            f"{status_path} records the step {step!r}, not a step count; {RESTORE_OR_FORCE}."
        )
    if status.get("state") not in get_args(State):  # else resumed as if running
        raise TacbenchError(
            f"{status_path} records the state {status.get('state')!r}, not one of "
            f"{', '.join(get_args(State))}; {RESTORE_OR_FORCE}."
        )
    return {**status, "step": step}


def check_resume_or_force(resume: bool, force: bool) -> None:
    """Refuse ``--resume`` together with ``--force``, which contradict each other."""
    if resume and force:
        raise TacbenchError(
            "--resume continues a run and --force deletes it to start over: pass one of them."
        )


def _check_a_folder(directory: Path) -> None:
    """Refuse a run directory's path that holds a file or a link: starting afresh would delete
    what is there (or fail half-way), and no run lives in it."""
    if directory.is_symlink() or (directory.exists() and not directory.is_dir()):
        what = "a link" if directory.is_symlink() else "a file"
        raise TacbenchError(
            f"{directory} is {what}, where this run's directory goes; nothing was changed. Move "
            "it away, or write the runs somewhere else with --out."
        )


def check_nothing_to_lose(directory: Path) -> None:
    """Refuse (TacbenchError) a run directory without config.json where starting afresh would
    delete something: a file or link in its place, or anything in it but the temporary file of
    a write a crash cut short (``*.tmp``). A run writes config.json before anything else, so
    what is there is not a run's, or its config.json was lost."""
    _check_a_folder(directory)
    if not directory.is_dir():
        return
    found = sorted(p.name for p in directory.iterdir() if not p.name.endswith(".tmp"))
    if found:
        listed = listing(found, shown=3)
        raise TacbenchError(
            f"{directory} holds {listed} but no config.json, so it is not a run this command "
            f"can resume or replace; nothing was changed. Restore its config.json, or "
            f"{START_OVER}."
        )


def check_checkpoint(directory: Path, step: int) -> None:
    """Refuse to resume a run whose status.json records progress (``step``) that no checkpoint
    holds: it would start over from step 0 under the rows already written."""
    checkpoint = directory / "checkpoint"
    if step and checkpoints.newest_step(checkpoint) is None:
        what = "is a file" if checkpoint.is_file() else "holds no checkpoint"
        raise TacbenchError(
            f"cannot resume {directory}: status.json records step {step}, but {checkpoint} "
            f"{what}; nothing was changed. Restore the checkpoint, or {START_OVER}."
        )


def _check_no_rows(directory: Path) -> None:
    """Refuse a run directory without status.json whose CSVs hold rows: a run writes its
    status before any row, so its progress is unknown and starting over would lose them."""
    for name in ("eval.csv", "train.csv", "losses.csv"):
        path = directory / name
        if path.exists() and len(path.read_bytes().splitlines()) > 1:
            raise TacbenchError(
                f"{directory} has rows in {name} but no status.json, so its progress is unknown; "
                f"nothing was changed. Restore status.json, or {START_OVER}."
            )


@dataclass(frozen=True)
class Outcome:
    """How one run ended in this call."""

    seed: int
    directory: Path
    state: str  # "complete", "failed", "interrupted" or "skipped"
    step: int
    message: str = ""


Config = TypeVar("Config", bound=RunIdentity)  # what planning needs of a TAC or baseline config


def plan_runs(
    configs: Sequence[Config], out: Path, *, resume: bool, force: bool
) -> tuple[list[Outcome], list[tuple[Config, Path]]]:
    """Plan each config's run directory under ``out`` (:func:`plan_run`: start,
    resume, skip or refuse with a clear error) before anything is trained. Returns the skipped
    runs' outcomes and the runs to train with their directories; a directory that starts afresh
    (``force``, or nothing worth resuming in it) is emptied here, once every run is planned, so
    that a refusal changes nothing."""
    ensure_writable(Path(out))
    skipped, active = [], []
    for config in configs:
        directory = run_directory(out, config.algo, config.env, config.variant, config.seed)
        plan = plan_run(
            directory,
            config.to_dict(),
            resume=resume,
            force=force,
            neutral=RESULT_NEUTRAL_FIELDS,
            read_as=config,
        )
        if plan.action == "skip":  # a run failed before is still failed: the exit status says so
            state, message = (
                ("failed", f"skipped: {plan.message}") if plan.failed else ("skipped", plan.message)
            )
            skipped.append(Outcome(config.seed, directory, state, -1, message))
            continue
        active.append((config, directory, plan.action))
    for _, directory, action in active:
        if action == "start" and directory.exists():
            shutil.rmtree(directory)
    return skipped, [(config, directory) for config, directory, _ in active]


@contextmanager
def planned_runs(
    configs: Sequence[Config], out: Path, *, resume: bool, force: bool
) -> Iterator[tuple[list[Outcome], list[tuple[Config, Path]]]]:
    """:func:`plan_runs`, holding the lock of every run directory (:func:`locks.writing`) from
    before the plan to the end of the block, so that no other process writes them meanwhile."""
    check_resume_or_force(resume, force)
    check_results_folder(out)
    ensure_writable(Path(out))
    directories = [run_directory(out, c.algo, c.env, c.variant, c.seed) for c in configs]
    with writing(directories):
        yield plan_runs(configs, out, resume=resume, force=force)
