"""Issue 74, SQLite's own files beside the database: the fuzz harness (:mod:`tests.test_fuzz`'s
settings) over ``DB-journal``, ``DB-wal`` and ``DB-shm``.

SQLite opens ``DB-journal`` on every open (to look for a hot journal to roll back) and removes
``DB-wal`` and ``DB-shm`` when its last connection closes: a FIFO there made every command hang,
a device node or a FIFO there was deleted. Each side file is made, in the test's own folder
(never the machine's /dev), a character device, a FIFO, a socket, a folder, or a symbolic link to
anything (a device, a FIFO, a regular file, nothing): SQLite opens its WAL and shared-memory
files without following links, so a link there is refused whatever it points to; every command that opens the
database then refuses it with exit 2 and one ``error:`` line naming the side file, and every entry
of the lab is left as it was (:func:`tests.test_fuzz_targets.state`: kind, mode, link target,
bytes). A FIFO that a command would block on is opened for writing after :data:`HANG_S` seconds,
which unblocks the reader: a command that hangs fails its test instead of hanging it.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import socket
import stat
import threading
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from nutribench.cli import app
from tests.conftest import one_error_line
from tests.test_fuzz import FAST, REPO, fuzz
from tests.test_fuzz_targets import DEVICES, state

runner = CliRunner()

#: seconds a command may take before a FIFO it reads is fed (a busy machine is slow, not wrong)
HANG_S = 60.0
SIDES = ("-journal", "-wal", "-shm")
KINDS = [
    k
    for k in ("dev", "fifo", "socket", "folder", "link_dev", "link_fifo", "link_file", "link_dangling")
    if DEVICES or "dev" not in k
]

#: command -> (its database in the lab, its command line)
COMMANDS = {
    "status": ("real.db", ["status", "--db", "real.db"]),
    "report": ("real.db", ["report", "--table", "results", "--db", "real.db", "--out", "rep"]),
    "leaderboard": ("real.db", ["leaderboard", "--db", "real.db", "--reps", "100", "--out", "lb"]),
    "db export": ("real.db", ["db", "export", "out.npz", "--db", "real.db"]),
    "db import": ("real.db", ["db", "import", "real.npz", "--db", "real.db"]),
    "db import into a new database": ("new.db", ["db", "import", "real.npz", "--db", "new.db"]),
    "run --upgrade-only": ("real.db", ["run", "--upgrade-only", "--db", "real.db"]),
    "run into a new database": (
        "new.db",
        ["run", "--db", "new.db", "--regimes", "run0", "--algos", "mc", "--seeds", "0", "--days", "1"],
    ),
    "tune status": ("real.db", ["tune", "status", "--study", "s", "--db", "real.db"]),
}
CASES = [(c, side, kind) for c in COMMANDS for side in SIDES for kind in KINDS]


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """A lab: a copy of the regimes, a database of two recorded jobs and its archive."""
    from tests.recorded import recorded_archive

    lab = tmp_path_factory.mktemp("sides")
    shutil.copytree(REPO / "regimes", lab / "regimes")
    recorded_archive(lab)  # real.db, real.npz
    return lab


def place(lab: Path, path: Path, kind: str) -> Path | None:
    """Make ``path`` a ``kind`` (specials in ``lab/specials``); the FIFO a reader could block on."""
    specials = lab / "specials"
    specials.mkdir(exist_ok=True)
    made = specials / f"{kind}{path.name}"
    if kind.endswith("dev"):
        os.mknod(made, stat.S_IFCHR | 0o600, os.makedev(1, 3))
    elif kind.endswith("fifo"):
        os.mkfifo(made)
    elif kind == "socket":
        with socket.socket(socket.AF_UNIX) as s:
            s.bind(str(made))
    elif kind == "folder":
        made.mkdir()
    elif kind == "link_file":
        made.write_bytes(b"")
    if kind.startswith("link"):
        path.symlink_to(made)
    else:
        made.rename(path)
    return path if kind.endswith("fifo") else None


@contextlib.contextmanager
def fed_after(fifo: Path | None, seconds: float):
    """Open ``fifo`` for writing (and close it) once ``seconds`` have passed, should a reader be
    blocked opening it then: it reads an empty file and goes on, and the test fails instead of
    hanging."""

    def feed() -> None:
        try:
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        except OSError as e:  # ENXIO: nobody reading, nothing to unblock
            if e.errno != errno.ENXIO:
                raise

    timer = threading.Timer(seconds, feed) if fifo is not None else None
    if timer is not None:
        timer.start()
    try:
        yield
    finally:
        if timer is not None:
            timer.cancel()


def _invoke_in(lab: Path, args: list[str], fifo: Path | None):
    saved = Path.cwd()
    env = {"NUTRIBENCH_REGIMES": str(lab / "regimes"), "NUTRIBENCH_JOB": "fake"}
    os.chdir(lab)
    try:
        with pytest.MonkeyPatch.context() as mp, fed_after(fifo, HANG_S):
            for k, v in env.items():
                mp.setenv(k, v)
            mp.delenv("NUTRIBENCH_DB", raising=False)
            mp.delenv("NUTRIBENCH_AGENTS", raising=False)
            return runner.invoke(app, args)
    finally:
        os.chdir(saved)


def check_side_file(template: Path, where: Path, command: str, side: str, kind: str) -> None:
    if where.exists():
        shutil.rmtree(where)
    lab = shutil.copytree(template, where, symlinks=True)
    db, args = COMMANDS[command]
    target = lab / f"{db}{side}"
    fifo = place(lab, target, kind)
    before = state(lab)
    line = one_error_line(_invoke_in(lab, args, fifo))
    assert state(lab) == before, (command, side, kind, line, "the lab was changed by a refusal")
    assert str(target) in line and "SQLite" in line and "move it away" in line, (command, side, kind, line)


@fuzz(3 * FAST)
@given(case=st.sampled_from(CASES))
def test_fuzz_side_files(template, tmp_path_factory, case):
    check_side_file(template, tmp_path_factory.getbasetemp() / "fuzz-side", *case)


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=["-".join(c) for c in CASES])
def test_every_side_file(template, tmp_path_factory, case):
    check_side_file(template, tmp_path_factory.getbasetemp() / "every-side", *case)


@pytest.mark.parametrize("side", SIDES)
def test_a_fifo_beside_the_file_a_link_names(template, tmp_path, side):
    """``--db`` a symbolic link: SQLite keeps its files beside the file the link points to, and
    that is where they are checked."""
    lab = shutil.copytree(template, tmp_path / "lab")
    (lab / "elsewhere").mkdir()
    (lab / "real.db").rename(lab / "elsewhere" / "real.db")
    (lab / "link.db").symlink_to(lab / "elsewhere" / "real.db")
    fifo = lab / "elsewhere" / f"real.db{side}"
    os.mkfifo(fifo)
    before = state(lab)
    line = one_error_line(_invoke_in(lab, ["status", "--db", "link.db"], fifo))
    assert str(fifo) in line, line
    assert state(lab) == before


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_each_command_opens_a_database_with_plain_side_files(template, tmp_path, command):
    """The commands succeed with a regular side file there (an empty ``DB-shm`` left behind):
    their refusals above are the side file's doing."""
    lab = shutil.copytree(template, tmp_path / "lab")
    db, args = COMMANDS[command]
    (lab / f"{db}-shm").write_bytes(b"")
    res = _invoke_in(lab, args, None)
    assert res.exit_code == 0, (command, res.output)
