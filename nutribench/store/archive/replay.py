"""Evaluation days of an archive played again: the environment is deterministic given a regime
and a day's food stream, so every evaluation day an archive holds is replayed from its stored
foods and actions (``eval_steps``), on the regime the archive itself carries, and each stored
step (reward and absorbed ``C``/``F``/``P``) and each day's metrics (return, foods, final
distance, overshoot ratio, final ``C``/``F``/``P``, first overshoot step) must be what the
replay gives. The first disagreement is one line naming the job and the day.

Not replayed: the training days (the agent's own exploration, which only the agent can play
again), the entropy (the policy's, which the archive does not carry) and a dry run's synthetic
jobs (``fake``: never results). Before a day is replayed its foods are checked to be the
job's test days: a job of seed ``s`` evaluates on ``eval_food_streams(regime, s, n)``
(:mod:`nutribench.agents.days`), drawn from the seed alone, so the stored foods of every
evaluation day must be that stream's, drawn again here from the archive's regime and the
job's seed (easier days chosen by hand are refused). A replayed day proves that the stored
steps are a day of that regime on the seed's test days, not which agent played it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from nutribench.config.loading import ConfigError, EnvConfig
from nutribench.config.models import FoodCatalog, Regime, RewardConfig
from nutribench.env.metrics import METRIC_KEYS, EpisodeRecorder
from nutribench.env.vector_env import NutriRLVectorEnv
from nutribench.store.archive.format import InvalidArchive, first_row, job_label, short_repr

#: How far a stored value may be from the replayed one: float64 sums in another order (a
#: batched evaluation, another BLAS) differ in the last bits, an edited value by far more.
ATOL = 1e-9
RTOL = 1e-9
#: Days replayed side by side in one vector env.
CHUNK = 4096


def stored_regime(row: dict[str, Any]) -> EnvConfig:
    """The regime an archive (or a database: the leaderboard's re-run) carries, built from its
    stored body (``row``: name, version, body, sha256; data, validated); :class:`InvalidArchive`
    in one line for a body that is not a regime or does not hash to its sha256."""
    body = row["body"]
    what = f"regime {short_repr(row['name'])} v{row['version']}"
    try:
        cfg = EnvConfig(
            regime=Regime.model_validate(body["regime"]),
            catalog=FoodCatalog.model_validate(body["catalog"]),
            reward=RewardConfig.model_validate(body["reward"]),
        )
    except (KeyError, TypeError, ValueError, ConfigError) as e:
        raise InvalidArchive(f"{what}: its body is not a regime ({' '.join(str(e).split())[:120]})") from None
    if cfg.sha256 != row["sha256"]:
        raise InvalidArchive(f"{what}: its body does not describe the dynamics of its sha256")
    return cfg


def _check_test_days(cfg: EnvConfig, i: int, job: dict[str, Any], stored: np.ndarray) -> None:
    """The stored foods ``(n, H)`` of job ``i``'s evaluation days are its seed's test days."""
    from nutribench.agents.days import eval_food_streams

    expected = eval_food_streams(cfg, int(job["seed"]), len(stored))
    if (d := first_row((stored != expected).any(axis=1))) is not None:
        raise InvalidArchive(
            f"{job_label(i, job)} evaluation day {d}: its foods are not the test day {d} of seed {job['seed']} "
            "(eval_food_streams draws a job's evaluation days from its seed alone; the days were changed)"
        )


def _close(stored: np.ndarray, replayed: np.ndarray) -> np.ndarray:
    return np.isclose(stored, replayed, rtol=RTOL, atol=ATOL) | (np.isnan(stored) & np.isnan(replayed))


def replay_evaluations(
    meta: dict[str, Any], tables: dict[str, dict[str, np.ndarray]], per_job: dict[str, np.ndarray]
) -> None:
    """Replay every evaluation day of the archive's real jobs (checked complete and in range
    before); :class:`InvalidArchive` naming job and day at the first disagreement."""
    jobs = meta["jobs"]
    regimes = {(r["name"], r["version"]): r for r in meta["regimes"]}
    by_regime: dict[tuple[str, int], list[int]] = {}
    for i, job in enumerate(jobs):
        if not job.get("fake", False) and per_job["eval_episodes"][i] > 0:
            by_regime.setdefault(tuple(job["regime"]), []).append(i)
    st, ep = tables["eval_steps"], tables["episodes"]
    order = np.lexsort((st["step"], st["episode"], st["job"]))  # job, day, step
    evals = np.flatnonzero(ep["phase"] == "eval")
    ev_order = evals[np.lexsort((ep["episode"][evals], ep["job"][evals]))]
    # rows of job i: steps from step_start[i], days from day_start[i] (complete: checked before)
    step_start = np.concatenate([[0], np.cumsum(per_job["eval_episodes"] * per_job["horizon"])])
    day_start = np.concatenate([[0], np.cumsum(per_job["eval_episodes"])])
    for key, members in by_regime.items():
        cfg = stored_regime(regimes[key])
        H = cfg.reward.horizon
        for i in members:
            n = int(per_job["eval_episodes"][i])
            stored = st["food"][order[step_start[i] : step_start[i] + n * H]].reshape(n, H)
            _check_test_days(cfg, i, jobs[i], stored)
        days = [(i, d) for i in members for d in range(int(per_job["eval_episodes"][i]))]
        for lo in range(0, len(days), CHUNK):
            chunk = days[lo : lo + CHUNK]
            rows = np.stack([order[step_start[i] + d * H + np.arange(H)] for i, d in chunk])  # (n, H)
            _replay_chunk(cfg, chunk, rows, st, ep, ev_order[[day_start[i] + d for i, d in chunk]], jobs)


def _replay_chunk(
    cfg: EnvConfig,
    chunk: list[tuple[int, int]],
    rows: np.ndarray,
    st: dict[str, np.ndarray],
    ep: dict[str, np.ndarray],
    ep_rows: np.ndarray,
    jobs: list[dict[str, Any]],
) -> None:
    n, H = rows.shape

    def label(k: int) -> str:
        return f"{job_label(chunk[k][0], jobs[chunk[k][0]])} evaluation day {chunk[k][1]}"

    venv = NutriRLVectorEnv(n, regime=cfg)
    venv.reset(options={"foods": st["food"][rows]})
    recorder = EpisodeRecorder(n)
    metrics: list[dict[str, Any]] = []
    for t in range(H):
        _, rewards, terminated, truncated, info = venv.step(st["action"][rows[:, t]])
        metrics += recorder.record(rewards, terminated | truncated, info)
        state = np.asarray(info["state"]).reshape(n, 3)
        for name, replay in (("reward", rewards), ("C", state[:, 0]), ("F", state[:, 1]), ("P", state[:, 2])):
            stored = st[name][rows[:, t]]
            if (k := first_row(~_close(stored, replay))) is not None:
                raise InvalidArchive(
                    f"{label(k)} step {t + 1}: stored {name} {stored[k]:.6g} but replaying its foods and actions "
                    f"gives {replay[k]:.6g} (the measurements were changed)"
                )
    for key in METRIC_KEYS:
        replay = np.array([np.nan if m[key] is None else m[key] for m in metrics], dtype=np.float64)
        stored = ep[key][ep_rows].astype(np.float64)
        if key == "first_overshoot_step" and "first_overshoot_step.null" in ep:
            stored = np.where(ep["first_overshoot_step.null"][ep_rows], np.nan, stored)
        if (k := first_row(~_close(stored, replay))) is not None:
            raise InvalidArchive(
                f"{label(k)}: stored {key} {stored[k]:.6g} but its replayed steps give {replay[k]:.6g} "
                "(the measurements were changed)"
            )
