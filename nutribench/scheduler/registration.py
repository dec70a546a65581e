"""A grid's configs and job rows: load every regime and agent config it names, record
their content in the database (refusing a changed file whose version was not bumped), and
create the job rows it lacks. Used by :func:`nutribench.scheduler.driver.run_grid` before
any job runs; then :func:`spec_maker` turns each job row the driver claims into what a
worker is given (:class:`~nutribench.scheduler.worker.JobSpec`: the configs it runs with, their
hashes, its model file's path, its device). The recorder's jobs (:func:`store_external_job`)
are registered here too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import insert, select
from sqlalchemy.orm import Session

from nutribench.errors import UserError
from nutribench.scheduler.grid import Grid
from nutribench.scheduler.lifecycle import check_not_mixed, insert_job_rows
from nutribench.scheduler.worker import JobResult, JobSpec
from nutribench.store import AgentConfig, Job, RegimeConfig, session_scope, utcnow
from nutribench.store.engine import REGISTRATION_LOCK, hold_write_lock
from nutribench.store.models import METADATA_COLUMNS
from nutribench.store.schema import Store


class RunError(UserError):
    """A problem with the run a user can fix (config changed without a version bump, no
    job function). One line."""


@dataclass(frozen=True)
class _Config:
    name: str
    version: int
    sha256: str
    body: dict[str, Any]
    source: str
    obj: Any
    algo: str | None = None

    @classmethod
    def regime(cls, env: Any, name: str) -> _Config:
        """A regime config as recorded: its content and hash, its file (else ``name``) shown
        relative to the current folder."""
        return cls(env.name, env.version, env.sha256, env.content(), _shown(env.path or name), env)

    @classmethod
    def agent(cls, cfg: Any, source: str) -> _Config:
        """An agent config as recorded: its content and hash, and ``source``."""
        from nutribench.agents.config import agent_config_content, agent_config_sha256

        return cls(cfg.name, cfg.version, agent_config_sha256(cfg), agent_config_content(cfg), source, cfg, cfg.algo)


def _shown(path: Path | str) -> str:
    """A file path relative to the current folder when it lies below it."""
    p, cwd = Path(path), Path.cwd().resolve()
    return str(p.resolve().relative_to(cwd)) if p.resolve().is_relative_to(cwd) else str(p)


def load_grid_configs(grid: Grid) -> tuple[list[_Config], list[_Config]]:
    """Load every regime and agent config of the grid (ConfigError on a bad file, or on a
    plug-in whose entry point does not import)."""
    from nutribench.agents.config import load_agent_config, resolve_agent_path
    from nutribench.agents.registry import import_entry_point
    from nutribench.config import load_env_config

    regimes = [_Config.regime(load_env_config(name), name) for name in grid.regimes]

    agents = []
    for name in grid.algos:
        cfg = load_agent_config(name)
        if getattr(cfg, "entry_point", None):
            import_entry_point(cfg.entry_point)  # a plug-in that cannot import is refused before any job runs
        agents.append(_Config.agent(cfg, _shown(resolve_agent_path(name))))
    return regimes, agents


def _recorded(session: Session, table: type, name: str, version: int) -> Any:
    """The row of ``table`` (regimes or agent configs) recorded as ``name`` version ``version``, or None."""
    return session.execute(select(table).where(table.name == name, table.version == version)).scalar_one_or_none()


def _register(session: Session, table: type, configs: Sequence[_Config]) -> dict[str, int]:
    """Ids of ``configs`` in ``table``, inserting the new ones; refuses changed content."""
    ids: dict[str, int] = {}
    for c in configs:
        row = _recorded(session, table, c.name, c.version)
        if row is not None:
            if row.sha256 != c.sha256:
                raise RunError(
                    f"{c.source}: version {c.version} is already recorded with different content: bump the version"
                )
            ids[c.name] = row.id
            continue
        recorded = {key: getattr(c, key) for key in ("name", "version", "sha256", "body", "source")}
        new = table(**recorded, created_at=utcnow(), **({"algo": c.algo} if table is AgentConfig else {}))
        session.add(new)
        session.flush()
        ids[c.name] = new.id
    return ids


def register_grid(
    store: Store, grid: Grid, regimes: list[_Config], agents: list[_Config], fake: bool = False
) -> list[int]:
    """Record the configs and create the missing job rows, in one transaction; the ids of
    the grid's jobs in grid order. ``fake``: the rows are a dry run's (``jobs.fake``)."""
    with session_scope(store.engine) as s:
        hold_write_lock(s, REGISTRATION_LOCK)  # two drivers started at once: one registers, then the other
        rids = _register(s, RegimeConfig, regimes)
        aids = _register(s, AgentConfig, agents)
        budgets = {"episodes": grid.episodes, "eval_episodes": grid.eval_episodes}
        query = select(Job.id, Job.regime_id, Job.agent_config_id, Job.seed).filter_by(**budgets)
        query = query.where(Job.regime_id.in_(rids.values()), Job.agent_config_id.in_(aids.values()))
        existing = {(r.regime_id, r.agent_config_id, r.seed): r.id for r in s.execute(query)}
        keys = [(rids[r], aids[a], seed) for r, a, seed in grid.cells()]
        missing = [k for k in keys if k not in existing]
        if missing:
            new = budgets | {"status": "pending", "attempt": 0, "failures": 0, "episodes_done": 0}
            new |= {"created_at": utcnow(), "fake": fake}
            rows = [{"regime_id": r, "agent_config_id": a, "seed": seed, **new} for r, a, seed in missing]
            s.execute(insert(Job), rows)
            existing.update({(r.regime_id, r.agent_config_id, r.seed): r.id for r in s.execute(query)})
        return [existing[k] for k in keys]


def model_path(models_dir: Path, regime: _Config, agent: _Config, seed: int, episodes: int) -> Path:
    """``<models>/<regime>-v<rv>/<algo>-v<av>/seed<seed>-ep<episodes>.zip``."""
    folder = models_dir / f"{regime.name}-v{regime.version}" / f"{agent.name}-v{agent.version}"
    return folder / f"seed{seed}-ep{episodes}.zip"


def spec_maker(settings: Any, job_ids: list[int], regime_cfgs: list, agent_cfgs: list) -> Callable[[Job], JobSpec]:
    """A function from a job row of ``settings``' grid (a
    :class:`~nutribench.scheduler.settings.GridSettings`, its jobs ``job_ids`` in grid order as
    :func:`register_grid` returns them, registered from ``regime_cfgs`` and ``agent_cfgs``:
    :func:`~nutribench.scheduler.registration.load_grid_configs`)
    to its :class:`~nutribench.scheduler.worker.JobSpec`: its model file under ``settings.models``,
    trained on ``settings.device``, its TensorBoard events (if any) under ``settings.tensorboard``,
    evaluated on ``settings.val_episodes`` validation days every ``settings.eval_every`` training
    days (None or 0: never)."""
    regimes, agents = {r.name: r for r in regime_cfgs}, {a.name: a for a in agent_cfgs}
    cells = dict(zip(job_ids, settings.grid.cells()))  # job id -> (regime, agent config, seed)
    events = str(Path(settings.tensorboard).absolute()) if settings.tensorboard is not None else None
    how = {"device": settings.device, "tensorboard": events, "val_episodes": settings.val_episodes}
    how["eval_every"] = int(settings.eval_every or 0)

    def make_spec(job: Job) -> JobSpec:
        r, a = regimes[cells[job.id][0]], agents[cells[job.id][1]]
        path = str(model_path(settings.models, r, a, job.seed, job.episodes))
        ids = (job.id, r.name, r.version, r.sha256, a.name, a.version, a.sha256, job.seed, job.episodes)
        return JobSpec(*ids, job.eval_episodes, path, r.obj, a.obj, attempt=job.attempt, **how)

    return make_spec


def store_external_job(
    store: Store,
    *,
    env: Any,
    cfg: Any,
    seed: int,
    episodes: int,
    train: list[dict[str, Any]],
    evaluation: Any,
    metadata: dict[str, Any],
) -> int:
    """Record a job trained outside nutribench (:class:`nutribench.Recorder`, ``nutribench
    evaluate``): its regime ``env`` and agent ``cfg``, seed, budget ``episodes`` (its training
    rows' count, or the training days of a model trained elsewhere, a saved model's sidecar:
    then it has no ``train`` rows), its ``evaluation`` (its ``episodes`` and ``steps``) and
    ``metadata``; written as a done job with its rows, in one transaction; its id. A job with
    the same regime, agent, seed and budget already there is refused."""
    regime, agent = _Config.regime(env, env.name), _Config.agent(cfg, "recorded")
    check_not_mixed(store, fake=False)
    with session_scope(store.engine) as s:
        hold_write_lock(s, REGISTRATION_LOCK)
        rid = _register(s, RegimeConfig, [regime])[regime.name]
        aid = _register(s, AgentConfig, [agent])[agent.name]
        key = dict(
            regime_id=rid, agent_config_id=aid, seed=seed, episodes=episodes, eval_episodes=len(evaluation.episodes)
        )
        old = s.execute(select(Job.id).filter_by(**key)).scalar_one_or_none()
        if old is not None:
            raise RunError(
                f"{store.display}: {cfg.name} v{cfg.version} on {env.name} seed {seed} with {episodes} "
                f"training days is already recorded (job {old}): record another seed, or bump the agent's version"
            )
        meta = {k: metadata[k] for k in METADATA_COLUMNS if k in metadata}
        done = {"status": "done", "attempt": 1, "failures": 0, "episodes_done": episodes, "created_at": utcnow()}
        row = Job(**key, **done, fake=False, **meta)
        s.add(row)
        s.flush()
        insert_job_rows(s, JobResult(row.id, train, evaluation.episodes, evaluation.steps, metadata))
        return row.id


def check_external_entry(store: Store, env: Any, cfg: Any, seed: int, eval_episodes: int) -> None:
    """What :class:`nutribench.Recorder` checks as its ``with`` block opens, before any training:
    a database holding a dry run's jobs (:func:`~nutribench.scheduler.lifecycle.check_not_mixed`'s
    StoreError); the regime ``env`` and the agent ``cfg`` recorded with other content under the
    same version, or a job of this agent version on this regime and seed already there (whatever
    its training days): :class:`RunError` in one line naming agent, regime and seed."""
    from nutribench.agents.config import agent_config_sha256

    check_not_mixed(store, fake=False)
    what = f"Recorder {cfg.name} v{cfg.version} on {env.name} seed {seed}"
    where = store.display
    with session_scope(store.engine) as s:
        agent_row = _recorded(s, AgentConfig, cfg.name, cfg.version)
        if agent_row is not None and agent_row.sha256 != agent_config_sha256(cfg):
            raise RunError(
                f"{what}: {where} holds {cfg.name} v{cfg.version} with other params or description: "
                "bump the version (Recorder(version=...)) or give the stored ones"
            )
        regime_row = _recorded(s, RegimeConfig, env.name, env.version)
        if regime_row is not None and regime_row.sha256 != env.sha256:
            raise RunError(
                f"{what}: {where} holds regime {env.name} v{env.version} with other content: bump the regime file's version"
            )
        if agent_row is None or regime_row is None:
            return
        key = dict(regime_id=regime_row.id, agent_config_id=agent_row.id, seed=seed, eval_episodes=eval_episodes)
        old = s.execute(select(Job.id, Job.episodes).filter_by(**key)).first()
        if old is not None:
            raise RunError(
                f"{what}: already recorded in {where} (job {old.id}, {old.episodes} training days): "
                "record another seed, or bump the agent's version"
            )
