"""Every command that opens the results database reads ``NUTRIBENCH_DB`` when it is not
given one, as ``run``, ``status`` and ``report`` do: ``db copy`` (its destination),
``db export``, ``db import``, ``compare`` and ``evaluate``; and ``evaluate`` prints the
database without its password."""

from __future__ import annotations

import sqlite3
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.scheduler.driver import GridSettings, run_grid
from nutribench.scheduler.synthetic import synthetic_job

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]


def commands(group, path: tuple[str, ...] = ()):
    """(path of names, command) of every command under the click group ``group``."""
    for name, cmd in group.commands.items():
        if hasattr(cmd, "commands"):  # a group (typer's own click or the click package)
            yield from commands(cmd, (*path, name))
        else:
            yield (*path, name), cmd


def test_every_database_parameter_reads_nutribench_db() -> None:
    cli = typer.main.get_command(app)
    seen, missing = [], []
    for path, cmd in commands(cli):
        for param in cmd.params:
            if param.name == "db" or path == ("db", "copy") and param.name == "dst":
                seen.append(" ".join(path))
                if param.envvar != "NUTRIBENCH_DB":
                    missing.append(f"{' '.join(path)} {param.name}")
    assert {"run", "status", "report", "compare", "evaluate", "db copy", "db export", "db import"} <= set(seen), seen
    assert not missing, missing


def sql(db: Path, query: str) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return con.execute(query).fetchall()
    finally:
        con.close()


def test_db_copy_copies_into_nutribench_db(tmp_path, monkeypatch) -> None:
    src, dst = tmp_path / "src.db", tmp_path / "dst.db"
    run_grid(GridSettings(src, ["run0"], ["mc"], [0], 3, 1, workers=1, job_fn=synthetic_job, display=False))
    monkeypatch.setenv("NUTRIBENCH_DB", str(dst))
    res = runner.invoke(app, ["db", "copy", str(src)])
    assert res.exit_code == 0, res.output
    assert sql(dst, "SELECT count(*) FROM jobs WHERE status = 'done'") == [(1,)]


def test_db_copy_without_a_destination_is_one_line(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("NUTRIBENCH_DB", raising=False)
    res = runner.invoke(app, ["db", "copy", str(tmp_path / "src.db")])
    lines = [x for x in res.output.splitlines() if x.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and "NUTRIBENCH_DB" in lines[0], res.output
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def loader(tmp_path: Path):
    """``loaders:load``: an entry point whose "model" is a file and whose policy never eats."""
    (tmp_path / "loaders.py").write_text("def load(path):\n    return lambda obs: 0\n")
    (tmp_path / "model.bin").write_text("a model\n")
    sys.path.insert(0, str(tmp_path))
    sys.modules.pop("loaders", None)  # a test file run earlier in this process may have imported its own
    yield ["evaluate", "--model", str(tmp_path / "model.bin"), "--entry-point", "loaders:load", "--name", "never_eats"]
    sys.path.remove(str(tmp_path))
    sys.modules.pop("loaders", None)


def test_evaluate_stores_into_nutribench_db(tmp_path, monkeypatch, loader) -> None:
    db = tmp_path / "lab.db"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("NUTRIBENCH_DB", str(db))
    res = runner.invoke(app, loader)
    assert res.exit_code == 0, res.output
    assert sql(db, "SELECT count(*) FROM jobs WHERE engine = 'external'") == [(1,)]
    assert not (tmp_path / "nutribench.db").exists()


def test_evaluate_into_postgresql_prints_no_password(monkeypatch, loader, pg_url) -> None:
    url = pg_url.replace("postgresql+psycopg://nutribench@", "postgresql+psycopg://nutribench:s3cret@")
    assert "s3cret" in url  # trust auth ignores it
    monkeypatch.setenv("NUTRIBENCH_DB", url)
    res = runner.invoke(app, loader)
    assert res.exit_code == 0, res.output
    assert "s3cret" not in res.output and "stored in postgresql" in res.output.replace("\n", ""), res.output
