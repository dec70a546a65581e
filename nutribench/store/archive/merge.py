"""``nutribench db import``: an archive, checked whole (:func:`~nutribench.store.archive.check.
read_archive`), merged into a database in one transaction (:func:`import_results`).

Configs are matched by (name, version), jobs by (regime config, agent config, seed, budget,
evaluation days); a job done there is kept, one pending, interrupted or failed takes the
archived result, one running is refused. The rows written are counted before the commit; a
SQLite file the import created is removed again if it fails.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import delete, func, insert, select, update
from sqlalchemy.orm import Session

from nutribench.store.archive.check import read_archive
from nutribench.store.archive.format import ARCHIVE_TABLES, JOB_DEFAULTS, archive_table, columns
from nutribench.store.engine import (
    REGISTRATION_LOCK,
    StoreError,
    database_url,
    db_now,
    hold_write_lock,
    session_scope,
    side_files,
    sqlite_path,
)
from nutribench.store.models import AgentConfig, Job, RegimeConfig, diagnostic_rows, insert_rows, job_state
from nutribench.store.schema import open_store

_BATCH = 20_000


def _datetimes(table: type, row: dict[str, Any]) -> dict[str, Any]:
    """``row`` with the ISO strings of ``table``'s datetime columns read back as datetimes."""
    dates = {c.name for c in table.__table__.columns if c.type.python_type is datetime}
    return {k: datetime.fromisoformat(v) if k in dates and isinstance(v, str) else v for k, v in row.items()}


def _chunks(ids: list[int], n: int = 500) -> list[list[int]]:
    return [ids[i : i + n] for i in range(0, len(ids), n)]


def database_rows(
    name: str, arrays: dict[str, np.ndarray], rows: np.ndarray, job_id: int
) -> tuple[int, list[dict[str, Any]]]:
    """Rows ``rows`` (positions) of the archive's table ``name`` as insert dicts of job
    ``job_id`` for :func:`~nutribench.store.models.insert_rows`: how many archive rows, and the
    dicts (``diagnostics``: one per update and quantity, :func:`~nutribench.store.models.diagnostic_rows`)."""
    layout = archive_table(name, arrays)
    cols = {}
    for col in columns(layout):
        values = arrays[f"{name}.{col.name}"][rows].tolist()
        null = arrays.get(f"{name}.{col.name}.null")
        if null is not None:
            values = [None if n else v for v, n in zip(values, null[rows].tolist(), strict=True)]
        cols[col.name] = values  # by column name (``return``), which insert_rows takes as it is
    decoded = [dict(zip(cols, vals, strict=True)) for vals in zip(*cols.values(), strict=True)]
    if name == "diagnostics":
        return len(decoded), diagnostic_rows(job_id, decoded)
    return len(decoded), [{"job_id": job_id, **r} for r in decoded]


def import_results(
    path: str | os.PathLike[str], db: str, *, on_step: Callable[[str, int, int], None] = lambda *_: None
) -> dict[str, int]:
    """Merge the archive ``path`` into ``db`` (created or upgraded); counts of jobs ``imported`` and ``kept``
    (already done there) and of rows written per table. The archive is checked whole (:func:`read_archive`)
    before the database is opened. ``on_step(phase, done, total)``: ("checking", 0, 0), ("writing", i, n)."""
    on_step("checking", 0, 0)  # the checks, the evaluation days' replay included
    meta, arrays = read_archive(path)
    file = sqlite_path(database_url(db))
    new_file = file if file is not None and not file.exists() else None
    store = open_store(db, writer=True)
    try:
        with store:  # disposed of before a file the import created is removed
            return _write(store, meta, arrays, path, on_step)
    except BaseException:
        if store.created and new_file is not None:  # the SQLite file, its WAL and journal it created
            for p in (new_file, *side_files(new_file)):
                with contextlib.suppress(OSError):  # best effort: the failure is reported anyway
                    p.unlink(missing_ok=True)
        raise


def _config_ids(s: Session, meta: dict[str, Any], where: str, path: Any) -> dict[tuple[Any, ...], int]:
    """The database's id of every config of the archive, by (table, name, version): added where
    missing; StoreError for one recorded with other content."""
    ids = {}
    for table, rows in ((RegimeConfig, meta["regimes"]), (AgentConfig, meta["agent_configs"])):
        for row in rows:
            have = s.scalars(select(table).filter_by(name=row["name"], version=row["version"])).one_or_none()
            if have is not None and have.sha256 != row["sha256"]:
                raise StoreError(
                    f"db import: {row['name']} v{row['version']} is recorded in {where} with other "
                    f"content than in {path}: the two databases disagree on what that version is"
                )
            if have is None:
                have = table(**_datetimes(table, row))
                s.add(have)
                s.flush()
            ids[(table, row["name"], row["version"])] = have.id
    return ids


def _write(
    store: Any, meta: dict[str, Any], arrays: dict[str, np.ndarray], path: Any, on_step: Callable[[str, int, int], None]
) -> dict[str, int]:
    fake = bool(meta["jobs"] and meta["jobs"][0].get("fake", False))
    with session_scope(store.engine) as s:
        hold_write_lock(s, REGISTRATION_LOCK)
        if other := s.execute(select(func.count()).select_from(Job).where(Job.fake == (not fake))).scalar_one():
            ours, theirs = ("a dry run's jobs (fake)", "real jobs") if fake else ("real results", "dry-run jobs (fake)")
            raise StoreError(
                f"db import: {path} holds {ours} and {store.display} holds {other} {theirs}: the two are never "
                "mixed in one database; import into another --db"
            )
        config_ids = _config_ids(s, meta, store.display, path)
        now = db_now(s)
        positions = {name: np.argsort(arrays[f"{name}.job"], kind="stable") for name in ARCHIVE_TABLES}
        bounds = {
            name: np.searchsorted(arrays[f"{name}.job"][positions[name]], np.arange(len(meta["jobs"]) + 1))
            for name in ARCHIVE_TABLES
        }
        counts = {"imported": 0, "kept": 0, **{name: 0 for name in ARCHIVE_TABLES}}  # the archive's rows
        written = {name: 0 for name in ARCHIVE_TABLES}  # the database's (diagnostics: a row per quantity)
        imported: list[int] = []
        for i, job in enumerate(meta["jobs"]):
            on_step("writing", i, len(meta["jobs"]))
            job_id = _write_job(s, store.display, job, config_ids, now)
            if job_id is None:
                counts["kept"] += 1
                continue
            for name, table in ARCHIVE_TABLES.items():
                n, decoded = database_rows(name, arrays, positions[name][bounds[name][i] : bounds[name][i + 1]], job_id)
                counts[name] += n
                for start in range(0, len(decoded), _BATCH):
                    insert_rows(s, table, decoded[start : start + _BATCH])
                written[name] += len(decoded)
            counts["imported"] += 1
            imported.append(job_id)
        # compared before the commit: a mismatch rolls the whole import back
        for name, table in ARCHIVE_TABLES.items():
            held = sum(
                s.execute(select(func.count()).select_from(table).where(table.job_id.in_(chunk))).scalar_one()
                for chunk in _chunks(imported)
            )
            if held != written[name]:
                raise StoreError(
                    f"db import: {written[name]} {name} rows written but {held} found after: nothing imported"
                )
    return counts


def _write_job(
    s: Session, where: str, job: dict[str, Any], config_ids: dict[tuple[Any, ...], int], now: Any
) -> int | None:
    """Write the archive's ``job`` (its row; its old rows deleted where the database has it
    pending, interrupted or failed): its id, None where the database has it done (kept)."""
    rid = config_ids[(RegimeConfig, *job["regime"])]
    aid = config_ids[(AgentConfig, *job["agent"])]
    key = {"regime_id": rid, "agent_config_id": aid, **{k: job[k] for k in ("seed", "episodes", "eval_episodes")}}
    have = s.execute(select(Job).filter_by(**key).order_by(Job.id)).scalars().first()
    if have is not None and have.status == "done":
        return None
    if have is not None and job_state(have.status, have.heartbeat_at, now) == "running":
        label = f"{job['regime'][0]} x {job['agent'][0]} seed {job['seed']}"
        raise StoreError(f"db import: {label} is running in {where} (driver {have.owner}): import once that run stops")
    # every column but the id, those an older archive lacks at their defaults (the driver's bookkeeping,
    # format.JOB_SKIP, is in no archive: checked, so NULL), the stored model path dropped (an archive carries
    # no model, and a path is never trusted)
    values = {c.name: job.get(c.name, JOB_DEFAULTS.get(c.name)) for c in Job.__table__.columns if c.name != "id"}
    values = _datetimes(Job, values)
    values.update(model_path=None, regime_id=rid, agent_config_id=aid)
    if have is None:
        return s.execute(insert(Job).values(**values).returning(Job.id)).scalar_one()
    for table in ARCHIVE_TABLES.values():
        s.execute(delete(table).where(table.job_id == have.id))
    s.execute(update(Job).where(Job.id == have.id).values(**values).execution_options(synchronize_session=False))
    return have.id
