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
``fake = false`` and NULLs.

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
the arrays'. A stored model path is never trusted: the import drops it (``model_path``
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
import re
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import delete, func, insert, select, update
from sqlalchemy.orm import Session

from nutribench.config.loading import content_sha256
from nutribench.store.engine import (
    REGISTRATION_LOCK,
    StoreError,
    database_url,
    db_now,
    hold_write_lock,
    session_scope,
    sqlite_path,
)
from nutribench.store.jobs import job_state
from nutribench.store.models import JOB_STATUSES, PHASES, AgentConfig, Episode, EvalStep, Job, RegimeConfig
from nutribench.store.schema import open_store

FORMAT = "nutribench-results"
FORMAT_VERSION = 1
#: job columns an archive leaves out: ids (remapped on import) and the driver's bookkeeping
_JOB_SKIP = ("id", "regime_id", "agent_config_id", "owner", "heartbeat_at", "worker_pid")
_CONFIG_SKIP = ("id",)
_TABLES = {"episodes": Episode, "eval_steps": EvalStep}
_BATCH = 20_000

#: The names of regimes and agent configs: what files, figures and tables are named after.
NAME_PATTERN = re.compile(r"[a-z][a-z0-9_]*")
NAME_MAX = 64
#: job columns added by schema revision 0004, and what an archive written before them means
_JOB_DEFAULTS: dict[str, Any] = {"fake": False, "batch_id": None, "batch_size": None, "device": None, "source": None,
                                 "source_sha256": None}  # fmt: skip
#: what trained a job (``jobs.engine``); NULL for jobs of databases older than revision 0003
ENGINES = ("sb3", "batched", "external")
_SHA256 = re.compile(r"[0-9a-f]{64}")
_META_KEYS = {"format", "format_version", "source", "counts", "regimes", "agent_configs", "jobs"}
_INT32 = (-(2**31), 2**31 - 1)  # an Integer column on PostgreSQL


def valid_name(name: Any) -> bool:
    """Whether ``name`` is a regime or agent config name (``[a-z][a-z0-9_]*``, at most 64
    characters): the only strings read from a database or an archive that become part of a
    file name."""
    return isinstance(name, str) and len(name) <= NAME_MAX and NAME_PATTERN.fullmatch(name) is not None


class _Invalid(Exception):
    """What is wrong with an archive (the message, without the archive's name)."""


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


def _check_out(path: Path) -> None:
    """Refuse, before the database is read, an archive path that cannot be written."""
    if path.is_dir():
        raise StoreError(f"db export: {path} is a folder: give the archive's file name, e.g. {path / 'results.npz'}")
    parent = path.parent
    if not parent.is_dir():
        raise StoreError(f"db export: cannot write {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise StoreError(f"db export: cannot write {path}: folder {parent} is not writable")


def export_results(db: str, out: str | os.PathLike[str], algos: Sequence[str] | None = None,
                   regimes: Sequence[str] | None = None) -> dict[str, int]:  # fmt: skip
    """Write the done jobs of ``db`` (only those of agent configs named in ``algos`` and of
    regimes named in ``regimes``, where given) to the archive ``out``; rows written per table."""
    path = Path(out)
    _check_out(path)
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
        # what this archive will be checked for on import, checked now: a job of this database
        # that no import would take is named here, and nothing is written
        meta = json.loads(json.dumps(meta, default=str))
        try:
            _verify(meta, arrays)
        except _Invalid as e:
            raise StoreError(f"db export: {store.display} cannot be exported as it is: {e} (export the other jobs with --algos/--regimes)") from None
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
        tmp = path.with_name(path.name + ".tmp.npz")
        try:
            np.savez_compressed(tmp, **arrays)
            os.replace(tmp, path)
        except OSError as e:
            tmp.unlink(missing_ok=True)
            raise StoreError(f"db export: cannot write {path}: {e.strerror or e}") from None
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


# --------------------------------------------------------------------------- reading and checking
def _load(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The raw ``meta`` and arrays of the file ``path``; StoreError for one that is not a
    readable archive (missing, empty, truncated, bit-flipped, not a zip of arrays)."""
    not_archive = f"db import: {path} is not a results archive (`nutribench db export` writes one)"
    if os.path.isdir(path):
        raise StoreError(f"db import: {path} is a folder, not an archive: give the .npz file `nutribench db export` wrote")
    if not os.path.exists(path):
        raise StoreError(f"db import: {path}: no such file")
    try:
        if os.path.getsize(path) == 0:
            raise StoreError(f"{not_archive}: the file is empty")
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a .npy file: one array
            raise StoreError(f"{not_archive}: a single array, not a set of columns")
        with loaded as z:
            arrays = {k: z[k] for k in z.files}
    except StoreError:
        raise
    except Exception as e:  # noqa: BLE001 - bytes from anywhere: BadZipFile, zlib.error, EOFError, a bad .npy header
        # (ValueError, tokenize.TokenError, ...): whatever the reader trips on, the file is not an archive
        raise StoreError(f"{not_archive}: {_reason(e)}") from None
    meta_raw = arrays.pop("meta", None)
    if not isinstance(meta_raw, np.ndarray) or meta_raw.dtype != np.uint8 or meta_raw.ndim != 1:
        raise StoreError(f"{not_archive}: no meta")
    try:
        meta = json.loads(meta_raw.tobytes().decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise StoreError(f"{not_archive}: its meta is not JSON ({_reason(e)})") from None
    if not isinstance(meta, dict):
        raise StoreError(f"{not_archive}: its meta is not a JSON object")
    return meta, arrays


def _short(value: Any, n: int = 60) -> str:
    """``repr(value)``, cut to ``n`` characters: a value from the archive shown in the one line."""
    text = repr(value)
    return text if len(text) <= n else text[: n - 3] + "..."


def _reason(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def read_archive(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The archive's ``meta`` and its column arrays, every check of the module docstring
    passed; :class:`StoreError` (one line naming the archive and what is wrong) otherwise."""
    meta, arrays = _load(path)
    if meta.get("format") != FORMAT or type(meta.get("format_version")) is not int or meta["format_version"] != FORMAT_VERSION:
        if meta.get("format") != FORMAT:
            raise StoreError(f"db import: {path} is not a results archive (`nutribench db export` writes one): format {_short(meta.get('format'))}")
        raise StoreError(f"db import: {path} is format {FORMAT} v{_short(meta.get('format_version'), 20)}, "
                         f"this nutribench reads {FORMAT} v{FORMAT_VERSION}")  # fmt: skip
    try:
        _verify(meta, arrays)
    except _Invalid as e:
        raise StoreError(f"db import: {path} is damaged or was changed: {e}; nothing imported") from None
    except RecursionError:
        raise StoreError(f"db import: {path} is damaged or was changed: its meta is nested too deeply; nothing imported") from None
    return meta, arrays


def verify_archive(path: str | os.PathLike[str]) -> dict[str, int]:
    """Check the archive ``path`` (nothing is opened but the file); its counts."""
    meta, _ = read_archive(path)
    return dict(meta["counts"])


def _unsafe(value: Any) -> Any:
    """The stored body with ``"inf"``/``"-inf"``/``"nan"`` read back as the floats that
    :func:`nutribench.store.models.json_safe` wrote them for (the hash is of the config)."""
    if isinstance(value, str) and value in ("inf", "-inf", "nan"):
        return float(value)
    if isinstance(value, dict):
        return {k: _unsafe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_unsafe(v) for v in value]
    return value


def _check_value(col: Any, value: Any, what: str) -> None:
    """``value`` (from the meta's JSON) fits column ``col``."""
    if value is None:
        if not col.nullable:
            raise _Invalid(f"{what}: {col.name} is null")
        return
    kind = col.type.python_type if col.name != "body" else dict
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool) and _INT32[0] <= value <= _INT32[1]
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif kind is str:
        length = getattr(col.type, "length", None)
        ok = isinstance(value, str) and (length is None or len(value) <= length)
    elif kind is datetime:
        try:
            ok = isinstance(value, str) and bool(datetime.fromisoformat(value))
        except ValueError:
            ok = False
    elif kind is dict:
        ok = isinstance(value, dict)
    else:  # pragma: no cover - a column type this module does not know
        ok = False
    if not ok:
        raise _Invalid(f"{what}: {col.name} = {_short(value)} is not a valid {kind.__name__}"
                       + (f" (at most {col.type.length} characters)" if kind is str and isinstance(value, str) else ""))  # fmt: skip


def _check_row(table: type, row: Any, skip: Sequence[str], what: str, optional: dict[str, Any] | None = None,
               extra: Sequence[str] = ()) -> None:  # fmt: skip
    if not isinstance(row, dict):
        raise _Invalid(f"{what} is not a JSON object")
    cols = [c for c in table.__table__.columns if c.name not in skip]
    known = {c.name for c in cols} | set(extra)
    unknown = sorted(set(row) - known)
    if unknown:
        raise _Invalid(f"{what}: unknown field {_short(unknown[0])}")
    for col in cols:
        if col.name not in row:
            if optional is not None and col.name in optional:
                continue
            raise _Invalid(f"{what}: field {col.name!r} is missing")
        _check_value(col, row[col.name], what)


def _check_configs(meta: dict[str, Any]) -> dict[tuple[str, str, int], dict[str, Any]]:
    """The configs by (kind, name, version), each checked: fields, name, sha256 of its body."""
    out: dict[tuple[str, str, int], dict[str, Any]] = {}
    for key, table, kind in (("regimes", RegimeConfig, "regime"), ("agent_configs", AgentConfig, "agent config")):
        rows = meta.get(key)
        if not isinstance(rows, list):
            raise _Invalid(f"meta: {key!r} is missing or not a list")
        for i, row in enumerate(rows):
            what = f"{kind} {i}"
            _check_row(table, row, _CONFIG_SKIP, what)
            name, version = row["name"], row["version"]
            what = f"{kind} {_short(name)} v{version}"
            if not valid_name(name):
                raise _Invalid(f"{what}: the name is not a name ([a-z][a-z0-9_]*, at most {NAME_MAX} characters)")
            if kind == "agent config" and not valid_name(row["algo"]):
                raise _Invalid(f"{what}: algo {_short(row['algo'])} is not a name ([a-z][a-z0-9_]*)")
            if version < 1:
                raise _Invalid(f"{what}: version {version} is not a positive integer")
            if not _SHA256.fullmatch(row["sha256"]):
                raise _Invalid(f"{what}: sha256 {_short(row['sha256'], 70)} is not a sha256 (64 lowercase hex digits)")
            body = row["body"]
            if row["sha256"] not in (content_sha256(body), content_sha256(_unsafe(body))):
                raise _Invalid(f"{what}: its body does not hash to its sha256 {row['sha256'][:12]}... (the content was changed)")
            named = body.get("regime") if kind == "regime" else body
            if not isinstance(named, dict) or named.get("name") != name or named.get("version") != version:
                said = named if isinstance(named, dict) else {}
                raise _Invalid(f"{what}: its body describes {_short(said.get('name'))} v{_short(said.get('version'), 12)}, "
                               "not the config it is stored as")  # fmt: skip
            if kind == "agent config" and body.get("algo") != row["algo"]:
                raise _Invalid(f"{what}: its body's algo {_short(body.get('algo'))} is not its algo {_short(row['algo'])}")
            ident = (kind, name, version)
            if ident in out:
                raise _Invalid(f"{what} is listed twice")
            out[ident] = row
    return out


def _regime_shape(row: dict[str, Any], what: str) -> tuple[int, int]:
    """(horizon, number of foods) of a regime's stored body."""
    body = row["body"]
    reward, catalog = body.get("reward"), body.get("catalog")
    horizon = reward.get("horizon") if isinstance(reward, dict) else None
    foods = catalog.get("food") if isinstance(catalog, dict) else None
    if not isinstance(horizon, int) or isinstance(horizon, bool) or horizon < 1:
        raise _Invalid(f"{what}: its body has no horizon (reward.horizon)")
    if not isinstance(foods, list) or not foods:
        raise _Invalid(f"{what}: its body has no foods (catalog.food)")
    return horizon, len(foods)


def _check_jobs(meta: dict[str, Any], configs: dict[tuple[str, str, int], dict[str, Any]]) -> dict[str, np.ndarray]:
    """Every job checked; per job its budget, evaluation days, horizon, foods and engine."""
    jobs = meta.get("jobs")
    if not isinstance(jobs, list):
        raise _Invalid("meta: 'jobs' is missing or not a list")
    keys: set[tuple[Any, ...]] = set()
    shape: dict[tuple[str, int], tuple[int, int]] = {}
    out = {k: np.zeros(len(jobs), dtype=np.int64) for k in ("episodes", "eval_episodes", "horizon", "foods")}
    fakes = set()
    for i, job in enumerate(jobs):
        what = f"job {i}"
        _check_row(Job, job, _JOB_SKIP, what, optional=_JOB_DEFAULTS, extra=("regime", "agent"))
        refs = []
        for field, kind in (("regime", "regime"), ("agent", "agent config")):
            ref = job.get(field)
            if not (isinstance(ref, list) and len(ref) == 2 and isinstance(ref[0], str) and isinstance(ref[1], int)
                    and not isinstance(ref[1], bool)):  # fmt: skip
                raise _Invalid(f"{what}: {field} is not [name, version]")
            if (kind, ref[0], ref[1]) not in configs:
                raise _Invalid(f"{what}: its {kind} {_short(ref[0])} v{ref[1]} is not among the archive's configs")
            refs.append(tuple(ref))
        what = f"job {i} ({refs[0][0]} x {refs[1][0]} seed {job['seed']})"
        if job["status"] != "done":
            known = "a known status" if job["status"] in JOB_STATUSES else f"an unknown status (known: {', '.join(JOB_STATUSES)})"
            raise _Invalid(f"{what}: status {_short(job['status'])} is {known}; an archive holds done jobs only")
        if job["engine"] is not None and job["engine"] not in ENGINES:
            raise _Invalid(f"{what}: engine {_short(job['engine'])} is unknown (known: {', '.join(ENGINES)})")
        if job["episodes"] < 0 or job["eval_episodes"] < 0:
            raise _Invalid(f"{what}: a negative budget ({job['episodes']} training, {job['eval_episodes']} evaluation days)")
        if job.get("source_sha256") is not None and not _SHA256.fullmatch(job["source_sha256"]):
            raise _Invalid(f"{what}: source_sha256 {_short(job['source_sha256'], 70)} is not a sha256")
        key = (*refs, job["seed"], job["episodes"], job["eval_episodes"])
        if key in keys:
            raise _Invalid(f"{what} is listed twice (same configs, seed, budget and evaluation days)")
        keys.add(key)
        fakes.add(bool(job.get("fake", False)))
        if refs[0] not in shape:
            shape[refs[0]] = _regime_shape(configs[("regime", *refs[0])], f"regime {refs[0][0]!r} v{refs[0][1]}")
        out["episodes"][i], out["eval_episodes"][i] = job["episodes"], job["eval_episodes"]
        out["horizon"][i], out["foods"][i] = shape[refs[0]]
    if len(fakes) > 1:
        raise _Invalid("it mixes a dry run's jobs (fake) with real results")
    return out


def _check_arrays(arrays: dict[str, np.ndarray], n_jobs: int) -> dict[str, dict[str, np.ndarray]]:
    """Every table's columns there, of their type and length; NULL masks only where a column
    allows NULL; no other array. The columns by table (``job`` included, masks applied as NaN)."""
    expected: set[str] = set()
    tables: dict[str, dict[str, np.ndarray]] = {}
    for name, table in _TABLES.items():
        job = arrays.get(f"{name}.job")
        if not isinstance(job, np.ndarray) or job.ndim != 1 or job.dtype.kind != "i":
            raise _Invalid(f"column {name}.job is missing or not a column of integers")
        expected.add(f"{name}.job")
        n = len(job)
        cols = {"job": job}
        for col in _columns(table):
            key = f"{name}.{col.name}"
            arr = arrays.get(key)
            kind = col.type.python_type
            want = {float: "float64", int: "integers", str: "strings"}[kind]
            if arr is None:
                raise _Invalid(f"column {key} is missing")
            if not isinstance(arr, np.ndarray) or arr.ndim != 1:
                raise _Invalid(f"{key} is not a column")
            ok = {float: arr.dtype == np.float64, int: arr.dtype.kind == "i", str: arr.dtype.kind == "U"}[kind]
            if not ok:
                raise _Invalid(f"column {key} holds {arr.dtype}, not {want}")
            if len(arr) != n:
                raise _Invalid(f"column {key} has {len(arr):,} rows, {name}.job {n:,}")
            expected.add(key)
            null = arrays.get(f"{key}.null")
            if null is not None:
                if not col.nullable:
                    raise _Invalid(f"column {key} has NULLs, which it does not allow")
                if not isinstance(null, np.ndarray) or null.ndim != 1 or null.dtype != np.bool_ or len(null) != n:
                    raise _Invalid(f"{key}.null is not a boolean column of {n:,} rows")
                expected.add(f"{key}.null")
                cols[f"{col.name}.null"] = null
            if kind is float:
                bad = ~np.isfinite(arr)
                if null is not None:
                    bad &= ~null
                if bad.any():
                    row = int(np.argmax(bad))
                    raise _Invalid(f"column {key} holds {'NaN' if np.isnan(arr[row]) else arr[row]} in row {row} "
                                   "(a measurement is finite; a NULL is marked in its .null mask)")  # fmt: skip
                if null is not None:
                    arr = np.where(null, np.nan, arr)
            elif kind is int and n:
                vals = arr if null is None else arr[~null]
                if vals.size and (vals.min() < _INT32[0] or vals.max() > _INT32[1]):
                    raise _Invalid(f"column {key} holds integers out of range")
            elif kind is str and n:
                length = getattr(col.type, "length", None)
                if length is not None and arr.dtype.itemsize // 4 > length and (np.char.str_len(arr) > length).any():
                    raise _Invalid(f"column {key} holds strings longer than {length} characters")
            cols[col.name] = arr
        if n and (job.min() < 0 or job.max() >= n_jobs):
            bad = int(job.min()) if job.min() < 0 else int(job.max())
            raise _Invalid(f"{name} row {int(np.argmax(job == bad))} belongs to job {bad}, but the archive has {n_jobs} jobs")
        tables[name] = cols
    other = sorted(set(arrays) - expected)
    if other:
        raise _Invalid(f"array {_short(other[0])} is not part of the format")
    return tables


def _duplicate(keys: list[np.ndarray]) -> int | None:
    """A row whose key (the columns ``keys``) another row has too; None if all differ."""
    n = len(keys[0])
    if n < 2:
        return None
    order = np.lexsort(keys[::-1])
    same = np.ones(n - 1, dtype=bool)
    for k in keys:
        s = k[order]
        same &= s[1:] == s[:-1]
    if not same.any():
        return None
    return int(order[int(np.argmax(same)) + 1])


def _check_rows(tables: dict[str, dict[str, np.ndarray]], per_job: dict[str, np.ndarray], jobs: list[dict[str, Any]]) -> None:
    """Values in range and every job's rows complete: its budget of training days, its
    evaluation days, and H steps of each."""
    n_jobs = len(jobs)
    ep = tables["episodes"]
    job = ep["job"]
    phase_ok = np.isin(ep["phase"], PHASES)
    if not phase_ok.all():
        row = int(np.argmin(phase_ok))
        raise _Invalid(f"episodes row {row}: phase {_short(str(ep['phase'][row]))} is neither train nor eval")
    train = ep["phase"] == "train"
    limit = np.where(train, per_job["episodes"][job], per_job["eval_episodes"][job]) if job.size else job
    bad = (ep["episode"] < 0) | (ep["episode"] >= limit)
    if bad.any():
        row = int(np.argmax(bad))
        raise _Invalid(f"episodes row {row}: {ep['phase'][row]} episode {int(ep['episode'][row])} of job {int(job[row])} "
                       f"is out of its range 0..{int(limit[row]) - 1}")  # fmt: skip
    horizon = per_job["horizon"][job] if job.size else job
    bad = (ep["foods"] < 0) | (ep["foods"] > horizon)
    if bad.any():
        row = int(np.argmax(bad))
        raise _Invalid(f"episodes row {row}: {int(ep['foods'][row])} foods in a day of {int(horizon[row])} steps")
    first = ep["first_overshoot_step"]
    bad = (first < 1) | (first > horizon)
    if "first_overshoot_step.null" in ep:
        bad &= ~ep["first_overshoot_step.null"]
    if bad.any():
        row = int(np.argmax(bad))
        raise _Invalid(f"episodes row {row}: first_overshoot_step {int(first[row])} is out of its range 1..{int(horizon[row])}")
    row = _duplicate([job, train.astype(np.int8), ep["episode"]])
    if row is not None:
        raise _Invalid(f"episodes row {row}: job {int(job[row])}'s {ep['phase'][row]} episode {int(ep['episode'][row])} is there twice")
    st = tables["eval_steps"]
    sjob = st["job"]
    horizon = per_job["horizon"][sjob] if sjob.size else sjob
    for col, lo, hi in (("episode", 0, per_job["eval_episodes"][sjob] - 1 if sjob.size else sjob), ("step", 1, horizon),
                        ("food", 0, per_job["foods"][sjob] - 1 if sjob.size else sjob), ("action", 0, 1)):  # fmt: skip
        bad = (st[col] < lo) | (st[col] > hi)
        if bad.any():
            row = int(np.argmax(bad))
            top = hi if np.isscalar(hi) else int(hi[row])
            raise _Invalid(f"eval_steps row {row}: {col} {int(st[col][row])} of job {int(sjob[row])} is out of its range {lo}..{top}")
    row = _duplicate([sjob, st["episode"], st["step"]])
    if row is not None:
        raise _Invalid(f"eval_steps row {row}: job {int(sjob[row])}'s evaluation episode {int(st['episode'][row])} "
                       f"step {int(st['step'][row])} is there twice")  # fmt: skip
    trains = np.bincount(job[train], minlength=n_jobs)
    evals = np.bincount(job[~train], minlength=n_jobs)
    steps = np.bincount(sjob, minlength=n_jobs)
    want_steps = per_job["eval_episodes"] * per_job["horizon"]
    for i, j in enumerate(jobs):
        label = f"job {i} ({j['regime'][0]} x {j['agent'][0]} seed {j['seed']})"
        if trains[i] != per_job["episodes"][i]:
            budget = "the training days it recorded" if j.get("engine") == "external" else "its budget"
            raise _Invalid(f"{label} has {trains[i]:,} training episodes, {budget} is {per_job['episodes'][i]:,}")
        if evals[i] != per_job["eval_episodes"][i]:
            raise _Invalid(f"{label} has {evals[i]:,} evaluation episodes, not its {per_job['eval_episodes'][i]:,}")
        if steps[i] != want_steps[i]:
            raise _Invalid(f"{label} has {steps[i]:,} evaluation steps, not {per_job['eval_episodes'][i]} days x "
                           f"{per_job['horizon'][i]} = {want_steps[i]:,}")  # fmt: skip


def _verify(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Every check of the module docstring on an archive's content; :class:`_Invalid` with the
    first thing wrong."""
    unknown = sorted(set(meta) - _META_KEYS)
    if unknown:
        raise _Invalid(f"meta: unknown field {_short(unknown[0])}")
    configs = _check_configs(meta)
    per_job = _check_jobs(meta, configs)
    tables = _check_arrays(arrays, len(meta["jobs"]))
    _check_rows(tables, per_job, meta["jobs"])
    counts = meta.get("counts")
    have = {"jobs": len(meta["jobs"]), **{name: len(cols["job"]) for name, cols in tables.items()}}
    if not isinstance(counts, dict) or set(counts) != set(have):
        raise _Invalid(f"meta: counts should list {', '.join(have)}")
    for key, n in have.items():
        if counts[key] != n:
            raise _Invalid(f"meta says {counts[key]} {key}, the archive holds {n:,}")


# --------------------------------------------------------------------------- importing
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


def _job_values(job: dict[str, Any]) -> dict[str, Any]:
    """The job row to write: every column, those an older archive lacks at their defaults, the
    stored model path dropped (an archive carries no model, and a path is never trusted)."""
    values = {c.name: job.get(c.name, _JOB_DEFAULTS.get(c.name)) for c in Job.__table__.columns if c.name not in _JOB_SKIP}
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


def import_results(path: str | os.PathLike[str], db: str, *, on_job: Callable[[str], None] | None = None) -> dict[str, int]:
    """Merge the archive ``path`` into ``db`` (created or upgraded); counts of jobs
    ``imported`` and ``kept`` (already done there) and of rows written per table. The archive
    is checked whole (:func:`read_archive`) before the database is opened."""
    meta, arrays = read_archive(path)
    file = sqlite_path(database_url(db))
    new_file = file if file is not None and not file.exists() else None
    store = open_store(db, writer=True)
    ok = False
    try:
        counts = _write(store, meta, arrays, path, on_job)
        ok = True
        return counts
    finally:
        store.dispose()
        if not ok and store.created:
            _remove_new_file(new_file)


def _write(store: Any, meta: dict[str, Any], arrays: dict[str, np.ndarray], path: Any,
           on_job: Callable[[str], None] | None) -> dict[str, int]:  # fmt: skip
    fake = bool(meta["jobs"] and meta["jobs"][0].get("fake", False))
    with session_scope(store.engine) as s:
        hold_write_lock(s, REGISTRATION_LOCK)
        other = s.execute(select(func.count()).select_from(Job).where(Job.fake == (not fake))).scalar_one()
        if other:
            kind = ("a dry run's jobs (fake)", f"{other} real jobs") if fake else ("real results", f"{other} dry-run jobs (fake)")
            raise StoreError(f"db import: {path} holds {kind[0]} and {store.display} holds {kind[1]}: the two are never "
                             "mixed in one database; import into another --db")  # fmt: skip
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
            values = _job_values(job)
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
