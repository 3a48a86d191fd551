"""Checkpoint generations that survive a crash, a damaged file and a full disk (both trainers).

A checkpoint is a *generation*: the files a run's continuation needs at one step, and
``manifest-<step>.json``, which lists each file with its size and SHA-256 (and what each of
the run's CSVs held then: :mod:`tacbench.runs.resume_checks`) and is written last, so a
generation exists only once all its files do. Every file is written to a temporary name,
flushed and synced to the device, renamed, and its folder synced after the rename
(:func:`write_durably`). After a generation is committed, all but the newest
:data:`GENERATIONS` generations are pruned, with every file that no kept generation lists; so
the previous generation stays until the new one is complete, and one damaged file costs at
most one checkpoint interval.

On resume, :func:`usable_steps` checks every file of every generation against its manifest;
the trainer continues from the newest generation that all its members can use
(:func:`choose` says which, and what was damaged), checks the CSVs against it, then forgets
the generations after it (:func:`discard_after`) and cuts the CSVs back to it.

Test-only: ``TACBENCH_CHECKPOINT_PAUSE=<seconds>`` makes the writer sleep before it renames
each file and before it writes the manifest, so that a test can kill it in the middle.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from tacbench.errors import TacbenchError, listing
from tacbench.runs.resume_checks import START_OVER, LogDigest

GENERATIONS = 2  # kept after each commit: the new one and the previous one
MANIFEST = "manifest-{step:012d}.json"
KEPT = "the last checkpoint is kept"  # a failed run's reason: what is left to inspect
NONE_KEPT = "no checkpoint had been written yet"
_PAUSE = "TACBENCH_CHECKPOINT_PAUSE"
_CHUNK = 1 << 20
# the errors that mean "this folder cannot take what we write": full, over quota, read-only,
# no permission
FULL_ERRNOS = {errno.ENOSPC, errno.EDQUOT}
DISK_ERRNOS = {*FULL_ERRNOS, errno.EROFS, errno.EACCES, errno.EPERM}


class DiskError(TacbenchError):
    """A run's files cannot be written: the disk is full, read-only or not ours."""

    def __init__(self, message: str, *, full: bool) -> None:
        super().__init__(message)
        self.full = full


class NoCommonCheckpoint(TacbenchError):
    """Members of one group have checkpoints, but no step that every member can resume from."""


def _pause() -> None:
    seconds = float(os.environ.get(_PAUSE, "0") or 0)
    if seconds > 0:
        time.sleep(seconds)


def sync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_durably(path: Path, write: Callable[[IO[bytes]], object]) -> None:
    """Write ``path`` with ``write`` so that after a crash it holds the old or the new content,
    never a part: a temporary name, flushed and synced, renamed, the folder synced."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
    except BaseException as err:
        tmp.unlink(missing_ok=True)  # a full disk keeps no half file
        if isinstance(err, OSError) and err.filename is None:
            err.filename = str(path)  # name it in the error: a write() does not
        raise
    _pause()
    tmp.replace(path)
    sync_folder(path.parent)


def digest(path: Path) -> dict[str, Any]:
    """A file's size and SHA-256, as a manifest records them."""
    sha = hashlib.sha256()
    with path.open("rb") as handle:
        while block := handle.read(_CHUNK):
            sha.update(block)
    return {"size": path.stat().st_size, "sha256": sha.hexdigest()}


def _manifests(folder: Path) -> dict[int, Path]:
    found = {}
    for path in folder.glob("manifest-*.json"):
        try:
            found[int(path.stem.split("-")[1])] = path
        except (IndexError, ValueError):
            continue
    return dict(sorted(found.items()))


def commit(
    folder: Path, step: int, files: Iterable[Path], logs: Mapping[str, LogDigest] | None = None
) -> None:
    """Record the generation at ``step`` (its ``files``, all under ``folder`` and already
    written durably, and what each of the run's CSVs held then, ``logs``, by file name): its
    manifest, then the pruning of older generations and unlisted files."""
    entries = {p.relative_to(folder).as_posix(): digest(p) for p in files}
    _pause()
    record: dict[str, Any] = {"step": step, "files": entries}
    if logs is not None:
        record["logs"] = {name: log.to_dict() for name, log in logs.items()}
    payload = json.dumps(record, indent=1).encode()
    write_durably(folder / MANIFEST.format(step=step), lambda handle: handle.write(payload))
    manifests = list(_manifests(folder).values())
    kept = manifests[-GENERATIONS:]
    for path in manifests[:-GENERATIONS]:  # first, so a crash in between leaves no half one
        path.unlink()
    needed = {path.name for path in kept}
    for path in kept:
        needed |= set(json.loads(path.read_text())["files"])
    for path in folder.rglob("*"):  # older generations' files, unlisted ones, temporaries
        if path.is_file() and path.relative_to(folder).as_posix() not in needed:
            path.unlink()


def problems(folder: Path, step: int) -> list[str]:
    """What is wrong with the generation at ``step`` (empty: every file is as recorded)."""
    path = folder / MANIFEST.format(step=step)
    try:  # a manifest that parses but is not the object a commit writes is as unreadable
        manifest = json.loads(path.read_text())
        files = {name: (int(r["size"]), str(r["sha256"])) for name, r in manifest["files"].items()}
        for recorded in (manifest.get("logs") or {}).values():
            LogDigest.from_dict(recorded)
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
        return [f"{path.name}: unreadable ({type(err).__name__})"]
    found = []
    for name, (size, sha256) in files.items():
        file = folder / name
        if not file.is_file():
            found.append(f"{name}: missing")
            continue
        if file.stat().st_size != size:
            found.append(f"{name}: {file.stat().st_size} bytes, {size} recorded")
        elif digest(file)["sha256"] != sha256:
            found.append(f"{name}: its checksum does not match the manifest's")
    return found


def usable_steps(folder: Path) -> tuple[list[int], dict[int, list[str]]]:
    """The steps of the generations under ``folder`` whose files are intact (newest first),
    and the damaged ones with what is wrong with them."""
    good, bad = [], {}
    for step in reversed(_manifests(folder)):
        found = problems(folder, step)
        if found:
            bad[step] = found
        else:
            good.append(step)
    return good, bad


def discard_after(folder: Path, step: int) -> None:
    """Forget the generations after ``step``, which a resume from ``step`` abandons (as it cuts
    the CSVs back): their manifests go now, their files at the next commit."""
    for at, path in _manifests(folder).items():
        if at > step:
            path.unlink()


def recorded_logs(folder: Path, step: int) -> dict[str, LogDigest] | None:
    """What the (intact) generation at ``step`` records of the run's CSVs, by file name; None
    for a generation written before manifests recorded them."""
    manifest = json.loads((folder / MANIFEST.format(step=step)).read_text())
    logs = manifest.get("logs")
    return None if logs is None else {name: LogDigest.from_dict(d) for name, d in logs.items()}


def newest_step(folder: Path) -> int | None:
    """The step of the newest checkpoint generation under ``folder`` (intact or not; None:
    none)."""
    if not folder.is_dir():
        return None
    return max(_manifests(folder), default=None)


def files_of(folder: Path, step: int) -> list[Path]:
    """The files of the (intact) generation at ``step``."""
    manifest = json.loads((folder / MANIFEST.format(step=step)).read_text())
    return [folder / name for name in manifest["files"]]


def choose(folders: Sequence[Path]) -> tuple[int | None, list[str]]:
    """The newest step that every member's checkpoint folder has an intact generation of (None:
    no member has a checkpoint, or the group's first was cut short before every member wrote
    its own, so training starts afresh), and a note on each damaged generation passed over. A
    TacbenchError (exit status 2) when a member has checkpoints but none that every member can
    use; nothing is deleted."""
    usable, notes, without, having = [], [], [], []  # having: the steps of members with some
    with_some: list[Path] = []
    for folder in folders:
        if folder.exists() and not folder.is_dir():
            raise TacbenchError(
                f"{folder} is a file, not a checkpoint folder; nothing was changed. Move it "
                f"away, or {START_OVER}."
            )
        if (folder / "state.pt").exists():
            raise TacbenchError(
                f"{folder} holds a checkpoint written by an older tacbench (state.pt, no "
                "manifest), which this version cannot resume; finish it with the tacbench "
                f"that wrote it, or {START_OVER}."
            )
        good, bad = usable_steps(folder)
        usable.append(set(good))
        if good or bad:
            having.append(set(good))
            with_some.append(folder)
        else:
            without.append(folder.parent)
        for step, found in bad.items():
            notes.append(f"{folder}: the checkpoint at step {step} is damaged ({'; '.join(found)})")
    if not having:
        return None, []
    common = set.intersection(*usable)
    if not common and without and _first_cut_short(with_some, without):
        return None, [
            f"the group's first checkpoint (step {min(set.union(*having)):,}) was cut short "
            f"before {listing([str(d) for d in without], shown=3)} wrote theirs, so the group "
            "starts afresh"
        ]
    if not common and without and set.intersection(*having):
        # new members beside partial ones that could resume: --force would lose their steps
        named = listing([str(d) for d in without], shown=3)
        raise NoCommonCheckpoint(
            f"{named} {'have' if len(without) > 1 else 'has'} no checkpoint, and the other "
            "members have: a group resumes only from a checkpoint all its members share. "
            "Nothing was deleted; resume the others in a command without the new members (their "
            "seeds, q or alpha), then train those in a command of their own"
            + "".join(f"; {note}" for note in notes)
            + "."
        )
    if not common and notes:
        raise NoCommonCheckpoint(
            f"no usable checkpoint to resume from: {'; '.join(notes)}. Nothing was deleted; "
            f"{START_OVER}."
        )
    if not common:  # every checkpoint intact: members resumed apart, say, and went on apart
        held = "; ".join(
            f"{folder.parent.parent.name}/{folder.parent.name} at "
            + ", ".join(f"{step:,}" for step in sorted(steps))
            for folder, steps in zip(with_some, having, strict=True)
        )
        raise NoCommonCheckpoint(
            f"the members' checkpoints are at different steps ({held}), and a group resumes "
            "only from a step all its members share. Nothing was deleted; resume each member "
            "in a command of its own (its --seed, --q or --alpha alone), or rerun the group "
            "with --force to start it over."
        )
    return max(common), notes


def _first_cut_short(with_some: Sequence[Path], without: Sequence[Path]) -> bool:
    """Whether the members that have a checkpoint folder each hold one intact generation, of
    one step, and those without one (run directories) trained in the same group from its start
    (their config.json lists the same members): the group was stopped while its members
    committed their first checkpoint one after another, and none can resume without the rest."""
    steps = [usable_steps(folder) for folder in with_some]
    if any(len(good) != 1 or bad for good, bad in steps) or len({good[0] for good, _ in steps}) > 1:
        return False
    groups = [recorded_members(folder.parent) for folder in with_some]
    groups += [recorded_members(d) for d in without]
    return None not in groups and all(group == groups[0] for group in groups)


def recorded_members(directory: Path) -> list[Any] | None:
    """The group a run directory's config.json records (None: no readable config.json, or one
    without a ``members`` list, as an older config.json lists the seeds alone)."""
    try:
        data = json.loads((directory / "config.json").read_text())
    except (OSError, ValueError):
        return None
    members = data.get("members") if isinstance(data, dict) else None
    return members if isinstance(members, list) and members else None


RESUME_RUN = "rerun with --resume: what was written up to the last checkpoint is intact"
"""What to do once a full disk has space again, in ``tacbench run``."""


@contextmanager
def disk_errors(
    what: str, again: str = RESUME_RUN, elsewhere: str = "choose a folder you can write with --out"
) -> Iterator[None]:
    """Turn an OS error that means the folder cannot take our files (full, read-only, not
    writable) into a :class:`DiskError` that names the file and says what to do: free some
    space, then ``again``; or ``elsewhere``."""
    try:
        yield
    except OSError as err:
        if err.errno not in DISK_ERRNOS:
            raise
        full = err.errno in FULL_ERRNOS
        reason = "the disk is full" if full else os.strerror(err.errno or 0).lower()
        where = f" ({err.filename})" if err.filename else ""
        advice = f"free some space, then {again}" if full else elsewhere
        raise DiskError(f"cannot write {what}{where}: {reason}; {advice}.", full=full) from None
