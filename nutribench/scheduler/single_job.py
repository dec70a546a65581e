"""The real job: train one agent on one regime with one seed, evaluate it, save the model.

Runs in a worker process; never touches the database. Progress goes to ``sink`` (see
:mod:`nutribench.scheduler.worker`); the result is a :class:`~nutribench.scheduler.worker.JobResult`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from nutribench.agents.api import eval_food_streams, evaluate, train, validation_food_streams
from nutribench.agents.config import agent_config_sha256
from nutribench.agents.registry import entry_point_source
from nutribench.baselines import day_yardsticks
from nutribench.clock import utcnow
from nutribench.engines import Engine
from nutribench.provenance import collect_metadata
from nutribench.scheduler.worker import JobFailed, JobProgress, JobResult, JobSpec, Sink


def check_configs(spec: JobSpec) -> None:
    """The configs a job carries must still hash to what the driver recorded."""
    if spec.regime_config.sha256 != spec.regime_sha256:
        raise JobFailed(f"{spec.label}: regime content changed since the job was recorded")
    if agent_config_sha256(spec.agent_config) != spec.algo_sha256:
        raise JobFailed(f"{spec.label}: agent config content changed since the job was recorded")


def with_yardsticks(spec: JobSpec, validation: list[dict]) -> list[dict]:
    """A job's validation rows, each with the ``never`` and ``planner`` returns on its day (the
    yardsticks of its share of the gap), as stored in ``validation_episodes``."""
    if not validation:
        return []
    days = day_yardsticks(spec.regime_config, validation_food_streams(spec.regime_config, spec.seed, spec.val_episodes))
    return [row | {key: days[row["episode"]][key] for key in ("never", "planner")} for row in validation]


def run_job(spec: JobSpec, sink: Sink | None = None) -> JobResult:
    """Train ``spec.agent_config`` on ``spec.regime_config`` for ``spec.episodes`` days with
    ``spec.seed``, then evaluate greedily on ``spec.eval_episodes`` days drawn from the seed
    (the same days for every algorithm), and save the model to ``spec.model_path``; every
    ``spec.eval_every`` training days, a greedy evaluation on the validation days. The
    result carries the training diagnostics (one row per update), also written as
    TensorBoard events under ``spec.tensorboard`` when it is set."""
    check_configs(spec)
    started, t0 = utcnow(), time.perf_counter()
    progress = JobProgress(spec, sink)
    progress.start()
    agent = train(
        spec.regime_config,
        spec.agent_config,
        seed=spec.seed,
        episodes=spec.episodes,
        on_episode=lambda row: progress.episode(row["episode"] + 1, row["return"]),
        tensorboard=Path(spec.tensorboard) / spec.run_name if spec.tensorboard else None,
        eval_every=getattr(spec, "eval_every", 0),
        val_episodes=getattr(spec, "val_episodes", 5),
    )
    progress.phase("eval")

    def metadata() -> dict:
        meta = collect_metadata() | {"started_at": started, "finished_at": utcnow()}
        meta |= {"wall_seconds": time.perf_counter() - t0, "engine": Engine.SB3.value, "device": "cpu"}
        if getattr(spec.agent_config, "entry_point", None):  # a plug-in: trained by its own code, in this harness
            meta["engine"] = Engine.EXTERNAL.value
            meta["source"], meta["source_sha256"] = entry_point_source(spec.agent_config.entry_point)
        return meta

    return finished_result(spec, agent, metadata)


def finished_result(spec: JobSpec, agent: Any, metadata: Callable[[], dict]) -> JobResult:
    """The result of ``spec``'s job, its ``agent`` trained: evaluated greedily on
    ``spec.eval_episodes`` days drawn from the seed (the same days for every algorithm), saved
    to ``spec.model_path``, with its training diagnostics, its validation days (with their
    yardsticks) and ``metadata()`` (called once it is evaluated and saved)."""
    streams = eval_food_streams(spec.regime_config, spec.seed, spec.eval_episodes)
    evaluation = evaluate(agent, spec.regime_config, streams, record_steps=True)
    model_path = str(agent.save(Path(spec.model_path))) if spec.model_path else None
    return JobResult(
        spec.job_id,
        agent.train_episodes,
        evaluation.episodes,
        evaluation.steps,
        metadata(),
        model_path=model_path,
        diagnostics=list(getattr(agent, "diagnostics", None) or []),
        validation=with_yardsticks(spec, agent.validation),
    )
