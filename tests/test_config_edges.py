"""Hostile config files and sizes (issue 74): a FIFO, a device, a file nested 100,000 deep, a
catalog of 10^5 foods, a horizon or a network no machine holds, ``learning_rate = true``, a NUL
in a description. Each is refused when the file is read, in one line naming the file (and the
field), quickly; none hangs (FIFOs only in temporary folders; the device is a link to
``/dev/zero`` there)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import time
import tomllib
from contextlib import contextmanager
from pathlib import Path

import pytest
import tomli_w
from typer.testing import CliRunner

from nutribench.agents.config import parse_agent_config
from nutribench.cli import app
from nutribench.config import ConfigError, FoodCatalog, sizes
from nutribench.config.reading import MAX_CONFIG_BYTES, MAX_DEPTH, MAX_TEXT, parse_config, read_config_bytes

REPO = Path(__file__).resolve().parents[1]


@contextmanager
def within(seconds: int):
    """Fail (not hang) if the block takes longer than ``seconds`` (a FIFO would block for ever)."""

    def alarm(*_):
        raise TimeoutError(f"still busy after {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture
def lab(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the regimes (and so of the shipped agents, ``regimes/agents``), the synthetic job."""
    shutil.copytree(REPO / "regimes", tmp_path / "regimes")
    (tmp_path / "agents").symlink_to(tmp_path / "regimes" / "agents")
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(tmp_path / "regimes"))
    monkeypatch.delenv("NUTRIBENCH_AGENTS", raising=False)
    monkeypatch.setenv("NUTRIBENCH_JOB", "fake")
    monkeypatch.delenv("NUTRIBENCH_DB", raising=False)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def refused(args: list[str], *needles: str, seconds: int = 60) -> str:
    """``args`` exit 2 with one ``error:`` line holding every needle, within ``seconds``."""
    with within(seconds):
        res = CliRunner().invoke(app, args)
    out = res.output.strip()
    assert res.exit_code == 2, (args, res.exit_code, res.output, res.exception)
    assert len(out.splitlines()) == 1 and out.startswith("error:") and "Traceback" not in out, out
    for needle in needles:
        assert needle in out, (needle, out)
    return out


RUN = ["run", "--db", "r.db", "--regimes", "run0", "--algos", "mc", "--seeds", "0", "--episodes", "1"]


# --------------------------------------------------------------------------- what is read
def test_a_fifo_or_a_device_is_never_read_as_a_config_file(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "fifo.toml")
    (tmp_path / "zero.toml").symlink_to("/dev/zero")  # a device, reached through a link
    with within(10):
        for name, kind in (("fifo.toml", "a FIFO"), ("zero.toml", "a character device")):
            with pytest.raises(ConfigError, match=re.escape(f"{name}: is {kind}")):
                read_config_bytes(tmp_path / name)


@pytest.mark.parametrize("name", ["run0.toml", "foods.toml", "reward.toml", "run9.toml"])
def test_a_fifo_in_the_regimes_folder_is_one_line_for_every_command_that_reads_it(lab: Path, name: str) -> None:
    path = lab / "regimes" / name
    path.unlink(missing_ok=True)
    os.mkfifo(path)
    for args in (["regimes", "check"], ["regimes", "list"], ["baselines", "--regimes", "run0", "--episodes", "1"], RUN):
        if name == "run9.toml" and args[0] == "baselines":
            continue  # names run0 only: run9.toml is read by the commands that list the folder
        refused(args, str(path), "is a FIFO (named pipe), not a regular file")


def test_an_agent_file_that_is_a_fifo_is_said_so_not_unknown(lab: Path) -> None:
    (lab / "agents" / "mc.toml").unlink()
    os.mkfifo(lab / "agents" / "mc.toml")
    out = refused(RUN, "agents/mc.toml: is a FIFO")
    assert "unknown agent config" not in out
    refused(["train", "--algo", str(lab / "agents" / "mc.toml"), "--days", "1"], "agents/mc.toml: is a FIFO")


@pytest.mark.parametrize("variable", ["NUTRIBENCH_AGENTS", "NUTRIBENCH_REGIMES"])
@pytest.mark.parametrize("kind", ["fifo", "device", "file"])
def test_a_folder_setting_that_is_no_folder_is_refused_not_ignored(
    lab: Path, monkeypatch: pytest.MonkeyPatch, variable: str, kind: str
) -> None:
    target = lab / "not_a_folder"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "device":
        target.symlink_to("/dev/null")
    else:
        target.write_text("x = 1\n")
    monkeypatch.setenv(variable, str(target))
    refused(RUN, f"{variable}={target}: is ", "not a folder")


DEEP = 100_000


@pytest.mark.parametrize(
    "nest",
    [
        "zz = " + "[" * DEEP + "]" * DEEP,
        "zz = " + "{a = " * DEEP + "1" + "}" * DEEP,
        "zz." + ".".join(["a"] * DEEP) + " = 1",
        "[" + ".".join(["t"] * 40) + "]\n" + "u." * 40 + "v = 1",  # a header's and a key's parts add up
    ],
    ids=["arrays", "inline tables", "a dotted key", "header and key"],
)
def test_toml_nested_too_deep_is_one_line_fast(lab: Path, nest: str) -> None:
    """Before: a RecursionError traceback after 16 s (a dotted key of 10^5 parts: out of memory)."""
    regime = lab / "regimes" / "run0.toml"
    regime.write_text(regime.read_text() + "\n" + nest + "\n")
    agent = lab / "agents" / "mc.toml"
    agent.write_text(nest + "\n" + agent.read_text())
    t0 = time.perf_counter()
    refused(["regimes", "check", "--regimes", "run0"], "run0.toml", f"nest more than {MAX_DEPTH} levels deep")
    refused(RUN, "nest more than", seconds=60)
    regime.write_text((REPO / "regimes" / "run0.toml").read_text())
    refused(RUN, "mc.toml", "nest more than")
    assert time.perf_counter() - t0 < 45


def test_nesting_in_strings_and_comments_is_no_nesting() -> None:
    text = 'a = "[[[[{{{{.a.b.c" # [[[[[[ ' + "[" * 100 + '\nb = """\n' + "[" * 100 + '\n"""\nc = 1.5\n'
    assert parse_config("x.toml", text.encode()) == {"a": "[[[[{{{{.a.b.c", "b": "[" * 100 + "\n", "c": 1.5}


@pytest.mark.parametrize("foods", [10**5, 10**6])
def test_a_catalog_of_a_hundred_thousand_foods_is_refused_before_it_is_read(lab: Path, foods: int) -> None:
    """Before: 9.7 / 97 MB appended to foods.toml kept every command busy past 40 s. The file
    bound refuses it from its size (nothing read), the catalog bound any catalog larger than
    its dynamics could be held (``sizes.MAX_FOODS``)."""
    entry = (
        '\n[[food]]\nkey = "f{i}"\nname = "Rice, white, long-grain, regular, enriched, cooked"\n'
        'portion = "large bowl, 350 g"\nportion_g = 350.0\nper_100g = {{ C = 28.17, F = 0.28, P = 2.69 }}\n'
        'source_id = "NDB 20045"\n'
    )
    with open(lab / "regimes" / "foods.toml", "a") as fh:
        for start in range(0, foods, 10_000):
            fh.write("".join(entry.format(i=i) for i in range(start, start + 10_000)))
    size = (lab / "regimes" / "foods.toml").stat().st_size
    assert size > 9_000_000
    t0 = time.perf_counter()
    refused(["regimes", "check"], "foods.toml", f"{size:,} bytes, more than the {MAX_CONFIG_BYTES:,}")
    refused(["baselines", "--regimes", "run0", "--episodes", "1"], "foods.toml")
    assert time.perf_counter() - t0 < 30


def test_the_catalog_bound_is_what_its_dynamics_could_hold() -> None:
    assert (
        sizes.dynamics_bytes(sizes.MAX_FOODS, 1) <= sizes.MEMORY_CEILING < sizes.dynamics_bytes(sizes.MAX_FOODS + 1, 1)
    )
    (bound,) = [m.max_length for m in FoodCatalog.model_fields["food"].metadata if hasattr(m, "max_length")]
    assert bound == sizes.MAX_FOODS
    foods = [
        {
            "key": f"f{i}",
            "name": "x",
            "portion": "x",
            "portion_g": 1.0,
            "per_100g": {"C": 1, "F": 1, "P": 1},
            "source_id": "x",
        }
        for i in range(3)
    ]
    base = {"name": "c", "version": 1, "source": "s", "target_grams": {"C": 1, "F": 1, "P": 1}}
    with pytest.raises(ValueError, match="duplicate food keys"):
        FoodCatalog.model_validate({**base, "food": [*foods, foods[0]]})


# --------------------------------------------------------------------------- sizes
def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert re.search(old, text), (path, old)
    path.write_text(re.sub(old, new, text, count=1))


@pytest.mark.parametrize(
    "old, new, needles",
    [
        (r"horizon = \d+", "horizon = 1000000000000", ["reward.toml: horizon: 1,000,000,000,000 is more than"]),
        (r"horizon = \d+", "horizon = 2147483648", ["reward.toml: horizon", "INTEGER"]),
        (r"horizon = \d+", "horizon = true", ["reward.toml: horizon: true or false is no number"]),
    ],
)
def test_a_horizon_no_machine_holds_is_refused_by_regimes_check(lab: Path, old: str, new: str, needles) -> None:
    """Before: horizon = 10^12 passed ``regimes check``; ``baselines`` died with a MemoryError."""
    edit(lab / "regimes" / "reward.toml", old, new)
    refused(["regimes", "check"], *needles)
    refused(["baselines", "--regimes", "run0", "--episodes", "1"], *needles)


def test_a_horizon_whose_dynamics_exceed_the_ceiling_is_refused_with_the_arithmetic(lab: Path) -> None:
    """2 x 10^9 steps fit the step column; at level 4, 10 foods' dynamics need 1.1 TiB."""
    edit(lab / "regimes" / "reward.toml", r"horizon = \d+", "horizon = 2000000000")
    edit(
        lab / "regimes" / "run0.toml",
        r'reward = "reward.toml"',
        'reward = "reward.toml"\nobserve_clock = true\nobserve_pending = true\nobserve_latent = true',
    )
    assert sizes.dynamics_bytes(10, 2 * 10**9, 4) > sizes.MEMORY_CEILING >= sizes.dynamics_bytes(10, 2 * 10**9, 1)
    refused(["regimes", "check", "--regimes", "run0"], "run0.toml", "a horizon of 2,000,000,000 steps", "TiB")


AGENT_SIZES = [
    ("ppo", "net_arch", [1_000_000] * 3, "a network of [1000000, 1000000, 1000000] would need at least 29.1 TiB"),
    ("ppo", "n_steps", 10**12, "n_steps: 1,000,000,000,000 is more than 2,147,483,647"),
    ("ppo", "batch_size", 10**12, "batch_size: 1,000,000,000,000 is more than"),
    ("ddqn", "buffer_size", 10**12, "buffer_size: 1,000,000,000,000 is more than"),
    ("sac", "buffer_size", 10**12, "buffer_size"),
    ("sac", "net_arch", [300_000, 300_000], "TiB"),
    ("gru_ppo", "hidden_size", 10**6, "hidden_size: 1,000,000 is more than 107,019"),
    ("ddqn", "n_step", 10**10, "n_step = 10,000,000,000: a batch's n-step returns"),
    ("ppo", "learning_rate", True, "learning_rate: true or false is no number"),
    ("ppo", "n_epochs", True, "n_epochs: true or false is no number"),
    ("ppo", "max_grad_norm", False, "max_grad_norm: true or false is no number"),
    ("ppo", "normalize_obs", 1, "normalize_obs: Input should be a valid boolean"),
    ("ppo", "description", "a\x00b", "description: its value holds the control character U+0000 (a NUL)"),
    ("ppo", "description", "\x1b[31mred", "U+001B"),
    ("ppo", "description", "x" * (MAX_TEXT + 1), f"{MAX_TEXT + 1:,} characters, more than the {MAX_TEXT:,}"),
]


@pytest.mark.parametrize("algo, field, value, needle", AGENT_SIZES, ids=[f"{a}.{f}" for a, f, *_ in AGENT_SIZES])
def test_an_agent_file_with_a_size_no_machine_holds_or_a_lax_value_is_refused_at_load(
    lab: Path, algo: str, field: str, value, needle: str
) -> None:
    """Before: net_arch = [10^6] * 3 and n_steps = 10^12 passed and the job failed later
    (``DefaultCPUAllocator``, ``MemoryError ... 47.3 TiB``); learning_rate = true ran as 1.0."""
    path = lab / "agents" / f"{algo}.toml"
    data = tomllib.loads(path.read_text())
    data[field] = value
    path.write_text(tomli_w.dumps(data))
    refused([*RUN[:5], "--algos", algo, *RUN[7:]], f"{algo}.toml: ", needle)


def test_a_recurrent_rollout_no_machine_holds_is_refused() -> None:
    data = tomllib.loads((REPO / "regimes" / "agents" / "gru_ppo.toml").read_text())
    data.update(n_steps=50 * 10**7, sequence_length=50, hidden_size=4096)
    with pytest.raises(ConfigError, match="n_steps = 500,000,000 with hidden_size = 4,096: a rollout"):
        parse_agent_config(data, "x.toml")


def test_the_network_bound_is_a_lower_bound_of_what_torch_holds() -> None:
    """The arithmetic never counts more than the real network has: 16 bytes per parameter of the
    shipped PPO's policy (weights, gradients, Adam's two moments) is at least ``network_bytes``
    without its 64-byte allocation minimum."""
    import numpy as np

    from tests.conftest import sb3_model

    cfg, model = sb3_model("ppo", seed=0)
    params = sum(int(np.prod(p.shape)) for p in model.policy.parameters())
    dims = [4, *cfg.net_arch, 2]
    assert 16 * params >= 16 * sum(a * b + b for a, b in zip(dims, dims[1:]))
    assert sizes.network_bytes(cfg.net_arch) <= 16 * params + 8 * 64 * len(dims)


def test_a_regime_description_with_a_nul_is_refused_before_the_run(lab: Path) -> None:
    """Before: accepted by ``run`` (SQLite and PostgreSQL) and refused later by ``db export``."""
    edit(lab / "regimes" / "run0.toml", r'description = "', r'description = "\\u0000')
    refused(["regimes", "check", "--regimes", "run0"], "run0.toml: description", "(a NUL)")
    refused(RUN, "run0.toml: description", "(a NUL)")
    assert not (lab / "r.db").exists()
    edit(lab / "regimes" / "run0.toml", r'description = "\\u0000', 'description = "' + "x" * 10_000_000)
    refused(["regimes", "check", "--regimes", "run0"], "run0.toml", "bytes, more than the")


def test_a_regime_with_lax_values_is_refused(lab: Path) -> None:
    edit(lab / "regimes" / "run0.toml", r"seed = \d+", "seed = true")
    refused(["regimes", "check", "--regimes", "run0"], "run0.toml: seed: true or false is no number")
    edit(lab / "regimes" / "run0.toml", r"seed = true", "seed = 1000\nobserve_clock = 1")
    refused(["regimes", "check", "--regimes", "run0"], "run0.toml: observe_clock: Input should be a valid boolean")
