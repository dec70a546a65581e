"""Every committed config file still loads under the bounds of issue 74 (no size, depth or text
bound refuses a shipped or committed file): the regimes of every regimes folder (with their
catalog and reward), every agent file, every search space, the shared knobs, and the TOML
examples of the docs."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from nutribench.agents.config import load_agent_config, parse_agent_config
from nutribench.config import load_env_config
from nutribench.config.reading import MAX_CONFIG_BYTES, parse_config, read_config_bytes
from nutribench.tuning.space import load_search_space

REPO = Path(__file__).resolve().parents[1]


def committed(pattern: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", pattern], cwd=REPO, capture_output=True, text=True, check=True)
    return [REPO / line for line in out.stdout.splitlines()]


TOML = [p for p in committed("*.toml") if p.name != "pyproject.toml"]
REGIMES = [p for p in TOML if re.fullmatch(r"run\d+", p.stem)]
AGENTS = [p for p in TOML if p.parent.name.startswith("agents")]
SPACES = [p for p in TOML if p.parent.name == "search"]


def test_the_committed_files_are_all_classified() -> None:
    """Each committed config file is one of the kinds loaded below (a new kind must be added)."""
    others = {p.relative_to(REPO).as_posix() for p in TOML} - {
        p.relative_to(REPO).as_posix() for p in (*REGIMES, *AGENTS, *SPACES)
    }
    assert all(Path(p).name in ("foods.toml", "reward.toml", "shared_knobs.toml") for p in others), sorted(others)
    assert len(REGIMES) >= 22 and len(AGENTS) >= 38 and len(SPACES) >= 10  # as committed now


@pytest.mark.parametrize("path", REGIMES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_committed_regime_loads(path: Path) -> None:
    cfg = load_env_config(path)  # its catalog and reward too, and the dynamics' size
    assert cfg.name == path.stem


@pytest.mark.parametrize("path", AGENTS, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_committed_agent_file_loads(path: Path) -> None:
    assert load_agent_config(path).name == path.stem


@pytest.mark.parametrize("path", SPACES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_committed_search_space_loads(path: Path) -> None:
    assert load_search_space(path).name == path.stem  # every end of every range a valid config


def test_every_committed_config_file_is_well_within_the_reading_bounds() -> None:
    for path in TOML:
        data = read_config_bytes(path)
        assert len(data) * 100 < MAX_CONFIG_BYTES, path
        parse_config(path, data)


def test_the_docs_toml_examples_read_and_the_agent_files_among_them_validate() -> None:
    blocks = []
    for page in [*sorted((REPO / "docs").glob("*.md")), REPO / "README.md"]:
        for n, block in enumerate(re.findall(r"```toml\n(.*?)```", page.read_text(), re.S)):
            if block.startswith("--8<--"):
                continue  # a committed file, included when the site is built: loaded above
            where = f"{page.name} block {n}"
            data = parse_config(where, block.encode())
            blocks.append(where)
            if "algo" in data and "name" in data:
                parse_agent_config(data, where)
    assert len(blocks) >= 4, blocks
