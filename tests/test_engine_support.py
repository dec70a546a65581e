"""What the batched engine trains, and what each batched job records.

1. Settings the batched engine does not implement (``normalize_reward`` for DDQN and SAC,
   whose SB3 replay scales sampled rewards; GRU-PPO sequences that are not whole days; other
   algorithms) are never trained otherwise than the reference would: ``nutribench.engine.supports``
   says why, the engine refuses such a config in one line before training, and ``nutribench
   run --engine batched`` trains its jobs with the SB3 engine instead.
2. A batched job's result depends by float rounding on its batch and device: each job
   stores ``batch_id``, ``batch_size`` and ``device``; an SB3 job stores device ``cpu``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.agents.config import agents_dir, load_agent_config
from nutribench.agents.registry import paper_names
from nutribench.engine import UnsupportedConfig, check_supported, supports
from nutribench.errors import UserError
from nutribench.scheduler.driver import GridSettings, run_grid
from nutribench.scheduler.pools import batch_pools
from nutribench.scheduler.synthetic import synthetic_batch, synthetic_job
from nutribench.store import read_jobs


@pytest.fixture
def agents(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An agents folder with the five paper configs and variants the batched engine refuses:
    DDQN and SAC with ``normalize_reward = true``, GRU-PPO with 25-step sequences."""
    folder = tmp_path / "agents"
    folder.mkdir()
    for algo in paper_names():
        (folder / f"{algo}.toml").write_text((agents_dir() / f"{algo}.toml").read_text())
    for algo in ("ddqn", "sac"):
        text = (agents_dir() / f"{algo}.toml").read_text().replace(f'name = "{algo}"', f'name = "{algo}_nr"')
        (folder / f"{algo}_nr.toml").write_text(text.replace("normalize_reward = false", "normalize_reward = true"))
    text = (agents_dir() / "gru_ppo.toml").read_text().replace('name = "gru_ppo"', 'name = "gru_ppo_half"')
    (folder / "gru_ppo_half.toml").write_text(text.replace("sequence_length = 50", "sequence_length = 25"))
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(folder))
    assert load_agent_config("ddqn_nr").normalize_reward and load_agent_config("gru_ppo_half").sequence_length == 25
    return folder


# ------------------------------------------------------------------- 3. supported settings
def test_the_paper_configs_are_supported_and_the_variants_refused_in_one_line(agents: Path) -> None:
    for algo in paper_names():
        assert supports(load_agent_config(algo), 50) is None and supports(algo) is None
    for name, words in (
        ("ddqn_nr", "normalize_reward"),
        ("sac_nr", "normalize_reward"),
        ("gru_ppo_half", "sequence_length (25)"),
    ):
        reason = supports(load_agent_config(name), 50)
        assert (
            reason is not None
            and words in reason
            and repr(name) in reason
            and "--engine sb3" in reason
            and "\n" not in reason
        )
    assert supports("gru_ppo_half") is None  # whole days of an unknown horizon: decided where the horizon is known
    external = load_agent_config("ppo").model_copy(update={"algo": "external"})
    assert "--engine sb3" in supports(external)
    with pytest.raises(UnsupportedConfig) as err:
        check_supported("sac_nr")
    assert isinstance(err.value, UserError)


@pytest.mark.parametrize("name", ["ddqn_nr", "sac_nr", "gru_ppo_half"])
def test_the_engine_refuses_an_unsupported_config_before_training(
    name: str, agents: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from nutribench.engine.envs import AgentEnvs
    from nutribench.engine.train import train_batched

    def no_env(*args, **kwargs):
        raise AssertionError("trained")

    monkeypatch.setattr(AgentEnvs, "__init__", no_env)
    with pytest.raises(UnsupportedConfig, match="--engine sb3"):
        train_batched([("run0", 0)], name, 2)
    algo = load_agent_config(name).algo  # as one of a batch's per-agent configs too
    with pytest.raises(UnsupportedConfig, match="--engine sb3"):
        train_batched([("run0", 0)], algo, 2, agent_configs=[name])


def test_batch_pools_send_unsupported_configs_to_the_sb3_engine(agents: Path) -> None:
    cells = [
        ("a", "ppo", 0),
        ("a", "ddqn_nr", 0),
        ("a", "sac", 0),
        ("a", "sac_nr", 1),
        ("a", "gru_ppo_half", 0),
        ("b", "gru_ppo", 0),
    ]
    algo_of = {c: load_agent_config(c).algo for _, c, _ in cells}
    pools = batch_pools([1, 2, 3, 4, 5, 6], cells, algo_of, {"a": (50, 10), "b": (50, 10)}, claimable=len, slots=1)
    assert [(p.job_ids, p.batched) for p in pools] == [([1], True), ([3], True), ([6], True), ([2, 4, 5], False)]
    # a GRU-PPO of 50-step sequences on a regime of 40-step days: not whole days, so the SB3 engine
    pools = batch_pools([1], [("c", "gru_ppo", 0)], {"gru_ppo": "gru_ppo"}, {"c": (40, 10)}, claimable=len, slots=1)
    assert [(p.job_ids, p.batched) for p in pools] == [([1], False)]


def test_run_with_the_batched_engine_trains_unsupported_configs_with_the_sb3_engine(
    agents: Path, tmp_path: Path
) -> None:
    db = tmp_path / "r.db"
    s = run_grid(
        GridSettings(
            db,
            ["run0"],
            ["ppo", "ddqn_nr"],
            [0, 1],
            2,
            1,
            workers=1,
            job_fn=synthetic_job,
            batch_fn=synthetic_batch,
            display=False,
            engine="batched",
        )
    )
    assert (s.done, s.failed) == (4, 0)
    jobs = read_jobs(db)
    engines = {(a, e == "batched") for a, e in zip(jobs["algo"], jobs["engine"])}
    assert engines == {("ppo", True), ("ddqn_nr", False)}


def test_bench_learn_refuses_an_unsupported_config_in_one_line(agents: Path) -> None:
    from tests.conftest import benchmark_script

    res = CliRunner().invoke(
        benchmark_script("learn").app,
        [
            "--algos",
            "sac_nr",
            "--regimes",
            "run0",
            "--seeds",
            "0",
            "--episodes",
            "2",
            "--engine",
            "batched",
            "--device",
            "cpu",
        ],
    )
    assert res.exit_code == 2, res.output
    line = " ".join(res.output.split())
    assert "normalize_reward" in line and "--engine sb3" in line


def test_run_batch_refuses_an_unsupported_config(agents: Path, tmp_path: Path) -> None:
    """The worker side too: a batch of a config the engine does not support fails, never trains."""
    from nutribench.scheduler.batched_job import run_batch
    from nutribench.scheduler.grid import Grid
    from nutribench.scheduler.registration import load_grid_configs
    from nutribench.scheduler.worker import JobFailed, JobSpec

    regimes, configs = load_grid_configs(Grid(("run0",), ("sac_nr",), (0,), 2, 1))
    r, a = regimes[0], configs[0]
    spec = JobSpec(
        1, r.name, r.version, r.sha256, a.name, a.version, a.sha256, 0, 2, 1, str(tmp_path / "m.zip"), r.obj, a.obj
    )
    with pytest.raises(JobFailed, match="normalize_reward"):
        run_batch([spec])


# ------------------------------------------------------------------- 4. provenance
@pytest.mark.slow
def test_batched_jobs_store_their_batch_and_device_and_sb3_jobs_the_cpu(tmp_path: Path) -> None:
    """A tiny real grid: three PPO jobs in batches of at most two (one of 2, one of 1), then one SB3 job."""
    db = tmp_path / "r.db"
    s = run_grid(
        GridSettings(
            db,
            ["run0"],
            ["ppo"],
            [0, 1, 2],
            2,
            1,
            workers=1,
            display=False,
            engine="batched",
            max_batch=2,
            device="cpu",
        )
    )
    assert (s.done, s.failed) == (3, 0)
    jobs = read_jobs(db)
    assert set(jobs["engine"]) == {"batched"} and set(jobs["device"]) == {"cpu"}
    sizes = jobs.groupby("batch_id")["batch_size"].agg(["size", "first", "nunique"])
    assert len(sizes) == 2 and all(sizes["nunique"] == 1) and all(sizes["size"] == sizes["first"])
    assert sorted(sizes["size"]) == [1, 2]
    assert all(isinstance(b, str) and len(b) == 32 for b in jobs["batch_id"])

    s = run_grid(GridSettings(db, ["run3"], ["ppo"], [0], 2, 1, workers=1, display=False))
    assert (s.done, s.failed) == (1, 0)
    sb3 = read_jobs(db).query("regime == 'run3'")
    assert list(sb3["engine"]) == ["sb3"] and list(sb3["device"]) == ["cpu"]
    assert sb3["batch_id"].isna().all() and sb3["batch_size"].isna().all()
