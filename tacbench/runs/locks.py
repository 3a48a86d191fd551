"""One writer per run directory (and per regression reference folder): an OS lock held for the
writer's lifetime.

Each run directory ``.../<variant>/seed<k>`` has a lock file beside it,
``.../<variant>/.seed<k>.lock``, outside the directory so that ``--force`` can delete and
recreate the directory while its lock is held. A writer takes an exclusive ``flock`` on it
before it reads or writes anything in the directory and keeps it until it exits; the kernel
releases it when the process ends in any way (kill -9 included), so no stale lock survives.
The file records the holder's PID and host, for the error a second writer gets. The file is
never deleted: a writer that deleted it could leave two processes holding locks on different
files of the same name.
"""

from __future__ import annotations

import errno
import fcntl
import os
import socket
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path

from tacbench.errors import TacbenchError


def lock_path(directory: Path) -> Path:
    """The lock file of run directory ``directory``."""
    return directory.parent / f".{directory.name}.lock"


class Held(Exception):
    """Another process holds the lock; ``recorded`` is what its holder wrote in the file."""

    def __init__(self, recorded: str) -> None:
        super().__init__(recorded)
        self.recorded = recorded


def hold(path: Path, record: str) -> int:
    """Take the exclusive ``flock`` on ``path`` (created if need be) without waiting, and write
    ``record`` (who holds it) in the file: the open descriptor, whose closing releases the
    lock. :class:`Held` if another process holds it; a TacbenchError if a folder or a link
    stands where the file goes (a link is not followed: its target would be overwritten)."""
    try:
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError as err:
        if not (isinstance(err, IsADirectoryError) or err.errno == errno.ELOOP):
            raise
        what = "a folder" if isinstance(err, IsADirectoryError) else "a link"
        raise TacbenchError(
            f"{path} is {what}, where tacbench keeps a lock file; nothing was changed. Move it "
            "away, or write somewhere else."
        ) from None
    try:
        recorded = _held_by(descriptor)
        if recorded is not None:
            raise Held(recorded)
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, record.encode(), 0)
    except BaseException:
        os.close(descriptor)
        raise
    return descriptor


def _held_by(descriptor: int) -> str | None:
    """Take the exclusive ``flock`` on the open lock file ``descriptor`` without waiting: None
    once taken, else what the process holding it recorded in the file."""
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return os.pread(descriptor, 4096, 0).decode(errors="replace").strip()
    return None


def holder(directory: Path) -> str | None:
    """Who holds run directory ``directory``'s lock now (its record; "holder unknown" if it
    wrote none), or None where no process does; creates and writes nothing."""
    try:
        descriptor = os.open(lock_path(directory), os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:  # no lock file (no writer ever), or no file at all: hold() will say so
        return None
    try:
        recorded = _held_by(descriptor)
    finally:
        os.close(descriptor)  # releases a lock taken here
    return None if recorded is None else recorded or "holder unknown"


@contextmanager
def _hold(directory: Path, hint: str) -> Iterator[None]:
    path = lock_path(directory)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor = hold(path, f"PID {os.getpid()} on {socket.gethostname()}\n")
    except (NotADirectoryError, FileExistsError):  # others (a read-only disk) say what they are
        raise TacbenchError(
            f"cannot create {path}: a file stands where a folder of {directory} goes; nothing "
            "was changed. Move it away, or write somewhere else."
        ) from None
    except Held as held:
        raise TacbenchError(
            f"{directory} is being written by another tacbench process "
            f"({held.recorded or 'holder unknown'}); wait for it to finish or stop it, then "
            f"run this again{hint}."
        ) from None
    try:
        yield
    finally:
        os.close(descriptor)  # releases the lock


@contextmanager
def writing(
    directories: Sequence[Path], hint: str = " (--resume continues an unfinished run)"
) -> Iterator[None]:
    """Hold the lock of every directory in ``directories`` (a member group's run directories,
    all before any is read; or the regression references that ``tacbench regress --update``
    rewrites), or raise a TacbenchError naming the directory and its writer's PID and host,
    ending with ``hint``."""
    with ExitStack() as stack:
        for directory in sorted(set(directories)):
            stack.enter_context(_hold(directory, hint))
        yield
