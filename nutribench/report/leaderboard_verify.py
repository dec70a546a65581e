"""``nutribench leaderboard --verify MODELS``: the leaderboard's entries re-run from their trained
models, on the reader's machine, so that its ``checked`` column can tell what was re-run from
what was only replayed.

Replaying an archive (:mod:`nutribench.store.archive.replay`) proves that its stored actions fit
the regime and the seed's test days, not that an agent chose them: the test days are public,
so a planner's actions written into an archive replay as well as a trained agent's. Here each
job of an entry whose trained model is supplied is played again:

* **where the model is**: ``MODELS/<regime>-v<rv>/<agent>-v<av>/seed<seed>-ep<budget>.zip`` (with
  its ``.json`` sidecar), the layout ``nutribench run --models-dir MODELS`` writes
  (:func:`nutribench.scheduler.registration.model_path`), so the folder a run wrote is given as
  it is;
* **loaded as data**: :meth:`nutribench.agents.api.TrainedAgent.load` (weights only, nothing
  unpickled; a plug-in's model, which needs a loader named by its user, is not loaded here);
  its sidecar must name the job's agent config (same settings hash) and regime;
* **played greedily** on the job's test days (``eval_food_streams(regime, seed,
  eval_episodes)``, the days the job was evaluated on, all side by side as the job played
  them, torch on one thread as in a worker), on the regime stored with the job;
* **compared action for action**: actions are discrete (eat or skip), so the rule is exact: the
  model's action must be the stored one at every step of every evaluation day (then every
  return follows, the environment being deterministic; the returns are compared too, within
  the replay's 1e-9). On the machine that ran the job the greedy actions are identical; on
  another CPU (another BLAS, other vector instructions) float rounding can flip a greedy
  action where two choices are within rounding of each other, and that shows here as a
  difference: the cell then gives the first differing day and step and the share of days
  whose actions all match, so a near-tie flip (one day of many) can be told from a forgery
  (most days differ). Only the exact match is called verified.

The ``checked`` cell of an entry: ``verified (re-run)`` when every job of the entry has its model
and every day matches; ``re-run: differs (...)`` when a supplied model plays another action
(the first differing job, day and step; how many days match); ``re-run: failed (...)`` when a
supplied model cannot be loaded or is another agent's; ``replayed, not re-run`` when no model of
the entry is supplied; ``replayed; re-run on k of n jobs: match`` when only some are. An entry
whose cell says ``differs`` or ``failed`` (:func:`not_reproduced`) is set apart by the leaderboard:
listed after the ranked rows, without a rank, with the reason in its flags and in the caption.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd

from nutribench.report.data import ENTRY, Log

#: The ``checked`` cell of an entry none of whose models was supplied (replayed only).
REPLAYED = "replayed, not re-run"
#: The ``checked`` cell of an entry whose every job's model played the stored actions.
VERIFIED = "verified (re-run)"
DIFFERS = "re-run: differs"
FAILED = "re-run: failed"
#: Added to :data:`REPLAYED` when the entry's supplied models are a plug-in's.
PLUGIN_NOTE = " (a plug-in's models: their loader is its own code, not imported here; nutribench evaluate --entry-point re-runs one)"
#: How far a re-run return may be from the stored one (the replay's tolerance: float64 sums).
RETURN_TOL = 1e-9


@dataclass
class JobCheck:
    """One job re-run from its model: ``status`` is ``missing`` (no model supplied), ``plugin``
    (a plug-in's model: not loaded), ``match``, ``differs`` or ``failed``; ``days``/``matching``: its evaluation days and how many match;
    ``first``: where the first difference (or the failure) is, in words."""

    label: str
    status: str
    days: int = 0
    matching: int = 0
    first: str = ""


def model_file(models_dir: str | Path, job: dict[str, Any]) -> Path:
    """The model of ``job`` (a row of :func:`nutribench.store.read_jobs`) under ``models_dir``,
    where ``nutribench run --models-dir`` writes it."""
    from nutribench.scheduler.registration import model_path

    regime = SimpleNamespace(name=job["regime"], version=int(job["regime_version"]))
    agent = SimpleNamespace(name=job["algo"], version=int(job["algo_version"]))
    return model_path(Path(models_dir), regime, agent, int(job["seed"]), int(job["episodes"]))


def rerun_job(path: Path, job: dict[str, Any], configs: dict[str, Any], steps: pd.DataFrame, returns) -> JobCheck:
    """Re-run the model at ``path`` on ``job``'s test days and compare with its stored
    evaluation ``steps`` (columns episode, step, action) and day ``returns`` (by episode).
    ``configs``: the job's regime and agent config rows (``regime_body``, ``regime_sha256``,
    ``agent_sha256``)."""
    from nutribench.agents.api import TrainedAgent, evaluate, single_threaded
    from nutribench.agents.config import agent_config_sha256
    from nutribench.agents.days import eval_food_streams
    from nutribench.errors import UserError
    from nutribench.store.archive.format import InvalidArchive
    from nutribench.store.archive.replay import stored_regime

    label = f"{job['regime']} x {job['algo']} seed {int(job['seed'])}"
    if not path.is_file():
        return JobCheck(label, "missing")
    if configs.get("plugin"):
        return JobCheck(label, "plugin")
    n = int(job["eval_episodes"])
    try:
        regime = {"name": job["regime"], "version": job["regime_version"], "body": configs["regime_body"]}
        cfg = stored_regime({**regime, "sha256": configs["regime_sha256"]})
        agent = TrainedAgent.load(path)
    except (UserError, InvalidArchive, OSError, ValueError, KeyError, TypeError, RuntimeError) as e:
        return JobCheck(label, "failed", n, 0, f"{label}: {path.name} not loaded: {' '.join(str(e).split())[:160]}")
    if agent_config_sha256(agent.config) != configs["agent_sha256"]:
        return JobCheck(label, "failed", n, 0, f"{label}: {path.name}'s sidecar names another agent config")
    made_on = agent.provenance.get("regime_sha256")
    if made_on is not None and made_on != cfg.sha256:
        return JobCheck(label, "failed", n, 0, f"{label}: {path.name} was trained on another regime")
    with single_threaded():
        result = evaluate(agent, cfg, eval_food_streams(cfg, int(job["seed"]), n), record_steps=True)
    H = cfg.reward.horizon
    played = np.array([s["action"] for s in result.steps], dtype=np.int64).reshape(H, n).T  # steps come t-major
    stored = np.full((n, H), -1, dtype=np.int64)
    ok = steps["episode"].between(0, n - 1) & steps["step"].between(1, H)
    s = steps[ok]
    stored[s["episode"].to_numpy(dtype=int), s["step"].to_numpy(dtype=int) - 1] = s["action"].to_numpy(dtype=int)
    rerun = np.array([r["return"] for r in result.episodes], dtype=np.float64)
    kept = np.array([returns.get(d, np.nan) for d in range(n)], dtype=np.float64)
    same_return = np.isclose(rerun, kept, rtol=RETURN_TOL, atol=RETURN_TOL)
    day_ok = (played == stored).all(axis=1) & same_return
    if day_ok.all():
        return JobCheck(label, "match", n, n)
    d = int(np.argmax(~day_ok))
    bad = np.flatnonzero(played[d] != stored[d])
    if bad.size:
        t = int(bad[0])
        where = f"{label} day {d} step {t + 1}: stored action {stored[d, t]}, the model plays {played[d, t]}"
    else:
        where = f"{label} day {d}: stored return {kept[d]:.6g}, the model's {rerun[d]:.6g}"
    return JobCheck(label, "differs", n, int(day_ok.sum()), where)


def entry_cell(checks: list[JobCheck]) -> str:
    """The ``checked`` cell of an entry from its jobs' checks."""
    run = [c for c in checks if c.status not in ("missing", "plugin")]
    if not run:
        return REPLAYED + (PLUGIN_NOTE if any(c.status == "plugin" for c in checks) else "")
    failed = [c for c in run if c.status == "failed"]
    if failed:
        return f"{FAILED} ({failed[0].first})"
    differs = [c for c in run if c.status == "differs"]
    if differs:
        days = sum(c.days for c in run)
        matching = sum(c.matching for c in run)
        return f"{DIFFERS} ({differs[0].first}; {matching} of {days} days match)"
    if len(run) == len(checks):
        return VERIFIED
    return f"replayed; re-run on {len(run)} of {len(checks)} jobs: match"


def not_reproduced(cell: str) -> bool:
    """Whether the ``checked`` cell ``cell`` says the entry's supplied models do not reproduce its
    stored actions (:data:`DIFFERS`) or could not be re-run as its own (:data:`FAILED`): such an
    entry is set apart, not ranked among the others (its numbers are not its models')."""
    return cell.startswith((DIFFERS, FAILED))


def verify_entries(
    db, ev: pd.DataFrame, models_dir: str | Path, log: Log | None = None
) -> dict[tuple[str, int, int], str]:
    """The ``checked`` cell of every entry (name, version, budget:
    :data:`nutribench.report.data.ENTRY`) of the evaluation episodes ``ev`` (one job per entry
    and run, as the leaderboard drew them) of the database ``db``, its jobs re-run from the models in
    ``models_dir`` (:func:`model_file`)."""
    from sqlalchemy import select

    from nutribench.agents.registry import by_entry_point
    from nutribench.store import AgentConfig, RegimeConfig, open_store, read_eval_trajectories, read_jobs, session_scope

    job_ids = sorted({int(j) for j in ev["job_id"]})
    with open_store(db) as store:
        jobs = read_jobs(store.engine).set_index("id")
        with session_scope(store.engine) as s:
            regimes = {r.id: (r.body, r.sha256) for r in s.execute(select(RegimeConfig)).scalars()}
            agents = {a.id: (a.sha256, a.body) for a in s.execute(select(AgentConfig)).scalars()}
        steps = read_eval_trajectories(store.engine, algos=sorted(ev["algo"].unique()))
    steps = steps[steps["job_id"].isin(job_ids)]
    by_job = dict(tuple(steps.groupby("job_id")))
    checks: dict[int, JobCheck] = {}
    for jid in job_ids:
        job = {"id": jid, **jobs.loc[jid].to_dict()}
        body, sha = regimes[int(job["regime_id"])]
        agent_sha, agent_body = agents[int(job["agent_config_id"])]
        plugin = isinstance(agent_body, dict) and by_entry_point(agent_body.get("algo"))
        configs = {"regime_body": body, "regime_sha256": sha, "agent_sha256": agent_sha, "plugin": plugin}
        days = ev[(ev["job_id"] == jid)]
        returns = dict(zip(days["episode"].astype(int), days["return"].astype(float)))
        path = model_file(models_dir, job)
        mine = by_job.get(jid, pd.DataFrame(columns=["episode", "step", "action"]))
        checks[jid] = rerun_job(path, job, configs, mine, returns)
        if log and checks[jid].status not in ("missing", "plugin"):
            log(f"re-ran {checks[jid].label} from {path}: {checks[jid].status}")
    return {
        (str(e[0]), int(e[1]), int(e[2])): entry_cell([checks[j] for j in sorted({int(j) for j in rows["job_id"]})])
        for e, rows in ev.groupby(list(ENTRY))
    }
