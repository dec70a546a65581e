"""A batched engine's batch digest (:func:`nutribench.scheduler.batched_job.batch_digest`, the
name of a batch's checkpoint): the same for the same batch, another for another commit,
nutribench version, evaluation or set of jobs (``reports/ladder/rename_checkpoints.py``, a
finished study's script, renames checkpoints by it)."""

from __future__ import annotations

from nutribench.scheduler.batched_job import batch_digest

JOBS = [
    {"job_id": i, "algo_sha256": "a" * 64, "regime_sha256": r * 64, "seed": s, "episodes": 5000}
    for i, (r, s) in enumerate([("b", 3800), ("b", 3801), ("c", 3800)], start=1)
]


def test_the_digest_covers_commit_version_and_evaluation():
    base = batch_digest("c1", JOBS, 100, 5)
    assert len(base) == 16 and base == batch_digest("c1", JOBS, 100, 5)
    others = {batch_digest("c2", JOBS, 100, 5), batch_digest("c1", JOBS, 100, 5, "0.0.0+unknown")}
    others |= {batch_digest("c1", JOBS, None, 5), batch_digest("c1", JOBS[:2], 100, 5)}
    assert base not in others and len(others) == 4
