"""The synthetic job: a stand-in for training that the scheduler runs like a real job, with
no torch and no training. Production code uses it for dry runs (``NUTRIBENCH_JOB=fake
nutribench run ...``: the rows are marked ``fake`` and never count as results) and for
``python benchmarks/status.py``'s synthetic paper-grid database; the scheduler's and the store's
tests use it to run grids in seconds.

It sleeps ``$NUTRIBENCH_FAKE_SECONDS`` (default 0.001) per training episode and makes
deterministic metrics from the seed; ``$NUTRIBENCH_FAKE_LOG``, a folder, gets a file per
execution (to count runs). ``before_episode`` is called before each training episode: the
tests' fault jobs (``tests/fake_jobs.py``) fail or kill their process there; nothing here does.
"""

from __future__ import annotations

import os
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np

from nutribench import HORIZON
from nutribench.clock import utcnow
from nutribench.engines import Engine
from nutribench.provenance import collect_metadata
from nutribench.safe_write import atomic_write
from nutribench.scheduler.worker import JobProgress, JobResult, JobSpec, Sink

#: Called with a job's spec and the training episode about to run (0-based)
EpisodeHook = Callable[[JobSpec, int], None]


def _metrics(rng: np.random.Generator, k: int) -> dict:
    return {
        "episode": k,
        "return": float(rng.normal(-5.0 + 0.01 * k, 1.0)),
        "foods": int(rng.integers(0, 10)),
        "final_distance": float(rng.uniform(0, 3)),
        "overshoot_ratio": float(rng.uniform(0, 1)),
        "final_C": float(rng.uniform(0, 2)),
        "final_F": float(rng.uniform(0, 2)),
        "final_P": float(rng.uniform(0, 2)),
        "first_overshoot_step": int(rng.integers(1, HORIZON + 1)) if rng.random() < 0.5 else None,
        "entropy": float(rng.uniform(0, 0.7)),
    }


def synthetic_job(
    spec: JobSpec, progress: Sink | None = None, before_episode: EpisodeHook | None = None, seconds: float | None = None
) -> JobResult:
    """One job's synthetic result: ``spec.episodes`` training rows, ``spec.eval_episodes``
    evaluation episodes of HORIZON steps, and a placeholder model file at ``spec.model_path``;
    ``before_episode(spec, k)`` before training episode ``k``; ``seconds`` per training episode
    (None: ``$NUTRIBENCH_FAKE_SECONDS``)."""
    started, t0 = utcnow(), time.perf_counter()
    log = os.environ.get("NUTRIBENCH_FAKE_LOG")
    if log:
        (Path(log) / f"job{spec.job_id}-pid{os.getpid()}-{uuid.uuid4().hex[:8]}").touch()
    if seconds is None:
        seconds = float(os.environ.get("NUTRIBENCH_FAKE_SECONDS", "0.001"))
    rng = np.random.default_rng([spec.seed, spec.job_id])
    reporter = JobProgress(spec, progress, interval=0.2)
    reporter.start()
    train = []
    for k in range(spec.episodes):
        if before_episode is not None:
            before_episode(spec, k)
        time.sleep(seconds)
        train.append(_metrics(rng, k))
        reporter.episode(k + 1, train[-1]["return"])
    evals, steps = [], []
    for e in range(spec.eval_episodes):
        evals.append(_metrics(rng, e))
        s = np.cumsum(rng.uniform(0, 0.05, size=(HORIZON, 3)), axis=0)
        for t in range(HORIZON):  # the draws in this order: food, action, reward
            step = {"episode": e, "step": t + 1, "food": int(rng.integers(0, 10)), "action": int(rng.integers(0, 2))}
            steps.append(step | dict(zip("CFP", map(float, s[t]))) | {"reward": float(rng.normal())})
    with atomic_write(spec.model_path, "model file") as tmp:
        tmp.write_text("fake model\n")
    meta = collect_metadata() | {"started_at": started, "finished_at": utcnow()}
    meta["wall_seconds"] = time.perf_counter() - t0
    return JobResult(spec.job_id, train, evals, steps, meta, model_path=spec.model_path)


synthetic_job.fake = True  # type: ignore[attr-defined]  # the driver marks its jobs as a dry run's


def synthetic_batch(
    specs: list[JobSpec], progress: Sink | None = None, before_episode: EpisodeHook | None = None
) -> list[JobResult]:
    """The synthetic job for each spec of a batch, in turn (the scheduler's batching, tested
    without training); an exception of ``before_episode`` on any of them fails the whole batch."""
    results = [synthetic_job(spec, progress, before_episode) for spec in specs]
    for r in results:
        r.metadata["engine"] = Engine.BATCHED.value
    return results


synthetic_batch.fake = True  # type: ignore[attr-defined]
