"""The job lifecycle, in one place: the only code that changes a job's status.

A job row moves ``pending`` -> ``running`` (claimed by one driver: owner token, heartbeat)
-> ``done`` (its episodes, evaluation steps, training diagnostics and metadata written in the
same transaction)
or ``failed`` (one more failure, the error kept) or ``interrupted`` (given back on Ctrl-C).
Runnable ("claimable") are ``pending``, ``interrupted``, ``failed`` below
:data:`MAX_FAILURES` failures, and ``running`` jobs whose heartbeat is older than
:data:`STALE_AFTER_S` (their driver is gone). The driver (:mod:`nutribench.scheduler.driver`)
writes through these functions and ``nutribench status`` reads the same rule
(:func:`~nutribench.store.models.job_state`, beside the statuses in the store, so that
``db import`` can ask it too), so the two never disagree on which job is orphaned; ``nutribench db
import`` (:mod:`nutribench.store.archive`) asks the same rule before it replaces a job.

A claim takes the write lock (``BEGIN IMMEDIATE`` on SQLite; on PostgreSQL it locks the rows it
takes with ``SELECT ... FOR UPDATE SKIP LOCKED``, and its UPDATE re-checks the rule), so two
drivers never claim one job; heartbeats and the stale rule use the database's clock
(:func:`~nutribench.store.engine.db_now`), not each host's. Every write checks the owner
token, so a driver that lost a job (taken over as stale) writes nothing for it.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import TYPE_CHECKING, Any

from sqlalchemy import and_, func, or_, select, update

from nutribench.store.engine import StoreError, db_now, session_scope
from nutribench.store.models import (
    EPISODE_METRICS,
    EVAL_STEP_COLUMNS,
    METADATA_COLUMNS,
    STALE_AFTER_S,
    VALIDATION_COLUMNS,
    Diagnostic,
    Episode,
    EvalStep,
    Job,
    ValidationEpisode,
    diagnostic_rows,
    insert_rows,
    job_state,
    stale_before,
)
from nutribench.store.schema import Store

if TYPE_CHECKING:
    from nutribench.scheduler.worker import JobResult

MAX_FAILURES = 3  # a job that failed this often is no longer retried
#: what a worker reports of a running job (its training seconds so far, a resumed batch's earlier
#: runs included; its recent return; its process id), the column the driver writes it to, its type
_REPORTED = (("wall", "wall_seconds", float), ("ret", "last_return", float), ("pid", "worker_pid", int))


def check_not_mixed(store: Store, fake: bool) -> None:
    """A dry run's synthetic jobs and real results never share a database: refuse, in one
    line, to add real work to a database holding dry-run jobs, or a dry run to one holding real
    jobs (so a real run never counts a synthetic job as done, and no synthetic row is drawn)."""
    with store.engine.connect() as conn:
        n = conn.execute(select(func.count()).select_from(Job).where(Job.fake == (not fake))).scalar_one()
    if not n:
        return
    if fake:
        raise StoreError(
            f"{store.display} holds {n} real jobs: a dry run (NUTRIBENCH_JOB=fake) would mix synthetic rows "
            "with results; give it a database of its own (--db)"
        )
    raise StoreError(
        f"{store.display} holds {n} dry-run jobs (NUTRIBENCH_JOB=fake), which are never results: write real "
        "work to another database (--db), or delete this one"
    )


def _set(session: Any, *where: Any, **values: Any) -> int:
    """UPDATE the jobs that match ``where`` to ``values`` (in the database alone: no ORM object
    is synchronised); how many rows it changed."""
    query = update(Job).where(*where).values(**values).execution_options(synchronize_session=False)
    return session.execute(query).rowcount


def reset_given_up(store: Store, job_ids: Sequence[int]) -> int:
    """``--retry-failed``: jobs of ``job_ids`` that failed :data:`MAX_FAILURES` times get their
    failure count reset (their last error stays until they succeed); how many."""
    with session_scope(store.engine) as s:
        return _set(s, Job.id.in_(job_ids), Job.status == "failed", Job.failures >= MAX_FAILURES, failures=0)


def _claimable(now) -> Any:
    stale = stale_before(now)
    return or_(
        Job.status.in_(("pending", "interrupted")),
        and_(Job.status == "failed", Job.failures < MAX_FAILURES),
        and_(Job.status == "running", or_(Job.heartbeat_at.is_(None), Job.heartbeat_at < stale)),
    )


def count_claimable(store: Store, job_ids: Sequence[int]) -> int:
    """How many of ``job_ids`` a claim could take now."""
    with store.engine.connect() as conn:
        return len(conn.execute(select(Job.id).where(Job.id.in_(job_ids), _claimable(db_now(conn)))).all())


def claim_jobs(store: Store, job_ids: Sequence[int], exclude: set[int], n: int, owner: str) -> list[Job]:
    """Atomically take up to ``n`` runnable jobs of ``job_ids`` (not in ``exclude``) for
    ``owner``: status ``running``, owner token, fresh heartbeat, attempt + 1."""
    candidates = [j for j in job_ids if j not in exclude]
    if n <= 0 or not candidates:
        return []
    with session_scope(store.engine) as s:  # BEGIN IMMEDIATE on SQLite: one claimer at a time
        now = db_now(s)
        # PostgreSQL: lock the rows taken, and pass over rows another claimer has locked (SQLite
        # has one writer at a time and ignores FOR UPDATE). The UPDATE re-checks the rule anyway.
        query = select(Job.id).where(Job.id.in_(candidates), _claimable(now)).order_by(Job.id).limit(n)
        ids = s.scalars(query.with_for_update(skip_locked=True)).all()
        if not ids:
            return []
        claimed = {"status": "running", "owner": owner, "heartbeat_at": now, "started_at": now, "finished_at": None}
        fresh = {"episodes_done": 0, "last_return": None, "worker_pid": None, "wall_seconds": None}
        _set(s, Job.id.in_(ids), _claimable(now), attempt=Job.attempt + 1, **claimed, **fresh)
        return list(s.scalars(select(Job).where(Job.id.in_(ids), Job.owner == owner, Job.status == "running")))


def held_elsewhere(store: Store, job_ids: Sequence[int], owner: str) -> tuple[int, datetime | None]:
    """How many of ``job_ids`` another driver is running (fresh heartbeat), and when the
    last of them becomes claimable if that driver's heartbeat stops now."""
    with store.engine.connect() as conn:
        fresh = stale_before(db_now(conn))
        running = (Job.id.in_(job_ids), Job.status == "running", Job.owner != owner, Job.heartbeat_at >= fresh)
        beats = conn.scalars(select(Job.heartbeat_at).where(*running)).all()
    if not beats:
        return 0, None
    return len(beats), max(beats) + timedelta(seconds=STALE_AFTER_S)


def grid_counts(store: Store, job_ids: Sequence[int], owner: str) -> dict[str, int]:
    """Status counts of the grid's jobs, as this driver sees them at the end."""
    out = {"done": 0, "given_up": 0, "busy": 0}
    with store.engine.connect() as conn:
        now = db_now(conn)
        query = select(Job.status, Job.failures, Job.owner, Job.heartbeat_at).where(Job.id.in_(job_ids))
        rows = conn.execute(query).all()
    for status, failures, job_owner, beat in rows:
        if status == "done":
            out["done"] += 1
        elif status == "failed" and failures >= MAX_FAILURES:
            out["given_up"] += 1
        elif job_owner != owner and job_state(status, beat, now) == "running":
            out["busy"] += 1
    return out


def insert_job_rows(session: Any, job: JobResult) -> None:
    """A finished job's rows, under its ``job_id``: its training and evaluation episodes,
    evaluation steps, training diagnostics and validation days (an external job's result has
    none of the last two, nor has a result pickled before it had them)."""
    job_id = job.job_id
    rows = [
        {"job_id": job_id, "phase": phase, "episode": int(ep["episode"]), **{c: ep.get(c) for c in EPISODE_METRICS}}
        for phase, episodes in (("train", job.train), ("eval", job.eval))
        for ep in episodes
    ]
    insert_rows(session, Episode, rows)  # none: no statement
    steps = [{"job_id": job_id, **{k: st[k] for k in EVAL_STEP_COLUMNS}} for st in job.eval_steps]
    insert_rows(session, EvalStep, steps)
    insert_rows(session, Diagnostic, diagnostic_rows(job_id, getattr(job, "diagnostics", None) or []))
    days = getattr(job, "validation", None) or []
    insert_rows(
        session, ValidationEpisode, [{"job_id": job_id, **{c: d.get(c) for c in VALIDATION_COLUMNS}} for d in days]
    )


def store_result(store: Store, result: JobResult, owner: str, model_path: str | None) -> bool:
    """Write a finished job in one transaction: its episodes, evaluation steps, training
    diagnostics, validation days, metadata and status ``done``. False (nothing written) if this driver no
    longer owns the job."""
    with session_scope(store.engine) as s:
        meta = {k: result.metadata[k] for k in METADATA_COLUMNS if k in result.metadata}
        if meta.get("platform"):
            meta["platform"] = str(meta["platform"])[:255]
        job = s.execute(select(Job).where(Job.id == result.job_id)).scalar_one()
        done = {"status": "done", "owner": None, "heartbeat_at": db_now(s), "episodes_done": job.episodes}
        mine = (Job.id == result.job_id, Job.owner == owner, Job.status == "running")
        if _set(s, *mine, **done, error=None, model_path=result.model_path or model_path, **meta) != 1:
            return False
        insert_job_rows(s, result)
        return True


def _ended(session: Any) -> dict[str, Any]:
    """What a job that stops running (failed, or given back) is set to: no owner, its end now, and
    no ``wall_seconds`` (a running job's training seconds so far, not what its attempt took)."""
    return {"owner": None, "finished_at": db_now(session), "wall_seconds": None}


def store_failure(store: Store, job_id: int, owner: str, error: str) -> None:
    """Status ``failed``, one more failure, the error text kept."""
    with session_scope(store.engine) as s:
        failed = {"status": "failed", "failures": Job.failures + 1, "error": error}
        _set(s, Job.id == job_id, Job.owner == owner, **failed, **_ended(s))


def release_jobs(store: Store, job_ids: Sequence[int], owner: str, status: str = "interrupted") -> int:
    """Give back jobs this driver claimed (Ctrl-C, executor failure): no rows, new status."""
    if not job_ids:
        return 0
    with session_scope(store.engine) as s:
        running = (Job.id.in_(list(job_ids)), Job.owner == owner, Job.status == "running")
        return _set(s, *running, status=status, **_ended(s))


def flush_progress(store: Store, owner: str, live: dict[int, dict[str, Any]]) -> None:
    """Heartbeat every job this driver runs, with its episodes done, recent return and (where
    its worker reports it) its training seconds so far in ``wall_seconds``."""
    if not live:
        return
    with session_scope(store.engine) as s:
        now = db_now(s)
        for job_id, st in live.items():
            values = {column: kind(st[key]) for key, column, kind in _REPORTED if st.get(key) is not None}
            values |= {"heartbeat_at": now, "episodes_done": int(st.get("k", 0))}
            _set(s, Job.id == job_id, Job.owner == owner, **values)
