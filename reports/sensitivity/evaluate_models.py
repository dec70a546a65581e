"""Play the saved models of a study database again on their jobs' fixed evaluation days, greedy
and/or stochastic, under a chosen regimes folder; one CSV row per (job, mode, draw, day).

Greedy: the argmax, as the job's own evaluation (``nutribench.agents.evaluate``); played under
the regimes the job was trained on, it must give the database's evaluation returns (checked,
``--check``). Stochastic: each step's action drawn from the policy's P(eat) with numpy's
generator seeded by (salt, job seed, draw), ``--draws`` independent draws of the same days.
With ``--yardsticks`` the never-eat and full-information planner policies are played on the
same days under the same regimes (rows with mode ``never`` / ``planner``).

    python reports/sensitivity/evaluate_models.py --db /tmp/sens/study.db --algo ppo \
        --modes greedy,stochastic --draws 20 --regimes-dir regimes --yardsticks --check \
        --out reports/sensitivity/eval_control.csv
"""

from __future__ import annotations

import argparse
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import torch as th

from nutribench.agents import eval_food_streams, evaluate
from nutribench.agents.api import TrainedAgent
from nutribench.baselines import play_simple_policy
from nutribench.config import load_env_config
from nutribench.env.metrics import EpisodeRecorder
from nutribench.env.vector_env import NutriRLVectorEnv

DRAW_SALT = 26_002  # issue 26, section 2
KEYS = ("return", "foods", "final_distance", "overshoot_ratio")


def done_jobs(db: str, algo: str) -> pd.DataFrame:
    q = """select j.id as job_id, r.name as regime, r.version as regime_version, a.name as algo, a.version as algo_version, j.seed, j.episodes as budget,
                  j.eval_episodes, j.model_path
           from jobs j join regimes r on r.id = j.regime_id join agent_configs a on a.id = j.agent_config_id
           where j.status = 'done' and j.fake = 0 and a.name = ? order by r.name, j.episodes, j.seed"""
    return pd.read_sql(q, sqlite3.connect(db), params=(algo,))


def p_eat(agent: TrainedAgent, obs: np.ndarray) -> np.ndarray:
    """The policy's probability of eating for raw observations ``(n, obs_dim)`` (feed-forward policies)."""
    x = th.as_tensor(agent.normalize(obs))
    with th.no_grad():
        probs = agent.model.policy.get_distribution(x).distribution.probs
    return probs[:, 1].cpu().numpy()


def play_stochastic(agent: TrainedAgent, env_cfg, streams: np.ndarray, rng: np.random.Generator) -> list[dict]:
    """One play of the days ``streams`` ``(n, H)``, each action sampled from P(eat)."""
    n, horizon = streams.shape
    venv = NutriRLVectorEnv(n, regime=env_cfg)
    obs, _ = venv.reset(options={"foods": streams})
    recorder = EpisodeRecorder(n)
    finished = []
    for _ in range(horizon):
        actions = (rng.random(n) < p_eat(agent, obs)).astype(np.int64)
        obs, rewards, terminated, truncated, info = venv.step(actions)
        finished += recorder.record(rewards, terminated | truncated, info)
    return finished


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--db", required=True)
    ap.add_argument("--algo", required=True, help="the agent config's name in the database")
    ap.add_argument("--level", default=None, help="the study level's id in the CSV (default: --algo)")
    ap.add_argument("--modes", default="greedy,stochastic")
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--regimes-dir", default="regimes", help="the regimes folder to play under")
    ap.add_argument("--budget", type=int, default=None, help="only jobs of this many training days")
    ap.add_argument(
        "--regime-version", type=int, default=None, help="only jobs trained on this regime version (lo0: 102)"
    )
    ap.add_argument("--yardsticks", action="store_true", help="also play never and the planner on the same days")
    ap.add_argument("--check", action="store_true", help="greedy returns must equal the database's evaluation returns")
    ap.add_argument(
        "--models-dir",
        default=None,
        help="read each model from here instead (its path below the job's models/ folder), e.g. the unpacked data/models_*.tar.gz",
    )
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    th.set_num_threads(1)
    modes = [m for m in a.modes.split(",") if m]
    jobs = done_jobs(a.db, a.algo)
    if a.budget is not None:
        jobs = jobs[jobs.budget == a.budget]
    if a.regime_version is not None:
        jobs = jobs[jobs.regime_version == a.regime_version]
    if jobs.empty:
        raise SystemExit(f"no done jobs of {a.algo} in {a.db}")
    stored = pd.read_sql("select job_id, episode, return from episodes where phase = 'eval'", sqlite3.connect(a.db))
    rows, checked = [], 0
    for job in jobs.itertuples():
        env_cfg = load_env_config(Path(a.regimes_dir) / f"{job.regime}.toml")
        streams = eval_food_streams(env_cfg, int(job.seed), int(job.eval_episodes))
        path = job.model_path
        if a.models_dir is not None:  # the layout of the models/ folder; an imported archive has no model paths
            path = str(
                Path(a.models_dir)
                / f"{job.regime}-v{job.regime_version}"
                / f"{job.algo}-v{job.algo_version}"
                / f"seed{job.seed}-ep{job.budget}.zip"
            )
        agent = TrainedAgent.load(path)
        base = {
            "level": a.level or a.algo,
            "algo": job.algo,
            "regime": job.regime,
            "reward_version": env_cfg.reward.version,
            "regime_version_played": env_cfg.version,
            "seed": int(job.seed),
            "budget": int(job.budget),
            "job_id": int(job.job_id),
        }
        if "greedy" in modes:
            played = evaluate(agent, env_cfg, streams, record_steps=False).episodes
            rows += [
                {**base, "mode": "greedy", "draw": 0, "episode": e, **{k: r[k] for k in KEYS}}
                for e, r in enumerate(played)
            ]
            if a.check:
                mine = stored[stored.job_id == job.job_id].sort_values("episode")["return"].to_numpy()
                ours = np.array([r["return"] for r in played])
                if not np.allclose(mine, ours, rtol=0, atol=1e-9):
                    raise SystemExit(f"job {job.job_id}: greedy replay {ours} differs from the database's {mine}")
                checked += 1
        if "stochastic" in modes:
            for d in range(a.draws):
                rng = np.random.default_rng([DRAW_SALT, int(job.seed), d])
                played = play_stochastic(agent, env_cfg, streams, rng)
                rows += [
                    {**base, "mode": "stochastic", "draw": d, "episode": e, **{k: r[k] for k in KEYS}}
                    for e, r in enumerate(played)
                ]
        if a.yardsticks:
            for name in ("never", "planner"):
                played = play_simple_policy(name, env_cfg, streams)
                rows += [
                    {**base, "mode": name, "draw": 0, "episode": e, **{k: r[k] for k in KEYS}}
                    for e, r in enumerate(played)
                ]
    out = pd.DataFrame(rows)
    out.to_csv(a.out, index=False, float_format="%.6f")
    summary = out.groupby(["regime", "mode"])[["return", "foods"]].mean().round(2)
    print(summary.to_string())
    if a.check:
        print(f"greedy replay equals the database's evaluation returns for {checked} of {len(jobs)} jobs")
    print(f"wrote {len(out)} rows to {a.out}")


if __name__ == "__main__":
    main()
