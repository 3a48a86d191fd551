"""Regression checks against committed reference results (``tacbench regress``, docs/regression.md).

Three kinds of reference live under ``results/reference/``, one folder each:

- ``exact/``: short deterministic runs (every suite task, TAC at q = 1, 1.5, 2, every
  baseline) whose CSVs a fresh run must reproduce to the last printed digit on the same library
  versions and platform (:mod:`tacbench.regress.exact`);
- ``theory/``: the CSVs of the paper's theory figures, reproduced exactly;
- ``stat/``: final-return distributions of longer runs over several seeds, against which fresh
  seeds are tested for a drop (:mod:`tacbench.regress.stat`).

:func:`check` compares, :func:`update` regenerates; both train in a scratch folder.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from tacbench import runs
from tacbench.errors import TacbenchError
from tacbench.regress.exact import (
    check_exact,
    check_theory,
    theory_staged,
    update_exact,
    update_theory,
)
from tacbench.regress.manifest import Runner, subprocess_runner
from tacbench.regress.outcome import Row, TierResult, format_result
from tacbench.regress.stat import check_stat, update_stat
from tacbench.runs import locks

__all__ = ["TIERS", "Row", "TierResult", "check", "format_result", "update"]

TIERS = ("exact", "theory", "stat")
"""``exact``: the exact runs and the theory CSVs; ``theory``: the CSVs alone; ``stat``: the
statistical tier."""

Log = Callable[[str], None]


def _quiet(_: str) -> None:
    """A log that drops its messages."""


@contextmanager
def _scratch(work: Path | None) -> Iterator[Path]:
    """``work`` (must be empty or absent; kept afterwards), or a temporary folder (deleted)."""
    if work is None:
        with tempfile.TemporaryDirectory(prefix="tacbench-regress-") as tmp:
            yield Path(tmp)
        return
    if work.exists() and (not work.is_dir() or any(work.iterdir())):
        raise TacbenchError(f"--work {work} is not an empty folder; give a new or empty one.")
    runs.check_writable(work, "--work")
    work.mkdir(parents=True, exist_ok=True)
    yield work


def _check_tier(tier: str) -> None:
    if tier not in TIERS:
        raise TacbenchError(f"--tier must be one of {', '.join(TIERS)} (got {tier!r}).")


def check(
    reference: Path,
    tier: str = "exact",
    work: Path | None = None,
    names: Sequence[str] = (),
    log: Log = _quiet,
    runner: Runner = subprocess_runner,
) -> list[TierResult]:
    """Compare fresh results with the references of ``tier`` under ``reference``; ``names``
    limits the exact or statistical tier to those runs or groups. ``runner`` runs each
    recorded ``tacbench run`` command (a new process by default)."""
    _check_tier(tier)
    reference = Path(reference)
    if not reference.is_dir():
        raise TacbenchError(
            f"--against {reference}: no such folder; the committed references are in "
            "results/reference (run from the repository root)."
        )
    if names and tier == "theory":
        raise TacbenchError(
            "--only names exact runs or statistical groups; the theory tier compares all of its "
            "CSVs (leave --only out)."
        )
    with _scratch(work) as scratch:
        if tier == "stat":
            return [check_stat(reference, scratch / "stat", names, log, runner)]
        results = [] if names else [check_theory(reference, scratch / "theory")]
        if tier == "exact":
            results.append(check_exact(reference, scratch / "exact", names, log, runner))
        return results


def update(
    reference: Path,
    tier: str = "exact",
    work: Path | None = None,
    log: Log = _quiet,
    runner: Runner = subprocess_runner,
) -> list[Path]:
    """Regenerate ``tier``'s references under ``reference`` (``exact`` also rewrites the theory
    CSVs); returns the manifests written."""
    _check_tier(tier)
    reference = Path(reference)
    runs.check_writable(reference, "--against")  # before minutes of training, not after
    with locks.writing([reference], hint=""), _scratch(work) as scratch:
        # each tier's staged() refuses a folder that is not references, before any training
        if tier == "stat":
            return [update_stat(reference, scratch / "stat", log=log, runner=runner)]
        if tier == "theory":
            return [update_theory(reference, scratch / "theory")]
        # both tiers built before either is published: stopped or failed, neither changes
        with theory_staged(reference, scratch / "theory") as publish_theory:
            exact = update_exact(reference, scratch / "exact", log=log, runner=runner)
            return [publish_theory(), exact]
