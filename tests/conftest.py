"""Shared fixtures: small hand-made regime folders for exact tests."""

from __future__ import annotations

import importlib
import sys
import textwrap
import time
from pathlib import Path
from types import ModuleType

import pytest

#: The developer's benchmarks, scripts beside the package (``python benchmarks/learn.py``), importable
#: by their names as when run, from the start (a process pool's server started later inherits the path)
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))


def benchmark_script(name: str) -> ModuleType:
    """``benchmarks/NAME.py`` as a module (its ``app`` is the script's command)."""
    return importlib.import_module(name)


CATALOG = """\
name = "tiny"
version = 1
source = "test"
target_grams = { C = 100.0, F = 100.0, P = 100.0 }

[[food]]
key = "a"
name = "food a"
portion = "100 g"
portion_g = 100.0
per_100g = { C = 50.0, F = 0.0, P = 10.0 }
source_id = "test-a"

[[food]]
key = "b"
name = "food b"
portion = "200 g"
portion_g = 200.0
per_100g = { C = 0.0, F = 10.0, P = 20.0 }
source_id = "test-b"
"""

REWARD = """\
name = "reward"
version = 1
horizon = 8
lp = 1.0
lc = 0.5
lo = 2.0
tau_c = 0.5
"""

REGIME = """\
name = "tiny"
version = 1
description = "hand example"
seed = 0
catalog = "foods.toml"
reward = "reward.toml"

[ranges]
tau = { C = { low = 0.0, high = 5.0 }, F = { low = 0.0, high = 5.0 }, P = { low = 0.0, high = 5.0 } }
sigma = { C = { low = 0.0, high = 5.0 }, F = { low = 0.0, high = 5.0 }, P = { low = 0.0, high = 5.0 } }

[foods]
a = { tau = { C = 1.0, F = 0.0, P = 0.0 }, sigma = { C = 0.0, F = 0.0, P = 0.0 } }
b = { tau = { C = 0.0, F = 2.0, P = 2.6 }, sigma = { C = 0.0, F = 1.0, P = 0.0 } }
"""


def run_cli_args(
    db: Path,
    *extra: str,
    regimes: str = "run0",
    algos: str = "ppo",
    seeds: str | None = "0",
    episodes: int = 20,
    eval_episodes: int = 1,
) -> list[str]:
    """``nutribench run``'s arguments for a test: its database and grid (``seeds=None``: the
    option left out), the budgets, then ``extra``."""
    args = ["run", "--db", str(db), "--regimes", regimes, "--algos", algos]
    if seeds is not None:
        args += ["--seeds", seeds]
    return [*args, "--episodes", str(episodes), "--eval-episodes", str(eval_episodes), *extra]


def one_error_line(result) -> str:
    """The command failed the user-error way: exit 2, one line starting "error:", no traceback."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.output
    return lines[0]


def wait_for(predicate, timeout: float) -> None:
    """Poll ``predicate`` every 0.1 s until it holds; fail the test after ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError("timed out")


def sb3_model(algo: str, seed: int, regime: str = "run0"):
    """``(config, model)``: the SB3 engine's model of the shipped ``algo`` config on ``regime``
    as a job builds it, with a silent logger so that ``train()`` can be called directly."""
    from stable_baselines3.common.logger import Logger

    from nutribench.agents.algos import build_model
    from nutribench.agents.api import make_train_env
    from nutribench.agents.config import load_agent_config
    from nutribench.config import load_env_config

    cfg, env_cfg = load_agent_config(algo), load_env_config(regime)
    _, env = make_train_env(env_cfg, cfg)
    model = build_model(cfg, env, seed=seed, horizon=env_cfg.reward.horizon)
    model.set_logger(Logger(folder=None, output_formats=[]))
    return cfg, model


def two_day_rollouts(cfg):
    """A copy of an on-policy ``cfg`` (PPO, GRU-PPO) with rollouts of 2 days (``n_steps`` 100)
    and minibatches of one whole day (50), so that a short test reaches its updates in a few
    days instead of the files' 10-day rollouts."""
    return cfg.model_copy(update={"n_steps": 100, "batch_size": 50})


def shake(params, seed: int, scale: float = 0.05) -> None:
    """Add seeded noise to ``params`` in place (a target network unlike its online one)."""
    import torch as th

    with th.no_grad():
        for p in params:
            p.add_(scale * th.randn(p.shape, generator=th.Generator().manual_seed(seed)))


def random_batch(rng, k: int, b: int, obs_dim: int, reward_scale: float, gamma: float, n_step: int = 1):
    """Random replay samples of K agents (``engine.off_policy.Batch``): normal observations
    and rewards (times ``reward_scale``), 20 % dones, and discounts ``gamma ** m`` with ``m``
    drawn in 1..``n_step`` (``gamma`` everywhere for one-step returns)."""
    import torch as th

    from nutribench.engine.off_policy import Batch

    f32 = lambda x: th.as_tensor(x, dtype=th.float32)  # noqa: E731
    obs, actions = f32(rng.normal(size=(k, b, obs_dim))), th.as_tensor(rng.integers(0, 2, size=(k, b)))
    rewards, next_obs = f32(rng.normal(size=(k, b)) * reward_scale), f32(rng.normal(size=(k, b, obs_dim)))
    dones = f32(rng.random((k, b)) < 0.2)
    discounts = f32(gamma ** rng.integers(1, n_step + 1, size=(k, b))) if n_step > 1 else th.full((k, b), gamma)
    return Batch(obs=obs, actions=actions, rewards=rewards, next_obs=next_obs, dones=dones, discounts=discounts)


def sb3_updates(algo_cls, regime: str, cfg, episodes: int, what) -> list:
    """Train ``cfg`` with the SB3 engine (seed 0) and return ``what(model)`` at each call of
    ``algo_cls.train`` (before the update): when and how the SB3 agent updates."""
    from nutribench.agents.api import train

    seen: list = []
    original = algo_cls.train

    def spy(self, gradient_steps, batch_size=100):
        seen.append(what(self))
        original(self, gradient_steps, batch_size)

    algo_cls.train = spy
    try:
        train(regime, cfg, seed=0, episodes=episodes)
    finally:
        algo_cls.train = original
    return seen


def write_regime_dir(folder: Path, regime: str = REGIME, catalog: str = CATALOG, reward: str = REWARD) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "foods.toml").write_text(textwrap.dedent(catalog))
    (folder / "reward.toml").write_text(textwrap.dedent(reward))
    (folder / "tiny.toml").write_text(textwrap.dedent(regime))
    return folder / "tiny.toml"


@pytest.fixture
def tiny_regime(tmp_path: Path) -> Path:
    return write_regime_dir(tmp_path / "regimes")


@pytest.fixture(scope="session")
def postgres():
    """A throwaway PostgreSQL server for the session (tests/pg.py). If it cannot start, the
    tests that use it fail with the reason: they are never skipped."""
    from tests import pg

    try:
        server = pg.start()
    except pg.PostgresUnavailable as e:
        pytest.fail(f"the PostgreSQL tests need a throwaway server and none could start: {e}", pytrace=False)
    yield server
    server.stop()


@pytest.fixture
def pg_url(postgres) -> str:
    """The SQLAlchemy URL of a new empty database on the throwaway server."""
    return postgres.create_database()


def tiny_study_settings(space: str = "ppo", **kw):
    """The settings of a tiny tuning study (run0, tuning seed 101, 4 days, evaluated every 2, no
    pruning) for the tuning tests; ``kw`` replaces any of them."""
    from nutribench.tuning.space import load_search_space
    from nutribench.tuning.study import StudySettings

    s = load_search_space(space)
    base = dict(
        space=space,
        space_version=s.version,
        space_sha256=s.sha256,
        regimes=("run0",),
        seeds=(101,),
        days=4,
        eval_every=2,
        val_episodes=1,
        sampler_seed=0,
        pruner="none",
    )
    return StudySettings(**{**base, **kw})
