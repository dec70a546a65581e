"""The first check of a results archive, before anything in it is decompressed: the sizes its
zip directory and its arrays' ``.npy`` headers declare, and no member name twice
(:func:`check_sizes`; :mod:`nutribench.store.archive_check` runs it first, and so does the
leaderboard's look at an archive's configs before its import)."""

from __future__ import annotations

import os
import zipfile
from collections import Counter

import numpy as np

from nutribench.store.archive_meta import one_line_reason, short_repr
from nutribench.store.engine import StoreError

#: The most bytes an archive may inflate to (its members' declared sizes, summed; the committed
#: ones inflate to 17 MB at most): ``db import`` holds about this much at once, never more.
MAX_ARCHIVE_BYTES = 1 << 30
#: The most members (arrays) an archive may have.
MAX_MEMBERS = 1024


def check_sizes(path: str | os.PathLike[str]) -> None:
    """The archive's declared sizes within :data:`MAX_ARCHIVE_BYTES`, before anything is
    decompressed: each member's size in the zip directory (a reader stops there) and each
    array's shape in its ``.npy`` header (what NumPy allocates up front), summed; no member name
    twice (NumPy would read the last, a zip tool perhaps the first); StoreError."""
    where = f"db import: {path}"
    if not zipfile.is_zipfile(path):
        return  # not a zip: np.load reads no more than the file, and the reader refuses it
    with zipfile.ZipFile(path) as zf:
        infos = zf.infolist()
        if len(infos) > MAX_MEMBERS:
            raise StoreError(f"{where}: {len(infos):,} arrays (at most {MAX_MEMBERS:,}); nothing imported")
        twice = [n for n, c in Counter(i.filename for i in infos).items() if c > 1]
        if twice:  # a reader keeps one of two same-named members (the last): which is the archive?
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
                        f"{where}: array {info.filename} has a bad header ({one_line_reason(e)})"
                    ) from None
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if nbytes > info.file_size:
                raise StoreError(
                    f"{where}: array {info.filename} declares {nbytes:,} bytes in a member of {info.file_size:,}; "
                    "nothing imported"
                )
