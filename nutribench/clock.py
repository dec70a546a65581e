"""The one time representation nutribench stores: naive UTC (SQLite has no time zones).

A module of its own at the bottom of the house, so that the scheduler's workers
(``nutribench.scheduler.worker`` and the jobs it runs) can stamp times without importing the
database layer."""

from __future__ import annotations

from datetime import UTC, datetime


def utcnow() -> datetime:
    """Naive UTC now."""
    return datetime.now(UTC).replace(tzinfo=None)
