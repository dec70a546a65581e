"""The results archive's format and its one reader (:func:`open_archive`).

The format (``nutribench db export`` / ``db import``, described in
:mod:`nutribench.store.archive`): its name and version, the job and config columns it leaves
out or defaults, the names regimes and agent configs may have (:func:`valid_config_name`), the tables
it carries (:data:`ARCHIVE_TABLES`) and the columns each has in an archive (:func:`archive_table`).

Every table travels as its columns, but ``diagnostics``: the database holds it long (one row
per job, update and quantity, schema revision 0007), an archive wide, one row per update
(:func:`diagnostics_layout`), as it was written since revision 0005, so every archive reads as
it did; a quantity of a plug-in's is one more column, under its name.

:func:`open_archive` is the only code that opens an archive file: before anything is
decompressed it reads the sizes the zip directory and the arrays' ``.npy`` headers declare (at
most :data:`MAX_ARCHIVE_BYTES` in all, no member name twice), then the ``meta`` JSON and the
arrays (no pickle). What is wrong with the content raises :class:`InvalidArchive` with the
message, without the archive's name; :mod:`nutribench.store.archive.check` adds that.
"""

from __future__ import annotations

import json
import os
import zipfile
from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np
from sqlalchemy import Column, Float, Integer, MetaData, Table

from nutribench.diagnostics import NAME_MAX, NAME_PATTERN, QUANTITIES, TIMESTEP
from nutribench.diagnostics import valid_name as valid_quantity
from nutribench.engines import ENGINES
from nutribench.store.engine import StoreError, one_line_error
from nutribench.store.models import Diagnostic, Episode, EvalStep, ValidationEpisode

FORMAT = "nutribench-results"
FORMAT_VERSION = 1
#: job columns an archive leaves out: ids (remapped on import) and the driver's bookkeeping
JOB_SKIP = ("id", "regime_id", "agent_config_id", "owner", "heartbeat_at", "worker_pid")
#: agent/regime config columns an archive leaves out (ids, remapped on import)
CONFIG_SKIP = ("id",)
#: job columns added by schema revision 0004, and what an archive written before them means
JOB_DEFAULTS: dict[str, Any] = dict.fromkeys(("batch_id", "batch_size", "device", "source", "source_sha256"))
JOB_DEFAULTS["fake"] = False
#: the keys of an archive's ``meta``
META_KEYS = {"format", "format_version", "source", "counts", "regimes", "agent_configs", "jobs"}
#: The tables of a job an archive carries, by name.
ARCHIVE_TABLES = {
    "episodes": Episode,
    "eval_steps": EvalStep,
    "diagnostics": Diagnostic,
    "validation_episodes": ValidationEpisode,
}
#: tables an archive written before them lacks: read as empty (revision 0005: diagnostics;
#: 0006: validation_episodes)
OPTIONAL_TABLES = ("diagnostics", "validation_episodes")
#: The most bytes an archive may inflate to (its members' declared sizes, summed; the committed
#: ones inflate to 17 MB at most): ``db import`` holds about this much at once, never more.
MAX_ARCHIVE_BYTES = 1 << 30
#: The most members (arrays) an archive may have.
MAX_MEMBERS = 1024

__all__ = ["ENGINES", "FORMAT", "FORMAT_VERSION", "NAME_MAX", "NAME_PATTERN", "open_archive", "valid_config_name"]


def valid_config_name(name: Any) -> bool:
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


def first_row(bad: np.ndarray) -> int | None:
    """The first row that is ``bad`` (a boolean column); None if none is."""
    return int(np.argmax(bad)) if bad.any() else None


def job_label(i: int, job: dict[str, Any]) -> str:
    """Job ``i`` of an archive's meta as its one-line messages name it."""
    return f"job {i} ({job['regime'][0]} x {job['agent'][0]} seed {job['seed']})"


def columns(table: Any) -> list[Any]:
    """The columns of ``table`` (an ORM model or a :class:`~sqlalchemy.Table`) but ``job_id``."""
    return [c for c in getattr(table, "__table__", table).columns if c.name != "job_id"]


def diagnostics_layout(extra: Sequence[str] = ()) -> Table:
    """The columns of an archive's ``diagnostics``: one row per update, wide (as the table was
    before schema revision 0007, so that every archive written since revision 0005 reads as it
    was): ``update``, ``timestep``, the quantities of :data:`nutribench.diagnostics.QUANTITIES`,
    then ``extra``, the names of a plug-in's own quantities (float, NULL where absent)."""
    return Table(
        "diagnostics",
        MetaData(),
        Column("job_id", Integer, nullable=False),
        Column("update", Integer, nullable=False),
        Column(TIMESTEP, Integer, nullable=False),
        *(Column(q, Float) for q in (*QUANTITIES, *extra)),
    )


def archive_table(name: str, arrays: dict[str, np.ndarray]) -> Any:
    """What table ``name`` of :data:`ARCHIVE_TABLES` holds in an archive: the database table's columns,
    but ``diagnostics`` in :func:`diagnostics_layout`, with the plug-in quantities ``arrays`` has
    a column of (a name :func:`nutribench.diagnostics.valid_name` allows; another is an array
    that is not part of the format)."""
    if name != "diagnostics":
        return ARCHIVE_TABLES[name]
    have = {k[len("diagnostics.") :].removesuffix(".null") for k in arrays if k.startswith("diagnostics.")}
    extra = have - {"job", "update", TIMESTEP, *QUANTITIES}
    return diagnostics_layout(sorted(e for e in extra if valid_quantity(e)))


def _check_sizes(path: str | os.PathLike[str], where: str) -> None:
    """The archive's declared sizes within :data:`MAX_ARCHIVE_BYTES`, before anything is
    decompressed: each member's size in the zip directory (a reader stops there) and each
    array's shape in its ``.npy`` header (what NumPy allocates up front), summed; no member name
    twice (NumPy would read the last, a zip tool perhaps the first); StoreError."""
    if not zipfile.is_zipfile(path):
        return  # not a zip: np.load reads no more than the file, and the reader refuses it
    with zipfile.ZipFile(path) as zf:
        infos = zf.infolist()
        if len(infos) > MAX_MEMBERS:
            raise StoreError(f"{where}: {len(infos):,} arrays (at most {MAX_MEMBERS:,}); nothing imported")
        # a reader keeps one of two same-named members (the last): which is the archive?
        if twice := [n for n, c in Counter(i.filename for i in infos).items() if c > 1]:
            raise StoreError(
                f"{where}: member {short_repr(twice[0])} is there twice (a zip that two readers can read "
                "differently is refused); nothing imported"
            )
        declared = sum(i.file_size for i in infos)
        if declared > MAX_ARCHIVE_BYTES:
            raise StoreError(
                f"{where}: it would inflate to {declared:,} bytes, more than the {MAX_ARCHIVE_BYTES:,} an archive "
                "may hold; nothing imported"
            )
        for info in infos:
            with zf.open(info) as fh:
                try:
                    version = np.lib.format.read_magic(fh)
                except ValueError:
                    continue  # not an array: read as the bytes it declares, and refused as no column
                if version not in ((1, 0), (2, 0)):
                    raise StoreError(f"{where}: array {info.filename} is .npy version {version}, not 1.0 or 2.0")
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                try:
                    shape, _, dtype = read(fh)
                except ValueError as e:
                    raise StoreError(
                        f"{where}: array {info.filename} has a bad header ({one_line_error(e, 160)})"
                    ) from None
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if nbytes > info.file_size:
                raise StoreError(
                    f"{where}: array {info.filename} declares {nbytes:,} bytes in a member of {info.file_size:,}; "
                    "nothing imported"
                )


def open_archive(path: str | os.PathLike[str], *, arrays: bool = True) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The raw ``meta`` (a JSON object) and the arrays of the archive file ``path`` (only its
    meta with ``arrays=False``), nothing in them checked yet; :class:`StoreError` in one line for
    a file that is not a readable archive (missing, a folder, empty, truncated, bit-flipped, too
    large once inflated, not a zip of arrays)."""
    where = f"db import: {path}"
    not_archive = f"{where} is not a results archive (`nutribench db export` writes one)"
    if os.path.isdir(path):
        raise StoreError(f"{where} is a folder, not an archive: give the .npz file `nutribench db export` wrote")
    if not os.path.exists(path):
        raise StoreError(f"{where}: no such file")
    try:
        if os.path.getsize(path) == 0:
            raise StoreError(f"{not_archive}: the file is empty")
        _check_sizes(path, where)
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a .npy file: one array
            raise StoreError(f"{not_archive}: a single array, not a set of columns")
        with loaded as z:
            found = {k: z[k] for k in z.files if arrays or k == "meta"}
    except StoreError:
        raise
    except Exception as e:  # noqa: BLE001 - bytes from anywhere: BadZipFile, zlib.error, EOFError, a bad .npy header
        # (ValueError, tokenize.TokenError, ...): whatever the reader trips on, the file is not an archive
        raise StoreError(f"{not_archive}: {one_line_error(e, 160)}") from None
    meta_raw = found.pop("meta", None)
    if not isinstance(meta_raw, np.ndarray) or meta_raw.dtype != np.uint8 or meta_raw.ndim != 1:
        raise StoreError(f"{not_archive}: no meta")
    try:
        meta = json.loads(meta_raw.tobytes().decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise StoreError(f"{not_archive}: its meta is not JSON ({one_line_error(e, 160)})") from None
    if not isinstance(meta, dict):
        raise StoreError(f"{not_archive}: its meta is not a JSON object")
    return meta, found
