"""From job rows to job specs: what a worker is given for each job a driver claims (the
configs it runs with, their hashes, its model file's path, its device)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

from sqlalchemy import select

from nutribench.jobs.spec import JobSpec
from nutribench.scheduler.grid import Grid
from nutribench.scheduler.registration import model_path
from nutribench.store import AgentConfig, Job, RegimeConfig
from nutribench.store.schema import Store


def spec_maker(
    store: Store,
    grid: Grid,
    regime_cfgs: Sequence,
    agent_cfgs: Sequence,
    models_dir: Path,
    device: str,
    tensorboard: str | os.PathLike[str] | None,
    eval_every: int = 0,
    val_episodes: int = 5,
) -> Callable[[Job], JobSpec]:
    """A function from a job row of ``grid`` (registered in ``store`` from ``regime_cfgs`` and
    ``agent_cfgs``: :func:`~nutribench.scheduler.registration.load_grid_configs`) to its
    :class:`~nutribench.jobs.spec.JobSpec`: its model file under ``models_dir``, trained on
    ``device``, its TensorBoard events (if any) under ``tensorboard``, evaluated on
    ``val_episodes`` validation days every ``eval_every`` training days (0: never)."""
    regimes, agents = {r.name: r for r in regime_cfgs}, {a.name: a for a in agent_cfgs}
    with store.engine.connect() as conn:
        rid = dict(
            conn.execute(select(RegimeConfig.id, RegimeConfig.name).where(RegimeConfig.name.in_(grid.regimes))).all()
        )
        aid = dict(conn.execute(select(AgentConfig.id, AgentConfig.name).where(AgentConfig.name.in_(grid.algos))).all())
    events = str(Path(tensorboard).absolute()) if tensorboard is not None else None

    def make_spec(job: Job) -> JobSpec:
        r, a = regimes[rid[job.regime_id]], agents[aid[job.agent_config_id]]
        path = model_path(models_dir, r, a, job.seed, job.episodes)
        return JobSpec(
            job.id,
            r.name,
            r.version,
            r.sha256,
            a.name,
            a.version,
            a.sha256,
            job.seed,
            job.episodes,
            job.eval_episodes,
            str(path),
            r.obj,
            a.obj,
            attempt=job.attempt,
            device=device,
            tensorboard=events,
            eval_every=int(eval_every or 0),
            val_episodes=val_episodes,
        )

    return make_spec
