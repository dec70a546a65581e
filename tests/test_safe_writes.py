"""Every command that writes a path the user named refuses a device node, a FIFO or a folder
there in one line (exit 2) and leaves it as it was; it writes through a unique temporary file
beside the target, renamed at the end, never left behind (:mod:`nutribench.safe_write`).

``nutribench db export /dev/null`` run as root replaced /dev/null with a regular file;
``leaderboard --out /dev/null`` was a ``NotADirectoryError`` traceback. The device nodes and
FIFOs here are made in the test's own folder, never the machine's /dev entries.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.safe_write import (
    WriteError,
    atomic_write,
    check_file_target,
    check_folder_target,
    check_regular_file,
)
from tests.conftest import one_error_line
from tests.recorded import recorded_archive

runner = CliRunner()
SPECIALS = ("dev", "fifo")


def make_special(folder: Path, kind: str, name: str | None = None) -> Path:
    """A character device (1, 3: what /dev/null is) or a FIFO at ``folder/name``; a test
    that needs a device node is skipped where this process may not make one (not root)."""
    path = folder / (name or kind)
    if kind == "fifo":
        os.mkfifo(path)
        return path
    try:
        os.mknod(path, stat.S_IFCHR | 0o600, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs root")
    return path


def still_special(path: Path, kind: str) -> bool:
    mode = os.lstat(path).st_mode
    return stat.S_ISCHR(mode) if kind == "dev" else stat.S_ISFIFO(mode)


def leftovers(folder: Path) -> list[str]:
    """What a write may have left in ``folder``: temporary files, probe folders."""
    return sorted(p.name for p in folder.rglob("*") if ".tmp" in p.name or p.name.startswith(".nutribench-probe"))


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Path:
    """A small database of two recorded jobs (:func:`tests.recorded.recorded_archive`)."""
    db, _ = recorded_archive(tmp_path_factory.mktemp("lab"))
    return db


# --------------------------------------------------------------------------- the helper
@pytest.mark.parametrize("kind", SPECIALS)
def test_a_special_file_is_refused_and_left_as_it_was(tmp_path: Path, kind: str) -> None:
    target = make_special(tmp_path, kind)
    for check in (check_regular_file, check_file_target):
        with pytest.raises(WriteError, match=f"{target}: is a"):
            check(target, "--out")
    with pytest.raises(WriteError, match="not a folder"):
        check_folder_target(target, "--out")
    with pytest.raises(WriteError, match="not a folder"):
        check_file_target(target / "x.md", "--out")
    with pytest.raises(WriteError, match="not a regular file"), atomic_write(target) as tmp:
        tmp.write_text("never")
    assert still_special(target, kind) and leftovers(tmp_path) == []


def test_a_folder_is_no_file_and_a_file_no_folder(tmp_path: Path) -> None:
    with pytest.raises(WriteError, match="is a folder, not a regular file"):
        check_file_target(tmp_path)
    (tmp_path / "f").write_text("")
    with pytest.raises(WriteError, match="lies in .*f, which is a file, not a folder"):
        check_folder_target(tmp_path / "f" / "sub")


def test_a_write_is_whole_with_the_usual_mode_and_leaves_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "new" / "out.npz"
    with atomic_write(target) as tmp:
        assert tmp.parent == target.parent and tmp.name.startswith(".out.npz.") and tmp.suffix == ".npz"
        tmp.write_text("one")
    umask = os.umask(0)
    os.umask(umask)
    assert target.read_text() == "one" and stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask
    target.chmod(0o640)
    with atomic_write(target) as tmp:
        tmp.write_text("two")
    assert target.read_text() == "two" and stat.S_IMODE(target.stat().st_mode) == 0o640
    assert leftovers(tmp_path) == []


def test_a_write_that_fails_leaves_the_target_and_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "out.md"
    target.write_text("old")
    with pytest.raises(WriteError, match=r"^--out: cannot write .*out\.md: No space left on device: free space$"):
        with atomic_write(target, "--out", hint="free space") as tmp:
            tmp.write_text("half")
            raise OSError(28, "No space left on device")
    with pytest.raises(KeyError), atomic_write(target) as tmp:  # not an OSError: raised as it is
        tmp.write_text("half")
        raise KeyError("bug")
    assert target.read_text() == "old" and leftovers(tmp_path) == []


def test_through_a_symbolic_link_the_file_is_replaced_and_the_link_kept(tmp_path: Path) -> None:
    real = tmp_path / "real.csv"
    real.write_text("old")
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    with atomic_write(link) as tmp:
        tmp.write_text("new")
    assert link.is_symlink() and real.read_text() == "new" and leftovers(tmp_path) == []
    fifo = make_special(tmp_path, "fifo")
    (tmp_path / "to_fifo").symlink_to(fifo)
    with pytest.raises(WriteError, match="to_fifo: is a FIFO"):
        check_file_target(tmp_path / "to_fifo")
    assert still_special(fifo, "fifo")


@pytest.mark.skipif(os.geteuid() == 0, reason="permission bits do not bind root")
def test_a_read_only_folder_is_one_line(tmp_path: Path) -> None:
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(WriteError, match="cannot have new files in"):
            check_file_target(folder / "a.npz", "db export")
        with pytest.raises(WriteError, match="cannot have new files in"):
            check_folder_target(folder / "sub", "--out")
    finally:
        folder.chmod(0o700)
    assert list(folder.iterdir()) == []


# --------------------------------------------------------------------------- the commands
@pytest.mark.parametrize("kind", SPECIALS)
def test_db_export_refuses_a_special_file(lab: Path, tmp_path: Path, kind: str) -> None:
    """The issue's case: ``db export /dev/null`` replaced the device with a regular file, exit 0."""
    target = make_special(tmp_path, kind)
    line = one_error_line(runner.invoke(app, ["db", "export", str(target), "--db", str(lab)]))
    assert str(target) in line and "not a regular file" in line, line
    assert still_special(target, kind) and leftovers(tmp_path) == []


def test_db_export_to_a_new_file_and_through_a_link(lab: Path, tmp_path: Path) -> None:
    out = tmp_path / "a.npz"
    assert runner.invoke(app, ["db", "export", str(out), "--db", str(lab)]).exit_code == 0
    link = tmp_path / "link.npz"
    link.symlink_to(out)
    size = out.stat().st_size
    out.write_text("stale")
    res = runner.invoke(app, ["db", "export", str(link), "--db", str(lab)])
    assert res.exit_code == 0, res.output
    assert link.is_symlink() and out.stat().st_size == size and leftovers(tmp_path) == []


@pytest.mark.parametrize("kind", SPECIALS)
def test_leaderboard_out_that_is_a_special_file_is_one_line(lab: Path, tmp_path: Path, kind: str) -> None:
    """``leaderboard --out /dev/null`` was a NotADirectoryError traceback."""
    target = make_special(tmp_path, kind)
    args = ["leaderboard", "--db", str(lab), "--reps", "100", "--out"]
    line = one_error_line(runner.invoke(app, [*args, str(target)]))
    assert f"--out {target}: is a" in line and "not a folder" in line, line
    # a special file where one of its files goes: refused before anything is written
    out = tmp_path / "out"
    out.mkdir()
    make_special(out, kind, "leaderboard.tex")
    line = one_error_line(runner.invoke(app, [*args, str(out)]))
    assert str(out / "leaderboard.tex") in line, line
    assert still_special(target, kind) and still_special(out / "leaderboard.tex", kind)
    assert list(out.iterdir()) == [out / "leaderboard.tex"] and leftovers(tmp_path) == []


@pytest.mark.parametrize("kind", SPECIALS)
def test_report_out_that_is_a_special_file_is_one_line(lab: Path, tmp_path: Path, kind: str) -> None:
    target = make_special(tmp_path, kind)
    res = runner.invoke(app, ["report", "--table", "results", "--db", str(lab), "--out", str(target)])
    line = one_error_line(res)
    assert f"--out {target}: is a" in line, line
    assert still_special(target, kind) and leftovers(tmp_path) == []


@pytest.mark.parametrize("kind", SPECIALS)
def test_evaluate_refuses_a_special_database_file(tmp_path: Path, kind: str) -> None:
    (tmp_path / "model.bin").write_text("a model\n")
    target = make_special(tmp_path, kind)
    args = ["evaluate", "--model", str(tmp_path / "model.bin"), "--entry-point", "builtins:str", "--name", "a"]
    line = one_error_line(runner.invoke(app, [*args, "--db", str(target)]))
    assert f"--db {target}: is a" in line, line
    assert still_special(target, kind) and leftovers(tmp_path) == []


@pytest.fixture
def regimes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A private copy of the shipped regimes folder (regime, catalog and reward files)."""
    import shutil

    folder = tmp_path / "regimes"
    shutil.copytree(Path(__file__).resolve().parents[1] / "regimes", folder)
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(folder))
    monkeypatch.delenv("NUTRIBENCH_AGENTS", raising=False)
    return folder


@pytest.mark.parametrize("kind", SPECIALS)
def test_regimes_generate_write_refuses_a_special_file(regimes: Path, kind: str) -> None:
    target = make_special(regimes, kind, "run8.toml")
    args = ["regimes", "generate", "run8", "--from", "run6", "--tau", "C=10-12", "--write"]
    for extra in ([], ["--force"]):
        line = one_error_line(runner.invoke(app, [*args, *extra]))
        assert f"{target}: is a" in line, line
    assert still_special(target, kind) and leftovers(regimes) == []
    target.unlink()
    assert runner.invoke(app, args).exit_code == 0 and (regimes / "run8.toml").is_file()
    assert leftovers(regimes) == []


@pytest.fixture
def fake_study(monkeypatch: pytest.MonkeyPatch):
    """``tune best`` on a study that needs no training: its best trial is the shipped mc config."""
    import nutribench.tuning.export as export
    import nutribench.tuning.study as study
    from nutribench.agents.config import load_agent_config

    cfg = load_agent_config("mc").model_copy(update={"name": "mc_tuned", "version": 1})
    monkeypatch.setattr(study, "open_study", lambda *a: None)
    monkeypatch.setattr(export, "tuned_config", lambda *a: (cfg, "# tuned"))
    return ["tune", "best", "--study", "s", "--write", "--out"]


@pytest.mark.parametrize("kind", SPECIALS)
def test_tune_best_out_refuses_a_special_file(fake_study, tmp_path: Path, kind: str) -> None:
    target = make_special(tmp_path, kind)
    line = one_error_line(runner.invoke(app, [*fake_study, str(target)]))
    assert f"--out {target}: is a" in line and "not a folder" in line, line
    folder = tmp_path / "agents"
    folder.mkdir()
    inside = make_special(folder, kind, "mc_tuned.toml")
    line = one_error_line(runner.invoke(app, [*fake_study, str(folder)]))
    assert f"{inside}: is a" in line, line
    assert still_special(target, kind) and still_special(inside, kind) and leftovers(tmp_path) == []
    inside.unlink()
    res = runner.invoke(app, [*fake_study, str(folder)])
    assert res.exit_code == 0, res.output
    assert (folder / "mc_tuned.toml").read_text().startswith("# tuned") and leftovers(tmp_path) == []


@pytest.mark.parametrize("kind", SPECIALS)
def test_run_models_dir_and_tensorboard_refuse_a_special_file(tmp_path: Path, kind: str) -> None:
    from tests.conftest import run_cli_args

    target = make_special(tmp_path, kind)
    db = tmp_path / "r.db"
    for option in ("--models-dir", "--tensorboard"):
        res = runner.invoke(app, run_cli_args(db, option, str(target), episodes=2), env={"NUTRIBENCH_JOB": "fake"})
        line = one_error_line(res)
        assert f"{option} {target}: is a" in line and "not a folder" in line, line
    assert still_special(target, kind) and not db.exists() and leftovers(tmp_path) == []


@pytest.mark.parametrize("kind", SPECIALS)
def test_train_save_refuses_a_special_file_before_training(tmp_path: Path, kind: str) -> None:
    target = make_special(tmp_path, kind, "model.zip")
    res = runner.invoke(app, ["train", "--algo", "mc", "--episodes", "1", "--save", str(target)])
    line = one_error_line(res)
    assert f"--save {target}: is a" in line, line
    assert still_special(target, kind) and leftovers(tmp_path) == []
