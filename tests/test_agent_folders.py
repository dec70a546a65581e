"""``NUTRIBENCH_AGENTS`` adds a folder of one's own to the shipped agents (issue 54): before,
it replaced them (`unknown algorithm ppo: known are trpo_mine, trpo_mine_tuned`)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from nutribench.agents.config import list_agent_configs, load_agent_config, resolve_agent_path
from nutribench.config.loading import ConfigError, regimes_dir


def own_folder(tmp_path: Path, name: str, base: str = "ppo") -> Path:
    """A folder holding one agent file, a copy of ``base``'s under ``name``."""
    folder = tmp_path / "agents"
    folder.mkdir(exist_ok=True)
    text = (regimes_dir() / "agents" / f"{base}.toml").read_text()
    (folder / f"{name}.toml").write_text(text.replace(f'name = "{base}"', f'name = "{name}"', 1))
    return folder


def test_an_own_folder_adds_to_the_shipped_agents(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(own_folder(tmp_path, "ppo_mine")))
    names = list_agent_configs()
    assert names[:5] == ["mc", "ddqn", "ppo", "sac", "gru_ppo"] and "ppo_mine" in names
    assert load_agent_config("ppo_mine").name == "ppo_mine"
    assert load_agent_config("ppo").name == "ppo"  # the shipped one, still found


def test_a_name_in_two_folders_says_which_file_is_used(tmp_path: Path, monkeypatch) -> None:
    folder = own_folder(tmp_path, "gru_ppo", base="gru_ppo")
    mine = folder / "gru_ppo.toml"
    mine.write_text(mine.read_text() + "# my own copy, changed\n")
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(folder))
    with pytest.warns(UserWarning, match=f"agent config 'gru_ppo': {folder / 'gru_ppo.toml'} is used, not "):
        assert resolve_agent_path("gru_ppo") == folder / "gru_ppo.toml"


def test_several_folders_in_path_order(tmp_path: Path, monkeypatch) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    first, second = own_folder(tmp_path / "a", "x_one"), own_folder(tmp_path / "b", "x_two")
    monkeypatch.setenv("NUTRIBENCH_AGENTS", os.pathsep.join([str(first), str(second)]))
    assert {"x_one", "x_two"} <= set(list_agent_configs())


def test_an_unknown_agent_says_where_agents_are_looked_for(tmp_path: Path, monkeypatch) -> None:
    folder = own_folder(tmp_path, "ppo_mine")
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(folder))
    with pytest.raises(ConfigError) as e:
        load_agent_config("trpo_mine")
    msg = str(e.value)
    assert str(folder) in msg and str(regimes_dir() / "agents") in msg and "NUTRIBENCH_AGENTS=" in msg
    shutil.rmtree(folder)


def test_a_copy_of_a_shipped_file_is_no_clash(tmp_path: Path, monkeypatch) -> None:
    import warnings

    folder = tmp_path / "agents"
    shutil.copytree(regimes_dir() / "agents", folder)
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(folder))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert resolve_agent_path("ppo") == folder / "ppo.toml"
