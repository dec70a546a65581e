"""A fuzz harness (Hypothesis) over what a user hands nutribench: generated regime and agent
TOML files, command lines, recorder call sequences and damaged archives. The property, for
every input: the command exits 0 or 2 (a user error: one line) and never with a traceback,
and a refusal leaves every file as it was (no database created or changed, nothing
half-written). Hostile config files (a FIFO, a device, nesting past the bound, a file too
large, a control character or too long a string, a size no machine holds: issue 74) are
refused, each in one line naming the file, by every command that reads them, within a minute.

Each property runs a few derandomized examples in the default run (CI: reproducible, a few
seconds each) and many more under ``-m slow`` (150 each, 450 command lines; set
``NUTRIBENCH_FUZZ_EXAMPLES`` for another number). Nothing trains: ``run`` uses the synthetic
job (``NUTRIBENCH_JOB=fake``) on a thread of this process instead of a worker process, and the
command lines leave out the commands that train (``train``, ``bench train|learn``).
"""

from __future__ import annotations

import os
import shutil
import tomllib
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from nutribench.cli import app

REPO = Path(__file__).resolve().parents[1]
#: examples per property: the default run, and -m slow
FAST, SLOW = 6, int(os.environ.get("NUTRIBENCH_FUZZ_EXAMPLES", "150"))


def fuzz(examples: int):
    """Hypothesis settings: derandomized (the same examples on every run), no deadline (a busy
    machine is slow, not wrong), no example database (nothing written beside the tests)."""
    return settings(
        max_examples=examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
    )


# --------------------------------------------------------------------------- the lab
@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """A user's folder, built once: a copy of the regimes, a results database holding one
    dry-run job (run0, ppo, seed 0), its archive, a plain file and a policy module."""
    lab = tmp_path_factory.mktemp("template")
    shutil.copytree(REPO / "regimes", lab / "regimes")
    (lab / "a_file").write_text("not a folder\n")
    (lab / "fuzz_policies.py").write_text("def load(path):\n    return lambda obs: int(obs[0] < 0.5)\n")
    with in_lab(lab):
        res = invoke(["run", "--db", "r.db", "--regimes", "run0", "--algos", "ppo", "--seeds", "0", "--episodes", "2"])
        assert res.exit_code == 0, res.output
        res = invoke(["db", "export", "r.npz", "--db", "r.db"])
        assert res.exit_code == 0, res.output
    shutil.rmtree(lab / "models", ignore_errors=True)
    return lab


def thread_executor(spec, workers, n_jobs):
    """``make_executor`` for the fuzzer: jobs on a thread of this process (no worker process to start)."""
    from nutribench.scheduler.executors import ExecutorHandle

    return ExecutorHandle(ThreadPoolExecutor(1), 1, "a thread (fuzz)"), None


@contextmanager
def in_lab(lab: Path):
    """Inside ``lab``: its regimes, the synthetic job on a thread, no database from the environment."""
    env = {"NUTRIBENCH_REGIMES": str(lab / "regimes"), "NUTRIBENCH_JOB": "fake"}
    saved = {k: os.environ.get(k) for k in (*env, "NUTRIBENCH_DB", "NUTRIBENCH_AGENTS")}
    cwd = Path.cwd()
    os.environ.update(env)
    for k in ("NUTRIBENCH_DB", "NUTRIBENCH_AGENTS"):
        os.environ.pop(k, None)
    os.chdir(lab)
    try:
        with mock.patch("nutribench.scheduler.driver.make_executor", thread_executor):
            yield lab
    finally:
        os.chdir(cwd)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def invoke(args: list[str]):
    return CliRunner().invoke(app, args, catch_exceptions=True)


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every path under ``folder`` and the bytes of its files (folders: None)."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))}


def fresh_lab(template: Path, where: Path) -> Path:
    if where.exists():
        shutil.rmtree(where)
    shutil.copytree(template, where)
    return where


def assert_clean_outcome(res, args: list[str], before: dict, lab: Path) -> None:
    """Exit 0, or exit 2 with no traceback and every file of the lab as it was."""
    out = res.output
    crashed = res.exception is not None and not isinstance(res.exception, SystemExit)
    assert not crashed and res.exit_code in (0, 2), (args, res.exit_code, repr(res.exception), out[-2000:])
    assert "Traceback" not in out, (args, out[-2000:])
    if res.exit_code == 2:
        assert out.strip(), (args, "a refusal says why")
        after = snapshot(lab)
        assert after == before, (args, out, sorted(set(after) ^ set(before)), "changed by a refusal")


# --------------------------------------------------------------------------- values
#: what a careless or hostile user types where a value goes
NASTY = st.sampled_from(
    [
        "",
        " ",
        "0",
        "1",
        "2",
        "-1",
        "1.5",
        "1e400",
        "nan",
        "inf",
        "99999999999999999999",
        "2147483648",
        "0x10",
        "²",
        "é",
        ",",
        "1,,2",
        "all",
        "run0",
        "run0,run1",
        "run99",
        "ppo",
        "mc,ppo",
        "recurrent_ppo",
        "../../etc/x",
        "a_file",
        "a_file/sub",
        "missing.npz",
        "r.npz",
        "r.db",
        "new.db",
        "/proc/nutribench",
        "sqlite://",
        "sqlite:///:memory:",
        "postgresql://u:p@h:x/d",
        "postgresql+psycopg://[::1",
        "fuzz_policies:load",
        "no_such_mod:load",
        "x" * 300,
    ]
)
TOML_VALUE = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.text(max_size=6),
    st.booleans(),
    st.lists(st.integers(min_value=-3, max_value=10**6), max_size=3),
    st.dictionaries(st.sampled_from(["C", "F", "P", "low", "high", "x"]), st.floats(-5, 30), max_size=3),
)


def near(value: Any):
    """Values of ``value``'s own type, at the edges: what passes the type check and meets the bounds."""
    if isinstance(value, bool):
        return st.booleans()
    if isinstance(value, int):
        return st.sampled_from([0, 1, -1, 2**31, 2**63, 10**30, value + 1])
    if isinstance(value, float):
        return st.sampled_from([0.0, -0.0, 1e-300, 1.0, 1.5, -1.0, 1e300, float("inf"), float("-inf"), float("nan")])
    if isinstance(value, str):
        return st.sampled_from(["", "x" * 100, "run0", "ppo", "é", "a b", "foods.toml", "../foods.toml", "/etc/passwd"])
    if isinstance(value, list):
        return st.lists(st.integers(min_value=-1, max_value=2**40), max_size=3)
    return TOML_VALUE


def _paths(data: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path of a TOML document (tables and values)."""
    out = []
    if isinstance(data, dict):
        for k, v in data.items():
            out.append((*prefix, k))
            out += _paths(v, (*prefix, k))
    return out


@st.composite
def mutated_toml(draw, source: dict) -> bytes:
    """``source`` with a few keys replaced, removed or added, written as TOML, and sometimes a
    byte of the file replaced (not UTF-8, or not TOML any more)."""
    import copy

    data = copy.deepcopy(source)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_paths(data) or [("x",)]))
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["set", "set", "delete", "add"]))
        if action == "delete":
            parent.pop(path[-1], None)
        elif action == "add":
            parent[draw(st.sampled_from(["extra", "Name", "seed2", "é"]))] = draw(TOML_VALUE)
        else:
            parent[path[-1]] = draw(near(parent.get(path[-1])) if draw(st.booleans()) else TOML_VALUE)
    text = tomli_w.dumps(data).encode()
    if draw(st.booleans()) and text:
        i = draw(st.integers(0, len(text) - 1))
        text = text[:i] + bytes([draw(st.sampled_from([0x00, 0x22, 0x5B, 0x80, 0xE9, 0xFF]))]) + text[i + 1 :]
    return text


def load_toml(path: Path) -> dict:
    return tomllib.loads(path.read_text())


# --------------------------------------------------------------------------- regime files
def check_regime_file(template: Path, where: Path, text: bytes) -> None:
    lab = fresh_lab(template, where)
    (lab / "regimes" / "run0.toml").write_bytes(text)
    with in_lab(lab):
        for args in (
            ["regimes", "check", "--regimes", "run0"],
            ["regimes", "list"],
            ["baselines", "--regimes", "run0", "--episodes", "1"],
            ["run", "--db", "r.db", "--regimes", "run0", "--algos", "mc", "--seeds", "1", "--episodes", "1"],
        ):
            before = snapshot(lab)
            res = invoke(args)
            if args[:2] == ["regimes", "check"] and res.exit_code == 1:  # valid, but not its seed's draw: said
                assert "values differ from a fresh draw" in res.output, res.output
                continue
            assert_clean_outcome(res, args, before, lab)


REGIME = load_toml(REPO / "regimes" / "run0.toml")


@fuzz(FAST)
@given(text=mutated_toml(REGIME))
def test_fuzz_regime_files(template, tmp_path_factory, text):
    check_regime_file(template, tmp_path_factory.getbasetemp() / "fuzz-regime", text)


@pytest.mark.slow
@fuzz(SLOW)
@given(text=mutated_toml(REGIME))
def test_fuzz_regime_files_more(template, tmp_path_factory, text):
    check_regime_file(template, tmp_path_factory.getbasetemp() / "fuzz-regime", text)


# --------------------------------------------------------------------------- agent files
AGENTS = {a: load_toml(REPO / "regimes" / "agents" / f"{a}.toml") for a in ("mc", "ddqn", "ppo", "sac", "gru_ppo")}
AGENT_FILE = st.sampled_from(sorted(AGENTS)).flatmap(lambda a: st.tuples(st.just(a), mutated_toml(AGENTS[a])))


def check_agent_file(template: Path, where: Path, algo: str, text: bytes) -> None:
    lab = fresh_lab(template, where)
    (lab / "regimes" / "agents" / f"{algo}.toml").write_bytes(text)
    args = ["run", "--db", "r.db", "--regimes", "run0", "--algos", algo, "--seeds", "1", "--episodes", "1"]
    with in_lab(lab):
        before = snapshot(lab)
        assert_clean_outcome(invoke(args), args, before, lab)


@fuzz(FAST)
@given(agent=AGENT_FILE)
def test_fuzz_agent_files(template, tmp_path_factory, agent):
    check_agent_file(template, tmp_path_factory.getbasetemp() / "fuzz-agent", *agent)


@pytest.mark.slow
@fuzz(SLOW)
@given(agent=AGENT_FILE)
def test_fuzz_agent_files_more(template, tmp_path_factory, agent):
    check_agent_file(template, tmp_path_factory.getbasetemp() / "fuzz-agent", *agent)


# --------------------------------------------------------------------------- hostile config files
#: where a hostile config file goes, the commands that read it, and a string field and a size
#: field of it (None: it has none)
SLOTS = {
    "regimes/run0.toml": ("description", None),
    "regimes/foods.toml": ("source", None),
    "regimes/reward.toml": ("name", "horizon"),
    "regimes/agents/mc.toml": ("description", "net_arch"),
}
READERS = [
    ["regimes", "check"],
    ["regimes", "list"],
    ["baselines", "--regimes", "run0", "--episodes", "1"],
    ["run", "--db", "r.db", "--regimes", "run0", "--algos", "mc", "--seeds", "1", "--episodes", "1"],
]
CONTROL = [*range(0x00, 0x09), *range(0x0B, 0x20), *range(0x7F, 0xA0)]


@st.composite
def hostile_config(draw) -> tuple[str, str, Any]:
    """A config file no command may read: a FIFO, a device, nested past the bound (arrays,
    inline tables, a dotted key), larger than the bound, a control character or too long a
    string in a text field, or a size no machine holds (issue 74)."""
    from nutribench.config.reading import MAX_CONFIG_BYTES, MAX_DEPTH, MAX_TEXT
    from nutribench.config.sizes import MAX_STEPS

    slot = draw(st.sampled_from(sorted(SLOTS)))
    text_field, size_field = SLOTS[slot]
    kinds = ["fifo", "device", "nested", "dotted", "large", "control", "long"] + (["size"] if size_field else [])
    kind = draw(st.sampled_from(kinds))
    if kind == "device":
        return slot, kind, draw(st.sampled_from(["/dev/zero", "/dev/null", "/dev/urandom"]))
    if kind == "nested":
        depth = draw(st.integers(MAX_DEPTH + 1, 100_000))
        opener, closer = draw(st.sampled_from([("[", "]"), ("{a = ", "}")]))
        return slot, kind, "zz = " + opener * depth + ("1" if opener != "[" else "") + closer * depth
    if kind == "dotted":
        return slot, kind, "zz." + ".".join(["a"] * draw(st.integers(MAX_DEPTH, 100_000))) + " = 1"
    if kind == "large":
        return slot, kind, "#" + "x" * draw(st.integers(MAX_CONFIG_BYTES, 3 * MAX_CONFIG_BYTES))
    if kind == "control":
        return slot, kind, (text_field, "a" + chr(draw(st.sampled_from(CONTROL))) + "b")
    if kind == "long":
        return slot, kind, (text_field, "x" * draw(st.integers(MAX_TEXT + 1, 20_000)))
    if kind == "size":
        if size_field == "horizon":
            return slot, kind, (size_field, draw(st.integers(MAX_STEPS + 1, 10**18)))
        widths = draw(st.lists(st.integers(300_000, 10**7), min_size=2, max_size=4))
        return slot, kind, (size_field, widths)
    return slot, kind, None


#: what the one line says, by kind of hostile file
SAYS = {
    "fifo": "is a FIFO (named pipe), not a regular file",
    "device": "is a character device, not a regular file",
    "nested": "levels deep",
    "dotted": "levels deep",
    "large": "bytes, more than the",
    "control": "control character",
    "long": "characters, more than the",
    "size": "is more than",
}


def check_hostile_config(template: Path, where: Path, slot: str, kind: str, payload: Any) -> None:
    """Every command that reads the file refuses it: exit 2, one line naming the file and saying
    why, within a minute (a FIFO used to hang them), nothing changed."""
    import signal

    lab = fresh_lab(template, where)
    path = lab / slot
    if kind == "fifo":
        path.unlink()
        os.mkfifo(path)
    elif kind == "device":
        path.unlink()
        path.symlink_to(payload)
    elif kind in ("nested", "dotted", "large"):
        path.write_text(path.read_text() + "\n" + payload + "\n")
    else:
        data = load_toml(path)
        data[payload[0]] = payload[1]
        path.write_bytes(tomli_w.dumps(data).encode())
    says = SAYS["size"] if kind == "size" and payload[0] == "horizon" else SAYS[kind]
    if kind == "size" and payload[0] == "net_arch":
        says = "of memory, more than any machine has"
    readers = READERS if slot.count("/") == 1 else READERS[-1:]

    def alarm(*_):
        raise TimeoutError("a command still reads the hostile file after 60 s")

    with in_lab(lab):
        for args in readers:
            before = snapshot(lab)
            old = signal.signal(signal.SIGALRM, alarm)
            signal.alarm(60)
            try:
                res = invoke(args)
            finally:
                signal.alarm(0)
                signal.signal(signal.SIGALRM, old)
            assert_clean_outcome(res, args, before, lab)
            out = res.output.strip()
            assert res.exit_code == 2 and len(out.splitlines()) == 1, (slot, kind, args, out[-2000:])
            assert path.name in out and says in out, (slot, kind, args, out[:500])


@fuzz(FAST)
@given(hostile=hostile_config())
def test_fuzz_hostile_config_files(template, tmp_path_factory, hostile):
    check_hostile_config(template, tmp_path_factory.getbasetemp() / "fuzz-hostile", *hostile)


@pytest.mark.slow
@fuzz(SLOW // 3)
@given(hostile=hostile_config())
def test_fuzz_hostile_config_files_more(template, tmp_path_factory, hostile):
    check_hostile_config(template, tmp_path_factory.getbasetemp() / "fuzz-hostile", *hostile)


# --------------------------------------------------------------------------- command lines
#: each command: its positional arguments, the options it is fuzzed with, its flags, and the
#: budgets that could make work, always given, from small values (a generated command never
#: trains or benchmarks for long)
COMMANDS: dict[tuple[str, ...], tuple[int, list[str], list[str], list[str]]] = {
    ("run",): (
        0,
        ["--db", "--regimes", "--algos", "--seeds", "--preset", "--engine", "--models-dir", "--executor", "--workers"],
        ["--retry-failed", "--upgrade-only"],
        ["--episodes", "--eval-episodes"],
    ),
    ("status",): (0, ["--db"], ["--json"], []),
    ("report",): (
        0,
        ["--db", "--out", "--fig", "--table", "--algos", "--algo", "--regime", "--seed", "--episode"],
        ["--all", "--trajectory", "--diagnostics"],
        [],
    ),
    ("compare",): (2, ["--db"], [], []),
    ("evaluate",): (0, ["--model", "--entry-point", "--name", "--regime", "--seed", "--db"], [], ["--eval-episodes"]),
    ("regimes", "list"): (0, [], [], []),
    ("regimes", "check"): (0, ["--regimes"], [], []),
    ("regimes", "generate"): (1, ["--from", "--tau", "--sigma", "--seed", "--description"], ["--write", "--force"], []),
    ("db", "export"): (1, ["--db", "--algos", "--regimes"], [], []),
    ("db", "import"): (1, ["--db"], [], []),
    ("db", "copy"): (2, [], [], []),
    ("bench", "env"): (0, ["--regimes"], [], []),
    ("baselines",): (0, ["--regimes", "--seed"], ["--markdown"], ["--episodes"]),
}
SMALL = st.sampled_from(["-1", "0", "1", "2", "x", "1.5", "99999999999999999999"])


@st.composite
def command_lines(draw) -> list[str]:
    """A command with its positional arguments, some of its options with nasty values, maybe a
    flag, and its budgets from small values; sometimes a stray argument (a usage error)."""
    cmd = draw(st.sampled_from(sorted(COMMANDS)))
    positional, options, flags, budgets = COMMANDS[cmd]
    args = [*cmd, *(draw(NASTY) for _ in range(positional))]
    for option in draw(st.lists(st.sampled_from(options), max_size=4, unique=True)) if options else []:
        args += [option, draw(NASTY)]
    for option in budgets:
        args += [option, draw(SMALL)]
    args += draw(st.lists(st.sampled_from(flags), max_size=2, unique=True)) if flags else []
    if draw(st.integers(0, 9)) == 0:
        args.append(draw(NASTY))
    if cmd == ("bench", "env"):  # only sizes that are refused: a valid one benchmarks for seconds
        args += ["--repeats", "1", "--sizes", draw(st.sampled_from(["-1", "0", "x", "1,,2", "9" * 20]))]
    if cmd == ("run",):  # never the whole paper grid of a preset, even synthetic
        args += [] if "--algos" in args else ["--algos", "ppo"]
        args += [] if "--regimes" in args else ["--regimes", "run0"]
    if cmd == ("report",):
        args += ["--reference-episodes", "1"]
    return args


#: command lines that succeed in the lab; the fuzzer replaces one of their values or drops one
GOOD = [
    ["run", "--db", "r.db", "--regimes", "run0", "--algos", "ppo", "--seeds", "1", "--episodes", "1"],
    ["status", "--db", "r.db", "--json"],
    ["db", "export", "out.npz", "--db", "r.db", "--algos", "ppo"],
    ["db", "import", "r.npz", "--db", "new.db"],
    ["regimes", "check", "--regimes", "run0,run1"],
    ["regimes", "generate", "run8", "--from", "run6", "--tau", "C=10-12", "--write"],
    ["evaluate", "--model", "a_file", "--entry-point", "fuzz_policies:load", "--name", "mine", "--eval-episodes", "1"],
]


@st.composite
def near_good_command_lines(draw) -> list[str]:
    """A command line of :data:`GOOD` with one of its values replaced by a nasty one, or one
    option dropped, or left whole: the paths past the first check."""
    args = list(draw(st.sampled_from(GOOD)))
    first = 2 if args[0] in ("db", "regimes") else 1
    i = draw(st.integers(first, len(args) - 1))
    change = draw(st.sampled_from(["replace", "replace", "drop", "none"]))
    if change == "replace" and not args[i].startswith("--"):
        args[i] = draw(NASTY if args[i - 1] not in ("--episodes", "--eval-episodes") else SMALL)
    elif change == "drop" and args[i].startswith("--") and i + 1 < len(args) and not args[i + 1].startswith("--"):
        del args[i : i + 2]
    if args[0] == "run" and "--episodes" not in args:
        args += ["--episodes", "1"]  # else the preset's 5000 synthetic days
    return args


def check_command_line(template: Path, where: Path, args: list[str]) -> None:
    lab = fresh_lab(template, where)
    with in_lab(lab):
        before = snapshot(lab)
        assert_clean_outcome(invoke(args), args, before, lab)


@fuzz(3 * FAST)
@given(args=st.one_of(command_lines(), near_good_command_lines()))
def test_fuzz_command_lines(template, tmp_path_factory, args):
    check_command_line(template, tmp_path_factory.getbasetemp() / "fuzz-cli", args)


@pytest.mark.slow
@fuzz(3 * SLOW)
@given(args=st.one_of(command_lines(), near_good_command_lines()))
def test_fuzz_command_lines_more(template, tmp_path_factory, args):
    check_command_line(template, tmp_path_factory.getbasetemp() / "fuzz-cli", args)


# --------------------------------------------------------------------------- archives
@st.composite
def damaged(draw, data: bytes) -> bytes:
    """``data`` truncated, or with a few bytes replaced."""
    if draw(st.booleans()):
        return data[: draw(st.integers(0, len(data) - 1))]
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        out[draw(st.integers(0, len(out) - 1))] = draw(st.integers(0, 255))
    return bytes(out)


def check_archive(template: Path, where: Path, data: bytes) -> None:
    """Only the outcome is checked here (exit 0 or 2, no traceback, the database unchanged
    after a refusal): what import refuses is tests/test_archive_verify.py's."""
    lab = fresh_lab(template, where)
    (lab / "damaged.npz").write_bytes(data)
    args = ["db", "import", "damaged.npz", "--db", "r.db"]
    with in_lab(lab):
        before = snapshot(lab)
        assert_clean_outcome(invoke(args), args, before, lab)


def archive_bytes() -> bytes:
    """The template's archive, built the first time a test asks (strategies are built at import)."""
    return _ARCHIVE["bytes"]


_ARCHIVE: dict[str, bytes] = {}


@pytest.fixture(scope="module")
def archive(template) -> bytes:
    _ARCHIVE["bytes"] = (template / "r.npz").read_bytes()
    return _ARCHIVE["bytes"]


@fuzz(FAST)
@given(data=st.data())
def test_fuzz_archives(template, archive, tmp_path_factory, data):
    check_archive(template, tmp_path_factory.getbasetemp() / "fuzz-archive", data.draw(damaged(archive)))


@pytest.mark.slow
@fuzz(SLOW)
@given(data=st.data())
def test_fuzz_archives_more(template, archive, tmp_path_factory, data):
    check_archive(template, tmp_path_factory.getbasetemp() / "fuzz-archive", data.draw(damaged(archive)))


# --------------------------------------------------------------------------- the recorder
ACTION = st.sampled_from([0, 1, True, 1.0, 2, -1, 0.5, 0.9, 1.9, "1", None, float("nan")])
SEED = st.sampled_from([0, 1, 7, -1, 1.7, "1", True, None, 2**31, 2**63])
STEP = st.one_of(
    st.tuples(st.just("reset")),
    st.tuples(st.just("step"), ACTION),
    st.tuples(st.just("evaluate"), ACTION),
    st.tuples(st.just("raise")),
)


def check_recorder(where: Path, seed: Any, eval_episodes: Any, in_block: bool, steps: list[tuple]) -> None:
    """A recorder made with ``seed`` and ``eval_episodes``, then ``steps`` in its with block (or
    without one). ``evaluate`` returns or raises a UserError; the env's ``step`` may also raise
    the environment's ValueError (a bad action) or RuntimeError (a step past the day's end), the
    Gymnasium contract. The database exists, with one job, exactly when the block ended without
    an exception after a successful evaluation."""
    import nutribench
    from nutribench.errors import UserError

    if where.exists():
        shutil.rmtree(where)
    where.mkdir(parents=True)
    db = where / "lab.db"
    try:
        rec = nutribench.Recorder(db, name="fuzz", regime="run0", seed=seed, eval_episodes=eval_episodes)
    except UserError:
        assert not db.exists()
        return
    evaluated = False

    def play(target) -> None:
        nonlocal evaluated
        for op in steps:
            if op[0] == "raise":
                raise KeyboardInterrupt  # the user's loop stops with an exception
            try:
                if op[0] == "evaluate":
                    target.evaluate(lambda obs, a=op[1]: a)
                    evaluated = True
                elif op[0] == "reset":
                    target.env.reset()
                else:
                    try:
                        target.env.step(op[1])
                    except (ValueError, RuntimeError) as e:
                        assert not isinstance(e, UserError) or not in_block
            except UserError as e:
                assert in_block or "use the recorder in a with block" in str(e), e
                assert op[0] == "evaluate" or not in_block, (op, e)

    if not in_block:
        try:
            play(rec)
        except KeyboardInterrupt:
            pass
        assert not evaluated and not db.exists()
        return
    interrupted = False
    try:
        with rec as r:
            play(r)
    except KeyboardInterrupt:
        interrupted = True
    except UserError as e:
        assert not evaluated and "call rec.evaluate(policy)" in str(e), e
    if evaluated and not interrupted:
        assert len(nutribench.store.read_jobs(db)) == 1
    else:
        assert not db.exists(), "nothing written: no database file either"


RECORDER = dict(
    seed=SEED,
    eval_episodes=st.sampled_from([1, 2, 0, 1.5, "2"]),
    in_block=st.booleans(),
    steps=st.lists(STEP, max_size=5),
)


@fuzz(2 * FAST)
@given(**RECORDER)
def test_fuzz_recorder_call_sequences(tmp_path_factory, seed, eval_episodes, in_block, steps):
    check_recorder(tmp_path_factory.getbasetemp() / "fuzz-recorder", seed, eval_episodes, in_block, steps)


@pytest.mark.slow
@fuzz(SLOW)
@given(**RECORDER)
def test_fuzz_recorder_call_sequences_more(tmp_path_factory, seed, eval_episodes, in_block, steps):
    check_recorder(tmp_path_factory.getbasetemp() / "fuzz-recorder", seed, eval_episodes, in_block, steps)


def test_the_good_command_lines_succeed_in_the_lab(template, tmp_path_factory):
    """The fuzzer's starting points work as they are: its refusals are the changes' doing."""
    for args in GOOD:
        lab = fresh_lab(template, tmp_path_factory.getbasetemp() / "fuzz-good")
        with in_lab(lab):
            res = invoke(args)
        assert res.exit_code == 0, (args, res.output, res.exception)
