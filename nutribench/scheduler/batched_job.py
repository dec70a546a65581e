"""The worker side of a batch: several jobs of one agent config trained at once by the
batched engine (:mod:`nutribench.engine`), each then evaluated, saved and returned as the
single-job worker does (:func:`nutribench.scheduler.single_job.run_job`), with ``engine = "batched"``.

A batch that raises fails all its jobs (the driver records each failure; the next run
retries them). Progress is reported per job, as for single jobs. Each job's result records
its batch: ``batch_id`` (one random id per batch run), ``batch_size`` (K) and ``device``
(the torch device it trained on), since a batched job's numbers depend on both by float
rounding. Each result carries its agent's training diagnostics (``agent.diagnostics``, one
row per update, where the engine records them), written as TensorBoard events under
``spec.tensorboard`` too when it is set (:func:`write_tensorboard`).

A batch saves its training state every few minutes (``$NUTRIBENCH_CHECKPOINT_SECONDS``,
default 300) to ``<models>/checkpoints/`` (see
:mod:`nutribench.engine.checkpoint`); a stopped batch started again by the next ``nutribench
run`` resumes from there. The file's name says what the batch is (agent config, budget,
regimes and seeds, code version), so another batch or another code version never reads it;
it is deleted once the batch's jobs are evaluated and handed to the driver. Beside it,
``<checkpoint>.jobs.json`` lists the batch's job ids (and what each job is): the scheduler
claims those jobs as one batch again before it forms new ones. A finished batch also deletes
the checkpoints that other batches left of any of its jobs (a batch killed and then formed
otherwise, or by another code version, whose name differs): those jobs are done, and such a
checkpoint could never be resumed.
"""

from __future__ import annotations

import hashlib
import json
import time
import uuid
from datetime import datetime
from pathlib import Path
from typing import Any

from nutribench.clock import utcnow
from nutribench.engine import supports
from nutribench.engine.checkpoint import Checkpoint, checkpoint_files
from nutribench.engine.device import resolve_device
from nutribench.engine.train import train_batched
from nutribench.engines import Engine
from nutribench.provenance import collect_metadata, git_state
from nutribench.safe_write import atomic_write
from nutribench.scheduler.single_job import check_configs, finished_result
from nutribench.scheduler.worker import JobFailed, JobProgress, JobResult, JobSpec, Sink


def run_batch(specs: list[JobSpec], sink: Sink | None = None) -> list[JobResult]:
    """Train the jobs ``specs`` (one agent config, one budget) at once; one result per job."""
    check_batch(specs)
    device = resolve_device(specs[0].device)
    # what a batched job's result depends on by float rounding, stored with each job (jobs.batch_*, jobs.device)
    batch = {"batch_id": uuid.uuid4().hex, "batch_size": len(specs), "device": str(device)}
    started, t0 = utcnow(), time.perf_counter()
    specs = sorted(specs, key=lambda s: s.job_id)  # one agent order for the batch, whatever the claim's
    path = checkpoint_path(specs)
    checkpoint = Checkpoint(path, device=device) if path is not None else None
    if path is not None:
        write_manifest(path, specs)

    def wall() -> float:
        """Training seconds of the batch so far, those before a resume included."""
        return time.perf_counter() - t0 + (checkpoint.seconds_before if checkpoint is not None else 0.0)

    # each job's progress is priced by its share of the batch's training seconds
    progress = [JobProgress(spec, sink, wall=lambda: wall() / len(specs)) for spec in specs]
    for p in progress:
        p.start()
    agents = train_batched(
        [(s.regime_config, s.seed) for s in specs],
        specs[0].agent_config,
        specs[0].episodes,
        on_episode=lambda j, row: progress[j].episode(row["episode"] + 1, row["return"]),
        checkpoint=checkpoint,
        device=device,
        eval_every=specs[0].eval_every,
        val_episodes=specs[0].val_episodes,
    )
    share = wall() / len(specs)
    meta = collect_metadata() | batch | {"engine": Engine.BATCHED.value}
    results = []
    for spec, agent, p in zip(specs, agents, progress):
        p.phase("eval")
        results.append(job_result(spec, agent, meta, started, share))
    if path is not None:
        checkpoint.remove()
        manifest(path).unlink(missing_ok=True)
        remove_abandoned(path.parent, specs)
    return results


def check_batch(specs: list[JobSpec]) -> None:
    """:class:`JobFailed` unless ``specs`` are one batch the batched engine trains: valid
    configs, one agent config, budget, device and evaluation period, each supported."""
    for spec in specs:
        check_configs(spec)
    if len({(s.algo, s.algo_version, s.episodes, s.device, s.eval_every, s.val_episodes) for s in specs}) != 1:
        raise JobFailed("a batch needs one agent config, one budget, one device and one evaluation period")
    for spec in specs:  # the scheduler sends such configs to the SB3 engine; never train them otherwise
        reason = supports(spec.agent_config, spec.regime_config.reward.horizon)
        if reason is not None:
            raise JobFailed(reason)


def job_result(spec: JobSpec, agent: Any, meta: dict, started: datetime, train_share: float) -> JobResult:
    """One trained job of a batch (started at ``started``) evaluated, saved (and its
    diagnostics written to TensorBoard when asked): its result, its wall time the batch's
    training seconds shared out (``train_share``) plus its own evaluation."""
    t_eval = time.perf_counter()

    def metadata() -> dict:
        wall = train_share + time.perf_counter() - t_eval
        return meta | {"started_at": started, "finished_at": utcnow(), "wall_seconds": wall}

    result = finished_result(spec, agent, metadata)
    if spec.tensorboard:
        write_tensorboard(Path(spec.tensorboard) / spec.run_name, result.diagnostics)
    return result


def write_tensorboard(folder: Path, rows: list[dict]) -> None:
    """``rows`` (training diagnostics) as TensorBoard events in ``folder``: each quantity as
    the scalar ``diagnostics/<name>`` at the row's env step, as the SB3 engine writes them (a
    plug-in algorithm's own names after the vocabulary's)."""
    from nutribench.agents.training_log import tensorboard_folder
    from nutribench.diagnostics import QUANTITIES, TIMESTEP, UPDATE

    log_dir = tensorboard_folder(folder)  # made, as the SB3 engine makes it; a clear error without tensorboard
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(log_dir=log_dir)
    try:
        for row in rows:
            other = sorted(set(row) - {UPDATE, TIMESTEP, *QUANTITIES})
            for name in (*QUANTITIES, *other):
                if row.get(name) is not None:
                    writer.add_scalar(f"diagnostics/{name}", float(row[name]), int(row[TIMESTEP]))
    finally:
        writer.close()


def manifest(path: Path) -> Path:
    """``<checkpoint>.jobs.json``: the job ids of the batch, so that the next run claims the
    same batch and it resumes (:func:`nutribench.scheduler.pools.checkpointed_first`)."""
    return path.with_name(path.name + ".jobs.json")


def _job(spec: JobSpec) -> dict[str, object]:
    """What a manifest records of one job: its id and what it is."""
    return {key: getattr(spec, key) for key in ("job_id", "algo_sha256", "regime_sha256", "seed", "episodes")}


def write_manifest(path: Path, specs: list[JobSpec]) -> None:
    """Write :func:`manifest` of the batch ``specs`` (to a temporary name, then renamed)."""
    with atomic_write(manifest(path), "checkpoint manifest") as tmp:
        tmp.write_text(json.dumps({"job_ids": [s.job_id for s in specs], "jobs": [_job(s) for s in specs]}))


def remove_abandoned(folder: Path, specs: list[JobSpec]) -> list[Path]:
    """Delete the manifests in ``folder`` that name one of the (now finished) jobs ``specs``,
    and their checkpoints: batches killed earlier whose jobs are done now. A job counts by
    its id and what it is (agent config, regime, seed, budget); a manifest of an older
    nutribench (job ids only) by its ids and the file name's agent config. Returns the
    manifests deleted."""
    from nutribench.scheduler.pools import MANIFEST_SUFFIX, read_manifests  # read as the driver reads them

    mine, ids = [_job(s) for s in specs], {s.job_id for s in specs}
    prefix = f"{specs[0].algo}-v{specs[0].algo_version}-"
    removed = []
    for path, jobs in read_manifests(folder).items():
        older = path.name.startswith(prefix) and any("algo_sha256" not in j and j["job_id"] in ids for j in jobs)
        if older or any(j in mine for j in jobs):
            for p in checkpoint_files(path.with_name(path.name[: -len(MANIFEST_SUFFIX)])):
                p.unlink(missing_ok=True)
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def checkpoint_path(specs: list[JobSpec]) -> Path | None:
    """``<models>/checkpoints/<config>-v<version>-<digest>.pt`` for the batch of ``specs``
    (None without a models folder); the digest covers the agent config's hash, the budget,
    each job's regime hash and seed, and the code version."""
    if not specs[0].model_path:
        return None
    digest = batch_digest(git_state()[0], [_job(s) for s in specs], specs[0].eval_every, specs[0].val_episodes)
    models = Path(specs[0].model_path).parents[2]
    return models / "checkpoints" / f"{specs[0].algo}-v{specs[0].algo_version}-{digest}.pt"


def batch_digest(
    commit: str | None, jobs: list[dict], eval_every: int | None, val_episodes: int, version: str | None = None
) -> str:
    """The 16 hex digits of a checkpoint's name: the nutribench ``version`` (default: this
    one's), the code ``commit``, and what the batch is (``jobs`` as a manifest lists them,
    :func:`_job`; the evaluation period)."""
    import nutribench

    first, regimes = jobs[0], [(j["regime_sha256"], j["seed"]) for j in jobs]
    what = [version or nutribench.__version__, commit, first["algo_sha256"], first["episodes"], regimes]
    if eval_every:  # evaluated during training: another checkpoint (names without it unchanged)
        what.append([eval_every, val_episodes])
    return hashlib.sha256(json.dumps(what).encode()).hexdigest()[:16]
