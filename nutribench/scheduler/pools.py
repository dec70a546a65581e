"""How ``nutribench run`` groups jobs for the workers: one by one (the SB3 engine), or, with
``--engine batched``, the jobs of each agent config in batches, one batch per worker."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

from nutribench.engines import TRAINING_ENGINES, Engine
from nutribench.scheduler.registration import RunError

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
