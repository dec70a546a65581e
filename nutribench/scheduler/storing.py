"""Storing finished jobs when the database pushes back; used by the driver.

- A lock held past the busy timeout ("database is locked": another writer holds SQLite's one
  write lock for long; PostgreSQL's lock timeouts) is not the job's fault: its result is kept
  in memory (:class:`HeldResults`) and stored again with a growing pause until it succeeds or
  the run stops, the job heartbeating meanwhile so that no other driver takes it over. A
  heartbeat or a claim that meets the lock is simply tried again later.
- Any other operational error while writing (disk full, I/O error, a read-only file, the
  server gone) stops the run with one line (:func:`stop_line`): its jobs are released if the
  database still takes that write, else left to the stale rule; the next run resumes them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy.exc import OperationalError

from nutribench.scheduler.lifecycle import STALE_AFTER_S, release_jobs, store_result
from nutribench.scheduler.spec import JobFailed, JobResult, JobSpec

RETRY_FIRST_S = 1.0  # the first pause before a held result is stored again; doubled each time
RETRY_MAX_S = 30.0
LOCK_WORDS = (
    "database is locked",
    "database table is locked",
    "lock timeout",
    "could not obtain lock",
    "deadlock detected",
)


def one_line(error: BaseException) -> str:
    """A database error's message on one line, without SQLAlchemy's statement and parameters."""
    return " ".join(str(getattr(error, "orig", None) or error).split()) or type(error).__name__


def is_lock_error(error: BaseException) -> bool:
    """A write that met another writer's lock for longer than the busy timeout."""
    return isinstance(error, OperationalError) and any(w in one_line(error).lower() for w in LOCK_WORDS)


def unless_locked(fn: Callable[..., Any], *args: Any, default: Any = None) -> Any:
    """``fn(*args)``, or ``default`` when it met the lock (another write is tried later)."""
    try:
        return fn(*args)
    except OperationalError as e:
        if not is_lock_error(e):
            raise
        return default


@dataclass
class Held:
    spec: Any
    result: Any
    due: float
    pause: float


class HeldResults(dict):
    """Finished jobs' results the database could not take yet (job id -> :class:`Held`)."""

    def hold(self, spec: Any, result: Any) -> float:
        """Keep ``result``; the pause until it is stored again (doubling up to RETRY_MAX_S)."""
        before = self.get(spec.job_id)
        pause = RETRY_FIRST_S if before is None else min(2 * before.pause, RETRY_MAX_S)
        self[spec.job_id] = Held(spec, result, time.monotonic() + pause, pause)
        return pause

    def due(self) -> list[Held]:
        now = time.monotonic()
        return [h for h in list(self.values()) if h.due <= now]

    def labels(self) -> str:
        return ", ".join(h.spec.label for h in self.values())


def release_quietly(store: Any, job_ids: Sequence[int], owner: str) -> int | str:
    """Release ``job_ids`` as interrupted: how many, or why the database refused that too."""
    try:
        return release_jobs(store, job_ids, owner)
    except OperationalError as e:
        return one_line(e)


def released_text(released: int | str, n: int) -> str:
    if n == 0:
        return "no job was running: nothing was lost"
    if isinstance(released, int):
        return f"{released} running job{'s' if released != 1 else ''} released, the next run resumes them"
    return (
        f"its {n} running job{'s' if n != 1 else ''} could not be released either ({released}): the next run "
        f"takes them over once their heartbeat is {STALE_AFTER_S:.0f} s old"
    )


def stop_line(where: str, error: BaseException | None, released: int | str, n: int, held: HeldResults) -> str:
    """The line a stopped run ends with: stopped by a storage ``error``, that error, the ``n``
    running jobs ``released`` (how many, or why not) and the results lost; stopped by a signal
    (no ``error``), only what it adds: results still held (the lock never cleared), jobs not released."""
    if error is not None:
        lost = f"; the results of {held.labels()} could not be stored (trained again next run)" if held else ""
        return f"cannot write to {where}: {one_line(error)}: the run stopped; {released_text(released, n)}{lost}"
    lost = f"the results of {held.labels()} could not be stored (the database stayed locked): trained again next run"
    kept = "" if isinstance(released, int) else released_text(released, n)
    return "; ".join(t for t in (lost if held else "", kept) if t)


def first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def store_finished(run: Any, spec: JobSpec, result: JobResult | None) -> bool:
    """Store a finished job for the driver's ``run``: True once stored. A result that meets the
    write lock is held (``run.held``) and stored again later; another operational error (disk
    full, I/O error, read-only) is raised: the driver stops; anything else is the job's failure."""
    try:
        if result is None:
            raise JobFailed(f"{spec.label}: its batch returned no result for it")
        stored = store_result(run.store, result, run.owner, spec.model_path)
    except OperationalError as e:
        if not is_lock_error(e):
            raise
        run.view.log(
            f"[yellow]kept[/] {spec.label}: {one_line(e)}; stored again in {run.held.hold(spec, result):.0f} s"
        )
        return False
    except Exception as e:  # noqa: BLE001 - recorded as the job's failure, the run goes on
        run._failed(spec, e, "could not be stored: ")
        stored = False
    if run.held.pop(spec.job_id, None) is not None:  # its job heartbeated while held
        run.live.pop(spec.job_id, None)
    return stored
