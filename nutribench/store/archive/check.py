"""An archive checked whole before anything is written (:mod:`nutribench.store.archive`'s
docstring lists the checks): :func:`read_archive` reads the file (:func:`~nutribench.store.
archive.format.open_archive`) and refuses, in one line naming the archive, one that is not an
archive of this format and version or whose content fails a check; :func:`verify_archive`
checks a file alone; :func:`check_contents` runs every check on a meta and its arrays.

The checks of the meta: the configs (fields, names, each body hashing to its ``sha256`` and
naming the config it is stored as, held against the installed ones:
:mod:`~nutribench.store.archive.installed`) and the jobs (fields, references to the archive's
configs, status, engine, budgets, no key twice). The checks of the arrays: every column there,
one-dimensional, of its type and length, NULL masks only where allowed, no other array; every
row's job, phase, episode, step, food and action in range; no key twice; per job its training
days, evaluation days and steps complete (an optional table that an archive written before it
lacks reads as empty); then the evaluation days replayed
(:mod:`~nutribench.store.archive.replay`), and the meta's counts compared.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from datetime import datetime
from typing import Any

import numpy as np

from nutribench.config.loading import content_sha256
from nutribench.engines import Engine
from nutribench.store.archive.format import (
    ARCHIVE_TABLES,
    CONFIG_SKIP,
    ENGINES,
    FORMAT,
    FORMAT_VERSION,
    JOB_DEFAULTS,
    JOB_SKIP,
    META_KEYS,
    NAME_MAX,
    OPTIONAL_TABLES,
    InvalidArchive,
    archive_table,
    columns,
    first_row,
    job_label,
    open_archive,
    short_repr,
    valid_config_name,
)
from nutribench.store.archive.installed import check_installed
from nutribench.store.archive.replay import replay_evaluations
from nutribench.store.engine import StoreError
from nutribench.store.models import JOB_STATUSES, PHASES, AgentConfig, Job, RegimeConfig

_SHA256 = re.compile(r"[0-9a-f]{64}")
#: the range of an Integer column on PostgreSQL
INT32_RANGE = (-(2**31), 2**31 - 1)
#: The longest text an archive may carry in a column without a length of its own (a source
#: path, an error text): a shared file's strings are read, so they are bounded.
TEXT_MAX = 65_536
#: The float metrics of ``episodes`` with a range: from 0 to this.
_EPISODE_FLOATS = (("overshoot_ratio", 1.0), ("final_distance", np.inf), ("entropy", np.inf))
#: Job columns that count something: never negative (a seed too: the CLI takes none below 0).
_NON_NEGATIVE = ("seed", "episodes", "eval_episodes", "attempt", "failures", "episodes_done", "wall_seconds")
_UNKNOWN_STATUS = f"an unknown status (known: {', '.join(JOB_STATUSES)})"


def read_archive(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The archive's ``meta`` and its column arrays, every check of
    :mod:`nutribench.store.archive`'s docstring passed; :class:`StoreError` (one line naming
    the archive and what is wrong) otherwise."""
    meta, arrays = open_archive(path)
    if meta.get("format") != FORMAT:
        raise StoreError(
            f"db import: {path} is not a results archive (`nutribench db export` writes one): format {short_repr(meta.get('format'))}"
        )
    if type(meta.get("format_version")) is not int or meta["format_version"] != FORMAT_VERSION:
        raise StoreError(
            f"db import: {path} is format {FORMAT} v{short_repr(meta.get('format_version'), 20)}, "
            f"this nutribench reads {FORMAT} v{FORMAT_VERSION}"
        )
    try:
        check_contents(meta, arrays)
    except (InvalidArchive, RecursionError) as e:
        reason = e if isinstance(e, InvalidArchive) else "its meta is nested too deeply"
        raise StoreError(f"db import: {path} is damaged or was changed: {reason}; nothing imported") from None
    return meta, arrays


def verify_archive(path: str | os.PathLike[str]) -> dict[str, int]:
    """Check the archive ``path`` (nothing is opened but the file); its counts."""
    meta, _ = read_archive(path)
    return dict(meta["counts"])


def check_contents(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Every check of :mod:`nutribench.store.archive`'s docstring on an archive's content;
    :class:`InvalidArchive` with the first thing wrong."""
    if unknown := sorted(set(meta) - META_KEYS):
        raise InvalidArchive(f"meta: unknown field {short_repr(unknown[0])}")
    configs = check_meta_configs(meta)
    check_installed(meta)
    per_job = check_meta_jobs(meta, configs)
    _fill_optional(arrays)
    tables = {name: _check_table(name, arrays, len(meta["jobs"])) for name in ARCHIVE_TABLES}
    if other := sorted(set(arrays) - {f"{name}.{col}" for name, cols in tables.items() for col in cols}):
        raise InvalidArchive(f"array {short_repr(other[0])} is not part of the format")
    _check_rows(tables, per_job, meta["jobs"])
    replay_evaluations(meta, tables, per_job)
    counts = meta.get("counts")
    have = {"jobs": len(meta["jobs"]), **{name: len(cols["job"]) for name, cols in tables.items()}}
    # an archive without an optional table (or without its rows) need not count it
    listed = counts if isinstance(counts, dict) else have
    have = {k: n for k, n in have.items() if n or k in listed or k not in OPTIONAL_TABLES}
    if not isinstance(counts, dict) or set(counts) != set(have):
        raise InvalidArchive(f"meta: counts should list {', '.join(have)}")
    for key, n in have.items():
        if counts[key] != n:
            raise InvalidArchive(f"meta says {counts[key]} {key}, the archive holds {n:,}")


# --------------------------------------------------------------------------- the meta
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


def _nul(value: Any) -> str | None:
    """Where ``value`` (a string, or a JSON body's keys and strings) holds a NUL character, which
    PostgreSQL stores in no text or JSON column (and SQLite would, so it is refused on both):
    ``"character 12"`` or ``"key 'a' character 3"``; None if it holds none."""
    if isinstance(value, str):
        k = value.find("\x00")
        return None if k < 0 else f"character {k}"
    named = isinstance(value, dict)
    for key, v in value.items() if named else enumerate(value) if isinstance(value, list) else ():
        if named and (where := _nul(key)) is not None:
            return f"a key, {where}"
        if (where := _nul(v)) is not None:
            return f"{short_repr(key, 30)} {where}" if named else f"[{key}] {where}"
    return None


def _valid(kind: type, col: Any, value: Any) -> bool:
    """Whether the (non-null) ``value`` is one of column ``col``, of Python type ``kind``."""
    if kind is datetime:
        try:
            return isinstance(value, str) and bool(datetime.fromisoformat(value))
        except ValueError:
            return False
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    return {
        bool: isinstance(value, bool),
        int: number and isinstance(value, int) and INT32_RANGE[0] <= value <= INT32_RANGE[1],
        float: number and math.isfinite(value),
        str: isinstance(value, str) and len(value) <= (getattr(col.type, "length", None) or TEXT_MAX),
        dict: isinstance(value, dict),
    }[kind]


def _check_row(table: type, row: Any, skip: Sequence[str], what: str, optional: Any = (), extra: Any = ()) -> None:
    """The meta's ``row`` has every column of ``table`` (but ``skip``; those of ``optional`` may
    be missing), each value fitting its column, no NUL character in a text, no other field."""
    if not isinstance(row, dict):
        raise InvalidArchive(f"{what} is not a JSON object")
    cols = [c for c in table.__table__.columns if c.name not in skip]
    if unknown := sorted(set(row) - {c.name for c in cols} - set(extra)):
        raise InvalidArchive(f"{what}: unknown field {short_repr(unknown[0])}")
    for col in (c for c in cols if c.name in row or c.name not in optional):
        if col.name not in row:
            raise InvalidArchive(f"{what}: field {col.name!r} is missing")
        value = row[col.name]
        if (where := _nul(value)) is not None:
            raise InvalidArchive(
                f"{what}: {col.name} holds a NUL byte ({where}), which no text column stores (PostgreSQL refuses it)"
            )
        if value is None and not col.nullable:
            raise InvalidArchive(f"{what}: {col.name} is null")
        kind = col.type.python_type if col.name != "body" else dict
        if value is not None and not _valid(kind, col, value):
            limit = getattr(col.type, "length", None) or TEXT_MAX
            most = f" (at most {limit:,} characters)" if kind is str and isinstance(value, str) else ""
            raise InvalidArchive(f"{what}: {col.name} = {short_repr(value)} is not a valid {kind.__name__}{most}")


def _check_config(kind: str, row: dict[str, Any]) -> None:
    """A config of the meta (fields checked): its name, version, sha256 and body."""
    name, version, body = row["name"], row["version"], row["body"]
    what = f"{kind} {short_repr(name)} v{version}"
    if not valid_config_name(name):
        raise InvalidArchive(f"{what}: the name is not a name ([a-z][a-z0-9_]*, at most {NAME_MAX} characters)")
    if kind == "agent config" and not valid_config_name(row["algo"]):
        raise InvalidArchive(f"{what}: algo {short_repr(row['algo'])} is not a name ([a-z][a-z0-9_]*)")
    if version < 1:
        raise InvalidArchive(f"{what}: version {version} is not a positive integer")
    if not _SHA256.fullmatch(row["sha256"]):
        raise InvalidArchive(
            f"{what}: sha256 {short_repr(row['sha256'], 70)} is not a sha256 (64 lowercase hex digits)"
        )
    if row["sha256"] not in (content_sha256(body), content_sha256(_unsafe(body))):
        raise InvalidArchive(
            f"{what}: its body does not hash to its sha256 {row['sha256'][:12]}... (the content was changed)"
        )
    named = body.get("regime") if kind == "regime" else body
    if not isinstance(named, dict) or named.get("name") != name or named.get("version") != version:
        said = named if isinstance(named, dict) else {}
        raise InvalidArchive(
            f"{what}: its body describes {short_repr(said.get('name'))} v{short_repr(said.get('version'), 12)}, "
            "not the config it is stored as"
        )
    if kind == "agent config" and body.get("algo") != row["algo"]:
        raise InvalidArchive(
            f"{what}: its body's algo {short_repr(body.get('algo'))} is not its algo {short_repr(row['algo'])}"
        )


def check_meta_configs(meta: dict[str, Any]) -> dict[tuple[str, str, int], dict[str, Any]]:
    """The configs by (kind, name, version), each checked: fields, name, sha256 of its body."""
    out: dict[tuple[str, str, int], dict[str, Any]] = {}
    for key, table, kind in (("regimes", RegimeConfig, "regime"), ("agent_configs", AgentConfig, "agent config")):
        rows = meta.get(key)
        if not isinstance(rows, list):
            raise InvalidArchive(f"meta: {key!r} is missing or not a list")
        for i, row in enumerate(rows):
            _check_row(table, row, CONFIG_SKIP, f"{kind} {i}")
            _check_config(kind, row)
            ident = (kind, row["name"], row["version"])
            if ident in out:
                raise InvalidArchive(f"{kind} {short_repr(row['name'])} v{row['version']} is listed twice")
            out[ident] = row
    return out


def _regime_shape(configs: dict[tuple[str, str, int], Any], ref: tuple[str, int]) -> tuple[int, int]:
    """(horizon, number of foods) of the stored body of the archive's regime ``ref`` (name, version)."""
    body, what = configs[("regime", *ref)]["body"], f"regime {ref[0]!r} v{ref[1]}"
    reward, catalog = body.get("reward"), body.get("catalog")
    horizon = reward.get("horizon") if isinstance(reward, dict) else None
    foods = catalog.get("food") if isinstance(catalog, dict) else None
    if not isinstance(horizon, int) or isinstance(horizon, bool) or horizon < 1:
        raise InvalidArchive(f"{what}: its body has no horizon (reward.horizon)")
    if not isinstance(foods, list) or not foods:
        raise InvalidArchive(f"{what}: its body has no foods (catalog.food)")
    return horizon, len(foods)


def _job_refs(job: dict[str, Any], what: str, configs: dict[tuple[str, str, int], Any]) -> list[tuple[str, int]]:
    """The job's (regime, agent config) references, each [name, version] of an archive's config."""
    refs = []
    for field, kind in (("regime", "regime"), ("agent", "agent config")):
        ref = job.get(field)
        if not (isinstance(ref, list) and len(ref) == 2 and isinstance(ref[0], str) and type(ref[1]) is int):
            raise InvalidArchive(f"{what}: {field} is not [name, version]")
        if (kind, ref[0], ref[1]) not in configs:
            raise InvalidArchive(
                f"{what}: its {kind} {short_repr(ref[0])} v{ref[1]} is not among the archive's configs"
            )
        refs.append((ref[0], ref[1]))
    return refs


def _check_job(job: dict[str, Any], what: str) -> None:
    """A job of the meta (fields checked): done, of a known engine, its counts in range."""
    if job["status"] != "done":
        known = "a known status" if job["status"] in JOB_STATUSES else _UNKNOWN_STATUS
        raise InvalidArchive(f"{what}: status {short_repr(job['status'])} is {known}; an archive holds done jobs only")
    if job["engine"] is not None and job["engine"] not in ENGINES:
        raise InvalidArchive(f"{what}: engine {short_repr(job['engine'])} is unknown (known: {', '.join(ENGINES)})")
    if job["episodes"] < 0 or job["eval_episodes"] < 0:
        raise InvalidArchive(
            f"{what}: a negative budget ({job['episodes']} training, {job['eval_episodes']} evaluation days)"
        )
    for col in _NON_NEGATIVE:
        if job.get(col) is not None and job[col] < 0:
            raise InvalidArchive(f"{what}: {col} {job[col]} is negative")
    if job.get("batch_size") is not None and job["batch_size"] < 1:
        raise InvalidArchive(f"{what}: batch_size {job['batch_size']} is not a positive integer")
    if job.get("source_sha256") is not None and not _SHA256.fullmatch(job["source_sha256"]):
        raise InvalidArchive(f"{what}: source_sha256 {short_repr(job['source_sha256'], 70)} is not a sha256")


def check_meta_jobs(meta: dict[str, Any], configs: dict[tuple[str, str, int], dict[str, Any]]) -> dict[str, np.ndarray]:
    """Every job checked; per job its budget, evaluation days, horizon and foods."""
    jobs = meta.get("jobs")
    if not isinstance(jobs, list):
        raise InvalidArchive("meta: 'jobs' is missing or not a list")
    keys: set[tuple[Any, ...]] = set()
    out = {k: np.zeros(len(jobs), dtype=np.int64) for k in ("episodes", "eval_episodes", "horizon", "foods")}
    for i, job in enumerate(jobs):
        _check_row(Job, job, JOB_SKIP, f"job {i}", optional=JOB_DEFAULTS, extra=("regime", "agent"))
        refs = _job_refs(job, f"job {i}", configs)
        what = job_label(i, job)
        _check_job(job, what)
        key = (*refs, job["seed"], job["episodes"], job["eval_episodes"])
        if key in keys:
            raise InvalidArchive(f"{what} is listed twice (same configs, seed, budget and evaluation days)")
        keys.add(key)
        out["episodes"][i], out["eval_episodes"][i] = job["episodes"], job["eval_episodes"]
        out["horizon"][i], out["foods"][i] = _regime_shape(configs, refs[0])
    if len({bool(job.get("fake", False)) for job in jobs}) > 1:
        raise InvalidArchive("it mixes a dry run's jobs (fake) with real results")
    return out


# --------------------------------------------------------------------------- the arrays
def inner_nul(arr: np.ndarray) -> np.ndarray:
    """Which strings of a ``<U`` column hold a NUL character: NumPy pads with NULs and drops
    the trailing ones, so a NUL is one followed by another character of the string."""
    width = arr.dtype.itemsize // 4
    if not len(arr) or not width:
        return np.zeros(len(arr), dtype=bool)
    filled = np.ascontiguousarray(arr).view(np.uint32).reshape(len(arr), width) != 0
    last = np.where(filled.any(axis=1), width - np.argmax(filled[:, ::-1], axis=1), 0)
    return filled.sum(axis=1) < last


def _fill_optional(arrays: dict[str, np.ndarray]) -> None:
    """An optional table (:data:`OPTIONAL_TABLES`) that an archive has no array of at all
    (written before the table existed) added to ``arrays`` as empty columns."""
    dtypes = {float: np.float64, int: np.int32, str: "<U1"}
    for name in OPTIONAL_TABLES:
        if not any(k.startswith(f"{name}.") for k in arrays):
            arrays[f"{name}.job"] = np.zeros(0, dtype=np.int32)
            for col in columns(archive_table(name, {})):
                arrays[f"{name}.{col.name}"] = np.zeros(0, dtype=dtypes[col.type.python_type])


def _check_column(col: Any, name: str, arrays: dict[str, np.ndarray], n: int) -> None:
    """Column ``col`` of table ``name`` in ``arrays`` (and its NULL mask, if any): there, one
    dimension of ``n`` rows, of its type; finite measurements, integers of their range, strings
    of their length without a NUL; a mask only where the column allows NULL."""
    kind, key = col.type.python_type, f"{name}.{col.name}"
    arr, null = arrays.get(key), arrays.get(f"{key}.null")
    if arr is None:
        raise InvalidArchive(f"column {key} is missing")
    if not isinstance(arr, np.ndarray) or arr.ndim != 1:
        raise InvalidArchive(f"{key} is not a column")
    if not {float: arr.dtype == np.float64, int: arr.dtype.kind == "i", str: arr.dtype.kind == "U"}[kind]:
        raise InvalidArchive(
            f"column {key} holds {arr.dtype}, not {({float: 'float64', int: 'integers', str: 'strings'})[kind]}"
        )
    if len(arr) != n:
        raise InvalidArchive(f"column {key} has {len(arr):,} rows, {name}.job {n:,}")
    if null is not None:
        if not col.nullable:
            raise InvalidArchive(f"column {key} has NULLs, which it does not allow")
        if not isinstance(null, np.ndarray) or null.ndim != 1 or null.dtype != np.bool_ or len(null) != n:
            raise InvalidArchive(f"{key}.null is not a boolean column of {n:,} rows")
    if kind is float and (row := first_row(~np.isfinite(arr) & (True if null is None else ~null))) is not None:
        raise InvalidArchive(
            f"column {key} holds {'NaN' if np.isnan(arr[row]) else arr[row]} in row {row} "
            "(a measurement is finite; a NULL is marked in its .null mask)"
        )
    vals = arr if null is None else arr[~null]
    if kind is int and vals.size and (vals.min() < INT32_RANGE[0] or vals.max() > INT32_RANGE[1]):
        raise InvalidArchive(f"column {key} holds integers out of range")
    if kind is str and n:
        length = getattr(col.type, "length", None)
        if length is not None and arr.dtype.itemsize // 4 > length and (np.char.str_len(arr) > length).any():
            raise InvalidArchive(f"column {key} holds strings longer than {length} characters")
        if (row := first_row(inner_nul(arr))) is not None:
            raise InvalidArchive(
                f"column {key} row {row} holds a NUL byte, which no text column stores (PostgreSQL refuses it)"
            )


def _check_table(name: str, arrays: dict[str, np.ndarray], n_jobs: int) -> dict[str, np.ndarray]:
    """Table ``name``'s columns (:func:`_check_column`) and NULL masks, by column name (``job``
    included, each mask as ``<column>.null``, a float column's NULLs as NaN), every row's job
    in range."""
    job = arrays.get(f"{name}.job")
    if not isinstance(job, np.ndarray) or job.ndim != 1 or job.dtype.kind != "i":
        raise InvalidArchive(f"column {name}.job is missing or not a column of integers")
    cols = {"job": job}
    for col in columns(archive_table(name, arrays)):
        _check_column(col, name, arrays, len(job))
        cols[col.name], null = arrays[f"{name}.{col.name}"], arrays.get(f"{name}.{col.name}.null")
        if null is not None:  # kept beside its column, and applied as NaN to a float one
            cols[f"{col.name}.null"] = null
            if col.type.python_type is float:
                cols[col.name] = np.where(null, np.nan, cols[col.name])
    if job.size and (job.min() < 0 or job.max() >= n_jobs):
        bad = int(job.min()) if job.min() < 0 else int(job.max())
        raise InvalidArchive(
            f"{name} row {int(np.argmax(job == bad))} belongs to job {bad}, but the archive has {n_jobs} jobs"
        )
    return cols


#: Each table's key (after ``job``) and how a message names a row's, for the no-key-twice check.
_KEYS = {
    "episodes": (("phase", "episode"), "{phase} episode {episode}"),
    "eval_steps": (("episode", "step"), "evaluation episode {episode} step {step}"),
    "diagnostics": (("update",), "update {update}"),
    "validation_episodes": (("train_day", "episode"), "validation day {episode} after training day {train_day}"),
}


def _ranges(tables: dict[str, dict[str, np.ndarray]], per_job: dict[str, np.ndarray]) -> dict[str, list[Any]]:
    """Per table, in the order checked, each ``(column, lo, hi, message)``: the column's values
    lie in lo..hi (a bound a scalar or one per row), the message formatted with the row's."""
    ep, st, va = tables["episodes"], tables["eval_steps"], tables["validation_episodes"]
    horizon = per_job["horizon"][ep["job"]]
    limit = np.where(ep["phase"] == "train", per_job["episodes"][ep["job"]], per_job["eval_episodes"][ep["job"]])
    step, valid = "{col} {v} of job {job} is out of its range {lo}..{hi}", "{col} {v} is out of its range"
    return {
        "episodes": [
            ("episode", 0, limit - 1, "{phase} episode {v} of job {job} is out of its range 0..{hi}"),
            ("foods", 0, horizon, "{v} foods in a day of {hi} steps"),
            *((c, 0.0, hi, "{col} {v:.6g} is out of its range {lo:g}..{hi:g}") for c, hi in _EPISODE_FLOATS),
            ("first_overshoot_step", 1, horizon, "first_overshoot_step {v} is out of its range 1..{hi}"),
        ],
        "eval_steps": [
            ("episode", 0, per_job["eval_episodes"][st["job"]] - 1, step),
            ("step", 1, per_job["horizon"][st["job"]], step),
            ("food", 0, per_job["foods"][st["job"]] - 1, step),
            ("action", 0, 1, step),
        ],
        "diagnostics": [(c, 0, np.inf, "{col} {v} is negative") for c in ("update", "timestep")],
        "validation_episodes": [
            ("train_day", 1, np.inf, valid),
            ("episode", 0, np.inf, valid),
            ("foods", 0, per_job["horizon"][va["job"]], valid),
        ],
    }


def _check_rows(
    tables: dict[str, dict[str, np.ndarray]], per_job: dict[str, np.ndarray], jobs: list[dict[str, Any]]
) -> None:
    """Table by table every row's values in range (a NULL passes: a float's is NaN, which
    compares false, an integer's has its mask) and no key twice; then every job's rows
    complete: its budget of training days, its evaluation days, and H steps of each."""
    ep, sjob = tables["episodes"], tables["eval_steps"]["job"]
    if (row := first_row(~np.isin(ep["phase"], PHASES))) is not None:
        raise InvalidArchive(f"episodes row {row}: phase {short_repr(str(ep['phase'][row]))} is neither train nor eval")
    for name, ranges in _ranges(tables, per_job).items():
        t = tables[name]
        for col, lo, hi, message in ranges:
            if (row := first_row(((t[col] < lo) | (t[col] > hi)) & ~t.get(f"{col}.null", np.False_))) is not None:
                at = {k: a[row] for k, a in t.items()} | {"col": col, "v": t[col][row]}
                at |= {k: b if np.isscalar(b) else b[row] for k, b in (("lo", lo), ("hi", hi))}
                raise InvalidArchive(f"{name} row {row}: {message.format_map(at)}")
        key, what = _KEYS[name]  # sorted by its key, a row with the key of the one before it is there twice
        keys = [t["job"], *(t[k] for k in key)]
        order = np.lexsort(keys[::-1])
        same = np.logical_and.reduce([k[order][1:] == k[order][:-1] for k in keys])
        if (twice := first_row(same)) is not None:
            row = int(order[twice + 1])
            said = what.format_map({k: t[k][row] for k in key})
            raise InvalidArchive(f"{name} row {row}: job {t['job'][row]}'s {said} is there twice")
    train = ep["phase"] == "train"
    trains = np.bincount(ep["job"][train], minlength=len(jobs))
    evals = np.bincount(ep["job"][~train], minlength=len(jobs))
    steps = np.bincount(sjob, minlength=len(jobs))
    want_steps = per_job["eval_episodes"] * per_job["horizon"]
    for i, j in enumerate(jobs):
        label = job_label(i, j)
        external = j.get("engine") == Engine.EXTERNAL
        # an external job trained elsewhere (a saved model evaluated) has its budget and no training rows
        if trains[i] != per_job["episodes"][i] and not (external and trains[i] == 0):
            budget = "the training days it recorded" if external else "its budget"
            raise InvalidArchive(f"{label} has {trains[i]:,} training episodes, {budget} is {per_job['episodes'][i]:,}")
        if evals[i] != per_job["eval_episodes"][i]:
            raise InvalidArchive(
                f"{label} has {evals[i]:,} evaluation episodes, not its {per_job['eval_episodes'][i]:,}"
            )
        if steps[i] != want_steps[i]:
            raise InvalidArchive(
                f"{label} has {steps[i]:,} evaluation steps, not {per_job['eval_episodes'][i]} days x "
                f"{per_job['horizon'][i]} = {want_steps[i]:,}"
            )
