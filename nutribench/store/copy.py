"""``nutribench db copy SRC DST``: every result of one database into another, e.g. a lab's
SQLite file into the PostgreSQL database its hosts will share.

The destination is created (or upgraded) to the newest schema and must hold no results yet:
rows keep their ids, so jobs, episodes and evaluation steps stay linked, and merging two
databases' ids is not attempted. The source must be at the newest schema (``nutribench run
--upgrade-only --db SRC`` first). Tables are copied parent first, in batches, in one
transaction: a failed copy leaves the destination as it was. Afterwards the row counts of
both are compared, and PostgreSQL's id sequences are moved past the copied ids so that new
jobs can be added.

The tuning studies in the source (Optuna's tables, :mod:`nutribench.tuning.study`) are copied
after the results, one by one with :func:`optuna.copy_study` (Optuna's supported copy: the
study's direction, user and system attributes, and every trial with its parameters, values,
intermediate values and attributes, under the same numbers); the destination must hold no
study of the same name (checked before anything is written), and each copy is checked trial
state by trial state. A trial running in the source is copied running, without its heartbeat:
the next driver of that study fails it once its grace period has passed and runs its
parameters again.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

from sqlalchemy import func, insert, inspect, select, text

from nutribench.store.engine import StoreError, session_scope
from nutribench.store.models import Base
from nutribench.store.schema import open_store

BATCH = 20_000


def copy_database(src: str, dst: str, *, on_table: Callable[[str, int], None] = lambda *_: None) -> dict[str, int]:
    """Copy every table of ``src`` into the empty database ``dst``; rows copied per table."""
    with open_store(src) as source, open_store(dst, writer=True) as target:
        studies = _check_empty(source, target)
        # one snapshot of the source for every table (a PostgreSQL source may be written meanwhile)
        read_options = {"isolation_level": "REPEATABLE READ"} if source.engine.dialect.name == "postgresql" else {}
        with source.engine.connect().execution_options(**read_options) as read, session_scope(target.engine) as write:
            counts = _copy_tables(read, write, on_table)
        if studies:
            on_table(f"tuning studies ({len(studies)}): trials", _copy_studies(source, target, studies))
        return counts


def _counts(conn: Any) -> dict[str, int]:
    """The rows of every table of the schema, by table name."""
    return {t.name: conn.execute(select(func.count()).select_from(t)).scalar_one() for t in Base.metadata.sorted_tables}


def _check_empty(source: Any, target: Any) -> list[str]:
    """StoreError unless ``target`` is another database than ``source``, without rows and without
    a tuning study of the source's names; the source's studies."""
    if source.url == target.url:
        raise StoreError(f"db copy: source and destination are the same database ({source.display})")
    with target.engine.connect() as conn:
        held = _counts(conn)
    if any(held.values()):
        rows = ", ".join(f"{n} {name}" for name, n in held.items() if n)
        raise StoreError(f"db copy: {target.display} already holds rows ({rows}): copy into a new, empty database")
    studies = _study_names(source.engine)
    if clash := sorted(set(studies) & set(_study_names(target.engine))):
        raise StoreError(
            f"db copy: {target.display} already holds the tuning studies {', '.join(clash)}: copy into a new, "
            "empty database"
        )
    return studies


def _copy_tables(read: Any, write: Any, on_table: Callable[[str, int], None]) -> dict[str, int]:
    """Every table of the connection ``read`` into the session ``write``, parents first, in
    batches; PostgreSQL's id sequences moved past the copied ids; the rows counted back."""
    counts: dict[str, int] = {}
    for table in Base.metadata.sorted_tables:  # parents before children
        n = 0
        result = read.execution_options(yield_per=BATCH).execute(select(table).order_by(*table.primary_key.columns))
        for batch in result.mappings().partitions(BATCH):
            write.execute(insert(table), [dict(row) for row in batch])
            n += len(batch)
        counts[table.name] = n
        on_table(table.name, n)
        if write.get_bind().dialect.name == "postgresql" and "id" in table.columns and table.c.id.primary_key:
            write.execute(
                text(
                    f"SELECT setval(pg_get_serial_sequence('{table.name}', 'id'), "
                    f"coalesce((SELECT max(id) FROM {table.name}), 0) + 1, false)"
                )
            )
    # compared before the commit: a mismatch rolls the whole copy back
    copied = _counts(write)
    if copied != counts:
        raise StoreError(f"db copy: row counts differ after the copy (source {counts}, destination {copied})")
    return counts


def _study_names(engine: Any) -> list[str]:
    """The names of the Optuna studies in a database ([] without Optuna's tables)."""
    with engine.connect() as conn:
        if not inspect(conn).has_table("studies"):
            return []
        return sorted(conn.execute(text("SELECT study_name FROM studies")).scalars())


def _copy_studies(source: Any, target: Any, names: list[str]) -> int:
    """Copy the studies ``names`` of ``source`` into ``target`` (:func:`optuna.copy_study`),
    each checked by its trials' states; the trials copied. Optuna's log is at ``WARNING``
    meanwhile, and as the caller had it afterwards."""
    import optuna
    from optuna.storages import RDBStorage

    verbosity = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storages: list[RDBStorage] = []
    try:
        try:
            for store, skip in ((source, True), (target, False)):
                storages.append(RDBStorage(store.url.render_as_string(hide_password=False), skip_table_creation=skip))
        except RuntimeError as e:  # Optuna's schema newer or older than this Optuna
            raise StoreError(
                f"db copy: the results were copied, the tuning studies were not: {' '.join(str(e).split())}"
            ) from None
        src, dst = storages
        n = 0
        for name in names:
            try:
                optuna.copy_study(from_study_name=name, from_storage=src, to_storage=dst)
            except Exception as e:
                raise StoreError(
                    f"db copy: the results were copied, the tuning study {name!r} was not ({type(e).__name__}: "
                    f"{' '.join(str(e).split())[:200]})"
                ) from None
            before, after = (
                Counter(t.state.name for t in optuna.load_study(study_name=name, storage=s).get_trials(deepcopy=False))
                for s in (src, dst)
            )
            if before != after:
                raise StoreError(
                    f"db copy: tuning study {name!r}: trials differ after the copy (source {dict(before)}, "
                    f"destination {dict(after)})"
                )
            n += sum(after.values())
        return n
    finally:
        for storage in storages:
            storage.engine.dispose()
        optuna.logging.set_verbosity(verbosity)
