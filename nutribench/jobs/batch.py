"""The worker side of a batch: several jobs of one agent config trained at once by the
batched engine (:mod:`nutribench.engine`), each then evaluated, saved and returned as the
single-job worker does (:func:`nutribench.jobs.run.run_job`), with ``engine = "batched"``.

A batch that raises fails all its jobs (the driver records each failure; the next run
retries them). Progress is reported per job, as for single jobs. Each job's result records
its batch: ``batch_id`` (one random id per batch run), ``batch_size`` (K) and ``device``
(the torch device it trained on), since a batched job's numbers depend on both by float
rounding.

A batch saves its training state every few minutes to ``<models>/checkpoints/`` (see
:mod:`nutribench.engine.checkpoint`); a stopped batch started again by the next ``nutribench
run`` resumes from there. The file's name says what the batch is (agent config, budget,
regimes and seeds, code version), so another batch or another code version never reads it;
it is deleted once the batch's jobs are evaluated and handed to the driver. Beside it,
``<checkpoint>.jobs.json`` lists the batch's job ids: the scheduler claims those jobs as one
batch again before it forms new ones.
"""

from __future__ import annotations

import hashlib
import json
import time
import uuid
from pathlib import Path

from nutribench.agents import eval_food_streams, evaluate
from nutribench.clock import utcnow
from nutribench.engine import supports
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.device import resolve_device
from nutribench.engine.train import train_batched
from nutribench.jobs.run import check_configs
from nutribench.jobs.spec import JobFailed, JobResult, JobSpec
from nutribench.jobs.worker import JobProgress, Sink
from nutribench.provenance import collect_metadata, git_state


def run_batch(specs: list[JobSpec], sink: Sink | None = None) -> list[JobResult]:
    """Train the jobs ``specs`` (one agent config, one budget) at once; one result per job."""
    for spec in specs:
        check_configs(spec)
    if len({(s.algo, s.algo_version, s.episodes, s.device) for s in specs}) != 1:
        raise JobFailed("a batch needs one agent config, one budget and one device")
    for spec in specs:  # the scheduler sends such configs to the SB3 engine; never train them otherwise
        reason = supports(spec.agent_config, spec.regime_config.reward.horizon)
        if reason is not None:
            raise JobFailed(reason)
    device = resolve_device(specs[0].device)
    # what a batched job's result depends on by float rounding, stored with each job (jobs.batch_*, jobs.device)
    batch = {"batch_id": uuid.uuid4().hex, "batch_size": len(specs), "device": str(device)}
    started, t0 = utcnow(), time.perf_counter()
    progress = [JobProgress(spec, sink) for spec in specs]
    for p in progress:
        p.start()
    specs = sorted(specs, key=lambda s: s.job_id)  # one agent order for the batch, whatever the claim's
    path = checkpoint_path(specs)
    checkpoint = None
    if path is not None:
        checkpoint = Checkpoint(path, device=device)
        path.parent.mkdir(parents=True, exist_ok=True)
        manifest(path).write_text(json.dumps({"job_ids": [s.job_id for s in specs]}))
    agents = train_batched(
        [(s.regime_config, s.seed) for s in specs], specs[0].agent_config, specs[0].episodes,
        on_episode=lambda j, row: progress[j].episode(row["episode"] + 1, row["return"]), checkpoint=checkpoint,
        device=device,
    )  # fmt: skip
    train_wall = time.perf_counter() - t0 + (checkpoint.seconds_before if checkpoint is not None else 0.0)
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
                                 meta | batch | {"started_at": started, "finished_at": utcnow(), "wall_seconds": wall, "engine": "batched"},
                                 model_path=model_path))  # fmt: skip
    if path is not None:
        checkpoint.remove()
        manifest(path).unlink(missing_ok=True)
    return results


def manifest(path: Path) -> Path:
    """``<checkpoint>.jobs.json``: the job ids of the batch, so that the next run claims the
    same batch and it resumes (:func:`nutribench.scheduler.batching.checkpointed_first`)."""
    return path.with_name(path.name + ".jobs.json")


def checkpoint_path(specs: list[JobSpec]) -> Path | None:
    """``<models>/checkpoints/<config>-v<version>-<digest>.pt`` for the batch of ``specs``
    (None without a models folder); the digest covers the agent config's hash, the budget,
    each job's regime hash and seed, and the code version."""
    if not specs[0].model_path:
        return None
    import nutribench

    what = [nutribench.__version__, git_state()[0], specs[0].algo_sha256, specs[0].episodes,
            [(s.regime_sha256, s.seed) for s in specs]]  # fmt: skip
    digest = hashlib.sha256(json.dumps(what).encode()).hexdigest()[:16]
    models = Path(specs[0].model_path).parents[2]
    return models / "checkpoints" / f"{specs[0].algo}-v{specs[0].algo_version}-{digest}.pt"
