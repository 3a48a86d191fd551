"""What a check found, and the table ``tacbench regress`` prints."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

Status = Literal["match", "drift", "missing", "ok", "drop"]
REGRESSIONS: frozenset[str] = frozenset({"drift", "missing", "drop"})
"""Statuses that make a check fail: an exact value changed, something the reference has was
not produced, or a statistically significant drop in return."""


@dataclass(frozen=True)
class Row:
    """One compared item: a run (or theory CSV, or statistical group), the part compared, the
    status and the numbers behind it."""

    item: str
    part: str
    status: Status
    detail: str = ""


@dataclass(frozen=True)
class TierResult:
    """One tier's check: its rows, notes (provenance, config differences) and, when the tier
    could not be checked here, why (``skipped``)."""

    tier: str
    reference: str
    rows: tuple[Row, ...] = ()
    notes: tuple[str, ...] = ()
    skipped: str = ""
    seconds: float = 0.0

    @property
    def regressions(self) -> list[Row]:
        """The rows that count as a regression."""
        return [row for row in self.rows if row.status in REGRESSIONS]

    @property
    def verdict(self) -> str:
        """``REGRESSION``, ``SKIPPED`` or ``PASS``."""
        if self.regressions:
            return "REGRESSION"
        return "SKIPPED" if self.skipped else "PASS"


def format_table(rows: Sequence[Row]) -> list[str]:
    """Rows as aligned text columns: item, part, status (upper case for a regression), detail."""
    cells = [("item", "part", "status", "detail")]
    cells += [
        (r.item, r.part, r.status.upper() if r.status in REGRESSIONS else r.status, r.detail)
        for r in rows
    ]
    widths = [max(len(cell[i]) for cell in cells) for i in range(3)]
    return [
        "  ".join(cell[i].ljust(widths[i]) for i in range(3)) + f"  {cell[3]}".rstrip()
        for cell in cells
    ]


def format_result(result: TierResult) -> str:
    """The full text for one tier: a heading, the table, the notes and the verdict."""
    lines = [f"== {result.tier} tier against {result.reference}"]
    lines += [f"   {note}" for note in result.notes]
    if result.rows:
        lines += format_table(result.rows)
    if result.skipped:
        lines.append(f"SKIPPED: {result.skipped}")
    counts = {
        s: sum(r.status == s for r in result.rows)
        for s in dict.fromkeys(r.status for r in result.rows)
    }
    summary = ", ".join(f"{n} {s}" for s, n in counts.items()) or "nothing compared"
    lines.append(f"{result.verdict} ({summary}; {result.seconds:.0f} s)")
    return "\n".join(lines)
