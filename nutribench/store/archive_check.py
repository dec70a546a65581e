"""Reading a results archive and checking it whole before anything is written
(:mod:`nutribench.store.archive`'s docstring lists the checks): :func:`read_archive` loads the
``.npz`` (no pickle) and refuses, in one line naming the archive, a file that is not a readable
archive of this format and version, or whose content fails a check; :func:`verify_archive`
checks a file alone. Here are the checks of the file and of its arrays (every column there,
one-dimensional, of its type and length, NULL masks only where allowed, no other array;
every row's job, phase, episode, step, food and action in range; no key twice; per job its
training days, evaluation days and steps complete; a training diagnostics table, which
archives written before it lack, read as empty) and :func:`check_contents`, which runs them with
the meta's checks (:mod:`nutribench.store.archive_meta`) and compares the meta's counts.
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from nutribench.engines import Engine
from nutribench.store.archive_installed import check_installed
from nutribench.store.archive_meta import (
    FORMAT,
    FORMAT_VERSION,
    INT32_RANGE,
    META_KEYS,
    InvalidArchive,
    check_meta_configs,
    check_meta_jobs,
    inner_nul,
    one_line_reason,
    short_repr,
)
from nutribench.store.archive_replay import replay_evaluations
from nutribench.store.archive_tables import OPTIONAL_TABLES, TABLES, archive_table, columns
from nutribench.store.archive_zip import check_sizes
from nutribench.store.engine import StoreError
from nutribench.store.models import PHASES


def _load(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The raw ``meta`` and arrays of the file ``path``; StoreError for one that is not a
    readable archive (missing, empty, truncated, bit-flipped, not a zip of arrays)."""
    not_archive = f"db import: {path} is not a results archive (`nutribench db export` writes one)"
    if os.path.isdir(path):
        raise StoreError(
            f"db import: {path} is a folder, not an archive: give the .npz file `nutribench db export` wrote"
        )
    if not os.path.exists(path):
        raise StoreError(f"db import: {path}: no such file")
    try:
        if os.path.getsize(path) == 0:
            raise StoreError(f"{not_archive}: the file is empty")
        check_sizes(path)
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a .npy file: one array
            raise StoreError(f"{not_archive}: a single array, not a set of columns")
        with loaded as z:
            arrays = {k: z[k] for k in z.files}
    except StoreError:
        raise
    except Exception as e:  # noqa: BLE001 - bytes from anywhere: BadZipFile, zlib.error, EOFError, a bad .npy header
        # (ValueError, tokenize.TokenError, ...): whatever the reader trips on, the file is not an archive
        raise StoreError(f"{not_archive}: {one_line_reason(e)}") from None
    meta_raw = arrays.pop("meta", None)
    if not isinstance(meta_raw, np.ndarray) or meta_raw.dtype != np.uint8 or meta_raw.ndim != 1:
        raise StoreError(f"{not_archive}: no meta")
    try:
        meta = json.loads(meta_raw.tobytes().decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise StoreError(f"{not_archive}: its meta is not JSON ({one_line_reason(e)})") from None
    if not isinstance(meta, dict):
        raise StoreError(f"{not_archive}: its meta is not a JSON object")
    return meta, arrays


def read_archive(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The archive's ``meta`` and its column arrays, every check of
    :mod:`nutribench.store.archive`'s docstring passed; :class:`StoreError` (one line naming
    the archive and what is wrong) otherwise."""
    meta, arrays = _load(path)
    if (
        meta.get("format") != FORMAT
        or type(meta.get("format_version")) is not int
        or meta["format_version"] != FORMAT_VERSION
    ):
        if meta.get("format") != FORMAT:
            raise StoreError(
                f"db import: {path} is not a results archive (`nutribench db export` writes one): format {short_repr(meta.get('format'))}"
            )
        raise StoreError(
            f"db import: {path} is format {FORMAT} v{short_repr(meta.get('format_version'), 20)}, "
            f"this nutribench reads {FORMAT} v{FORMAT_VERSION}"
        )
    try:
        check_contents(meta, arrays)
    except InvalidArchive as e:
        raise StoreError(f"db import: {path} is damaged or was changed: {e}; nothing imported") from None
    except RecursionError:
        raise StoreError(
            f"db import: {path} is damaged or was changed: its meta is nested too deeply; nothing imported"
        ) from None
    return meta, arrays


def verify_archive(path: str | os.PathLike[str]) -> dict[str, int]:
    """Check the archive ``path`` (nothing is opened but the file); its counts."""
    meta, _ = read_archive(path)
    return dict(meta["counts"])


def _check_arrays(arrays: dict[str, np.ndarray], n_jobs: int) -> dict[str, dict[str, np.ndarray]]:
    """Every table's columns there, of their type and length; NULL masks only where a column
    allows NULL; no other array. The columns by table (``job`` included, masks applied as NaN)."""
    expected: set[str] = set()
    tables: dict[str, dict[str, np.ndarray]] = {}
    for name in TABLES:
        table = archive_table(name, arrays)
        job = arrays.get(f"{name}.job")
        if not isinstance(job, np.ndarray) or job.ndim != 1 or job.dtype.kind != "i":
            raise InvalidArchive(f"column {name}.job is missing or not a column of integers")
        expected.add(f"{name}.job")
        n = len(job)
        cols = {"job": job}
        for col in columns(table):
            key = f"{name}.{col.name}"
            arr = arrays.get(key)
            kind = col.type.python_type
            want = {float: "float64", int: "integers", str: "strings"}[kind]
            if arr is None:
                raise InvalidArchive(f"column {key} is missing")
            if not isinstance(arr, np.ndarray) or arr.ndim != 1:
                raise InvalidArchive(f"{key} is not a column")
            ok = {float: arr.dtype == np.float64, int: arr.dtype.kind == "i", str: arr.dtype.kind == "U"}[kind]
            if not ok:
                raise InvalidArchive(f"column {key} holds {arr.dtype}, not {want}")
            if len(arr) != n:
                raise InvalidArchive(f"column {key} has {len(arr):,} rows, {name}.job {n:,}")
            expected.add(key)
            null = arrays.get(f"{key}.null")
            if null is not None:
                if not col.nullable:
                    raise InvalidArchive(f"column {key} has NULLs, which it does not allow")
                if not isinstance(null, np.ndarray) or null.ndim != 1 or null.dtype != np.bool_ or len(null) != n:
                    raise InvalidArchive(f"{key}.null is not a boolean column of {n:,} rows")
                expected.add(f"{key}.null")
                cols[f"{col.name}.null"] = null
            if kind is float:
                bad = ~np.isfinite(arr)
                if null is not None:
                    bad &= ~null
                if bad.any():
                    row = int(np.argmax(bad))
                    raise InvalidArchive(
                        f"column {key} holds {'NaN' if np.isnan(arr[row]) else arr[row]} in row {row} "
                        "(a measurement is finite; a NULL is marked in its .null mask)"
                    )
                if null is not None:
                    arr = np.where(null, np.nan, arr)
            elif kind is int and n:
                vals = arr if null is None else arr[~null]
                if vals.size and (vals.min() < INT32_RANGE[0] or vals.max() > INT32_RANGE[1]):
                    raise InvalidArchive(f"column {key} holds integers out of range")
            elif kind is str and n:
                length = getattr(col.type, "length", None)
                if length is not None and arr.dtype.itemsize // 4 > length and (np.char.str_len(arr) > length).any():
                    raise InvalidArchive(f"column {key} holds strings longer than {length} characters")
                nul = np.flatnonzero(inner_nul(arr))
                if nul.size:
                    raise InvalidArchive(
                        f"column {key} row {nul[0]} holds a NUL byte, which no text column stores (PostgreSQL refuses it)"
                    )
            cols[col.name] = arr
        if n and (job.min() < 0 or job.max() >= n_jobs):
            bad = int(job.min()) if job.min() < 0 else int(job.max())
            raise InvalidArchive(
                f"{name} row {int(np.argmax(job == bad))} belongs to job {bad}, but the archive has {n_jobs} jobs"
            )
        tables[name] = cols
    other = sorted(set(arrays) - expected)
    if other:
        raise InvalidArchive(f"array {short_repr(other[0])} is not part of the format")
    return tables


def _fill_optional(arrays: dict[str, np.ndarray]) -> None:
    """An optional table (:data:`OPTIONAL_TABLES`) that an archive has no array of at all
    (written before the table existed) added to ``arrays`` as empty columns."""
    for name in OPTIONAL_TABLES:
        if any(k.startswith(f"{name}.") for k in arrays):
            continue
        arrays[f"{name}.job"] = np.zeros(0, dtype=np.int32)
        for col in columns(archive_table(name, {})):
            kind = col.type.python_type
            arrays[f"{name}.{col.name}"] = np.zeros(0, dtype={float: np.float64, int: np.int32, str: "<U1"}[kind])


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


def _check_rows(
    tables: dict[str, dict[str, np.ndarray]], per_job: dict[str, np.ndarray], jobs: list[dict[str, Any]]
) -> None:
    """Values in range and every job's rows complete: its budget of training days, its
    evaluation days, and H steps of each."""
    n_jobs = len(jobs)
    ep = tables["episodes"]
    job = ep["job"]
    phase_ok = np.isin(ep["phase"], PHASES)
    if not phase_ok.all():
        row = int(np.argmin(phase_ok))
        raise InvalidArchive(f"episodes row {row}: phase {short_repr(str(ep['phase'][row]))} is neither train nor eval")
    train = ep["phase"] == "train"
    limit = np.where(train, per_job["episodes"][job], per_job["eval_episodes"][job]) if job.size else job
    bad = (ep["episode"] < 0) | (ep["episode"] >= limit)
    if bad.any():
        row = int(np.argmax(bad))
        raise InvalidArchive(
            f"episodes row {row}: {ep['phase'][row]} episode {int(ep['episode'][row])} of job {int(job[row])} "
            f"is out of its range 0..{int(limit[row]) - 1}"
        )
    horizon = per_job["horizon"][job] if job.size else job
    bad = (ep["foods"] < 0) | (ep["foods"] > horizon)
    if bad.any():
        row = int(np.argmax(bad))
        raise InvalidArchive(f"episodes row {row}: {int(ep['foods'][row])} foods in a day of {int(horizon[row])} steps")
    for col, lo, hi in (("overshoot_ratio", 0.0, 1.0), ("final_distance", 0.0, np.inf), ("entropy", 0.0, np.inf)):
        bad = (ep[col] < lo) | (ep[col] > hi)  # NaN (a NULL) compares false
        if bad.any():
            row = int(np.argmax(bad))
            raise InvalidArchive(f"episodes row {row}: {col} {ep[col][row]:.6g} is out of its range {lo:g}..{hi:g}")
    first = ep["first_overshoot_step"]
    bad = (first < 1) | (first > horizon)
    if "first_overshoot_step.null" in ep:
        bad &= ~ep["first_overshoot_step.null"]
    if bad.any():
        row = int(np.argmax(bad))
        raise InvalidArchive(
            f"episodes row {row}: first_overshoot_step {int(first[row])} is out of its range 1..{int(horizon[row])}"
        )
    row = _duplicate([job, train.astype(np.int8), ep["episode"]])
    if row is not None:
        raise InvalidArchive(
            f"episodes row {row}: job {int(job[row])}'s {ep['phase'][row]} episode {int(ep['episode'][row])} is there twice"
        )
    st = tables["eval_steps"]
    sjob = st["job"]
    horizon = per_job["horizon"][sjob] if sjob.size else sjob
    for col, lo, hi in (
        ("episode", 0, per_job["eval_episodes"][sjob] - 1 if sjob.size else sjob),
        ("step", 1, horizon),
        ("food", 0, per_job["foods"][sjob] - 1 if sjob.size else sjob),
        ("action", 0, 1),
    ):
        bad = (st[col] < lo) | (st[col] > hi)
        if bad.any():
            row = int(np.argmax(bad))
            top = hi if np.isscalar(hi) else int(hi[row])
            raise InvalidArchive(
                f"eval_steps row {row}: {col} {int(st[col][row])} of job {int(sjob[row])} is out of its range {lo}..{top}"
            )
    row = _duplicate([sjob, st["episode"], st["step"]])
    if row is not None:
        raise InvalidArchive(
            f"eval_steps row {row}: job {int(sjob[row])}'s evaluation episode {int(st['episode'][row])} "
            f"step {int(st['step'][row])} is there twice"
        )
    dg = tables["diagnostics"]
    for col in ("update", "timestep"):
        bad = dg[col] < 0
        if bad.any():
            row = int(np.argmax(bad))
            raise InvalidArchive(f"diagnostics row {row}: {col} {int(dg[col][row])} is negative")
    row = _duplicate([dg["job"], dg["update"]])
    if row is not None:
        raise InvalidArchive(
            f"diagnostics row {row}: job {int(dg['job'][row])}'s update {int(dg['update'][row])} is there twice"
        )
    _check_validation(tables["validation_episodes"], per_job)
    trains = np.bincount(job[train], minlength=n_jobs)
    evals = np.bincount(job[~train], minlength=n_jobs)
    steps = np.bincount(sjob, minlength=n_jobs)
    want_steps = per_job["eval_episodes"] * per_job["horizon"]
    for i, j in enumerate(jobs):
        label = f"job {i} ({j['regime'][0]} x {j['agent'][0]} seed {j['seed']})"
        if trains[i] != per_job["episodes"][i]:
            budget = "the training days it recorded" if j.get("engine") == Engine.EXTERNAL else "its budget"
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


def _check_validation(va: dict[str, np.ndarray], per_job: dict[str, np.ndarray]) -> None:
    """The rows of ``validation_episodes``: training days from 1, days from 0, foods within a
    day, no (job, training day, day) twice."""
    horizon = per_job["horizon"][va["job"]] if va["job"].size else va["job"]
    for col, lo, hi in (("train_day", 1, None), ("episode", 0, None), ("foods", 0, horizon)):
        bad = (va[col] < lo) | (va[col] > hi if hi is not None else False)
        if bad.any():
            row = int(np.argmax(bad))
            raise InvalidArchive(f"validation_episodes row {row}: {col} {int(va[col][row])} is out of its range")
    row = _duplicate([va["job"], va["train_day"], va["episode"]])
    if row is not None:
        raise InvalidArchive(
            f"validation_episodes row {row}: job {int(va['job'][row])}'s validation day {int(va['episode'][row])} "
            f"after training day {int(va['train_day'][row])} is there twice"
        )


def check_contents(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Every check of :mod:`nutribench.store.archive`'s docstring on an archive's content;
    :class:`InvalidArchive` with the first thing wrong."""
    unknown = sorted(set(meta) - META_KEYS)
    if unknown:
        raise InvalidArchive(f"meta: unknown field {short_repr(unknown[0])}")
    configs = check_meta_configs(meta)
    check_installed(meta)
    per_job = check_meta_jobs(meta, configs)
    _fill_optional(arrays)
    tables = _check_arrays(arrays, len(meta["jobs"]))
    _check_rows(tables, per_job, meta["jobs"])
    replay_evaluations(meta, tables, per_job)
    counts = meta.get("counts")
    have = {"jobs": len(meta["jobs"]), **{name: len(cols["job"]) for name, cols in tables.items()}}
    for name in OPTIONAL_TABLES:  # an archive without the table (or without its rows) need not count it
        if isinstance(counts, dict) and name not in counts and not have[name]:
            del have[name]
    if not isinstance(counts, dict) or set(counts) != set(have):
        raise InvalidArchive(f"meta: counts should list {', '.join(have)}")
    for key, n in have.items():
        if counts[key] != n:
            raise InvalidArchive(f"meta says {counts[key]} {key}, the archive holds {n:,}")
