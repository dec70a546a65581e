"""``nutribench db copy SRC DST``: every result of one database into another, e.g. a lab's
SQLite file into the PostgreSQL database its hosts will share.

The destination is created (or upgraded) to the newest schema and must hold no results yet:
rows keep their ids, so jobs, episodes and evaluation steps stay linked, and merging two
databases' ids is not attempted. The source must be at the newest schema (``nutribench run
--upgrade-only --db SRC`` first). Tables are copied parent first, in batches, in one
transaction: a failed copy leaves the destination as it was. Afterwards the row counts of
both are compared, and PostgreSQL's id sequences are moved past the copied ids so that new
jobs can be added.
"""

from __future__ import annotations

from collections.abc import Callable

from sqlalchemy import func, insert, select, text

from nutribench.store.engine import StoreError, session_scope
from nutribench.store.models import Base
from nutribench.store.schema import open_store

BATCH = 20_000


def copy_database(src: str, dst: str, *, on_table: Callable[[str, int], None] | None = None) -> dict[str, int]:
    """Copy every table of ``src`` into the empty database ``dst``; rows copied per table."""
    source = open_store(src)
    target = open_store(dst, writer=True)
    try:
        if source.url == target.url:
            raise StoreError(f"db copy: source and destination are the same database ({source.display})")
        with target.engine.connect() as conn:
            held = {
                t.name: conn.execute(select(func.count()).select_from(t)).scalar_one()
                for t in Base.metadata.sorted_tables
            }
        if any(held.values()):
            rows = ", ".join(f"{n} {name}" for name, n in held.items() if n)
            raise StoreError(f"db copy: {target.display} already holds rows ({rows}): copy into a new, empty database")
        counts: dict[str, int] = {}
        # one snapshot of the source for every table (a PostgreSQL source may be written meanwhile)
        read_options = {"isolation_level": "REPEATABLE READ"} if source.engine.dialect.name == "postgresql" else {}
        with source.engine.connect().execution_options(**read_options) as read, session_scope(target.engine) as write:
            for table in Base.metadata.sorted_tables:  # parents before children
                n = 0
                result = read.execution_options(yield_per=BATCH).execute(
                    select(table).order_by(*table.primary_key.columns)
                )
                for batch in result.mappings().partitions(BATCH):
                    write.execute(insert(table), [dict(row) for row in batch])
                    n += len(batch)
                counts[table.name] = n
                if on_table:
                    on_table(table.name, n)
            if write.get_bind().dialect.name == "postgresql":
                for table in Base.metadata.sorted_tables:
                    if "id" in table.columns and table.c.id.primary_key:
                        write.execute(
                            text(
                                f"SELECT setval(pg_get_serial_sequence('{table.name}', 'id'), "
                                f"coalesce((SELECT max(id) FROM {table.name}), 0) + 1, false)"
                            )
                        )
            # compared before the commit: a mismatch rolls the whole copy back
            copied = {
                t.name: write.execute(select(func.count()).select_from(t)).scalar_one()
                for t in Base.metadata.sorted_tables
            }
            if copied != counts:
                raise StoreError(f"db copy: row counts differ after the copy (source {counts}, destination {copied})")
        return counts
    finally:
        source.dispose()
        target.dispose()
