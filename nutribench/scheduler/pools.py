"""How ``nutribench run`` groups jobs for the workers: one by one (the SB3 engine), or, with
``--engine batched``, the jobs of each agent config in batches, one batch per worker; and the
driver's side of resuming stopped batches, through the batched engine's checkpoints folder,
``<models>/checkpoints/`` (the checkpoint files themselves: :mod:`nutribench.engine.checkpoint`).

A batch writes ``<checkpoint>.jobs.json`` (its jobs: id, agent config and regime hashes,
seed, budget) beside its checkpoint, and deletes both when it ends
(:mod:`nutribench.scheduler.batched_job`). The next run claims the jobs of each such manifest
as one batch before it forms new ones (:func:`checkpointed_first`), so that the batch resumes
from its checkpoint. A batch that was killed and whose jobs were then finished otherwise (by
the SB3 engine, by batches formed differently, by another driver) would leave them behind
for good: nothing resumes them. :func:`remove_finished_checkpoints` deletes each such
manifest and its checkpoint once every job it names is done in the database. A manifest
naming a job this database does not hold as named (another database sharing the models
folder) is left alone, as is one that cannot be read.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.exc import SQLAlchemyError

from nutribench.engines import TRAINING_ENGINES, Engine
from nutribench.scheduler.registration import RunError
from nutribench.store import AgentConfig, Job, RegimeConfig
from nutribench.store.schema import Store

#: at most this many jobs in one batch (the paper grid's 7 regimes x 5 seeds of one config)
MAX_BATCH = 35


def check_engine(engine: str, max_batch: int, device: str = "auto") -> None:
    """Refuse an unknown ``--engine``, a ``--batch-size`` below 1, or a ``--device`` the
    engine cannot train on, in one line. The SB3 engine trains on the CPU (its models are
    built there), so it takes ``auto`` (= the CPU) and ``cpu`` only; the batched engine takes
    any device :func:`~nutribench.engine.device.check_device` accepts here (CUDA only where
    this machine has it: a dask cluster whose driver has no GPU runs its GPUs with ``auto``)."""
    if engine not in TRAINING_ENGINES:  # a job per worker (the reference), or batches per agent config
        raise RunError(f"--engine {engine!r}: use {' or '.join(TRAINING_ENGINES)}")
    if max_batch < 1:
        raise RunError(f"--batch-size {max_batch}: use a positive number of jobs")
    if engine == Engine.SB3:
        if str(device).strip().lower() not in ("auto", "cpu"):
            raise RunError(
                f"--device {device}: the SB3 engine trains on the CPU; use --device cpu or auto, or --engine batched"
            )
        return
    from nutribench.engine.device import check_device

    check_device(device)


@dataclass
class Pool:
    """Jobs claimed and started together: one by one (the SB3 engine), or, for the batched
    engine, up to ``batch_size`` jobs of one agent config per worker."""

    job_ids: list[int]
    batched: bool = False
    batch_size: int = 1


def batch_pools(
    job_ids: list[int],
    cells: list[tuple[str, str, int]],
    algo_of: dict[str, str],
    shape_of: dict[str, tuple[int, int]],
    claimable: Callable[[list[int]], int],
    slots: int,
    max_batch: int = MAX_BATCH,
) -> list[Pool]:
    """``--engine batched``: a pool per agent config the batched engine trains and per regime
    shape (horizon, number of foods: one batch steps its agents in lockstep on one observation
    size), its batches sized so that the runnable jobs fill the slots (at most ``max_batch``:
    a batch's jobs are stored when the whole batch ends, so a stopped run loses the work of
    its unfinished batches); the other configs' jobs one by one, with the SB3 engine: those of
    other algorithms, and those with a setting the batched engine does not implement
    (:func:`nutribench.engine.supports`, the config read again by its name), so that
    ``--engine batched`` never trains a job otherwise than the reference would."""
    from nutribench.agents.config import load_agent_config
    from nutribench.agents.registry import batched_names
    from nutribench.engine import supports

    @functools.cache
    def batched(config: str, horizon: int) -> bool:
        return algo_of[config] in batched_names() and supports(load_agent_config(config), horizon) is None

    groups: dict[tuple, list[int]] = {}
    singles: list[int] = []
    for job_id, (regime, config, _) in zip(job_ids, cells):
        if batched(config, shape_of[regime][0]):
            groups.setdefault((config, shape_of[regime]), []).append(job_id)
        else:
            singles.append(job_id)
    pools = [Pool(ids, True, max(1, min(max_batch, -(-claimable(ids) // max(slots, 1))))) for ids in groups.values()]
    return pools + [Pool(singles)]


MANIFEST_SUFFIX = ".jobs.json"


def read_manifests(folder: Path) -> dict[Path, list[dict[str, Any]]]:
    """The jobs each batch manifest in ``folder`` names, by manifest: ``{"job_id": ..., ...what
    it is}`` (a manifest of an older nutribench lists job ids only: ``{"job_id": ...}``). A
    manifest that cannot be read, or names a job id that is not an integer, is left out; a
    folder that cannot be listed raises OSError."""
    manifests = {}
    for path in sorted(folder.glob(f"*{MANIFEST_SUFFIX}")) if folder.is_dir() else []:
        with suppress(OSError, ValueError, KeyError, TypeError, AttributeError):
            data = json.loads(path.read_text())
            listed = data.get("jobs")
            jobs = [dict(j) for j in listed] if isinstance(listed, list) else [{"job_id": i} for i in data["job_ids"]]
            if all(type(j.get("job_id")) is int for j in jobs):  # JSON's integers (not true or 3.0)
                manifests[path] = jobs
    return manifests


def _done(job: dict[str, Any], row: Any, prefix: str) -> bool:
    """Whether the manifest's ``job`` is ``row`` (the same job, not a namesake id of another
    database) and it is done."""
    if row is None or row.status != "done":
        return False
    if "algo_sha256" not in job:  # an older manifest: the file name's agent config must match
        return prefix.startswith(f"{row.name}-v{row.version}-")
    return all(job.get(key) == getattr(row, key) for key in ("algo_sha256", "regime_sha256", "seed", "episodes"))


def remove_finished_checkpoints(store: Store, folder: Path) -> list[Path]:
    """Delete the batch manifests in ``folder`` every job of which is done in ``store``, and
    their checkpoints (see the module docstring). Returns the manifests deleted. Never
    raises for a folder or a database it cannot read: housekeeping waits for the next run."""
    try:
        manifests = read_manifests(folder)
    except OSError:
        return []
    ids = sorted({j["job_id"] for jobs in manifests.values() for j in jobs})
    if not ids:
        return []
    columns = (Job.id, Job.status, Job.seed, Job.episodes, AgentConfig.name, AgentConfig.version)
    hashes = (AgentConfig.sha256.label("algo_sha256"), RegimeConfig.sha256.label("regime_sha256"))
    query = select(*columns, *hashes).join(AgentConfig, Job.agent_config_id == AgentConfig.id)
    query = query.join(RegimeConfig, Job.regime_id == RegimeConfig.id).where(Job.id.in_(ids))
    try:
        with store.engine.connect() as conn:
            rows = {row.id: row for row in conn.execute(query)}
    except SQLAlchemyError:
        return []
    removed = []
    for path, jobs in manifests.items():
        prefix = path.name[: -len(MANIFEST_SUFFIX)]
        if not jobs or not all(_done(j, rows.get(j["job_id"]), prefix) for j in jobs):
            continue
        from nutribench.engine.checkpoint import checkpoint_files  # torch: only when there is something to delete

        with suppress(OSError):  # a file it cannot delete: the manifest stays, for the next run
            for file in [*checkpoint_files(path.with_name(prefix)), path]:
                file.unlink(missing_ok=True)
            removed.append(path)
    return removed


def checkpointed_first(pools: list[Pool], folder: Path) -> list[Pool]:
    """``pools`` with, first, one pool per batch that left a checkpoint in ``folder``
    (``*.jobs.json``: its job ids), taken out of the pool that held its jobs: the next run
    claims the same batch again and it resumes from its checkpoint. A batch whose jobs are
    no longer all in one pool (another grid, or some were done since) is left alone."""
    first: list[Pool] = []
    for jobs in read_manifests(folder).values():
        ids = [j["job_id"] for j in jobs]
        for pool in pools:
            if pool.batched and ids and set(ids) <= set(pool.job_ids):
                pool.job_ids = [i for i in pool.job_ids if i not in set(ids)]
                first.append(Pool(ids, True, len(ids)))
                break
    return first + pools
