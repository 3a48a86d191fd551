"""Provenance, manifests and runs shared by the tiers.

Each tier's reference directory holds a ``manifest.json``: the tier, the command that
regenerates it, when and from which commit it was made, the library versions and platform, and
what each reference run was (its exact command). The exact tier keeps one such directory per
CPU class (``exact/<cpu class>/``, :func:`tacbench.hardware.cpu_class`), because the last
digits differ between CPUs; the other tiers have one. :class:`Runner` runs one recorded
``tacbench run`` command as a user would type it.
"""

from __future__ import annotations

import importlib.metadata
import math
import platform
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tacbench import runs
from tacbench.errors import TacbenchError, listing
from tacbench.hardware import cpu_class
from tacbench.interrupts import STOP_SIGNALS

FORMAT = 1  # the manifest layout; a reader refuses another
RECORDED_PACKAGES = ("torch", "numpy", "gymnasium", "mujoco", "stable_baselines3", "sb3_contrib")
MANIFEST = "manifest.json"
CLOCKS = ("wall_s", "cpu_s")  # the run's wall and CPU seconds (runs.RunClock)


def environment() -> dict[str, Any]:
    """What must be equal for a run to reproduce a reference to the last digit: the library
    versions, the operating system, the CPU architecture, the CPU instruction set that
    torch's kernels dispatch on and the CPU class (both change float rounding)."""
    import torch

    versions: dict[str, str | None] = {"python": platform.python_version()}
    for package in RECORDED_PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package.replace("_", "-"))
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    return {
        "versions": versions,
        "system": platform.system(),
        "machine": platform.machine(),
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "cpu": cpu_class(),
    }


def environment_differences(recorded: Mapping[str, Any], current: Mapping[str, Any]) -> list[str]:
    """``"torch 2.3.0 recorded, 2.4.0 here"`` for each entry that differs."""
    flat = {
        **recorded.get("versions", {}),
        **{k: v for k, v in recorded.items() if k != "versions"},
    }
    here = {**current.get("versions", {}), **{k: v for k, v in current.items() if k != "versions"}}
    return [
        f"{name} {flat.get(name)} recorded, {here.get(name)} here"
        for name in sorted(set(flat) | set(here))
        if flat.get(name) != here.get(name)
    ]


def regenerate_command(tier: str, reference: Path) -> str:
    """The command that rewrites ``tier``'s references under ``reference``."""
    return shlex.join(
        ["tacbench", "regress", "--update", "--tier", tier, "--against", str(reference)]
    )


def provenance(tier: str, reference: Path) -> dict[str, Any]:
    """A manifest's header: tier, format, regeneration command, date, commit, environment."""
    return {
        "tier": tier,
        "format": FORMAT,
        "regenerate": regenerate_command(tier, reference),
        "created": runs.now_iso(),
        "git_commit": runs.git_commit(),
        "platform": platform.platform(),
        "environment": environment(),
    }


def write_manifest(directory: Path, manifest: Mapping[str, Any]) -> None:
    """``<directory>/manifest.json``, written atomically."""
    runs.atomic_write_json(directory / MANIFEST, manifest)


def tier_directory(reference: Path, tier: str, cpu: str | None = None) -> Path:
    """Where ``tier``'s references live: ``<reference>/exact/<cpu class>`` for the exact tier
    (``cpu``, this machine's class by default), ``<reference>/<tier>`` for the others."""
    return reference / tier / (cpu or cpu_class()) if tier == "exact" else reference / tier


def recorded_cpu_classes(reference: Path) -> list[str]:
    """The CPU classes that have exact references under ``reference``."""
    root = reference / "exact"
    return sorted(p.parent.name for p in root.glob(f"*/{MANIFEST}")) if root.is_dir() else []


# what each tier's manifest must hold: its lists (of entries with a name, or of file names)
# never empty, so that a check can never pass having compared nothing; alpha a level in (0, 1);
# the provenance every check prints (provenance_note)
_PROVENANCE = {"created": "text", "git_commit": "text", "regenerate": "text"}
CONTENTS: dict[str, dict[str, str]] = {
    "exact": {"runs": "named entries", "files": "names", "environment": "versions", **_PROVENANCE},
    "theory": {"files": "names", "environment": "versions", **_PROVENANCE},
    "stat": {
        "groups": "named entries",
        "alpha": "number",
        "last": "count",
        "test": "text",
        "environment": "versions",
        **_PROVENANCE,
    },
}


# what each entry of a manifest's list must hold, besides its name: what a check reads
ENTRY_FIELDS: dict[str, dict[str, type]] = {
    "runs": {"args": list, "config": dict, "state": str, "step": int},
    "groups": {"args": list, "check_seeds": list, "scores": dict},
}


def _entry_problems(manifest: Mapping[str, Any]) -> list[str]:
    """``"<name> lacks 'args'"`` for each manifest entry lacking a field a check reads, or
    holding it as the wrong kind; a statistical group needs two check seeds and two recorded
    scores at least, or its test compares nothing."""
    problems = []
    for key, fields in ENTRY_FIELDS.items():
        for entry in manifest.get(key) or ():
            wrong = [f for f, kind in fields.items() if not isinstance(entry.get(f), kind)]
            if key == "groups" and not wrong:
                wrong = [f for f in ("check_seeds", "scores") if not _two_of(entry[f])]
            if wrong:
                problems.append(f"{entry['name']!r} lacks {', '.join(map(repr, wrong))}")
    return problems


def _two_of(values: Any) -> bool:
    """Whether ``values`` (a list of seeds, or scores by seed) holds two distinct seeds or two
    finite scores at least."""
    if isinstance(values, dict):
        numbers = [v for v in values.values() if _number(v) and math.isfinite(v)]
        return len(numbers) == len(values) >= 2
    return all(_number(v) and isinstance(v, int) for v in values) and len(set(values)) >= 2


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _holds(value: Any, kind: str) -> bool:
    if kind == "text":
        return isinstance(value, str) and bool(value)
    if kind == "versions":
        return isinstance(value, dict) and isinstance(value.get("versions"), dict)
    if kind == "number":
        return _number(value) and 0 < value < 1
    if kind == "count":
        return isinstance(value, int) and not isinstance(value, bool) and value > 0
    if not isinstance(value, list) or not value:
        return False
    if kind == "names":
        return all(isinstance(item, str) and item for item in value)
    return all(isinstance(item, dict) and isinstance(item.get("name"), str) for item in value)


def read_manifest(reference: Path, tier: str, cpu: str | None = None) -> dict[str, Any]:
    """The manifest of ``tier`` under ``reference`` (the exact tier's for CPU class ``cpu``,
    this machine's by default); a TacbenchError says how to create it."""
    path = tier_directory(reference, tier, cpu) / MANIFEST
    if not path.is_file() and not any((reference / name).is_dir() for name in CONTENTS):
        raise TacbenchError(
            f"{reference} holds no references (no exact/, theory/ or stat/ folder): --against "
            "names the references folder (results/reference). To record new references there "
            f"on purpose: {regenerate_command(tier, reference)}"
        )
    if not path.is_file():
        raise TacbenchError(
            f"no {tier} references at {path.parent}; create them with: "
            f"{regenerate_command(tier, reference)}"
        )
    manifest = runs.read_json(
        path, f"restore it from git, or regenerate it with: {regenerate_command(tier, reference)}"
    )
    if manifest.get("tier") != tier or manifest.get("format") != FORMAT:
        raise TacbenchError(
            f"{path} is not a format-{FORMAT} {tier} manifest; regenerate it with: "
            f"{regenerate_command(tier, reference)}"
        )
    damaged = [key for key, kind in CONTENTS[tier].items() if not _holds(manifest.get(key), kind)]
    if damaged:
        raise TacbenchError(
            f"{path} is damaged: {', '.join(map(repr, damaged))} missing, empty or of the wrong "
            f"kind; restore it from git, or regenerate it with: "
            f"{regenerate_command(tier, reference)}"
        )
    problems = _entry_problems(manifest)
    if problems:
        raise TacbenchError(
            f"{path} is damaged: {'; '.join(problems)} (or of the wrong kind); restore it from "
            f"git, or regenerate it with: {regenerate_command(tier, reference)}"
        )
    return manifest


def require_files(paths: Sequence[Path], tier: str, reference: Path) -> None:
    """A TacbenchError, before anything is trained, when reference files that ``tier``'s
    manifest lists are missing or cannot be read as text."""
    missing = [str(path) for path in paths if not path.is_file()]
    if missing:
        raise TacbenchError(
            f"the {tier} references lack {listing(missing, 3)}, which their manifest lists; "
            f"restore them from git, or regenerate them with: {regenerate_command(tier, reference)}"
        )
    for path in paths:
        try:
            path.read_bytes().decode()
        except (OSError, UnicodeDecodeError) as err:
            raise TacbenchError(
                f"the {tier} reference {path} cannot be read as text ({err}); restore it from "
                f"git, or regenerate it with: {regenerate_command(tier, reference)}"
            ) from None


def select(entries: list[dict[str, Any]], names: Sequence[str], reference: Path) -> list[Any]:
    """The manifest entries named in ``names`` (all of them when it is empty)."""
    known = list(dict.fromkeys(e["name"] for e in entries))  # each once: several CPU classes
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise TacbenchError(
            f"no reference named {', '.join(unknown)} under {reference}; known: {', '.join(known)}"
        )
    return [e for e in entries if not names or e["name"] in names]


def provenance_note(manifest: dict[str, Any]) -> str:
    """One line: when, at which commit and with which versions a reference was made."""
    versions = ", ".join(f"{k} {v}" for k, v in manifest["environment"]["versions"].items())
    return (
        f"recorded {manifest['created']} at commit {manifest['git_commit']} with {versions}; "
        f"regenerate: {manifest['regenerate']}"
    )


def check_replaceable(reference: Path, tier: str) -> None:
    """A TacbenchError when :func:`tier_directory` exists but holds no manifest: not
    references, and :func:`publish` would delete it."""
    target = tier_directory(reference, tier)
    if target.exists() and not (target / MANIFEST).is_file():
        raise TacbenchError(
            f"{target} holds no {tier} references (no {MANIFEST}), and --update would replace "
            f"it: is --against {reference} the references folder (results/reference)? Move "
            f"{target} away, or give another --against."
        )


@contextmanager
def staged(reference: Path, tier: str) -> Iterator[Path]:
    """An empty ``.<name>.new`` beside :func:`tier_directory` to build the new references in
    (:func:`publish` puts it in place); deleted if the block fails or is interrupted, so that
    the references stay as they were, with nothing half-built beside them."""
    check_replaceable(reference, tier)
    target = tier_directory(reference, tier)
    staging = target.parent / f".{target.name}.new"
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    try:
        yield staging
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def publish(staging: Path, manifest: Mapping[str, Any], reference: Path, tier: str) -> Path:
    """Write ``manifest`` into ``staging`` (:func:`staged`), then put ``staging`` where
    :func:`tier_directory` was (same parent, so the rename is cheap); returns the new
    manifest's path. The exact tier's other CPU classes are left as they are."""
    check_replaceable(reference, tier)
    write_manifest(staging, manifest)
    target = tier_directory(reference, tier)
    old = target.parent / f".{target.name}.old"  # the references replaced, until the swap is done
    if old.exists():
        shutil.rmtree(old)
    if target.exists():
        target.rename(old)
    try:
        staging.rename(target)
    except BaseException:
        if old.exists() and not target.exists():
            old.rename(target)  # the swap failed: the references stay as they were
        raise
    shutil.rmtree(old, ignore_errors=True)
    return target / MANIFEST


def without_clocks(text: str) -> str:
    """A CSV's text with its :data:`CLOCKS` columns removed (the only columns that are not
    deterministic); every other character is kept."""
    lines = text.splitlines()
    header = lines[0].split(",") if lines else []
    cols = {header.index(name) for name in CLOCKS if name in header}
    if not cols:
        return text
    kept = [",".join(v for i, v in enumerate(line.split(",")) if i not in cols) for line in lines]
    return "\n".join(kept) + "\n"


@dataclass(frozen=True)
class CommandResult:
    """How one in-process ``tacbench run`` ended: exit status, its output, and the run
    directories it wrote (one per seed)."""

    exit_code: int
    output: str
    directories: tuple[Path, ...]

    @property
    def last_line(self) -> str:
        """The last non-empty line of the output (the error, when the command was refused)."""
        lines = [line for line in self.output.splitlines() if line.strip()]
        return lines[-1] if lines else ""


def command_line(args: Sequence[str]) -> str:
    """The recorded form of a run: ``tacbench run ARGS --out DIR``."""
    return shlex.join(["tacbench", "run", *args]) + " --out DIR"


Runner = Callable[[Sequence[str], Path], CommandResult]
"""Runs ``tacbench run ARGS --out OUT`` and says how it ended (:func:`subprocess_runner`; the
CLI passes one that runs the command in its own process)."""


def subprocess_runner(args: Sequence[str], out: Path) -> CommandResult:
    """Run ``tacbench run ARGS --out OUT`` in a new Python process, its output captured. A
    command this tacbench refuses (a flag renamed since it was recorded) ends with exit status 2
    and the error as the last line of its output, as on the command line."""
    command = [sys.executable, "-m", "tacbench", "run", *args, "--out", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    return finished(done.returncode, done.stdout + done.stderr, out)


class RunStopped(KeyboardInterrupt):
    """A recorded command stopped by a stop signal (Ctrl-C, SIGTERM, SIGHUP): the check or
    update stops too, instead of counting the interrupted run as drift and training on."""

    def __init__(self, exit_status: int) -> None:
        super().__init__(f"a reference run was interrupted (exit status {exit_status})")
        self.exit_status = exit_status


def finished(exit_code: int, output: str, out: Path) -> CommandResult:
    """A :class:`CommandResult` from a finished command that wrote under ``out``;
    :class:`RunStopped` if a stop signal ended it."""
    if exit_code in {128 + signum for signum in STOP_SIGNALS}:
        raise RunStopped(exit_code)
    directories = tuple(sorted((out / "runs").glob("*/*/*/seed*")))
    return CommandResult(exit_code, output, directories)
