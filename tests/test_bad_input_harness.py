"""The fault audit's bad-input harness as one parametrised test: every input below is refused
with exit 2, one ``error:`` line, no traceback, and nothing created (no database file, no
models folder, no output file). Nothing trains: runs use the synthetic job."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import app

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def lab(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A user's folder: a copy of the regimes (with a run7.toml copied from run0.toml and its
    name left as run0), a plain file, an empty and a truncated archive."""
    regimes = tmp_path / "regimes"
    shutil.copytree(REPO / "regimes", regimes)
    (regimes / "run7.toml").write_text((regimes / "run0.toml").read_text())
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(regimes))
    monkeypatch.setenv("NUTRIBENCH_JOB", "fake")
    monkeypatch.delenv("NUTRIBENCH_DB", raising=False)
    (tmp_path / "a_file").write_text("not a folder\n")
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "truncated.npz").write_bytes(b"PK\x03\x04" + b"\x00" * 20)
    monkeypatch.chdir(tmp_path)
    return tmp_path


GRID = [
    "run",
    "--db",
    "new.db",
    "--regimes",
    "run0",
    "--algos",
    "ppo",
    "--seeds",
    "0",
    "--episodes",
    "2",
    "--eval-episodes",
    "1",
]

BAD = {
    "regime name differs from its file name": (
        ["run", "--db", "new.db", "--regimes", "run7", "--algos", "ppo", "--seeds", "0", "--episodes", "2"],
        "run7",
    ),
    "seed too large": ([*GRID[:7], "--seeds", "99999999999999999999999", "--episodes", "2"], "too large"),
    "negative seed": ([*GRID[:7], "--seeds", "-1", "--episodes", "2"], "seed"),
    "unknown regime": (["run", "--db", "new.db", "--regimes", "run99", "--algos", "ppo", "--episodes", "2"], "run99"),
    "regime name that is a path": (
        ["run", "--db", "new.db", "--regimes", "../../etc/x", "--algos", "ppo", "--episodes", "2"],
        "",
    ),
    "unknown agent": (
        ["run", "--db", "new.db", "--regimes", "run0", "--algos", "recurrent_ppo", "--episodes", "2"],
        "recurrent_ppo",
    ),
    "zero training days": ([*GRID[:9], "--days", "0"], "--days"),
    "zero training days, the old spelling": ([*GRID[:9], "--episodes", "0"], "--days"),
    "unknown engine": ([*GRID, "--engine", "fast"], "--engine"),
    "models folder is a file": ([*GRID, "--models-dir", "a_file"], "a_file"),
    "unknown preset": (["run", "--db", "new.db", "--preset", "huge"], "huge"),
    "export to a missing folder": (["db", "export", "/nonexistent/o.npz", "--db", "new.db"], "/nonexistent"),
    "import an empty archive": (["db", "import", "empty.npz", "--db", "new.db"], "empty.npz"),
    "import a truncated archive": (["db", "import", "truncated.npz", "--db", "new.db"], "truncated.npz"),
    "import a missing archive": (["db", "import", "missing.npz", "--db", "new.db"], "missing.npz"),
    "report of a missing database": (["report", "--all", "--db", "new.db", "--out", "out"], "new.db"),
    "status of a missing database": (["status", "--db", "new.db"], "new.db"),
    "compare on a missing database": (["compare", "ppo", "mc", "--db", "new.db"], "new.db"),
    "evaluate a missing model": (
        ["evaluate", "--model", "nope.zip", "--entry-point", "x.y:load", "--name", "a", "--db", "new.db"],
        "nope.zip",
    ),
    "evaluate with a bad entry point": (
        ["evaluate", "--model", "a_file", "--entry-point", "no_such_mod_xyz:load", "--name", "a", "--db", "new.db"],
        "no_such_mod_xyz",
    ),
    "no evaluation days": ([*GRID[:11], "--eval-episodes", "0"], "--eval-episodes 0"),
    "a training budget too large for the database": (
        [*GRID[:9], "--episodes", "100000000000000000000"],
        "too large",
    ),
    "an evaluation budget too large for the database": ([*GRID[:11], "--eval-episodes", "2147483648"], "too large"),
    "run into an in-memory database": (["run", "--db", "sqlite://", *GRID[3:]], "in-memory"),
    "run into an in-memory database by name": (["run", "--db", "sqlite:///:memory:", *GRID[3:]], "in-memory"),
    "a database URL whose port is not a number": (
        ["status", "--db", "postgresql://me:secret@host:notaport/lab"],
        "me:***@host",
    ),
    "a database URL with a broken host": (["status", "--db", "postgresql+psycopg://[::1"], "host or port"),
    "a database URL whose query port is not a number": (
        ["report", "--all", "--db", "postgresql://me@/lab?host=/tmp&port=abc"],
        "port",
    ),
    "bench env with a negative size": (["bench", "env", "--regimes", "run0", "--sizes", "-1"], "--sizes"),
    "bench env with a zero size": (["bench", "env", "--regimes", "run0", "--sizes", "0"], "--sizes"),
    "bench env with a huge size": (
        ["bench", "env", "--regimes", "run0", "--sizes", "1,99999999999999999999"],
        "--sizes",
    ),
    "report into a file": (["report", "--all", "--db", "new.db", "--out", "a_file"], "a_file"),
    "report into a folder below a file": (["report", "--all", "--db", "new.db", "--out", "a_file/sub"], "a_file"),
    "report into /proc": (["report", "--all", "--db", "new.db", "--out", "/proc/nutribench"], "/proc"),
    "a database name too long for the file system": (["status", "--db", "x" * 300], "File name too long"),
    "a report folder name too long for the file system": (
        ["report", "--all", "--db", "new.db", "--out", "x" * 300],
        "File name too long",
    ),
    "baselines with a negative seed": (
        ["baselines", "--regimes", "run0", "--eval-episodes", "1", "--seed", "-1"],
        "--seed",
    ),
    "baselines with more days than fit side by side": (
        ["baselines", "--regimes", "run0", "--episodes", "99999999999999999999"],
        "side by side",
    ),
    "train with a negative seed": (["train", "--seed", "-1", "--episodes", "1"], "--seed -1"),
    "train with more evaluation days than fit side by side": (
        ["train", "--episodes", "1", "--eval-episodes", "20000"],
        "side by side",
    ),
    "evaluate with more evaluation days than fit side by side": (
        ["evaluate", "--model", "a_file", "--entry-point", "os.path:exists", "--name", "a", "--eval-episodes", "20000"],
        "eval_episodes goes from 1 to 10000",
    ),
    "compare with more resamples than fit": (
        ["compare", "ppo", "mc", "--db", "new.db", "--reps", "99999999999"],
        "--reps",
    ),
    "compare with too few resamples": (["compare", "ppo", "mc", "--db", "new.db", "--reps", "1"], "100 to 100,000"),
    "compare as JSON and as Markdown": (["compare", "ppo", "mc", "--db", "new.db", "--json", "--markdown"], "--json"),
    "an empty models folder": ([*GRID, "--models-dir", ""], "--models-dir is empty"),
    "an empty report folder": (["report", "--all", "--db", "new.db", "--out", ""], "--out is empty"),
    "an empty folder for a tuned agent file": (
        ["tune", "best", "--study", "s", "--write", "--out", ""],
        "--out is empty",
    ),
    "an empty leaderboard folder": (["leaderboard", "--db", "new.db", "--out", ""], "--out is empty"),
    "a blank leaderboard folder": (["leaderboard", "--db", "new.db", "--out", "  "], "--out is empty"),
    "an empty folder of archives": (["leaderboard", "--archives", ""], "--archives is empty"),
    "an empty folder of models to verify": (["leaderboard", "--db", "new.db", "--verify", ""], "--verify is empty"),
    "an empty TensorBoard folder for run": ([*GRID, "--tensorboard", ""], "--tensorboard is empty"),
    "an empty TensorBoard folder for train": (["train", "--days", "1", "--tensorboard", ""], "--tensorboard is empty"),
    "an empty model path for evaluate": (
        ["evaluate", "--model", "", "--entry-point", "os.path:exists", "--name", "a", "--db", "new.db"],
        "--model is empty",
    ),
    "a NUL in a new regime's description": (
        ["regimes", "generate", "run8", "--from", "run6", "--description", "slow\x00C", "--write"],
        "U+0000 (a NUL)",
    ),
    "an escape sequence in a new regime's description": (
        ["regimes", "generate", "run8", "--from", "run6", "--description", "\x1b[31mred", "--write"],
        "U+001B",
    ),
    "a new regime's description too long for a config file": (
        ["regimes", "generate", "run8", "--from", "run6", "--description", "x" * 5000, "--write"],
        "more than the 4,096",
    ),
    "a control byte in a regime name, echoed escaped": (
        ["run", "--db", "new.db", "--regimes", "run0\x1b[31m", "--algos", "ppo", "--episodes", "2"],
        "run0\\x1b[31m",
    ),
    "new regime with a reversed range": (
        ["regimes", "generate", "run8", "--from", "run6", "--tau", "C=12-10", "--write"],
        "C",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_one_line_exit_2_and_creates_nothing(lab: Path, case: str) -> None:
    args, needle = BAD[case]
    before = {p.relative_to(lab) for p in lab.rglob("*")}
    res = CliRunner().invoke(app, args)
    out = res.output.strip()
    assert res.exit_code == 2, (case, res.exit_code, res.output, res.exception)
    assert "Traceback" not in res.output and len(out.splitlines()) == 1 and out.startswith("error:"), (case, res.output)
    assert needle in out, (case, out)
    assert not any(c < " " or "\x7f" <= c <= "\x9f" for c in out), (case, "a control character reached the terminal")
    assert {p.relative_to(lab) for p in lab.rglob("*")} == before, case  # nothing created


def test_the_harness_sees_a_good_input_create_its_database(lab: Path) -> None:
    """The same checks would notice a created file: a good run makes its database."""
    res = CliRunner().invoke(app, GRID)
    assert res.exit_code == 0, res.output
    assert (lab / "new.db").is_file()
