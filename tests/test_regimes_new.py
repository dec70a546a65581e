"""New regimes are first-class: `regimes generate NAME --from ...` writes one, `regimes
check` validates it, Gymnasium makes it by name with a TimeLimit, and bad input is one line."""

from __future__ import annotations

import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import TimeAwareObservation, TimeLimit
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from nutribench.config import ConfigError, load_env_config
from nutribench.config.generate import default_seed, derive_regime, parse_ranges, regime_to_toml
from tests.conftest import one_error_line

runner = CliRunner()
TAU = "C=10-12,F=18-20,P=14-16"
SIGMA = "C=5-8.4,F=9-14,P=7-11.2"
SHIPPED = Path(__file__).resolve().parents[1] / "regimes"


@pytest.fixture
def folder(tmp_path, monkeypatch) -> Path:
    """A copy of the shipped regimes folder, used through NUTRIBENCH_REGIMES."""
    dst = tmp_path / "regimes"
    shutil.copytree(SHIPPED, dst)
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(dst))
    return dst


def generate(*args: str):
    return runner.invoke(app, ["regimes", "generate", *args])


def test_create_check_and_play_a_new_regime(folder):
    result = generate("run7", "--from", "run6", "--tau", TAU, "--sigma", SIGMA, "--write")
    assert result.exit_code == 0 and "wrote" in result.output, result.output
    cfg = load_env_config("run7")
    assert cfg.path == folder / "run7.toml"
    assert (cfg.name, cfg.version, cfg.regime.seed) == ("run7", 1, default_seed("run7"))
    assert cfg.regime.ranges.sigma.P.high == 11.2 and cfg.regime.ranges.tau.F.low == 18.0
    assert cfg.regime.catalog == "foods.toml" and cfg.regime.reward == "reward.toml"

    check = runner.invoke(app, ["regimes", "check"])
    assert check.exit_code == 0 and "run7.toml: ok" in check.output, check.output
    assert "run7" in runner.invoke(app, ["regimes", "list"]).output

    env = TimeAwareObservation(gym.make(nutribench.ENV_ID, regime="run7"))
    assert env.unwrapped.config.name == "run7" and env.observation_space.shape == (14,)
    obs, _ = env.reset(seed=0)
    steps, truncated = 0, False
    while not truncated:
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        steps += 1
        assert not terminated and np.isfinite(reward)
    assert steps == 50 and obs[-1] == 50  # one truncation, at the end of the day
    assert gym.make(nutribench.ENV_ID, regime=str(cfg.path)).unwrapped.config.sha256 == cfg.sha256


def test_print_is_what_write_writes_and_the_draw_is_deterministic(folder):
    printed = generate("run7", "--from", "run6", "--tau", TAU)
    assert printed.exit_code == 0 and not (folder / "run7.toml").exists()
    assert printed.output == generate("run7", "--from", "run6", "--tau", TAU).output
    assert generate("run7", "--from", "run6", "--tau", TAU, "--write").exit_code == 0
    assert (folder / "run7.toml").read_text() == printed.output
    other = generate("run7", "--from", "run6", "--tau", TAU, "--seed", "3").output
    assert other != printed.output and "seed = 3\n" in other


def test_nutrients_left_out_keep_the_source_ranges_and_description_is_escaped(folder):
    result = generate("slow_c", "--from", "run2", "--tau", "C=20-22", "--description", 'slow "C"', "--write")
    assert result.exit_code == 0, result.output
    new, run2 = load_env_config("slow_c").regime, load_env_config("run2").regime
    assert (new.ranges.tau.C.low, new.ranges.tau.C.high) == (20.0, 22.0)
    assert new.ranges.tau.F == run2.ranges.tau.F and new.ranges.sigma == run2.ranges.sigma
    assert new.description == 'slow "C"'


@pytest.mark.parametrize(
    ("option", "value", "says"),
    [
        ("--tau", "C=12-10", "above high"),
        ("--tau", "C=-1-2", "negative"),
        ("--sigma", "C=1-2,X=1-2", "unknown nutrient 'X'"),
        ("--tau", "C=10", "malformed"),
        ("--tau", "C=a-b", "malformed"),
        ("--sigma", "C=1-2,C=2-3", "given twice"),
        ("--tau", "", "no ranges"),
    ],
)
def test_bad_ranges_are_one_line_and_write_nothing(folder, option, value, says):
    line = one_error_line(generate("run7", "--from", "run6", option, value, "--write"))
    assert option in line and says in line
    assert not (folder / "run7.toml").exists()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["Run-7", "--from", "run6"], "not valid"),
        (["run7", "--from", "run6", "--seed", "-1"], "negative"),
        (["run7", "--from", "run9"], "unknown regime 'run9'"),
        (["run7", "--write"], "--from"),  # a new name without --from: say how to create it
        (["run3", "--tau", TAU], "needs --from"),
    ],
)
def test_other_bad_input_is_one_line(folder, args, says):
    assert says in one_error_line(generate(*args))
    assert not (folder / "run7.toml").exists()


def test_an_existing_file_is_kept_unless_force(folder):
    assert generate("run7", "--from", "run6", "--write").exit_code == 0
    before = (folder / "run7.toml").read_text()
    line = one_error_line(generate("run7", "--from", "run5", "--write"))
    assert "already exists" in line and "--force" in line
    assert (folder / "run7.toml").read_text() == before
    forced = generate("run7", "--from", "run5", "--write", "--force")
    assert forced.exit_code == 0 and "bump its version" in forced.output
    assert load_env_config("run7").regime.ranges == load_env_config("run5").regime.ranges
    # a shipped regime too, and the redraw of an existing regime still works as before
    assert "already exists" in one_error_line(generate("run3", "--from", "run6", "--write"))
    assert generate("run3", "--write").exit_code == 0
    assert (folder / "run3.toml").read_text() == (SHIPPED / "run3.toml").read_text()


def test_a_folder_without_the_catalog_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(tmp_path))
    line = one_error_line(generate("run7", "--from", str(SHIPPED / "run6.toml"), "--write"))
    assert "no foods.toml" in line and "copy" in line
    assert not (tmp_path / "run7.toml").exists()


def test_a_name_that_differs_from_the_file_name_is_one_line(folder):
    path = folder / "run7.toml"
    path.write_text((folder / "run6.toml").read_text())  # still says name = "run6"
    line = one_error_line(runner.invoke(app, ["regimes", "check", "--regimes", "run7"]))
    assert str(path) in line and "differs from the file name" in line and 'set name = "run7"' in line
    all_check = runner.invoke(app, ["regimes", "check"])
    assert all_check.exit_code == 2 and "differs from the file name" in all_check.output
    with pytest.raises(ConfigError, match="differs from the file name"):
        gym.make(nutribench.ENV_ID, regime="run7")


def test_specs_carry_the_horizon_and_make_adds_one_time_limit():
    horizon = load_env_config("run0").reward.horizon
    assert nutribench.HORIZON == horizon == 50
    ids = [nutribench.ENV_ID] + [f"nutribench/NutriRL-{r}-v0" for r in nutribench.SHIPPED_REGIMES]
    assert all(gym.spec(i).max_episode_steps == horizon for i in ids)
    env = gym.make("nutribench/NutriRL-run6-v0")
    limits = [w for w in _wrappers(env) if isinstance(w, TimeLimit)]
    assert len(limits) == 1 and limits[0]._max_episode_steps == horizon


def test_a_shorter_time_limit_truncates_early_and_the_vector_env_refuses_it():
    env = gym.make(nutribench.ENV_ID, regime="run1", max_episode_steps=10)
    env.reset(seed=0)
    flags = [env.step(0)[3] for _ in range(10)]
    assert flags == [False] * 9 + [True]
    vec = gym.make_vec(nutribench.ENV_ID, num_envs=2, regime="run1")
    assert type(vec).__name__ == "NutriRLVectorEnv"
    with pytest.raises(ValueError, match="below the horizon"):
        gym.make_vec(nutribench.ENV_ID, num_envs=2, max_episode_steps=10)


def test_derive_regime_api():
    run6 = load_env_config("run6")
    new = derive_regime(run6.regime, run6.catalog, "run7", tau=parse_ranges(TAU), sigma=parse_ranges(SIGMA, "--sigma"))
    assert new.name == "run7" and new.version == 1 and set(new.foods) == set(run6.catalog.keys)
    assert regime_to_toml(new).count("\n") == 16 + len(new.foods)


def _wrappers(env):
    while isinstance(env, gym.Wrapper):
        yield env
        env = env.env
