"""The results archive's format (``nutribench db export`` / ``db import``, see
:mod:`nutribench.store.archive`) and the checks of its ``meta``: the format's name and
version, the columns an archive leaves out or defaults, the names regimes and agent configs
may have (:func:`valid_name`), and the checks of the configs (fields, names, each body
hashing to its ``sha256`` and naming the config it is stored as) and of the jobs (fields,
references to the archive's configs, status, engine, budgets, no key twice, per job its
budget, evaluation days, horizon and foods). What is wrong raises :class:`InvalidArchive` with the
message, without the archive's name; :mod:`nutribench.store.archive_check` adds that.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from datetime import datetime
from typing import Any

import numpy as np

from nutribench.config.loading import content_sha256
from nutribench.engines import ENGINES as ALL_ENGINES
from nutribench.store.models import (
    JOB_STATUSES,
    AgentConfig,
    Job,
    RegimeConfig,
)

FORMAT = "nutribench-results"
FORMAT_VERSION = 1
#: job columns an archive leaves out: ids (remapped on import) and the driver's bookkeeping
JOB_SKIP = ("id", "regime_id", "agent_config_id", "owner", "heartbeat_at", "worker_pid")
#: agent/regime config columns an archive leaves out (ids, remapped on import)
CONFIG_SKIP = ("id",)

#: The names of regimes and agent configs: what files, figures and tables are named after.
NAME_PATTERN = re.compile(r"[a-z][a-z0-9_]*")
NAME_MAX = 64
#: job columns added by schema revision 0004, and what an archive written before them means
JOB_DEFAULTS: dict[str, Any] = {
    "fake": False,
    "batch_id": None,
    "batch_size": None,
    "device": None,
    "source": None,
    "source_sha256": None,
}
#: what trained a job (``jobs.engine``); NULL for jobs of databases older than revision 0003
ENGINES = ALL_ENGINES
_SHA256 = re.compile(r"[0-9a-f]{64}")
#: the keys of an archive's ``meta``
META_KEYS = {"format", "format_version", "source", "counts", "regimes", "agent_configs", "jobs"}
#: the range of an Integer column on PostgreSQL
INT32_RANGE = (-(2**31), 2**31 - 1)
#: The longest text an archive may carry in a column without a length of its own (a source
#: path, an error text): a shared file's strings are read, so they are bounded.
TEXT_MAX = 65_536
#: Job columns that count something: never negative (a seed too: the CLI takes none below 0).
_NON_NEGATIVE = ("seed", "episodes", "eval_episodes", "attempt", "failures", "episodes_done", "wall_seconds")


def valid_name(name: Any) -> bool:
    """Whether ``name`` is a regime or agent config name (``[a-z][a-z0-9_]*``, at most 64
    characters): the only strings read from a database or an archive that become part of a
    file name."""
    return isinstance(name, str) and len(name) <= NAME_MAX and NAME_PATTERN.fullmatch(name) is not None


class InvalidArchive(Exception):
    """What is wrong with an archive (the message, without the archive's name)."""


def short_repr(value: Any, n: int = 60) -> str:
    """``repr(value)``, cut to ``n`` characters: a value from the archive shown in the one line."""
    text = repr(value)
    return text if len(text) <= n else text[: n - 3] + "..."


def one_line_reason(e: BaseException) -> str:
    """``str(e)`` on one line (whitespace collapsed), cut to 160 characters; the type's name if empty."""
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 160 else text[:157] + "..."


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
    if isinstance(value, dict):
        for key, v in value.items():
            where = _nul(key) if isinstance(key, str) else None
            if where is not None:
                return f"a key, {where}"
            where = _nul(v)
            if where is not None:
                return f"{short_repr(key, 30)} {where}"
    if isinstance(value, list):
        for n, v in enumerate(value):
            where = _nul(v)
            if where is not None:
                return f"[{n}] {where}"
    return None


def _check_value(col: Any, value: Any, what: str) -> None:
    """``value`` (from the meta's JSON) fits column ``col``; no NUL character in a text."""
    where = _nul(value)
    if where is not None:
        raise InvalidArchive(
            f"{what}: {col.name} holds a NUL byte ({where}), which no text column stores (PostgreSQL refuses it)"
        )
    if value is None:
        if not col.nullable:
            raise InvalidArchive(f"{what}: {col.name} is null")
        return
    kind = col.type.python_type if col.name != "body" else dict
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool) and INT32_RANGE[0] <= value <= INT32_RANGE[1]
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    elif kind is str:
        length = getattr(col.type, "length", None) or TEXT_MAX
        ok = isinstance(value, str) and len(value) <= length
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
        raise InvalidArchive(
            f"{what}: {col.name} = {short_repr(value)} is not a valid {kind.__name__}"
            + (
                f" (at most {getattr(col.type, 'length', None) or TEXT_MAX:,} characters)"
                if kind is str and isinstance(value, str)
                else ""
            )
        )


def _check_row(
    table: type,
    row: Any,
    skip: Sequence[str],
    what: str,
    optional: dict[str, Any] | None = None,
    extra: Sequence[str] = (),
) -> None:
    if not isinstance(row, dict):
        raise InvalidArchive(f"{what} is not a JSON object")
    cols = [c for c in table.__table__.columns if c.name not in skip]
    known = {c.name for c in cols} | set(extra)
    unknown = sorted(set(row) - known)
    if unknown:
        raise InvalidArchive(f"{what}: unknown field {short_repr(unknown[0])}")
    for col in cols:
        if col.name not in row:
            if optional is not None and col.name in optional:
                continue
            raise InvalidArchive(f"{what}: field {col.name!r} is missing")
        _check_value(col, row[col.name], what)


def check_meta_configs(meta: dict[str, Any]) -> dict[tuple[str, str, int], dict[str, Any]]:
    """The configs by (kind, name, version), each checked: fields, name, sha256 of its body."""
    out: dict[tuple[str, str, int], dict[str, Any]] = {}
    for key, table, kind in (("regimes", RegimeConfig, "regime"), ("agent_configs", AgentConfig, "agent config")):
        rows = meta.get(key)
        if not isinstance(rows, list):
            raise InvalidArchive(f"meta: {key!r} is missing or not a list")
        for i, row in enumerate(rows):
            what = f"{kind} {i}"
            _check_row(table, row, CONFIG_SKIP, what)
            name, version = row["name"], row["version"]
            what = f"{kind} {short_repr(name)} v{version}"
            if not valid_name(name):
                raise InvalidArchive(f"{what}: the name is not a name ([a-z][a-z0-9_]*, at most {NAME_MAX} characters)")
            if kind == "agent config" and not valid_name(row["algo"]):
                raise InvalidArchive(f"{what}: algo {short_repr(row['algo'])} is not a name ([a-z][a-z0-9_]*)")
            if version < 1:
                raise InvalidArchive(f"{what}: version {version} is not a positive integer")
            if not _SHA256.fullmatch(row["sha256"]):
                raise InvalidArchive(
                    f"{what}: sha256 {short_repr(row['sha256'], 70)} is not a sha256 (64 lowercase hex digits)"
                )
            body = row["body"]
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
            ident = (kind, name, version)
            if ident in out:
                raise InvalidArchive(f"{what} is listed twice")
            out[ident] = row
    return out


def _regime_shape(row: dict[str, Any], what: str) -> tuple[int, int]:
    """(horizon, number of foods) of a regime's stored body."""
    body = row["body"]
    reward, catalog = body.get("reward"), body.get("catalog")
    horizon = reward.get("horizon") if isinstance(reward, dict) else None
    foods = catalog.get("food") if isinstance(catalog, dict) else None
    if not isinstance(horizon, int) or isinstance(horizon, bool) or horizon < 1:
        raise InvalidArchive(f"{what}: its body has no horizon (reward.horizon)")
    if not isinstance(foods, list) or not foods:
        raise InvalidArchive(f"{what}: its body has no foods (catalog.food)")
    return horizon, len(foods)


def check_meta_jobs(meta: dict[str, Any], configs: dict[tuple[str, str, int], dict[str, Any]]) -> dict[str, np.ndarray]:
    """Every job checked; per job its budget, evaluation days, horizon, foods and engine."""
    jobs = meta.get("jobs")
    if not isinstance(jobs, list):
        raise InvalidArchive("meta: 'jobs' is missing or not a list")
    keys: set[tuple[Any, ...]] = set()
    shape: dict[tuple[str, int], tuple[int, int]] = {}
    out = {k: np.zeros(len(jobs), dtype=np.int64) for k in ("episodes", "eval_episodes", "horizon", "foods")}
    fakes = set()
    for i, job in enumerate(jobs):
        what = f"job {i}"
        _check_row(Job, job, JOB_SKIP, what, optional=JOB_DEFAULTS, extra=("regime", "agent"))
        refs = []
        for field, kind in (("regime", "regime"), ("agent", "agent config")):
            ref = job.get(field)
            if not (
                isinstance(ref, list)
                and len(ref) == 2
                and isinstance(ref[0], str)
                and isinstance(ref[1], int)
                and not isinstance(ref[1], bool)
            ):
                raise InvalidArchive(f"{what}: {field} is not [name, version]")
            if (kind, ref[0], ref[1]) not in configs:
                raise InvalidArchive(
                    f"{what}: its {kind} {short_repr(ref[0])} v{ref[1]} is not among the archive's configs"
                )
            refs.append(tuple(ref))
        what = f"job {i} ({refs[0][0]} x {refs[1][0]} seed {job['seed']})"
        if job["status"] != "done":
            known = (
                "a known status"
                if job["status"] in JOB_STATUSES
                else f"an unknown status (known: {', '.join(JOB_STATUSES)})"
            )
            raise InvalidArchive(
                f"{what}: status {short_repr(job['status'])} is {known}; an archive holds done jobs only"
            )
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
        key = (*refs, job["seed"], job["episodes"], job["eval_episodes"])
        if key in keys:
            raise InvalidArchive(f"{what} is listed twice (same configs, seed, budget and evaluation days)")
        keys.add(key)
        fakes.add(bool(job.get("fake", False)))
        if refs[0] not in shape:
            shape[refs[0]] = _regime_shape(configs[("regime", *refs[0])], f"regime {refs[0][0]!r} v{refs[0][1]}")
        out["episodes"][i], out["eval_episodes"][i] = job["episodes"], job["eval_episodes"]
        out["horizon"][i], out["foods"][i] = shape[refs[0]]
    if len(fakes) > 1:
        raise InvalidArchive("it mixes a dry run's jobs (fake) with real results")
    return out


def inner_nul(arr: np.ndarray) -> np.ndarray:
    """Which strings of a ``<U`` column hold a NUL character: NumPy pads with NULs and drops
    the trailing ones, so a NUL is one followed by another character of the string."""
    width = arr.dtype.itemsize // 4
    if not len(arr) or not width:
        return np.zeros(len(arr), dtype=bool)
    filled = np.ascontiguousarray(arr).view(np.uint32).reshape(len(arr), width) != 0
    last = np.where(filled.any(axis=1), width - np.argmax(filled[:, ::-1], axis=1), 0)
    return filled.sum(axis=1) < last
