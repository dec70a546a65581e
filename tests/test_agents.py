"""The five agents behind one interface: config files, training on the real
regimes, evaluation on paired food streams, determinism, save/load, double-DQN target,
and learning on run0 within a CI budget."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch as th
from typer.testing import CliRunner

from nutribench.agents import eval_food_streams, evaluate, load_agent_config, train
from nutribench.agents.algos import double_dqn_target
from nutribench.agents.api import TrainedAgent
from nutribench.agents.config import (
    agent_config_sha256,
    agent_config_to_toml,
    agents_dir,
    list_agent_configs,
)
from nutribench.agents.registry import paper_names
from nutribench.cli import app
from nutribench.config.loading import ConfigError
from nutribench.env.metrics import METRIC_KEYS

ALGOS = tuple(paper_names())

runner = CliRunner()
EXPECTED_KEYS = {"episode", *METRIC_KEYS, "entropy"}


# ---------------------------------------------------------------------- config files
@pytest.mark.parametrize("algo", ALGOS)
def test_config_round_trips_file_model_file(algo, tmp_path):
    cfg = load_agent_config(algo)
    assert cfg.algo == algo and cfg.name == algo
    text = agent_config_to_toml(cfg)
    copy = tmp_path / f"{algo}.toml"
    copy.write_text(text)
    again = load_agent_config(copy)
    assert again == cfg
    assert agent_config_sha256(again) == agent_config_sha256(cfg)
    assert agent_config_to_toml(again) == text


def test_the_five_paper_configs_are_listed_first():
    assert list_agent_configs()[:5] == list(ALGOS)


def test_spec3_values_in_the_files():
    ddqn = load_agent_config("ddqn")
    assert (ddqn.buffer_size, ddqn.learning_starts, ddqn.batch_size, ddqn.n_step, ddqn.max_grad_norm) == (
        300_000,
        10_000,
        128,
        5,
        10,
    )
    assert (ddqn.learning_rate_start, ddqn.learning_rate_end) == (1e-3, 1e-4)
    sac = load_agent_config("sac")
    assert (sac.alpha, sac.tau, sac.actor_learning_rate, sac.critic_learning_rate, sac.buffer_size, sac.batch_size) == (
        0.2,
        0.005,
        1e-4,
        1e-3,
        100_000,
        128,
    )
    for algo in ("mc", "ddqn", "ppo", "sac"):
        assert load_agent_config(algo).net_arch == [256, 128]
    assert load_agent_config("gru_ppo").hidden_size == 128


def _variant(tmp_path: Path, algo: str, edit) -> Path:
    text = (agents_dir() / f"{algo}.toml").read_text()
    path = tmp_path / "agents" / f"{algo}.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(edit(text))
    return path


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda t: t + "\nlearning_rte = 0.1\n", "learning_rte"),  # typo: unknown key
        (lambda t: t.replace("clip_range", "# clip_range"), "clip_range"),  # missing field
        (lambda t: t.replace("gamma = 0.99", "gamma = -1"), "gamma"),  # out of range
        (lambda t: t.replace('algo = "ppo"', 'algo = "a3c"'), "known are mc, ddqn, ppo, sac, gru_ppo"),
        (lambda t: t.replace('name = "ppo"', 'name = "ppo2"'), "differs from the file name"),
    ],
)
def test_bad_config_file_one_line_naming_file_and_field(tmp_path, edit, expected):
    path = _variant(tmp_path, "ppo", edit)
    with pytest.raises(ConfigError) as err:
        load_agent_config(path)
    message = str(err.value)
    assert str(path) in message and expected in message and "\n" not in message
    result = runner.invoke(app, ["train", "--algo", str(path), "--episodes", "1"])
    assert result.exit_code == 2
    assert expected in result.output and "Traceback" not in result.output


def test_unknown_algorithm_name_lists_the_known_ones():
    result = runner.invoke(app, ["train", "--algo", "a3c", "--episodes", "1"])
    assert result.exit_code == 2
    out = " ".join(result.output.split())
    assert "unknown agent config 'a3c'" in out
    for algo in ALGOS:
        assert algo in out


def test_a_copied_file_with_a_new_name_is_a_variant(tmp_path, monkeypatch):
    folder = tmp_path / "agents"
    folder.mkdir()
    text = (
        (agents_dir() / "ppo.toml")
        .read_text()
        .replace('name = "ppo"', 'name = "ppo_fast"')
        .replace("n_epochs = 10", "n_epochs = 2")
    )
    (folder / "ppo_fast.toml").write_text(text)
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(folder))
    cfg = load_agent_config("ppo_fast")
    assert cfg.algo == "ppo" and cfg.n_epochs == 2


# ---------------------------------------------------------------------- training
@pytest.mark.parametrize("regime", ["run0", "run6"])
@pytest.mark.parametrize("algo", ALGOS)
def test_each_algorithm_trains_and_evaluates(algo, regime):
    seen: list[dict] = []
    agent = train(regime, algo, seed=1, episodes=3, on_episode=seen.append)
    assert len(agent.train_episodes) == 3 and seen == agent.train_episodes
    for k, row in enumerate(agent.train_episodes):
        assert set(row) == EXPECTED_KEYS and row["episode"] == k
        assert 0 <= row["foods"] <= 50 and row["return"] < 0
        if algo == "ddqn":  # a greedy value learner has no policy entropy (defined only where there is a policy)
            assert row["entropy"] is None
        else:
            assert math.isfinite(row["entropy"]) and 0 <= row["entropy"] <= math.log(2) + 1e-6
    result = evaluate(agent, regime, eval_food_streams(regime, 1, 5), record_steps=True)
    assert [r["episode"] for r in result.episodes] == list(range(5))
    assert len(result.steps) == 5 * 50
    assert {s["action"] for s in result.steps} <= {0, 1}
    # eaten foods in the per-step rows add up to the per-day counts
    for r in result.episodes:
        assert sum(s["action"] for s in result.steps if s["episode"] == r["episode"]) == r["foods"]


@pytest.mark.parametrize("algo", ALGOS)
def test_training_leaves_no_sb3_log_folder_behind(algo, tmp_path, monkeypatch):
    """SB3's default logger makes a folder tempdir/SB3-<date> at every learn(): one per job."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    train("run0", algo, seed=1, episodes=1)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith("SB3-")] == []


def test_recorded_training_returns_are_raw_rewards_not_normalised():
    cfg = load_agent_config("ppo")
    assert cfg.normalize_reward
    agent = train("run0", cfg, seed=3, episodes=2)
    raw = train("run0", cfg.model_copy(update={"normalize_reward": False}), seed=3, episodes=2)
    # the first day is played before any update: same actions, so the same raw return
    assert agent.train_episodes[0]["return"] == pytest.approx(raw.train_episodes[0]["return"])
    # and a raw daily return is tens to hundreds in size, not a unit-scale normalised one
    assert abs(agent.train_episodes[0]["return"]) > 20


def test_evaluation_streams_are_paired_and_derived_from_the_seed():
    a = eval_food_streams("run0", 0, 5)
    assert a.shape == (5, 50)
    assert np.array_equal(a, eval_food_streams("run3", 0, 5))  # same days in every regime
    assert not np.array_equal(a, eval_food_streams("run0", 21, 5))


@pytest.mark.parametrize("algo", ["ppo", "ddqn", "gru_ppo"])
def test_same_seed_gives_identical_metrics(algo):
    def run() -> tuple[list[dict], list[dict]]:
        agent = train("run3", algo, seed=7, episodes=4)
        return agent.train_episodes, evaluate(agent, "run3", eval_food_streams("run3", 7, 3)).episodes

    assert run() == run()


@pytest.mark.parametrize("algo", ["mc", "sac", "gru_ppo"])
def test_save_and_load_give_the_same_greedy_evaluation(algo, tmp_path):
    agent = train("run2", algo, seed=4, episodes=3)
    streams = eval_food_streams("run2", 4, 3)
    before = evaluate(agent, "run2", streams, record_steps=True)
    path = agent.save(tmp_path / "m" / f"{algo}.zip")
    assert path.is_file() and path.with_suffix(".json").is_file()
    loaded = TrainedAgent.load(path)
    assert loaded.algo == algo and loaded.config == agent.config
    assert loaded.provenance["regime"] == "run2" and loaded.provenance["seed"] == 4
    again = loaded.save(tmp_path / "m2" / f"{algo}.zip")  # a loaded agent saves everything again
    assert again.with_suffix(".vecnormalize.pkl").is_file()
    after = evaluate(loaded, "run2", streams, record_steps=True)
    assert after.episodes == before.episodes and after.steps == before.steps


# ---------------------------------------------------------------------- double DQN
def test_double_dqn_target_differs_from_the_max_target():
    # online net prefers action 1, target net values action 0 higher: double DQN must take
    # the target net's value of action 1, vanilla DQN the target net's max (action 0).
    q_online = th.tensor([[0.0, 5.0], [3.0, 1.0]])
    q_target = th.tensor([[10.0, 2.0], [4.0, 8.0]])
    rewards = th.tensor([[1.0], [-1.0]])
    dones = th.tensor([[0.0], [0.0]])
    double = double_dqn_target(q_online, q_target, rewards, dones, 0.9)
    vanilla = rewards + 0.9 * q_target.max(dim=1, keepdim=True).values
    assert double.flatten().tolist() == pytest.approx([1 + 0.9 * 2.0, -1 + 0.9 * 4.0])
    assert vanilla.flatten().tolist() == pytest.approx([1 + 0.9 * 10.0, -1 + 0.9 * 8.0])
    # a finished day does not bootstrap; per-sample n-step discounts are honoured
    done = double_dqn_target(q_online, q_target, rewards, th.tensor([[1.0], [0.0]]), th.tensor([[0.5], [0.25]]))
    assert done.flatten().tolist() == pytest.approx([1.0, -1 + 0.25 * 4.0])


def test_ddqn_training_uses_the_double_target(monkeypatch):
    import nutribench.agents.sb3_models as algos

    calls = []
    real = algos.double_dqn_target

    def spy(*args, **kwargs):
        calls.append(args[0].shape)
        return real(*args, **kwargs)

    monkeypatch.setattr(algos, "double_dqn_target", spy)
    cfg = load_agent_config("ddqn").model_copy(update={"learning_starts": 100})
    train("run0", cfg, seed=0, episodes=4)
    assert calls and all(shape == (cfg.batch_size, 2) for shape in calls)


# ---------------------------------------------------------------------- learning (CI budget)
#: The CI learning bar: share of the never -> planner gap closed on the fixed evaluation
#: days. "never" scores 0 and "random" far below 0 by construction; trained PPO 80 % or more
#: (README "Learnability").
CI_GAP_BAR = 0.5
CI_EVAL_DAYS = 10
#: PPO learns to eat within 300-500 days on run0 (greedy at 150 days: never; at 300 days
#: 0-83 % of the gap over seeds 0-3). Seeds differ a lot: measured on this project's CPU
#: machine (torch 2.13.0+cpu, SB3 2.9.2), share of the gap at 500 days for seeds 0-7:
#: 0.65, 0.42, 0.98, 0.89, 0.84, 0.82, 0.98, 0.91 (median 0.87); at 800 days seed 1 is
#: still low (0.20) while the others reach 0.78-1.03. So one seed is no test of "PPO
#: learns": the CI test trains three and bars their median, and bars every one of them far
#: above what learning nothing scores (never 0, random below 0).
PPO_CI_DAYS = 500
PPO_CI_SEEDS = (0, 1, 2)
PPO_CI_EACH_BAR = 0.25


def gap_closed(returns: list[float], streams: np.ndarray) -> float:
    from nutribench.baselines import day_yardsticks
    from nutribench.baselines import gap_closed as share_of_gap

    ref = day_yardsticks("run0", streams)
    never, planner = (float(np.mean([d[name] for d in ref])) for name in ("never", "planner"))
    return share_of_gap(float(np.mean(returns)), never, planner)


def simple_policy_returns(policy: str, streams: np.ndarray) -> list[float]:
    from nutribench.baselines import play_simple_policy

    return [r["return"] for r in play_simple_policy(policy, "run0", streams)]


@pytest.mark.parametrize("policy", ["never", "random", "always"])
def test_the_learning_bar_fails_for_the_policies_that_learn_nothing(policy):
    streams = eval_food_streams("run0", 0, CI_EVAL_DAYS)
    assert gap_closed(simple_policy_returns(policy, streams), streams) < CI_GAP_BAR


def test_the_learning_bar_passes_for_the_planner():
    streams = eval_food_streams("run0", 0, CI_EVAL_DAYS)
    assert gap_closed(simple_policy_returns("planner", streams), streams) == pytest.approx(1.0)


@pytest.mark.slow
def test_ppo_learns_to_eat_on_run0_within_a_ci_budget():
    """PPO (its config file, unchanged) on run0 for PPO_CI_DAYS days, seeds PPO_CI_SEEDS:
    the median seed closes at least half of the never -> planner gap on its fixed evaluation
    days, every seed closes more than PPO_CI_EACH_BAR of it eating a planner-like 2-8 foods,
    and every training curve improved."""
    results = []
    for seed in PPO_CI_SEEDS:
        agent = train("run0", "ppo", seed=seed, episodes=PPO_CI_DAYS)
        streams = eval_food_streams("run0", seed, CI_EVAL_DAYS)
        rows = evaluate(agent, "run0", streams, record_steps=False).episodes
        gap = gap_closed([r["return"] for r in rows], streams)
        foods = float(np.mean([r["foods"] for r in rows]))
        # the training curve improved: the last 20 days beat the first 20
        first = np.mean([r["return"] for r in agent.train_episodes[:20]])
        last = np.mean([r["return"] for r in agent.train_episodes[-20:]])
        results.append((seed, round(gap, 3), foods, round(float(first), 1), round(float(last), 1)))
    gaps = [r[1] for r in results]
    assert np.median(gaps) >= CI_GAP_BAR, results
    assert all(gap > PPO_CI_EACH_BAR and 2 <= foods <= 8 for _, gap, foods, _, _ in results), results
    assert all(last > first for *_, first, last in results), results


@pytest.mark.parametrize("algo", ["ddqn", "sac"])
def test_sb3_s_random_actions_do_not_depend_on_the_food_offered(algo):
    """SB3 seeds the action space and the env with one seed; the env draws foods from a
    PCG64 stream seeded the same way, so without the action space's own stream every warm-up
    "random" action was eat exactly for the upper half of the food indices (measured: eat
    fraction 0.0 for foods 0-4, 1.0 for 5-9). Now each half eats about half the time."""
    from nutribench.agents.algos import build_model
    from nutribench.agents.api import make_train_env
    from nutribench.config import load_env_config

    cfg = load_agent_config(algo).model_copy(update={"learning_starts": 10_000})
    base, env = make_train_env(load_env_config("run0"), cfg)
    model = build_model(cfg, env, seed=0, horizon=50)
    seen: list[tuple[int, int]] = []
    step_async = base.step_async
    base.step_async = lambda a: (
        seen.append((int(base.venv._foods[0, base.venv._t]), int(np.ravel(a)[0]))),
        step_async(a),
    )[1]
    model.learn(total_timesteps=2000)
    foods, acts = np.array(seen).T
    low, high = acts[foods < 5].mean(), acts[foods >= 5].mean()
    assert 0.4 < low < 0.6 and 0.4 < high < 0.6, (low, high)


@pytest.mark.slow
def test_ddqn_learns_on_run0_within_a_ci_budget():
    """CI budget: learning starts after 1,000 steps instead of the paper's 10,000 (200 days
    of 50 steps would otherwise leave no update). At 200 days DDQN has learned to eat a
    little (seed 0: -14.2 with 1.9 foods, 41 % of the gap), which "never" (0 %, 0 foods) and
    "random" (far below 0 %) fail."""
    cfg = load_agent_config("ddqn").model_copy(update={"learning_starts": 1000})
    agent = train("run0", cfg, seed=0, episodes=200)
    streams = eval_food_streams("run0", 0, CI_EVAL_DAYS)
    rows = evaluate(agent, "run0", streams, record_steps=False).episodes
    gap = gap_closed([r["return"] for r in rows], streams)
    foods = float(np.mean([r["foods"] for r in rows]))
    assert gap >= 0.2 and 1 <= foods <= 8, (gap, foods)


def test_bench_train_reports_each_algorithm_and_its_bare_references():
    from nutribench.bench.throughput import bench_train

    rows = bench_train(["ppo", "ddqn", "mc"], episodes=2, repeats=1)
    assert [r["what"] for r in rows] == [
        "nutribench ppo",
        "bare SB3 PPO",
        "nutribench ddqn",
        "bare SB3 DQN loop, double target",
        "bare SB3 DQN, vanilla target",
        "nutribench mc",
    ]
    grid_steps = 7 * 5 * 5000 * 50
    for r in rows:
        assert r["steps_per_s"] > 0
        assert r["paper_grid_cpu_hours"] == pytest.approx(grid_steps / r["steps_per_s"] / 3600)
    # our rows with a bare reference carry the paired ratio, the others (and bare rows) none
    assert [("vs_bare" in r) for r in rows] == [True, False, True, False, False, False]
    # a ratio of two timings: its shape is tested, never its size (timings belong in benchmarks)
    assert all(math.isfinite(r["vs_bare"]) and r["vs_bare"] > 0 for r in rows if "vs_bare" in r)


# ---------------------------------------------------------------------- last rollout
@pytest.mark.parametrize(
    ("algo", "days", "updates"),
    [
        ("mc", 3, 3),
        ("ppo", 4, 2),
        ("gru_ppo", 4, 2),
        pytest.param("ppo", 25, 2, marks=pytest.mark.slow),
    ],
)
def test_on_policy_jobs_update_on_their_last_rollout(algo, days, updates, monkeypatch):
    """MC updates once per day and (GRU-)PPO once per rollout, the last rollout included (SB3
    skips a rollout's update when a callback stops it). The fast cases take rollouts of 2 days
    (n_steps 100, minibatches of a day): 4 days, 2 updates. The slow case takes the file's
    10-day rollouts: 25 PPO days end in the middle of the third rollout, which SB3 cannot
    update on: 2 updates, 25 days. (The files' 10-day rollouts over 20 days, 2 updates each:
    tests/test_diagnostics.py, a row per update of each agent.)"""
    from nutribench.agents.algos import model_arguments
    from tests.conftest import two_day_rollouts

    calls = []
    cfg = load_agent_config(algo)
    if algo != "mc" and days < 10:
        cfg = two_day_rollouts(cfg)
    cls, _ = model_arguments(cfg, 50)
    original = cls.train
    monkeypatch.setattr(
        cls, "train", lambda self, *a, **k: (calls.append(self.num_timesteps), original(self, *a, **k))[1]
    )
    agent = train("run0", cfg, seed=0, episodes=days)
    assert len(agent.train_episodes) == days
    assert len(calls) == updates
    assert agent.model.num_timesteps == days * 50


def test_ddqn_learning_rate_schedule_is_sb3s_picklable_linear_schedule(tmp_path):
    """No closure as schedule (cloudpickle would pickle it into the saved model and break
    loading elsewhere): SB3's LinearSchedule is a plain class."""
    import pickle

    from stable_baselines3.common.utils import LinearSchedule

    from nutribench.agents.algos import build_model
    from nutribench.agents.api import make_train_env
    from nutribench.config import load_env_config

    cfg = load_agent_config("ddqn")
    _, env = make_train_env(load_env_config("run0"), cfg)
    model = build_model(cfg, env, seed=0, horizon=50)
    schedule = pickle.loads(pickle.dumps(model.lr_schedule))  # plain pickle: no closure inside
    assert isinstance(getattr(schedule, "value_schedule", schedule), LinearSchedule)
    assert (
        schedule(1.0) == pytest.approx(1e-3)
        and schedule(0.5) == pytest.approx(5.5e-4)
        and schedule(0.0) == pytest.approx(1e-4)
    )


@pytest.mark.parametrize(("algo", "sb3_class"), [("ppo", "PPO"), ("mc", "A2C"), ("ddqn", "DQN")])
def test_a_saved_model_plays_the_same_greedy_actions_in_plain_sb3(algo, sb3_class, tmp_path):
    """The plain-SB3 recipe (the model's SB3 class, VecNormalize
    loaded from the pickle beside it) acts exactly as nutribench's own agent does."""
    import json

    import stable_baselines3
    from stable_baselines3.common.vec_env import VecNormalize

    from nutribench.agents.api import vec_normalize_path
    from nutribench.env.sb3 import NutriRLSB3VecEnv

    cfg = load_agent_config(algo).model_copy(update={"learning_starts": 100} if algo == "ddqn" else {})
    agent = train("run3", cfg, seed=3, episodes=12)
    path = agent.save(tmp_path / f"{algo}.zip")
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["load_with"] == f"stable_baselines3.{sb3_class}"
    assert (
        side["provenance"]["regime"] == "run3"
        and side["provenance"]["seed"] == 3
        and side["provenance"]["episodes"] == 12
    )

    env = VecNormalize.load(str(vec_normalize_path(path)), NutriRLSB3VecEnv(num_envs=4, regime="run3"))
    env.training, env.norm_reward = False, False
    model = getattr(stable_baselines3, sb3_class).load(path, device="cpu")
    env.seed(5)
    obs = env.reset()
    agreed = []
    for _ in range(50):
        action, _ = model.predict(obs, deterministic=True)
        ours, _ = agent.act(env.get_original_obs())
        agreed.append(np.array_equal(np.asarray(action).reshape(-1), np.asarray(ours).reshape(-1)))
        obs, _, _, _ = env.step(action)
    assert all(agreed)
