"""``nutribench db export`` / ``db import``: the finished jobs of a database as one portable
file, and that file merged into another database.

Where ``db copy`` moves a whole database into an empty one keeping ids, an archive carries
chosen *results* between databases that already hold others: a grid run in parts on
machines (or working sessions) that do not share a disk, or a reproduction's results
shipped beside its report for anyone to load and query.

The file is a NumPy ``.npz`` (zip, no pickle): ``meta`` is UTF-8 JSON (format, the configs'
full rows, one entry per job with every column but its ids and the driver's bookkeeping);
``episodes.<column>`` and ``eval_steps.<column>`` are column arrays, ``job`` being the
job's position in ``meta["jobs"]``. Values are kept exactly (float64); a NULL becomes NaN
(floats) or -1 (``first_overshoot_step``) with a ``<column>.null`` mask beside it.

Import matches configs by (name, version) and refuses one recorded with other content (a
changed file whose version was not bumped); it matches jobs by (regime config, agent config,
seed, budget, evaluation episodes). A job the destination already has done is left alone
(counted as ``kept``); one it has pending, interrupted or failed takes the archived result;
one another driver is running is refused. Everything is written in one transaction, and
the rows written are counted against the archive's before the commit.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import delete, func, insert, select, update
from sqlalchemy.orm import Session

from nutribench.store.engine import REGISTRATION_LOCK, StoreError, db_now, hold_write_lock, session_scope
from nutribench.store.jobs import job_state
from nutribench.store.models import AgentConfig, Episode, EvalStep, Job, RegimeConfig
from nutribench.store.schema import open_store

FORMAT = "nutribench-results"
FORMAT_VERSION = 1
#: job columns an archive leaves out: ids (remapped on import) and the driver's bookkeeping
_JOB_SKIP = ("id", "regime_id", "agent_config_id", "owner", "heartbeat_at", "worker_pid")
_CONFIG_SKIP = ("id",)
_TABLES = {"episodes": Episode, "eval_steps": EvalStep}
_BATCH = 20_000


def _row(obj: Any, skip: Sequence[str]) -> dict[str, Any]:
    out = {}
    for col in obj.__table__.columns:
        if col.name in skip:
            continue
        value = getattr(obj, col.key)
        out[col.name] = value.isoformat() if isinstance(value, datetime) else value
    return out


def _datetimes(table: type, row: dict[str, Any]) -> dict[str, Any]:
    out = dict(row)
    for col in table.__table__.columns:
        if col.name in out and isinstance(out[col.name], str) and col.type.python_type is datetime:
            out[col.name] = datetime.fromisoformat(out[col.name])
    return out


def _columns(table: type) -> list[Any]:
    return [c for c in table.__table__.columns if c.name != "job_id"]


def export_results(db: str, out: str | os.PathLike[str], algos: Sequence[str] | None = None,
                   regimes: Sequence[str] | None = None) -> dict[str, int]:  # fmt: skip
    """Write the done jobs of ``db`` (only those of agent configs named in ``algos`` and of
    regimes named in ``regimes``, where given) to the archive ``out``; rows written per table."""
    store = open_store(db)
    try:
        with store.engine.connect() as conn:
            query = select(Job, RegimeConfig, AgentConfig).join(RegimeConfig, Job.regime_id == RegimeConfig.id).join(
                AgentConfig, Job.agent_config_id == AgentConfig.id).where(Job.status == "done").order_by(Job.id)  # fmt: skip
            if algos:
                query = query.where(AgentConfig.name.in_(list(algos)))
            if regimes:
                query = query.where(RegimeConfig.name.in_(list(regimes)))
            with Session(bind=conn) as s:
                found = s.execute(query).all()
                if not found:
                    which = "".join(f" of {', '.join(names)}" for names in (algos, regimes) if names)
                    raise StoreError(f"db export: {store.display} holds no done jobs{which}: nothing to export")
                regimes = {r.id: _row(r, _CONFIG_SKIP) for _, r, _ in found}
                agents = {a.id: _row(a, _CONFIG_SKIP) for _, _, a in found}
                jobs, index = [], {}
                for job, regime, agent in found:
                    index[job.id] = len(jobs)
                    jobs.append({**_row(job, _JOB_SKIP), "regime": [regime.name, regime.version], "agent": [agent.name, agent.version]})
                arrays: dict[str, np.ndarray] = {}
                counts = {"jobs": len(jobs)}
                for name, table in _TABLES.items():
                    cols = _columns(table)
                    rows = s.execute(
                        select(table.__table__.c.job_id, *[table.__table__.c[c.name] for c in cols])
                        .where(table.__table__.c.job_id.in_(list(index))).order_by(*table.__table__.primary_key.columns)
                    ).all()  # fmt: skip
                    counts[name] = len(rows)
                    arrays[f"{name}.job"] = np.array([index[r[0]] for r in rows], dtype=np.int32)
                    for i, col in enumerate(cols, start=1):
                        arrays.update(_encode(name, col, [r[i] for r in rows]))
        meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "source": store.display, "counts": counts,
                "regimes": list(regimes.values()), "agent_configs": list(agents.values()), "jobs": jobs}  # fmt: skip
        arrays["meta"] = np.frombuffer(json.dumps(meta, default=str).encode(), dtype=np.uint8)
        path = Path(out)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
        return counts
    finally:
        store.dispose()


def _encode(table: str, col: Any, values: list[Any]) -> dict[str, np.ndarray]:
    kind = col.type.python_type
    nulls = np.array([v is None for v in values], dtype=bool)
    key = f"{table}.{col.name}"
    if kind is float:
        arr = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
    elif kind is int:
        arr = np.array([-1 if v is None else v for v in values], dtype=np.int64)
        arr = arr.astype(np.int32) if arr.size == 0 or (arr.min() >= -(2**31) and arr.max() < 2**31) else arr
    else:
        arr = np.array(["" if v is None else v for v in values], dtype=str)
    out = {key: arr}
    if nulls.any():
        out[f"{key}.null"] = nulls
    return out


def _chunks(ids: list[int], n: int = 500) -> list[list[int]]:
    return [ids[i : i + n] for i in range(0, len(ids), n)]


def read_archive(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The archive's ``meta`` and its column arrays; :class:`StoreError` for a file that is
    not one."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(arrays.pop("meta").tobytes().decode())
    except FileNotFoundError:
        raise StoreError(f"db import: {path}: no such file") from None
    except (OSError, ValueError, KeyError) as e:
        raise StoreError(f"db import: {path} is not a results archive (`nutribench db export` writes one): {e}") from None
    if meta.get("format") != FORMAT or meta.get("format_version") != FORMAT_VERSION:
        raise StoreError(f"db import: {path} is format {meta.get('format')} v{meta.get('format_version')}, "
                         f"this nutribench reads {FORMAT} v{FORMAT_VERSION}")  # fmt: skip
    return meta, arrays


def _decoded(table: type, name: str, arrays: dict[str, np.ndarray], rows: np.ndarray) -> list[dict[str, Any]]:
    """Rows ``rows`` (positions) of table ``name`` as insert dicts (without job_id)."""
    cols = {}
    for col in _columns(table):
        arr = arrays[f"{name}.{col.name}"][rows]
        values = arr.tolist()
        null = arrays.get(f"{name}.{col.name}.null")
        if null is not None:
            values = [None if n else v for v, n in zip(values, null[rows].tolist(), strict=True)]
        cols[table.__mapper__.get_property_by_column(col).key] = values
    keys = list(cols)
    return [dict(zip(keys, vals, strict=True)) for vals in zip(*cols.values(), strict=True)]


def import_results(path: str | os.PathLike[str], db: str, *, on_job: Callable[[str], None] | None = None) -> dict[str, int]:
    """Merge the archive ``path`` into ``db`` (created or upgraded); counts of jobs
    ``imported`` and ``kept`` (already done there) and of rows written per table."""
    meta, arrays = read_archive(path)
    store = open_store(db, writer=True)
    try:
        with session_scope(store.engine) as s:
            hold_write_lock(s, REGISTRATION_LOCK)
            config_ids = {}
            for table, rows in ((RegimeConfig, meta["regimes"]), (AgentConfig, meta["agent_configs"])):
                for row in rows:
                    have = s.execute(select(table).where(table.name == row["name"], table.version == row["version"])).scalar_one_or_none()
                    if have is not None and have.sha256 != row["sha256"]:
                        raise StoreError(f"db import: {row['name']} v{row['version']} is recorded in {store.display} with other "
                                         f"content than in {path}: the two databases disagree on what that version is")  # fmt: skip
                    if have is None:
                        have = table(**_datetimes(table, row))
                        s.add(have)
                        s.flush()
                    config_ids[(table, row["name"], row["version"])] = have.id
            now = db_now(s)
            positions = {name: np.argsort(arrays[f"{name}.job"], kind="stable") for name in _TABLES}
            bounds = {name: np.searchsorted(arrays[f"{name}.job"][positions[name]], np.arange(len(meta["jobs"]) + 1)) for name in _TABLES}
            counts = {"imported": 0, "kept": 0, "episodes": 0, "eval_steps": 0}
            imported: list[int] = []
            for i, job in enumerate(meta["jobs"]):
                rid = config_ids[(RegimeConfig, *job["regime"])]
                aid = config_ids[(AgentConfig, *job["agent"])]
                label = f"{job['regime'][0]} x {job['agent'][0]} seed {job['seed']}"
                key = (Job.regime_id == rid, Job.agent_config_id == aid, Job.seed == job["seed"],
                       Job.episodes == job["episodes"], Job.eval_episodes == job["eval_episodes"])  # fmt: skip
                have = s.execute(select(Job).where(*key).order_by(Job.id)).scalars().first()
                values = {k: v for k, v in _datetimes(Job, job).items() if k not in ("regime", "agent")}
                values.update(regime_id=rid, agent_config_id=aid, owner=None, heartbeat_at=None, worker_pid=None)
                if have is not None and have.status == "done":
                    counts["kept"] += 1
                    continue
                if have is not None and job_state(have.status, have.heartbeat_at, now) == "running":
                    raise StoreError(f"db import: {label} is running in {store.display} (driver {have.owner}): import once that run stops")
                if have is None:
                    job_id = s.execute(insert(Job).values(**values).returning(Job.id)).scalar_one()
                else:
                    job_id = have.id
                    for table in _TABLES.values():
                        s.execute(delete(table).where(table.job_id == job_id))
                    s.execute(update(Job).where(Job.id == job_id).values(**values).execution_options(synchronize_session=False))
                for name, table in _TABLES.items():
                    rows = positions[name][bounds[name][i] : bounds[name][i + 1]]
                    decoded = _decoded(table, name, arrays, rows)
                    for start in range(0, len(decoded), _BATCH):
                        s.execute(insert(table), [{"job_id": job_id, **r} for r in decoded[start : start + _BATCH]])
                    counts[name] += len(decoded)
                counts["imported"] += 1
                imported.append(job_id)
                if on_job:
                    on_job(label)
            # compared before the commit: a mismatch rolls the whole import back
            for name, table in _TABLES.items():
                held = sum(s.execute(select(func.count()).select_from(table).where(table.job_id.in_(chunk))).scalar_one()
                           for chunk in _chunks(imported))  # fmt: skip
                if held != counts[name]:
                    raise StoreError(f"db import: {counts[name]} {name} rows written but {held} found after: nothing imported")
        return counts
    finally:
        store.dispose()
