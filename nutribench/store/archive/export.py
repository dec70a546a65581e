"""``nutribench db export``: the done jobs of a database written as one archive
(:func:`export_results`), checked as an import would check it before a byte is written.

Each job's rows go into column arrays (:func:`archive_rows`; ``diagnostics`` pivoted back to one
row per update, :func:`wide_diagnostics`), a NULL written as NaN or -1 with a ``.null`` mask.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import Table, select
from sqlalchemy.orm import Session

from nutribench.diagnostics import QUANTITIES, TIMESTEP
from nutribench.safe_write import atomic_write, check_file_target
from nutribench.store.archive.check import check_contents
from nutribench.store.archive.format import (
    ARCHIVE_TABLES,
    CONFIG_SKIP,
    FORMAT,
    FORMAT_VERSION,
    JOB_SKIP,
    InvalidArchive,
    columns,
    diagnostics_layout,
)
from nutribench.store.engine import StoreError
from nutribench.store.models import AgentConfig, Diagnostic, Job, RegimeConfig
from nutribench.store.schema import open_store


def _row(obj: Any, skip: Sequence[str]) -> dict[str, Any]:
    """The columns of the ORM object ``obj`` but ``skip``, by name, a datetime as its ISO string."""
    values = {c.name: getattr(obj, c.key) for c in obj.__table__.columns if c.name not in skip}
    return {k: v.isoformat() if isinstance(v, datetime) else v for k, v in values.items()}


def _check_out(path: Path) -> None:
    """Refuse, before the database is read, an archive path that cannot be written: a folder,
    a device node or a FIFO (:func:`nutribench.safe_write.check_file_target`), a missing folder."""
    if path.is_dir():
        raise StoreError(f"db export: {path} is a folder: give the archive's file name, e.g. {path / 'results.npz'}")
    check_file_target(path, "db export", StoreError)
    if not path.parent.is_dir():
        raise StoreError(f"db export: cannot write {path}: folder {path.parent} does not exist")


def export_results(
    db: str, out: str | os.PathLike[str], algos: Sequence[str] | None = None, regimes: Sequence[str] | None = None
) -> dict[str, int]:
    """Write the done jobs of ``db`` (only those of agent configs named in ``algos`` and of
    regimes named in ``regimes``, where given) to the archive ``out``; rows written per table."""
    path = Path(out)
    _check_out(path)
    with open_store(db) as store:
        with store.engine.connect() as conn, Session(bind=conn) as s:
            meta, arrays = _archive(s, store.display, algos, regimes)
        # what this archive will be checked for on import, checked now: a job of this database
        # that no import would take is named here, and nothing is written
        try:
            check_contents(meta, arrays)
        except InvalidArchive as e:
            raise StoreError(
                f"db export: {store.display} cannot be exported as it is: {e} (export the other jobs with --algos/--regimes)"
            ) from None
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
        with (
            atomic_write(path, "db export", StoreError, "free space or give another path") as tmp,
            open(tmp, "wb") as fh,
        ):
            np.savez_compressed(fh, **arrays)  # to the open file: numpy adds no .npz to its name
        return dict(meta["counts"])


def _archive(
    s: Session, display: str, algos: Sequence[str] | None, regimes: Sequence[str] | None
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The meta (as JSON reads it back) and the column arrays of the done jobs ``s`` holds of
    ``algos`` and ``regimes`` (all where None)."""
    query = (
        select(Job, RegimeConfig, AgentConfig)
        .join(RegimeConfig, Job.regime_id == RegimeConfig.id)
        .join(AgentConfig, Job.agent_config_id == AgentConfig.id)
        .where(Job.status == "done")
        .order_by(Job.id)
    )
    for column, names in ((AgentConfig.name, algos), (RegimeConfig.name, regimes)):
        if names:
            query = query.where(column.in_(list(names)))
    found = s.execute(query).all()
    if not found:
        which = "".join(f" of {', '.join(names)}" for names in (algos, regimes) if names)
        raise StoreError(f"db export: {display} holds no done jobs{which}: nothing to export")
    index = {job.id: i for i, (job, _, _) in enumerate(found)}
    jobs = [{**_row(j, JOB_SKIP), "regime": [r.name, r.version], "agent": [a.name, a.version]} for j, r, a in found]
    arrays: dict[str, np.ndarray] = {}
    counts = {"jobs": len(jobs)}
    for name in ARCHIVE_TABLES:
        cols, rows = archive_rows(s, name, list(index))
        counts[name] = len(rows)
        arrays[f"{name}.job"] = np.array([index[r[0]] for r in rows], dtype=np.int32)
        for i, col in enumerate(cols, start=1):
            arrays.update(_encode(name, col, [r[i] for r in rows]))
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "source": display,
        "counts": counts,
        "regimes": list({r.id: _row(r, CONFIG_SKIP) for _, r, _ in found}.values()),
        "agent_configs": list({a.id: _row(a, CONFIG_SKIP) for _, _, a in found}.values()),
        "jobs": jobs,
    }
    return json.loads(json.dumps(meta, default=str)), arrays


def _encode(table: str, col: Any, values: list[Any]) -> dict[str, np.ndarray]:
    kind, key = col.type.python_type, f"{table}.{col.name}"
    nulls = np.array([v is None for v in values], dtype=bool)
    fill, dtype = {float: (np.nan, np.float64), int: (-1, np.int64), str: ("", str)}[kind]  # a NULL's stand-in
    arr = np.array([fill if v is None else v for v in values], dtype=dtype)
    if kind is int and (arr.size == 0 or (arr.min() >= -(2**31) and arr.max() < 2**31)):
        arr = arr.astype(np.int32)
    return {key: arr, f"{key}.null": nulls} if nulls.any() else {key: arr}


def wide_diagnostics(session: Any, job_ids: list[int]) -> tuple[Table, list[tuple[Any, ...]]]:
    """The long ``diagnostics`` rows of jobs ``job_ids`` as an archive holds them: its layout
    (:func:`~nutribench.store.archive.format.diagnostics_layout`, with every other name they
    have) and one tuple per update (``job_id``, then the layout's columns; None where the update
    has no such quantity), ordered by job and update."""
    by: dict[tuple[int, int], dict[str, float]] = {}
    query = (
        select(Diagnostic.job_id, Diagnostic.update, Diagnostic.name, Diagnostic.value)
        .where(Diagnostic.job_id.in_(job_ids))
        .order_by(Diagnostic.job_id, Diagnostic.update, Diagnostic.name)
    )
    for job, update, name, value in session.execute(query):  # the timestep an integer column again
        by.setdefault((job, update), {})[name] = int(value) if name == TIMESTEP else value
    layout = diagnostics_layout(sorted({n for values in by.values() for n in values} - {TIMESTEP, *QUANTITIES}))
    names = [c.name for c in columns(layout)][1:]
    return layout, [(job, update, *(values.get(n) for n in names)) for (job, update), values in by.items()]


def archive_rows(session: Any, name: str, job_ids: list[int]) -> tuple[list[Any], list[Any]]:
    """Table ``name`` of jobs ``job_ids`` as an archive holds it: its columns (but ``job_id``)
    and its rows, each ``job_id`` first, by primary key (``diagnostics``: :func:`wide_diagnostics`)."""
    if name == "diagnostics":
        layout, rows = wide_diagnostics(session, job_ids)
        return columns(layout), rows
    t = ARCHIVE_TABLES[name].__table__
    cols = columns(t)
    query = select(t.c.job_id, *[t.c[c.name] for c in cols]).where(t.c.job_id.in_(job_ids))
    return cols, session.execute(query.order_by(*t.primary_key.columns)).all()
