"""A throwaway PostgreSQL server for the tests: ``initdb`` + ``pg_ctl`` in a temporary
folder, on a free local port, removed afterwards.

PostgreSQL refuses to run as root, so under root (CI) the server runs as the ``postgres``
user (``runuser``). The binaries are found in ``$NUTRIBENCH_PG_BIN``, else the newest
``/usr/lib/postgresql/*/bin``, else on ``PATH``. If the server cannot start, :func:`start`
raises with the reason and the server log: the PostgreSQL tests fail, they are never skipped.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path

USER = "nutribench"  # the database superuser initdb creates (trust authentication, local only)


class PostgresUnavailable(RuntimeError):
    """The throwaway server could not be started."""


def _bindir() -> Path:
    env = os.environ.get("NUTRIBENCH_PG_BIN")
    if env:
        return Path(env)
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    if initdb:
        return Path(initdb).parent
    raise PostgresUnavailable(
        "no PostgreSQL binaries (initdb) found: install the Debian package 'postgresql' "
        "or set NUTRIBENCH_PG_BIN to the folder holding initdb and pg_ctl"
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Server:
    """A running throwaway server."""

    folder: Path
    port: int
    bindir: Path
    run_as: str | None

    def url(self, database: str = "postgres") -> str:
        return f"postgresql+psycopg://{USER}@127.0.0.1:{self.port}/{database}"

    def _cmd(self, *args: str) -> list[str]:
        return (["runuser", "-u", self.run_as, "--"] if self.run_as else []) + list(args)

    def create_database(self) -> str:
        """A new empty database; its SQLAlchemy URL."""
        import psycopg

        name = f"t_{uuid.uuid4().hex[:12]}"
        with psycopg.connect(f"host=127.0.0.1 port={self.port} user={USER} dbname=postgres", autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def stop(self) -> None:
        subprocess.run(
            self._cmd(str(self.bindir / "pg_ctl"), "-D", str(self.folder / "data"), "-m", "immediate", "stop"),
            capture_output=True,
            check=False,
        )
        shutil.rmtree(self.folder, ignore_errors=True)


def start() -> Server:
    """initdb + pg_ctl start in a new temporary folder; raises PostgresUnavailable."""
    bindir = _bindir()
    run_as = None
    folder = Path(tempfile.mkdtemp(prefix="nutribench-pg-"))
    if os.geteuid() == 0:
        run_as = "postgres"
        try:
            pw = pwd.getpwnam(run_as)
        except KeyError:
            raise PostgresUnavailable("running as root and there is no 'postgres' user to run the server as") from None
        os.chown(folder, pw.pw_uid, pw.pw_gid)
    server = Server(folder, _free_port(), bindir, run_as)
    data, log = folder / "data", folder / "server.log"
    steps = [
        [str(bindir / "initdb"), "-D", str(data), "-U", USER, "--auth=trust", "-E", "UTF8", "--no-sync"],
        [
            str(bindir / "pg_ctl"),
            "-D",
            str(data),
            "-l",
            str(log),
            "-w",
            "-t",
            "60",
            "-o",
            f"-p {server.port} -k {folder} -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=200",
            "start",
        ],
    ]
    for step in steps:
        done = subprocess.run(server._cmd(*step), capture_output=True, text=True, check=False)
        if done.returncode != 0:
            tail = log.read_text()[-2000:] if log.exists() else ""
            server.stop()
            raise PostgresUnavailable(
                f"{' '.join(step[:1])} failed ({done.returncode}): {done.stderr.strip()[-2000:]} {tail}"
            )
    return server
