"""The worker side of a batch: several jobs of one agent config trained at once by the
batched engine (:mod:`nutribench.engine`), each then evaluated, saved and returned as the
single-job worker does (:func:`nutribench.jobs.run.run_job`), with ``engine = "batched"``.

A batch that raises fails all its jobs (the driver records each failure; the next run
retries them). Progress is reported per job, as for single jobs.
"""

from __future__ import annotations

import time
from pathlib import Path

from nutribench.agents import eval_food_streams, evaluate
from nutribench.clock import utcnow
from nutribench.engine.train import train_batched
from nutribench.jobs.run import check_configs
from nutribench.jobs.spec import JobFailed, JobResult, JobSpec
from nutribench.jobs.worker import JobProgress, Sink
from nutribench.provenance import collect_metadata

def run_batch(specs: list[JobSpec], sink: Sink | None = None) -> list[JobResult]:
    """Train the jobs ``specs`` (one agent config, one budget) at once; one result per job."""
    for spec in specs:
        check_configs(spec)
    if len({(s.algo, s.algo_version, s.episodes) for s in specs}) != 1:
        raise JobFailed("a batch needs one agent config and one budget")
    started, t0 = utcnow(), time.perf_counter()
    progress = [JobProgress(spec, sink) for spec in specs]
    for p in progress:
        p.start()
    agents = train_batched(
        [(s.regime_config, s.seed) for s in specs], specs[0].agent_config, specs[0].episodes,
        on_episode=lambda j, row: progress[j].episode(row["episode"] + 1, row["return"]),
    )  # fmt: skip
    train_wall = time.perf_counter() - t0
    meta = collect_metadata()
    results = []
    for spec, agent, p in zip(specs, agents, progress):
        p.phase("eval")
        t_eval = time.perf_counter()
        streams = eval_food_streams(spec.regime_config, spec.seed, spec.eval_episodes)
        evaluation = evaluate(agent, spec.regime_config, streams, record_steps=True)
        model_path = str(agent.save(Path(spec.model_path))) if spec.model_path else None
        # the batch's training time shared out, plus this job's own evaluation
        wall = train_wall / len(specs) + time.perf_counter() - t_eval
        results.append(JobResult(spec.job_id, agent.train_episodes, evaluation.episodes, evaluation.steps,
                                 meta | {"started_at": started, "finished_at": utcnow(), "wall_seconds": wall, "engine": "batched"},
                                 model_path=model_path))  # fmt: skip
    return results
