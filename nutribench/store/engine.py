"""Engines and sessions: the database URL, SQLite's WAL mode and busy timeout, and a
session scope that commits or rolls back.

``--db`` takes a file path (SQLite) or any SQLAlchemy URL (``postgresql+psycopg://...``).

SQLite: every connection sets a busy timeout, so a reader waits for a writer's short
transaction instead of failing with "database is locked"; the writer's engine puts the file
in WAL mode (readers and one writer at once) and opens each transaction with
``BEGIN IMMEDIATE``: it takes the write lock up front, so two drivers serialise their
transactions instead of failing when a read turns into a write. Readers use a plain
deferred ``BEGIN`` and never block the writer.
"""

from __future__ import annotations

import os
import re
import sqlite3
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from urllib.parse import unquote_plus

from sqlalchemy import Connection, Engine, create_engine, event, text
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import ArgumentError, NoSuchModuleError
from sqlalchemy.orm import Session

from nutribench.clock import utcnow
from nutribench.errors import UserError
from nutribench.safe_write import check_regular_file

BUSY_TIMEOUT_MS = 30_000
SQLITE_HEADER = b"SQLite format 3\x00"


class StoreError(UserError):
    """A database problem a user can fix (bad path, not a database, old schema). One line."""


def one_line_error(error: BaseException, n: int | None = None) -> str:
    """``str(error)`` on one line (whitespace collapsed: a driver's message, PostgreSQL's spans
    several), cut to ``n`` characters where given; the type's name if empty."""
    text = " ".join(str(error).split()) or type(error).__name__
    return text if n is None or len(text) <= n else text[: n - 3] + "..."


def database_url(db: str | os.PathLike[str]) -> URL:
    """A SQLAlchemy URL from ``--db``: a URL as is, anything else a SQLite file path. An ``@``
    left unencoded in the user part (``lab:p@ss@host``) belongs to it: the host starts after the
    last ``@`` (SQLAlchemy alone would take ``ss@host`` for the host, and the driver would show
    it in its errors)."""
    s = str(db)
    if "://" in s:
        try:
            return _host_after_last_at(make_url(s))
        except (ArgumentError, ValueError) as e:  # ValueError: a port that is not a number
            why = "its host or port is malformed" if isinstance(e, ValueError) else str(e)
            raise StoreError(
                f"--db {hide_secrets(s)}: not a valid SQLAlchemy URL ({why}): "
                "write dialect+driver://user:password@host:port/database, e.g. postgresql+psycopg://me@localhost:5432/lab"
            ) from None
    if not s.strip():
        raise StoreError("--db is empty: give a file path or a SQLAlchemy URL")
    return URL.create("sqlite", database=str(Path(s).expanduser().absolute()))


def _host_after_last_at(url: URL) -> URL:
    """``url`` with what SQLAlchemy parsed as the start of its host, up to the host's last ``@``,
    moved back into the user part it came from (a host name never holds an ``@``)."""
    if not url.host or "@" not in url.host:
        return url
    more, _, host = url.host.rpartition("@")
    if url.password is not None:
        return url.set(password=f"{url.password}@{more}", host=host)
    return url.set(username=f"{url.username or ''}@{more}", host=host)


#: Query parameters whose value is a secret, by a part of their name (lower case): ``password``,
#: ``sslpassword``, ``passfile``, ``sslkey``, ``token``, ``client_secret``, ...
SECRET_PARAMETERS = ("pass", "pwd", "secret", "token", "key", "credential")
_URL_START = re.compile(r"[A-Za-z][A-Za-z0-9+.\-]*://")
_QUERY_ITEM = re.compile(r"([?&;])([^=&;#]*)=([^&;#]*)")


def _secret_item(m: re.Match[str]) -> str:
    name = unquote_plus(m.group(2)).lower()
    return f"{m.group(1)}{m.group(2)}=***" if any(k in name for k in SECRET_PARAMETERS) else m.group(0)


def hide_secrets(url: str) -> str:
    """The database URL ``url`` (as given, parsed or not) with every secret it may hold shown as
    ``***``: the password of its user part, everything between ``user:`` and the LAST ``@`` (an
    unencoded ``@`` in a password does not end it), and the value of every query parameter whose
    name says it is one (:data:`SECRET_PARAMETERS`: ``?password=``, ``?sslpassword=``, ...).
    The one function that masks a URL: :func:`display_url` shows a parsed one through it, and
    :func:`hide_secrets_in` every URL of a message."""
    m = _URL_START.match(url)
    if m is None:
        return _QUERY_ITEM.sub(_secret_item, url)
    rest = url[m.end() :]
    if "@" in rest:
        user, _, host = rest.rpartition("@")
        name, colon, _ = user.partition(":")
        rest = f"{name}:***@{host}" if colon else f"{user}@{host}"
    return m.group(0) + _QUERY_ITEM.sub(_secret_item, rest)


def hide_secrets_in(text: str) -> str:
    """``text`` (an error line, a hint) with each URL in it, up to the next blank, through
    :func:`hide_secrets`."""
    return re.sub(r"[A-Za-z][A-Za-z0-9+.\-]*://\S*", lambda m: hide_secrets(m.group(0)), text)


def sqlite_path(url: URL) -> Path | None:
    """The file of a SQLite URL; None for other databases and in-memory SQLite."""
    db = url.database
    if url.get_backend_name() != "sqlite" or not db or db == ":memory:" or db.startswith("file:"):
        return None
    return Path(db)


def in_memory(url: URL) -> bool:
    """Whether ``url`` is an in-memory SQLite database (``sqlite://``, ``:memory:``, ``mode=memory``):
    it vanishes with the process that opened it."""
    if url.get_backend_name() != "sqlite":
        return False
    db = url.database or ""
    return db in ("", ":memory:") or "mode=memory" in db or url.query.get("mode") == "memory"


def display_url(url: URL) -> str:
    """The URL without its secrets (:func:`hide_secrets`: the password, ``?password=`` and the
    like), or the plain path of a SQLite file."""
    path = sqlite_path(url)
    return str(path) if path is not None else hide_secrets(url.render_as_string(hide_password=False))


def shown_db(db: str) -> str:
    """A database as a line shows it: a path as given, a URL as its kind (its password stays out)."""
    return db if "://" not in db else f"a {db.split('://', 1)[0]} database"


def check_sqlite_file(path: Path, *, create: bool) -> None:
    """Refuse early, with one line, what SQLite would report obscurely (or too late)."""
    try:
        if path.is_dir():
            raise StoreError(f"{path} is a directory, not a database file: give a file path to --db")
        check_regular_file(path, "--db", StoreError)  # a device node or a FIFO: never opened as a database
        check_side_files(path)
        if path.exists():
            if path.stat().st_size > 0:
                try:
                    with open(path, "rb") as fh:
                        header = fh.read(16)
                except OSError as e:
                    raise StoreError(f"cannot read {path}: {e.strerror}") from None
                if header != SQLITE_HEADER:
                    raise StoreError(f"{path} is not a SQLite database (no SQLite header): give another file to --db")
            if create and not os.access(path, os.W_OK):
                raise StoreError(f"cannot write to {path}: permission denied")
            return
        if not create:
            raise StoreError(f"no results database at {path}: `nutribench run --db {path}` creates it")
        parent = path.parent
        if not parent.is_dir():
            raise StoreError(f"cannot create {path}: folder {parent} does not exist")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise StoreError(f"cannot create {path}: folder {parent} is not writable")
    except OSError as e:  # a name too long, a path through a file the OS refuses to look at
        raise StoreError(f"--db {str(path)[:200]}: {e.strerror or e}: give another file path") from None


#: the files SQLite keeps beside a database ``DB``: its rollback journal (looked at on every open,
#: for a hot journal to roll back), its write-ahead log and the log's shared-memory index (both
#: removed when the last connection closes)
SIDE_FILES = ("-journal", "-wal", "-shm")


def side_files(path: Path) -> list[Path]:
    """The paths of SQLite's own files beside the database file ``path`` (:data:`SIDE_FILES`),
    beside the file a symbolic link points to, where SQLite keeps them."""
    real = Path(os.path.realpath(path))
    return [real.with_name(real.name + suffix) for suffix in SIDE_FILES]


def check_side_files(path: Path) -> None:
    """Refuse the database ``path`` when one of SQLite's own files beside it (:func:`side_files`)
    is there and is not a regular file: SQLite would block reading a FIFO, and delete a device
    node, a FIFO or a socket when it closes. A symbolic link there is refused too, wherever it
    points: SQLite opens its WAL and shared-memory files without following links (and fails,
    "unable to open database file"), and would write a rollback journal through one and then
    delete the link. (The database file itself is the user's to name: a link to it is followed.)
    Nothing is opened, changed or removed."""
    hint = "SQLite would block on it or delete it; move it away, or give another --db"
    for side in side_files(path):
        what = f"--db {path}: SQLite's own file"
        try:
            link = stat.S_ISLNK(os.lstat(side).st_mode)
        except (FileNotFoundError, NotADirectoryError):
            continue
        if link:
            raise StoreError(
                f"{what} {side}: is a symbolic link (to {os.readlink(side)}), which SQLite does not follow "
                f"for its own files: move it away, or give another --db"
            )
        check_regular_file(side, what, StoreError, hint)


def _switch_to_wal(cursor: sqlite3.Cursor, timeout_s: float) -> None:
    """``PRAGMA journal_mode = WAL``, waiting for the lock like every other statement.

    Switching a new database to WAL needs an exclusive lock, and SQLite reports "database is
    locked" at once, without calling the busy handler, while another connection holds a
    lock on it: two drivers started at the same moment on a new file would fail one time in
    ten. So: retry with a growing pause until the busy timeout."""
    deadline = time.monotonic() + timeout_s
    pause = 0.002
    while True:
        try:
            cursor.execute("PRAGMA journal_mode = WAL")
            return
        except sqlite3.OperationalError as e:
            if "locked" not in str(e) or time.monotonic() + pause > deadline:
                raise
            time.sleep(pause)
            pause = min(2 * pause, 0.1)


def read_only_file(path: Path) -> bool:
    """Whether this process cannot write the SQLite file ``path`` or its folder (where SQLite
    keeps a WAL database's ``-shm`` and ``-wal`` files): a read-only file, folder or file system."""
    return path.exists() and not (os.access(path, os.W_OK) and os.access(path.parent, os.W_OK | os.X_OK))


def _read_only_connector(path: Path, timeout_s: float):
    """Connections to a SQLite file this process cannot write, for the read-only commands
    (``status``, ``report``, ``db export``): ``mode=ro``; where SQLite cannot even create a WAL
    database's shared-memory file beside it (a read-only folder or file system), ``immutable=1``
    (then no process can be writing it either)."""
    uri = path.absolute().as_uri()

    def connect() -> sqlite3.Connection:
        conn = sqlite3.connect(f"{uri}?mode=ro", uri=True, timeout=timeout_s, check_same_thread=False)
        try:
            conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
            return conn
        except sqlite3.OperationalError:
            conn.close()
        return sqlite3.connect(f"{uri}?immutable=1", uri=True, timeout=timeout_s, check_same_thread=False)

    return connect


def make_engine(url: URL | str, *, writer: bool = False, busy_timeout_ms: int = BUSY_TIMEOUT_MS) -> Engine:
    """An engine for ``url``; on SQLite with the pragmas and transaction mode above."""
    url = url if isinstance(url, URL) else database_url(url)
    if url.get_backend_name() != "sqlite":
        try:
            return create_engine(url, pool_pre_ping=True)
        except (NoSuchModuleError, ImportError) as e:  # unknown dialect, driver not installed
            hint = (
                " (pip install 'nutribench[postgres]' installs psycopg 3, for URLs postgresql+psycopg://...)"
                if url.get_backend_name() == "postgresql"
                else ""
            )
            raise StoreError(f"--db {display_url(url)}: cannot use this database URL: {e}{hint}") from None
        except (ArgumentError, ValueError, TypeError) as e:  # e.g. ?port=abc
            raise StoreError(f"--db {display_url(url)}: not a usable database URL: {e}") from None
    path = sqlite_path(url)
    if not writer and path is not None and read_only_file(path):
        engine = create_engine(url, creator=_read_only_connector(path, busy_timeout_ms / 1000))
    else:
        engine = create_engine(url, connect_args={"timeout": busy_timeout_ms / 1000})

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record):  # pragma: no cover - exercised by every test
        dbapi_conn.isolation_level = None  # we emit BEGIN ourselves (see "begin" below)
        cur = dbapi_conn.cursor()
        cur.execute(f"PRAGMA busy_timeout = {int(busy_timeout_ms)}")
        cur.execute("PRAGMA foreign_keys = ON")
        if writer:
            _switch_to_wal(cur, busy_timeout_ms / 1000)
            cur.execute("PRAGMA synchronous = NORMAL")
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn):  # pragma: no cover
        conn.exec_driver_sql("BEGIN IMMEDIATE" if writer else "BEGIN")

    return engine


#: pg_advisory_xact_lock keys: one writer at a time for what SQLite serialises with BEGIN IMMEDIATE
MIGRATION_LOCK = 7_402_911  # creating or upgrading the schema
REGISTRATION_LOCK = 7_402_912  # recording configs and creating a grid's job rows


def hold_write_lock(conn: Connection | Session, key: int) -> None:
    """Serialise a transaction with every other one holding ``key``, until it ends. SQLite
    needs nothing more (a writer's BEGIN IMMEDIATE already takes the database's one write
    lock); PostgreSQL takes a transaction-level advisory lock. Without it two drivers
    started at once both inserted the same config row and one failed on the unique key."""
    bind = conn if isinstance(conn, Connection) else conn.connection()
    if bind.dialect.name == "postgresql":
        bind.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": key})


def db_now(conn: Connection | Session) -> datetime:
    """Now, naive UTC, by the database's clock on a server database (PostgreSQL), so that the
    drivers of several hosts judge heartbeats by one clock; by this host's clock on SQLite
    (a file: every driver runs on the host that holds it, or on one whose clock it shares)."""
    bind = conn if isinstance(conn, Connection) else conn.connection()
    if bind.dialect.name == "postgresql":
        return bind.execute(text("SELECT timezone('UTC', clock_timestamp())")).scalar_one()
    return utcnow()


@contextmanager
def session_scope(engine: Engine) -> Iterator[Session]:
    """One transaction: commit if the block succeeds, roll back if it raises."""
    with Session(engine, expire_on_commit=False) as session, session.begin():
        yield session
