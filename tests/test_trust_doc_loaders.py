"""Every plug-in loader the guides show (a ``cat > module.py`` block of docs/*.md defining
``load(path)``) loads a crafted model without running it (issue 52): the zip's pickled settings
and the ``.vecnormalize.pkl`` beside it hold a payload that writes a file when unpickled; the
loader is called directly, by ``TrainedAgent.load(path, load_with=...)`` and by ``nutribench
evaluate --entry-point``, and the file never appears. The control: SB3's own ``load`` (what
docs/leaderboard.md showed for QRDQN) runs it."""

from __future__ import annotations

import importlib
import re
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from nutribench.agents.api import TrainedAgent, train
from nutribench.agents.config import parse_agent_config
from nutribench.cli import app
from tests.test_own_agent import _blocks
from tests.test_trust_models import plant

REPO = Path(__file__).resolve().parents[1]
HEREDOC = re.compile(r"^cat > (?P<path>\S+) <<'EOF'\n(?P<body>.*?)^EOF$", re.S | re.M)


def doc_plugins() -> list[tuple[str, str, str, dict]]:
    """(page, module name, module source, its agent file) of every plug-in module with a
    ``load(path)`` that a page of docs/ writes, with the agent file of that page naming it."""
    found = []
    for page in sorted((REPO / "docs").glob("*.md")):
        files = {
            m["path"]: m["body"]
            for lang, code in _blocks(page.read_text(encoding="utf-8"))
            if lang == "bash"
            for m in HEREDOC.finditer(code)
        }
        agents = [tomllib.loads(body) for path, body in files.items() if path.endswith(".toml")]
        for path, body in files.items():
            if path.endswith(".py") and re.search(r"^def load\(", body, re.M):
                module = Path(path).stem
                cfg = next(a for a in agents if a.get("entry_point") == f"{module}:make_agent")
                found.append((page.name, module, body, cfg))
    return found


PLUGINS = doc_plugins()


def test_the_guides_loaders_are_all_found():
    assert {(page, module) for page, module, _, _ in PLUGINS} >= {
        ("leaderboard.md", "my_qrdqn"),
        ("own-agent.md", "my_agents"),
    }


@pytest.fixture
def plugin(request, tmp_path: Path, monkeypatch):
    """The page's module written to a folder on ``sys.path`` and imported; forgotten after."""
    page, module, body, cfg = request.param
    if "sb3_contrib" in body:
        pytest.importorskip("sb3_contrib", reason="the example's optional extra (pip install -e '.[contrib]')")
    folder = tmp_path / "code"
    folder.mkdir()
    (folder / f"{module}.py").write_text(body)
    monkeypatch.syspath_prepend(str(folder))
    sys.modules.pop(module, None)
    yield module, importlib.import_module(module), cfg
    sys.modules.pop(module, None)


@pytest.mark.parametrize("plugin", PLUGINS, ids=[f"{p}:{m}" for p, m, _, _ in PLUGINS], indirect=True)
def test_every_loader_the_guides_show_loads_a_crafted_model_and_runs_nothing(plugin, tmp_path: Path):
    module_name, module, cfg = plugin
    agent = train("run3", parse_agent_config(cfg), seed=1, episodes=1)
    path = agent.save(tmp_path / "model.zip")
    marker = tmp_path / "PWNED"
    plant(path, marker)
    obs = np.random.default_rng(0).uniform(0, 1, size=(16, agent.model.observation_space.shape[0])).astype(np.float32)

    loaded = module.load(str(path))  # the loader itself
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0], agent.act(obs)[0])
    assert not marker.exists()
    again = TrainedAgent.load(path, load_with=f"{module_name}:load")  # the loader named to nutribench
    assert np.array_equal(again.act(obs)[0], agent.act(obs)[0])
    assert not marker.exists()
    args = ["evaluate", "--model", str(path), "--entry-point", f"{module_name}:load", "--regime", "run3"]
    res = CliRunner().invoke(app, [*args, "--name", "crafted", "--db", str(tmp_path / "lab.db")])
    assert res.exit_code == 0, res.output
    assert not marker.exists()

    # the control: the class's own load, what docs/leaderboard.md showed for QRDQN, runs the payload
    sb3_class = type(agent.model)
    with pytest.raises(Exception):  # noqa: B017 - the payload returns None as the policy class, after it ran
        sb3_class.load(str(path), device="cpu")
    assert marker.read_text() == "ran"
