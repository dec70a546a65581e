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
(floats) or -1 (``first_overshoot_step``) with a ``<column>.null`` mask beside it. The job
columns of schema revision 0004 (``fake``, ``batch_id``, ``batch_size``, ``device``,
``source``, ``source_sha256``) travel too; an archive written before them reads as
``fake = false`` and NULLs. The tables of revisions 0005 and 0006 travel the same way:
``diagnostics.<column>`` (``job``, ``update``, ``timestep``, the quantities, and a column per
other name a plug-in recorded; one row per update, the long table pivoted, as before revision
0007; no update twice per job) and ``validation_episodes.<column>`` (no (training day, day) twice per job, training
days from 1, foods within a day); an archive written before them imports without those rows.

An archive is a file from anywhere, so nothing in it is believed (:func:`read_archive`):
before a database is opened (or created) the whole archive is checked, and the first thing
wrong is one line naming the archive, exit status 2, nothing written. Checked: the file is
a readable ``.npz`` of this format; every column is there, one-dimensional, of its type
(float64 for measurements, integers, strings, boolean NULL masks) and as long as the
table's ``job`` column; no array or field that the format does not have; every row's job
index in range; no NaN or infinity that is not a NULL, and no NULL where the column allows none; the
phases, statuses and engines known; no key twice (a config's name and version, a job's
key, an episode's or a step's primary key); per job, ``episodes`` training days (the
budget; an external agent's budget is the number of days it recorded), ``eval_episodes``
evaluation days and ``eval_episodes x H`` evaluation steps (H the regime's horizon), each
numbered in range, and foods and actions in range; every config's ``sha256`` recomputed
from its stored body, which names the same config; every name ``[a-z][a-z0-9_]*`` (64
characters at most), as files and figures are named after them; the meta's counts equal
the arrays'; seeds, counts and wall times non-negative, overshoot ratios in 0..1, texts at
most 65,536 characters, no infinity in the meta. Before anything is decompressed, the
members' declared sizes (at most 1 GiB in all) and each ``.npy`` header's shape (no larger
than its member) are read, no member name twice (:mod:`~nutribench.store.archive_zip`). No
text may hold a NUL (PostgreSQL stores none; refused on every backend). A config bearing a
shipped name and version must have the shipped content (:mod:`~nutribench.store.archive_installed`).
Every evaluation day's foods must be the seed's test days, and each is replayed from its
stored foods and actions on the archive's regime, and its steps and metrics must agree (:mod:`nutribench.store.archive_replay`); the
training days cannot be replayed. A stored model path is never trusted: the import drops it (``model_path``
NULL; an archive carries no model files, and a path from another machine names nothing
here). The configs' and jobs' ``source`` (the file or script they came from on the
exporting machine) are kept as text: nothing in nutribench opens them. :func:`export_results` runs the same checks before it writes, so a database whose
done jobs would not import says so at export.

Import matches configs by (name, version) and refuses one recorded with other content (a
changed file whose version was not bumped); it matches jobs by (regime config, agent config,
seed, budget, evaluation episodes). A job the destination already has done is left alone
(counted as ``kept``); one it has pending, interrupted or failed takes the archived result;
one another driver is running is refused; a dry run's jobs (``fake``) and real results are
never mixed in one database. Everything is written in one transaction, and the rows written
are counted against the archive's before the commit; a SQLite file the import created is
removed again if the import fails.
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

from nutribench.safe_write import atomic_write, check_file_target

# the format and the checks live in archive_meta and archive_check; importable here too (valid_name, ...)
from nutribench.store.archive_check import (
    check_contents,
    read_archive,
    verify_archive,
)
from nutribench.store.archive_meta import (
    CONFIG_SKIP,
    ENGINES,
    FORMAT,
    FORMAT_VERSION,
    JOB_DEFAULTS,
    JOB_SKIP,
    NAME_MAX,
    NAME_PATTERN,
    InvalidArchive,
    valid_name,
)
from nutribench.store.archive_tables import TABLES, archive_rows, database_rows
from nutribench.store.engine import (
    REGISTRATION_LOCK,
    StoreError,
    database_url,
    db_now,
    hold_write_lock,
    session_scope,
    sqlite_path,
)
from nutribench.store.models import AgentConfig, Job, RegimeConfig, insert_rows, job_state
from nutribench.store.schema import open_store

_BATCH = 20_000

__all__ = [
    "ENGINES",
    "FORMAT",
    "FORMAT_VERSION",
    "NAME_MAX",
    "NAME_PATTERN",
    "export_results",
    "import_results",
    "read_archive",
    "valid_name",
    "verify_archive",
]


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
    store = open_store(db)
    try:
        with store.engine.connect() as conn:
            query = (
                select(Job, RegimeConfig, AgentConfig)
                .join(RegimeConfig, Job.regime_id == RegimeConfig.id)
                .join(AgentConfig, Job.agent_config_id == AgentConfig.id)
                .where(Job.status == "done")
                .order_by(Job.id)
            )
            if algos:
                query = query.where(AgentConfig.name.in_(list(algos)))
            if regimes:
                query = query.where(RegimeConfig.name.in_(list(regimes)))
            with Session(bind=conn) as s:
                found = s.execute(query).all()
                if not found:
                    which = "".join(f" of {', '.join(names)}" for names in (algos, regimes) if names)
                    raise StoreError(f"db export: {store.display} holds no done jobs{which}: nothing to export")
                regimes = {r.id: _row(r, CONFIG_SKIP) for _, r, _ in found}
                agents = {a.id: _row(a, CONFIG_SKIP) for _, _, a in found}
                jobs, index = [], {}
                for job, regime, agent in found:
                    index[job.id] = len(jobs)
                    jobs.append(
                        {
                            **_row(job, JOB_SKIP),
                            "regime": [regime.name, regime.version],
                            "agent": [agent.name, agent.version],
                        }
                    )
                arrays: dict[str, np.ndarray] = {}
                counts = {"jobs": len(jobs)}
                for name in TABLES:
                    cols, rows = archive_rows(s, name, list(index))
                    counts[name] = len(rows)
                    arrays[f"{name}.job"] = np.array([index[r[0]] for r in rows], dtype=np.int32)
                    for i, col in enumerate(cols, start=1):
                        arrays.update(_encode(name, col, [r[i] for r in rows]))
        meta = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "source": store.display,
            "counts": counts,
            "regimes": list(regimes.values()),
            "agent_configs": list(agents.values()),
            "jobs": jobs,
        }
        # what this archive will be checked for on import, checked now: a job of this database
        # that no import would take is named here, and nothing is written
        meta = json.loads(json.dumps(meta, default=str))
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


# --------------------------------------------------------------------------- importing
def _job_values(job: dict[str, Any]) -> dict[str, Any]:
    """The job row to write: every column, those an older archive lacks at their defaults, the
    stored model path dropped (an archive carries no model, and a path is never trusted)."""
    values = {
        c.name: job.get(c.name, JOB_DEFAULTS.get(c.name)) for c in Job.__table__.columns if c.name not in JOB_SKIP
    }
    values["model_path"] = None
    return _datetimes(Job, values)


def _remove_new_file(path: Path | None) -> None:
    """Remove the SQLite file (and its WAL and journal) a failed import created."""
    if path is None:
        return
    for p in (path, *(path.with_name(path.name + s) for s in ("-wal", "-shm", "-journal"))):
        try:
            p.unlink(missing_ok=True)
        except OSError:  # pragma: no cover - best effort: the failure is reported anyway
            pass


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
    ok = False
    try:
        counts = _write(store, meta, arrays, path, on_step)
        ok = True
        return counts
    finally:
        store.dispose()
        if not ok and store.created:
            _remove_new_file(new_file)


def _write(
    store: Any, meta: dict[str, Any], arrays: dict[str, np.ndarray], path: Any, on_step: Callable[[str, int, int], None]
) -> dict[str, int]:
    fake = bool(meta["jobs"] and meta["jobs"][0].get("fake", False))
    with session_scope(store.engine) as s:
        hold_write_lock(s, REGISTRATION_LOCK)
        other = s.execute(select(func.count()).select_from(Job).where(Job.fake == (not fake))).scalar_one()
        if other:
            kind = (
                ("a dry run's jobs (fake)", f"{other} real jobs")
                if fake
                else ("real results", f"{other} dry-run jobs (fake)")
            )
            raise StoreError(
                f"db import: {path} holds {kind[0]} and {store.display} holds {kind[1]}: the two are never "
                "mixed in one database; import into another --db"
            )
        config_ids = {}
        for table, rows in ((RegimeConfig, meta["regimes"]), (AgentConfig, meta["agent_configs"])):
            for row in rows:
                have = s.execute(
                    select(table).where(table.name == row["name"], table.version == row["version"])
                ).scalar_one_or_none()
                if have is not None and have.sha256 != row["sha256"]:
                    raise StoreError(
                        f"db import: {row['name']} v{row['version']} is recorded in {store.display} with other "
                        f"content than in {path}: the two databases disagree on what that version is"
                    )
                if have is None:
                    have = table(**_datetimes(table, row))
                    s.add(have)
                    s.flush()
                config_ids[(table, row["name"], row["version"])] = have.id
        now = db_now(s)
        positions = {name: np.argsort(arrays[f"{name}.job"], kind="stable") for name in TABLES}
        bounds = {
            name: np.searchsorted(arrays[f"{name}.job"][positions[name]], np.arange(len(meta["jobs"]) + 1))
            for name in TABLES
        }
        counts = {"imported": 0, "kept": 0, **{name: 0 for name in TABLES}}  # the archive's rows
        written = {name: 0 for name in TABLES}  # the database's (diagnostics: a row per quantity)
        imported: list[int] = []
        for i, job in enumerate(meta["jobs"]):
            on_step("writing", i, len(meta["jobs"]))
            rid = config_ids[(RegimeConfig, *job["regime"])]
            aid = config_ids[(AgentConfig, *job["agent"])]
            label = f"{job['regime'][0]} x {job['agent'][0]} seed {job['seed']}"
            key = (
                Job.regime_id == rid,
                Job.agent_config_id == aid,
                Job.seed == job["seed"],
                Job.episodes == job["episodes"],
                Job.eval_episodes == job["eval_episodes"],
            )
            have = s.execute(select(Job).where(*key).order_by(Job.id)).scalars().first()
            values = _job_values(job)
            values.update(regime_id=rid, agent_config_id=aid, owner=None, heartbeat_at=None, worker_pid=None)
            if have is not None and have.status == "done":
                counts["kept"] += 1
                continue
            if have is not None and job_state(have.status, have.heartbeat_at, now) == "running":
                raise StoreError(
                    f"db import: {label} is running in {store.display} (driver {have.owner}): import once that run stops"
                )
            if have is None:
                job_id = s.execute(insert(Job).values(**values).returning(Job.id)).scalar_one()
            else:
                job_id = have.id
                for table in TABLES.values():
                    s.execute(delete(table).where(table.job_id == job_id))
                s.execute(
                    update(Job).where(Job.id == job_id).values(**values).execution_options(synchronize_session=False)
                )
            for name, table in TABLES.items():
                rows = positions[name][bounds[name][i] : bounds[name][i + 1]]
                n, decoded = database_rows(name, arrays, rows, job_id)
                counts[name] += n
                for start in range(0, len(decoded), _BATCH):
                    insert_rows(s, table, decoded[start : start + _BATCH])
                written[name] += len(decoded)
            counts["imported"] += 1
            imported.append(job_id)
        # compared before the commit: a mismatch rolls the whole import back
        for name, table in TABLES.items():
            held = sum(
                s.execute(select(func.count()).select_from(table).where(table.job_id.in_(chunk))).scalar_one()
                for chunk in _chunks(imported)
            )
            if held != written[name]:
                raise StoreError(
                    f"db import: {written[name]} {name} rows written but {held} found after: nothing imported"
                )
    return counts
