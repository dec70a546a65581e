"""Schema versions: alembic migrations in ``migrations/``, checked every time a database is
opened.

The driver (``nutribench run``) is the only one that creates or upgrades a schema:
:func:`open_store` with ``writer=True`` creates an empty database at the newest revision and
upgrades an older one, under the write lock (a second driver waits, then finds it done).
Readers (``status``, the report) refuse an older schema with the exact command to run, and
every opener refuses a schema newer than this nutribench knows.

nutribench's revision lives in its own table, :data:`VERSION_TABLE`
(``nutribench_alembic_version``), not in alembic's default ``alembic_version``: Optuna's RDB
storage (``nutribench tune``) keeps its own schema revision in a table of that default name, and
the two chains would overwrite each other in one database. A database written before the move
(its nutribench revision in ``alembic_version``) is still read as it is, and the first writer to
open it moves the revision over (:func:`adopt_legacy_version`), leaving ``alembic_version`` to
Optuna. Tables of Optuna's storage (:data:`OPTUNA_TABLES`) are not foreign to a nutribench
database.

Checking a schema imports no alembic (a fifth of ``nutribench status``'s start-up): the
revision is read from the version table with plain SQL and the chain from the revision files'
``revision`` / ``down_revision`` lines (:func:`revision_chain`); alembic is imported only to
upgrade or to move a legacy revision.
"""

from __future__ import annotations

import ast
import os
import shlex
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Connection, Engine, inspect, text
from sqlalchemy.engine import URL
from sqlalchemy.exc import DatabaseError, OperationalError

from nutribench.store.engine import (
    MIGRATION_LOCK,
    StoreError,
    check_sqlite_file,
    database_url,
    display_url,
    hide_secrets,
    hold_write_lock,
    in_memory,
    make_engine,
    one_line_error,
    sqlite_path,
)

if TYPE_CHECKING:
    from alembic.config import Config


def migrations_dir() -> Path:
    """``migrations/`` of the source checkout, else the copy shipped in the wheel."""
    if env := os.environ.get("NUTRIBENCH_MIGRATIONS"):
        return Path(env)
    package = Path(__file__).resolve().parents[1]
    for candidate in (package.parent / "migrations", package / "_migrations"):
        if (candidate / "env.py").is_file():
            return candidate
    raise StoreError("no migrations folder found: set NUTRIBENCH_MIGRATIONS to the folder holding env.py")


#: the table holding nutribench's schema revision (alembic's ``version_table``)
VERSION_TABLE = "nutribench_alembic_version"
#: where nutribench kept its revision before Optuna shared the database (alembic's default)
LEGACY_VERSION_TABLE = "alembic_version"
#: the tables Optuna's RDB storage creates (Optuna 3-5); a database holding only these is empty for nutribench
OPTUNA_TABLES = frozenset(
    {
        "studies",
        "study_directions",
        "study_user_attributes",
        "study_system_attributes",
        "trials",
        "trial_params",
        "trial_values",
        "trial_intermediate_values",
        "trial_user_attributes",
        "trial_system_attributes",
        "trial_heartbeats",
        "version_info",
        LEGACY_VERSION_TABLE,
    }
)


def alembic_config() -> Config:
    """A programmatic alembic Config (no alembic.ini needed); ``migrations/env.py`` reads
    :data:`VERSION_TABLE` from here."""
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(migrations_dir()))
    cfg.set_main_option("version_table", VERSION_TABLE)
    return cfg


def head_revision() -> str:
    """The newest schema revision this nutribench knows."""
    return revision_chain()[-1]


def revision_chain() -> list[str]:
    """Revisions from the first to the head, read from the ``revision`` and ``down_revision``
    lines of ``migrations/versions/*.py`` without importing alembic; anything but one straight
    chain of literal ids (a branch, a merge) is left to alembic's own reading."""
    return list(_revision_chain(migrations_dir()))


@cache
def _revision_chain(folder: Path) -> tuple[str, ...]:
    links = [_revision_link(path) for path in sorted((folder / "versions").glob("*.py"))]
    parent_of = dict(link for link in links if link is not None)
    child = {down: rev for rev, down in parent_of.items()}  # a parent of two (a branch): the chain misses one
    chain: list[str] = []
    while (chain[-1] if chain else None) in child:
        chain.append(child[chain[-1] if chain else None])
    if None in links or len(chain) != len(parent_of) or not chain:
        from alembic.script import ScriptDirectory

        return tuple(s.revision for s in reversed(list(ScriptDirectory.from_config(alembic_config()).walk_revisions())))
    return tuple(chain)


def _revision_link(path: Path) -> tuple[str, str | None] | None:
    """``(revision, down_revision)`` of one revision file, None unless both are literals (a
    string, and a string or None)."""
    found: dict[str, object] = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            if node.targets[0].id in ("revision", "down_revision") and isinstance(node.value, ast.Constant):
                found[node.targets[0].id] = node.value.value
    rev, down = found.get("revision"), found.get("down_revision", ...)
    if not isinstance(rev, str) or not (down is None or isinstance(down, str)):
        return None
    return rev, down


def _stored_revision(conn: Connection, table: str, display: str) -> str | None:
    """The one revision in alembic version table ``table`` (None: no table, or no row); more than
    one is refused in one line naming the database (``display``) and the table."""
    if not inspect(conn).has_table(table):
        return None
    rows = [r[0] for r in conn.execute(text(f"SELECT version_num FROM {table}"))]
    if len(rows) > 1:
        raise StoreError(
            f"{display}: its schema version table {table} holds {len(rows)} revisions ({', '.join(sorted(rows))}) "
            "where nutribench keeps exactly one: delete the rows that are not the database's schema revision "
            f"(this nutribench's newest is {head_revision()}), or use a copy of the database from before they "
            "were added"
        )
    return rows[0] if rows else None


def _legacy_revision(conn: Connection, display: str = "the database") -> str | None:
    """nutribench's revision in ``alembic_version`` (a database from before the move), else None."""
    rev = _stored_revision(conn, LEGACY_VERSION_TABLE, display)
    return rev if rev in revision_chain() else None


def adopt_legacy_version(conn: Connection, display: str = "the database") -> None:
    """Move nutribench's revision from ``alembic_version`` to :data:`VERSION_TABLE` (inside the
    caller's transaction), dropping ``alembic_version`` if nothing else is left in it, so that
    Optuna's storage can keep its own revision there. Nothing to do on a moved or new database."""
    rev = _legacy_revision(conn, display)
    if rev is None or inspect(conn).has_table(VERSION_TABLE):
        return
    from alembic.runtime.migration import MigrationContext
    from alembic.script import ScriptDirectory

    context = MigrationContext.configure(conn, opts={"version_table": VERSION_TABLE})
    context.stamp(ScriptDirectory.from_config(alembic_config()), rev)
    conn.execute(text(f"DELETE FROM {LEGACY_VERSION_TABLE} WHERE version_num = :rev"), {"rev": rev})
    if conn.execute(text(f"SELECT COUNT(*) FROM {LEGACY_VERSION_TABLE}")).scalar() == 0:
        conn.execute(text(f"DROP TABLE {LEGACY_VERSION_TABLE}"))


def upgrade_connection(conn: Connection, target: str = "head") -> None:
    """Run the migrations up to ``target`` on ``conn``, inside its current transaction."""
    from alembic import command

    cfg = alembic_config()
    cfg.attributes["connection"] = conn
    command.upgrade(cfg, target)


@dataclass
class Store:
    """An open results database: its engine, URL and what opening it did."""

    engine: Engine
    url: URL
    revision: str
    upgraded_from: str | None = None  # set when opening upgraded an older schema
    created: bool = False

    @property
    def display(self) -> str:
        return display_url(self.url)

    def dispose(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> Store:
        """``with open_store(db) as store:``: the engine disposed of when the block ends."""
        return self

    def __exit__(self, *exc: object) -> None:
        self.dispose()


#: the environment variable the CLI's ``--db`` options read (``run``, ``status``, ``report``, ``db``)
DB_ENV = "NUTRIBENCH_DB"


def db_command(command: str, url: URL) -> str:
    """```command --db DB``` as it can be pasted, no secret printed: a SQLite file's path or a
    URL without secrets as given; a URL with a password (in its user part or as a query
    parameter such as ``?password=``: :func:`~nutribench.store.engine.hide_secrets`) as
    ``"$NUTRIBENCH_DB"``, saying to set that variable (``***`` would fail when pasted)."""
    path = sqlite_path(url)
    if path is not None:
        return f"`{command} --db {shlex.quote(str(path))}`"
    given = url.render_as_string(hide_password=False)
    if hide_secrets(given) == given:
        return f"`{command} --db {shlex.quote(given)}`"
    return f'`{command} --db "${DB_ENV}"` (with {DB_ENV} set to the database URL, password included)'


def _upgrade_cmd(url: URL) -> str:
    return db_command("nutribench run --upgrade-only", url)


def _classify(conn: Connection, display: str) -> str | None:
    """The schema revision, None for an empty database; refuse foreign databases."""
    # a database from before VERSION_TABLE: its revision in alembic's default table (if nutribench's, not Optuna's)
    rev = _stored_revision(conn, VERSION_TABLE, display) or _legacy_revision(conn, display)
    if rev is None:
        if tables := set(inspect(conn).get_table_names()) - OPTUNA_TABLES:
            raise StoreError(
                f"{display} holds tables ({', '.join(sorted(tables)[:4])}...) but no nutribench schema: "
                "give another --db"
            )
        return None
    if rev not in revision_chain():
        raise StoreError(
            f"{display} is on schema revision {rev}, unknown to this nutribench (newest known: "
            f"{head_revision()}): it was written by a newer nutribench; upgrade nutribench"
        )
    return rev


def open_store(db: str | os.PathLike[str] | URL, *, writer: bool = False) -> Store:
    """Open ``db`` and check its schema.

    ``writer=True`` (the driver): create the file if missing, create or upgrade the schema.
    ``writer=False``: refuse a missing file, an empty
    database or an older schema with the command that fixes it.
    """
    url = db if isinstance(db, URL) else database_url(db)
    display = display_url(url)
    path = sqlite_path(url)
    if writer and in_memory(url):
        raise StoreError(
            f"--db {display}: an in-memory SQLite database is lost when the command ends, with everything "
            "written to it: give a file path (e.g. --db nutribench.db)"
        )
    if path is not None:
        check_sqlite_file(path, create=writer)
    engine = make_engine(url, writer=writer)
    head = head_revision()
    try:
        # the driver: BEGIN IMMEDIATE on SQLite (one upgrader at a time); a reader: a plain connection
        with engine.begin() if writer else engine.connect() as conn:
            if writer:
                hold_write_lock(conn, MIGRATION_LOCK)
                adopt_legacy_version(conn, display)
            rev = _classify(conn, display)
            if rev is None and not writer:
                raise StoreError(
                    f"{display} is an empty database, nothing has run yet: {db_command('nutribench run', url)} fills it"
                )
            if rev != head:
                if not writer:
                    raise StoreError(
                        f"{display} is on schema revision {rev}, this nutribench needs {head}: run {_upgrade_cmd(url)}"
                    )
                upgrade_connection(conn)
        return Store(engine, url, head, upgraded_from=rev if rev not in (None, head) else None, created=rev is None)
    except StoreError:
        engine.dispose()
        raise
    except OperationalError as e:
        engine.dispose()
        raise StoreError(f"cannot open database {display}: {one_line_error(e.orig)}") from None
    except DatabaseError as e:
        engine.dispose()
        raise StoreError(f"{display} is not a usable database: {one_line_error(e.orig)}") from None


def upgrade_schema(db: str | os.PathLike[str] | URL) -> str:
    """Create or upgrade ``db``'s schema (``run --upgrade-only``); the line that says what was done."""
    store = open_store(db, writer=True)
    store.dispose()
    what = (
        "created" if store.created else (f"upgraded from {store.upgraded_from}" if store.upgraded_from else "already")
    )
    return f"{store.display}: schema {what} at revision {store.revision}"
