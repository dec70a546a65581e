"""One algorithm, one registry entry (nutribench/agents/registry.py), in one place: a built-in
is one module of nutribench/agents/builtin/ (its config model, arguments, SB3 class and entry;
a new one is one new file, found by scanning the package), a plug-in package adds an
algorithm with its own validated config model through the entry-point group
``nutribench.algorithms`` and runs end to end (run, report, compare, db export/import) without
a line of nutribench changed; and no module outside the registry and an algorithm's own module
dispatches on an algorithm's name."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import nutribench
import nutribench.agents.registry as registry
from nutribench.agents.config import load_agent_config, parse_agent_config
from nutribench.config.loading import ConfigError

REPO = Path(__file__).resolve().parents[1]
PACKAGE = Path(nutribench.__file__).parent

PLUGIN = '''
"""SB3's A2C renamed, registered as algorithm "a2c_test" with a config model of its own."""
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field
from stable_baselines3 import A2C

from nutribench.agents.registry import Algorithm


class RenamedA2C(A2C):
    """A2C under another name."""


class A2CTestConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    algo: Literal["a2c_test"]
    name: str
    version: int
    description: str
    normalize_obs: bool = False
    normalize_reward: bool = False
    gamma: float = 0.99
    n_steps: int = Field(ge=1)  # required: no default
    learning_rate: float = Field(gt=0)


def arguments(cfg, horizon):
    return RenamedA2C, dict(policy="MlpPolicy", n_steps=cfg.n_steps, learning_rate=cfg.learning_rate)


ALGORITHM = Algorithm(
    "a2c_test", A2CTestConfig, arguments="nbtest_a2c:arguments", load="nbtest_a2c:RenamedA2C",
    plain="stable_baselines3.A2C", label="A2C-T", color="#000080",
)
'''

CONFIG = """
algo = "a2c_test"
name = "a2c_t"
version = 1
description = "SB3 A2C as a registered plug-in algorithm"
n_steps = 25
learning_rate = 7e-4
"""


def plugin_package(root: Path) -> Path:
    """A plug-in "installed" in ``root``: its module and a dist-info whose entry_points.txt
    names its Algorithm in the group (what ``pip install`` of its package would write)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "nbtest_a2c.py").write_text(textwrap.dedent(PLUGIN))
    info = root / "nbtest_a2c-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: nbtest-a2c\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{registry.ENTRY_POINT_GROUP}]\na2c_test = nbtest_a2c:ALGORITHM\n")
    return root


@pytest.fixture
def installed(tmp_path: Path, monkeypatch):
    """The plug-in on sys.path, the entry points read again; both undone afterwards."""
    monkeypatch.syspath_prepend(str(plugin_package(tmp_path)))
    registry.reload_installed()
    yield tmp_path
    monkeypatch.undo()
    sys.modules.pop("nbtest_a2c", None)
    registry.reload_installed()


def test_builtins_come_from_the_builtin_package_in_the_paper_order():
    assert [a.algo for a in registry.builtin_algorithms()] == ["mc", "ddqn", "ppo", "sac", "gru_ppo", "external"]
    assert registry.paper_names() == ["mc", "ddqn", "ppo", "sac", "gru_ppo"]
    assert list(registry.algorithms())[:6] == ["mc", "ddqn", "ppo", "sac", "gru_ppo", "external"]
    assert {a: registry.get(a).color for a in registry.paper_names()} == {  # the published figures' colours
        "mc": "#8c564b",
        "ddqn": "#1f77b4",
        "ppo": "#2ca02c",
        "sac": "#d62728",
        "gru_ppo": "#9467bd",
    }
    assert registry.batched_names() == registry.paper_names()


def test_each_builtin_is_one_module_named_like_its_algo():
    """A built-in's module holds its config model, its arguments function and its entry; the
    class its arguments build is the one its entry loads with, defined in or imported into that
    module (the big policies of SAC and GRU-PPO live in their packages)."""
    from nutribench.agents.algos import model_arguments

    for entry in registry.builtin_algorithms():
        module = sys.modules[entry.config_model().__module__]
        assert module.__name__ == f"{registry.BUILTIN_PACKAGE}.{entry.algo}" and module.ALGORITHM is entry
        assert entry.config_model().model_fields["algo"].annotation.__args__ == (entry.algo,)
        if entry.build is None:
            continue
        arguments = registry.import_entry_point(entry.arguments)
        assert arguments.__module__ == module.__name__, entry.arguments
        cls, _ = model_arguments(load_agent_config(entry.algo), 50)
        assert cls is registry.import_entry_point(entry.load) and getattr(module, cls.__name__) is cls


def test_the_hub_modules_name_no_algorithm_and_import_no_builtin():
    """registry.py, config.py and algos.py hold no algorithm's name (the grep below) and import
    no built-in's module: they learn of the built-ins by scanning the package only."""
    hubs = [PACKAGE / "agents" / f for f in ("registry.py", "config.py", "algos.py")]
    names = {a.algo for a in registry.builtin_algorithms()}
    for path in hubs:
        assert not name_literals(path, names), path
        tree = ast.parse(path.read_text())
        imported = [
            n.module if isinstance(n, ast.ImportFrom) else a.name
            for n in ast.walk(tree)
            if isinstance(n, (ast.Import, ast.ImportFrom))
            for a in n.names
        ]
        assert not [m for m in imported if m and m.startswith(registry.BUILTIN_PACKAGE)], path


def test_old_import_paths_of_the_builtins_still_resolve():
    """Code and agent files' entry points written before each built-in was one module."""
    import nutribench.agents.algos as algos
    import nutribench.agents.config as config
    from nutribench.agents.builtin import ddqn, external, mc

    assert config.MCConfig is mc.MCConfig and config.ExternalConfig is external.ExternalConfig
    assert algos.DoubleDQN is ddqn.DoubleDQN and algos.double_dqn_target is ddqn.double_dqn_target
    assert registry.import_entry_point("nutribench.agents.algos:mc_arguments") is mc.mc_arguments
    for name in ("ALGORITHM", "Algorithm", "nope", "_FeedForwardless"):  # every module's, or none's
        with pytest.raises(AttributeError, match=name):
            getattr(algos, name)


NEW_BUILTIN = '''
"""SB3's A2C as a sixth built-in: this file and nothing else."""
from typing import Literal

from stable_baselines3 import A2C

from nutribench.agents.config import PosFloat, PosInt, FeedForward
from nutribench.agents.registry import Algorithm


class NbtestSixthConfig(FeedForward):
    algo: Literal["nbtest_sixth"]
    n_steps: PosInt
    learning_rate: PosFloat


def sixth_arguments(cfg, horizon):
    return A2C, dict(policy="MlpPolicy", n_steps=cfg.n_steps, learning_rate=cfg.learning_rate)


ALGORITHM = Algorithm(
    "nbtest_sixth", NbtestSixthConfig, arguments=f"{__name__}:sixth_arguments", load="stable_baselines3:A2C",
    plain="stable_baselines3.A2C", label="Sixth", order=6,
)
'''


def test_a_new_builtin_is_one_new_file(tmp_path: Path, monkeypatch):
    """A module dropped into the built-in package (here: a folder added to its path) is a
    built-in: listed after the paper's five and before ``external``, its files validated by
    its config model, trained by ``build_model``; no other module changed."""
    import nutribench.agents.builtin as builtin
    from nutribench.agents.registry import make_model
    from nutribench.env.sb3 import NutriRLSB3VecEnv

    (tmp_path / "nbtest_sixth.py").write_text(textwrap.dedent(NEW_BUILTIN))
    monkeypatch.setattr(builtin, "__path__", [*builtin.__path__, str(tmp_path)])
    registry.reload_installed()
    try:
        assert list(registry.algorithms())[:7] == ["mc", "ddqn", "ppo", "sac", "gru_ppo", "nbtest_sixth", "external"]
        assert registry.paper_names()[-1] == "nbtest_sixth" and registry.get("nbtest_sixth").display == "Sixth"
        base = {"name": "s", "version": 1, "description": "d", "normalize_obs": False, "normalize_reward": False}
        data = {"algo": "nbtest_sixth", **base, "gamma": 0.9, "net_arch": [8], "n_steps": 5, "learning_rate": 1e-3}
        cfg = parse_agent_config(data)
        with pytest.raises(ConfigError, match="n_steps"):
            parse_agent_config({**data, "n_steps": 0})
        from nutribench.agents.config import NbtestSixthConfig  # found by name as the others'

        assert type(cfg) is NbtestSixthConfig
        model = make_model(cfg, NutriRLSB3VecEnv(regime="run0"), seed=0, horizon=50)
        assert type(model).__name__ == "A2C" and model.n_steps == 5
    finally:
        monkeypatch.undo()
        sys.modules.pop(f"{registry.BUILTIN_PACKAGE}.nbtest_sixth", None)
        registry.reload_installed()
    assert "nbtest_sixth" not in registry.algorithms()


def test_pyproject_lists_no_builtin_and_stale_metadata_is_skipped(tmp_path: Path, monkeypatch):
    """pyproject.toml's entry-point group holds no built-in (a new built-in needs no line
    there); an installed metadata that still names the old built-in entries (an editable
    install of an older checkout) is skipped, the package is read instead."""
    import tomllib

    groups = tomllib.loads((REPO / "pyproject.toml").read_text())["project"].get("entry-points", {})
    assert not [v for v in groups.get(registry.ENTRY_POINT_GROUP, {}).values() if v.startswith("nutribench")]
    info = tmp_path / "nutribench_stale-0.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: nutribench-stale\nVersion: 0.0\n")
    stale = "".join(f"{a} = nutribench.agents.registry:{a.upper()}\n" for a in registry.paper_names())
    (info / "entry_points.txt").write_text(f"[{registry.ENTRY_POINT_GROUP}]\n{stale}")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.reload_installed()
    try:
        assert list(registry.algorithms())[:6] == ["mc", "ddqn", "ppo", "sac", "gru_ppo", "external"]
    finally:
        monkeypatch.undo()
        registry.reload_installed()


def test_a_plugin_package_registers_an_algorithm_with_its_own_validated_config(installed):
    entry = registry.get("a2c_test")
    assert entry.display == "A2C-T" and "a2c_test" in registry.names() and "a2c_test" not in registry.batched_names()
    data = {"algo": "a2c_test", "name": "x", "version": 1, "description": "d", "n_steps": 5, "learning_rate": 1e-3}
    assert parse_agent_config(data).n_steps == 5
    with pytest.raises(ConfigError, match="n_steps"):  # its own schema: the required field
        parse_agent_config({k: v for k, v in data.items() if k != "n_steps"}, "x.toml")
    with pytest.raises(ConfigError, match="extra|unknown|not permitted"):
        parse_agent_config({**data, "net_arch": [8]}, "x.toml")
    from nutribench.engine import supports

    assert "batched engine trains" in supports(parse_agent_config(data))


def test_register_refuses_a_taken_name_and_unknown_algorithms_name_the_known():
    with pytest.raises(registry.AlgorithmRegistryError, match="already registered"):
        registry.register(registry.Algorithm("ppo", "x:Y"))
    with pytest.raises(ConfigError, match="known are mc, ddqn, ppo, sac, gru_ppo"):
        parse_agent_config({"algo": "nope"}, "f.toml")
    extra = registry.register(registry.Algorithm("mine_test", "nutribench.agents.config:MCConfig"))
    try:
        assert registry.get("mine_test") is extra
    finally:
        registry.unregister("mine_test")
    assert "mine_test" not in registry.algorithms()


def cli(*args: str, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    full = dict(os.environ, **env)
    full.pop("NUTRIBENCH_JOB", None)
    return subprocess.run(
        [sys.executable, "-m", "nutribench.cli", *args], cwd=cwd, env=full, capture_output=True, text=True, timeout=900
    )


@pytest.mark.slow
def test_a_plugin_algorithm_runs_end_to_end(tmp_path: Path):
    """run (2 days, 1 seed, 1 regime, beside MC), report, compare, db export and import, in
    fresh processes that find the plug-in only through its installed entry point."""
    plugin_package(tmp_path / "site")
    agents = tmp_path / "agents"
    agents.mkdir()
    for f in (REPO / "regimes" / "agents").glob("*.toml"):
        (agents / f.name).write_text(f.read_text())
    (agents / "a2c_t.toml").write_text(CONFIG)
    path = os.pathsep.join([str(REPO), str(tmp_path / "site"), os.environ.get("PYTHONPATH", "")])
    env = {"NUTRIBENCH_AGENTS": str(agents), "PYTHONPATH": path}
    db = tmp_path / "lab.db"
    common = ["--regimes", "run0", "--seeds", "0", "--episodes", "2", "--eval-episodes", "2", "--db", str(db)]
    res = cli("run", "--algos", "a2c_t,mc", *common, "--workers", "1", cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    from nutribench.store import read_episode_metrics, read_jobs

    jobs = read_jobs(db)
    assert set(jobs["status"]) == {"done"} and sorted(jobs["algo"]) == ["a2c_t", "mc"]
    df = read_episode_metrics(db)
    assert df[df["algo"] == "a2c_t"].groupby("phase").size().to_dict() == {"eval": 2, "train": 2}
    out = tmp_path / "report"
    res = cli("report", "--all", "--db", str(db), "--out", str(out), "--reference-episodes", "5", cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    text = "".join(p.read_text() for p in out.rglob("*.md"))
    assert "a2c_t" in text and "A2C-T variant" in text  # its config table says its registered algorithm
    res = cli("compare", "a2c_t", "mc", "--db", str(db), "--markdown", cwd=tmp_path, env=env)
    assert res.returncode == 0 and "run0" in res.stdout, res.stdout + res.stderr
    archive, merged = tmp_path / "a.npz", tmp_path / "merged.db"
    res = cli("db", "export", str(archive), "--db", str(db), "--algos", "a2c_t", cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    res = cli("db", "import", str(archive), "--db", str(merged), cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    again = read_episode_metrics(merged)
    assert set(again["algo"]) == {"a2c_t"} and len(again) == (df["algo"] == "a2c_t").sum()
    # the saved model loads by its registry entry, as a built-in's: rebuilt from weights
    model_path = jobs.loc[jobs["algo"] == "a2c_t", "model_path"].iloc[0]
    res = subprocess.run(
        [sys.executable, "-c", f"from nutribench.agents.api import TrainedAgent; print(type(TrainedAgent.load({model_path!r}).model).__name__)"],
        env=dict(os.environ, **env), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.stdout.strip() == "RenamedA2C", res.stderr


# ------------------------------------------------------------- no dispatch on names
#: the modules allowed to hold an algorithm's name, and why
ALLOWED_MODULES = {
    "nutribench/report/tables.py": "the paper's Tables 2-6 (which table shows which shipped agent file) and its "
    "published numbers, keyed by its agents",
    "nutribench/report/build.py": "the paper's Figure 4 draws the ppo and gru_ppo agent files",
}


def _docstrings(tree: ast.AST) -> set[int]:
    return {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and n.body
        and isinstance(n.body[0], ast.Expr)
        and isinstance(n.body[0].value, ast.Constant)
    }


def _defaults(tree: ast.AST) -> set[int]:
    """Default values of parameters (``algo: str = "ppo"``: the agent file a command starts
    from when none is given), not a choice of code."""
    out: set[int] = set()
    for n in ast.walk(tree):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            out |= {id(d) for d in [*n.args.defaults, *n.args.kw_defaults] if d is not None}
    return out


def _literal_types(tree: ast.AST) -> set[int]:
    """The constants of ``Literal["mc"]`` annotations: a config model declaring its own ``algo``
    key (the model the registry entry names), not a choice of code."""
    return {
        id(c)
        for n in ast.walk(tree)
        if isinstance(n, ast.Subscript) and isinstance(n.value, ast.Name) and n.value.id == "Literal"
        for c in ast.walk(n.slice)
    }


def _reads_algo(node: ast.AST) -> bool:
    return any(
        (isinstance(x, ast.Attribute) and x.attr == "algo")
        or (isinstance(x, ast.Name) and x.id == "algo")
        or (isinstance(x, ast.Constant) and x.value == "algo")
        for x in ast.walk(node)
    )


def _algo_comparisons(tree: ast.AST) -> list[ast.Constant]:
    """String constants compared (``==``, ``!=``, ``in``) with an expression that reads an
    ``algo`` (``cfg.algo``, ``data["algo"]``, ``body.get("algo")``, a variable ``algo``)."""
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Compare) and any(_reads_algo(s) for s in [n.left, *n.comparators]):
            sides = [n.left, *n.comparators]
            out += [c for s in sides for c in ast.walk(s) if isinstance(c, ast.Constant) and isinstance(c.value, str)]
    return out


def name_literals(path: Path, names: set[str], compared: frozenset[str] = frozenset()) -> list[str]:
    """``line: literal`` for each string constant of ``path`` equal to one of ``names`` (but
    docstrings, parameter defaults and ``Literal[...]`` annotations; comments are no
    constants), and each one of ``compared`` compared with an ``algo``."""
    tree = ast.parse(path.read_text(), str(path))
    skip = _docstrings(tree) | _defaults(tree) | _literal_types(tree)
    hits = [
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value in names and id(n) not in skip
    ]
    hits += [c for c in _algo_comparisons(tree) if c.value in compared]
    return [f"{n.lineno}: {n.value!r}" for n in sorted(hits, key=lambda n: (n.lineno, n.col_offset))]


def test_no_module_outside_its_own_names_an_algorithm():
    """No string constant equal to a built-in algorithm's name (mc, ddqn, ppo, sac, gru_ppo)
    in nutribench/ but in that algorithm's own module (``agents/builtin/<algo>.py``, its entry
    and config model), docstrings, comments, parameter defaults, ``Literal[...]`` annotations
    and the modules of :data:`ALLOWED_MODULES` (the paper's data); and no ``"external"``
    compared with an ``algo`` (the word is also a job's engine, and a recorded agent's config
    writes it). So nothing compares ``algo == "gru_ppo"`` or keeps a table keyed by algorithm,
    the registry included: a sixth algorithm is its own module."""
    names = set(registry.paper_names())
    builtin = PACKAGE / Path(*registry.BUILTIN_PACKAGE.split(".")[1:])
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).as_posix()
        own = {path.stem} if path.parent == builtin else set()
        if rel not in ALLOWED_MODULES and (hits := name_literals(path, names - own, frozenset({"external"}))):
            found[rel] = hits
    assert not found, found


def test_the_grep_finds_a_name_check(tmp_path: Path):
    """The grep sees a comparison, a table key, a tuple of names and "external" compared with
    an algo; not a docstring, a default, a Literal annotation or "external" as an engine."""
    src = textwrap.dedent(
        '''
        """mentions "ppo" in a docstring"""
        algo: Literal["ppo"]
        engine = "external"
        def f(cfg, data, algo="ppo"):  # a default
            if cfg.algo == "gru_ppo":
                return {"sac": 1}
            if data["algo"] != "external":
                return 0
            return cfg.algo in ("ddqn", "mc")
        '''
    )
    p = tmp_path / "probe.py"
    p.write_text(src)
    hits = name_literals(p, {"ppo", "gru_ppo", "sac", "ddqn", "mc"}, frozenset({"external"}))
    assert [h.split(": ")[1] for h in hits] == ["'gru_ppo'", "'sac'", "'external'", "'ddqn'", "'mc'"]


def test_load_agent_config_reads_a_builtin_through_its_registered_model():
    cfg = load_agent_config("gru_ppo")
    assert type(cfg) is registry.get("gru_ppo").config_model()


def test_commands_list_the_algorithms_the_registry_holds():
    """``benchmarks/engines.py`` takes the registry's batched algorithms (no list of its own)."""
    from typer.testing import CliRunner

    from tests.conftest import benchmark_script

    res = CliRunner().invoke(benchmark_script("engines").app, ["--algos", "nope"])
    assert res.exit_code == 2 and ", ".join(registry.batched_names()) in res.output, res.output
