"""The driver of ``nutribench run``: the only process that writes the results database.

One call of :func:`run_grid`:

1. opens (creates, upgrades) the database;
2. records the content of every regime and agent config of the grid (name, version,
   sha256, body); the same name and version with another hash is refused ("bump the
   version") before anything is written;
3. creates the missing job rows (unique on regime, agent config, seed, budget, eval
   episodes), so a re-run finds the done ones and skips them;
4. claims runnable jobs just in time, one short transaction per batch: ``pending``,
   ``interrupted``, ``failed`` below :data:`MAX_FAILURES` failures, and ``running`` ones
   whose driver stopped heartbeating :data:`STALE_AFTER_S` ago. A claim sets status,
   owner token and heartbeat under the write lock, so two drivers never run one job;
5. keeps at most ``slots`` jobs in flight on the executor, shows their progress, writes
   progress and a heartbeat of its running jobs every :data:`FLUSH_EVERY_S` seconds;
6. stores each finished job (its episodes, evaluation steps, metadata, status ``done``)
   in ONE transaction; a failed job gets status ``failed``, ``failures + 1`` and its error;
7. on Ctrl-C stops the workers and marks their jobs ``interrupted`` (no rows are written
   for them: rows are only written when a job completes).
"""

from __future__ import annotations

import os
import signal
import socket
import time
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from sqlalchemy import and_, insert, or_, select, update
from sqlalchemy.orm import Session

from nutribench.jobs.spec import JobFailed, JobResult, JobSpec
from nutribench.jobs.worker import JobFn, execute
from nutribench.scheduler.executors import ExecutorHandle, make_executor, probe_executor
from nutribench.scheduler.grid import Grid
from nutribench.store import AgentConfig, Episode, EvalStep, Job, RegimeConfig, open_store, session_scope, utcnow
from nutribench.store.engine import sqlite_path
from nutribench.store.schema import Store

MAX_FAILURES = 3  # a job that failed this often is no longer retried
STALE_AFTER_S = 120.0  # a running job whose heartbeat is older belongs to a dead driver
WAIT_POLL_S = 1.0  # how often a driver with nothing to run looks at jobs held by another
FLUSH_EVERY_S = 3.0  # progress + heartbeat writes
EPISODE_COLUMNS = ("return", "foods", "final_distance", "overshoot_ratio", "final_C", "final_F", "final_P",
                   "first_overshoot_step", "entropy")  # fmt: skip
STEP_COLUMNS = ("episode", "step", "food", "action", "C", "F", "P", "reward")
METADATA_COLUMNS = ("host", "platform", "python_version", "numpy_version", "torch_version", "sb3_version",
                    "nutribench_version", "git_commit", "git_dirty", "started_at", "finished_at", "wall_seconds")  # fmt: skip


class RunError(Exception):
    """A problem with the run a user can fix (config changed without a version bump, no
    job function). One line."""


@dataclass
class RunSummary:
    """What one ``run`` did. ``skipped``: already done before it started; ``busy``: being
    run by another driver; ``given_up``: failed :data:`MAX_FAILURES` times, not retried."""

    total: int = 0
    done: int = 0
    failed: int = 0
    skipped: int = 0
    busy: int = 0
    given_up: int = 0
    interrupted: int = 0
    user_interrupt: bool = False
    errors: list[str] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        """130 after Ctrl-C, 1 if any job of the grid failed, else 0."""
        if self.user_interrupt:
            return 130
        return 1 if (self.failed or self.given_up) else 0


# --------------------------------------------------------------------------- configs
@dataclass(frozen=True)
class _Config:
    name: str
    version: int
    sha256: str
    body: dict[str, Any]
    source: str
    obj: Any
    algo: str | None = None


def _shown(path: Path | str) -> str:
    """A file path relative to the current folder when it lies below it."""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def load_grid_configs(grid: Grid) -> tuple[list[_Config], list[_Config]]:
    """Load every regime and agent config of the grid (ConfigError on a bad file)."""
    from nutribench.agents.config import (
        agent_config_content,
        agent_config_sha256,
        load_agent_config,
        resolve_agent_path,
    )
    from nutribench.config import load_env_config

    regimes = []
    for name in grid.regimes:
        env = load_env_config(name)
        regimes.append(_Config(env.name, env.version, env.sha256, env.content(), _shown(env.path or name), env))
    agents = []
    for name in grid.algos:
        cfg = load_agent_config(name)
        source = _shown(resolve_agent_path(name))
        agents.append(_Config(cfg.name, cfg.version, agent_config_sha256(cfg), agent_config_content(cfg), source, cfg, cfg.algo))
    return regimes, agents


def _register(session: Session, table: type, configs: Sequence[_Config]) -> dict[str, int]:
    """Ids of ``configs`` in ``table``, inserting the new ones; refuses changed content."""
    ids: dict[str, int] = {}
    for c in configs:
        row = session.execute(select(table).where(table.name == c.name, table.version == c.version)).scalar_one_or_none()
        if row is not None:
            if row.sha256 != c.sha256:
                raise RunError(f"{c.source}: version {c.version} is already recorded with different content: bump the version")
            ids[c.name] = row.id
            continue
        extra = {"algo": c.algo} if table is AgentConfig else {}
        new = table(name=c.name, version=c.version, sha256=c.sha256, body=c.body, source=c.source, created_at=utcnow(), **extra)
        session.add(new)
        session.flush()
        ids[c.name] = new.id
    return ids


def register_grid(store: Store, grid: Grid, regimes: list[_Config], agents: list[_Config]) -> list[int]:
    """Record the configs and create the missing job rows, in one transaction; the ids of
    the grid's jobs in grid order."""
    with session_scope(store.engine) as s:
        rids = _register(s, RegimeConfig, regimes)
        aids = _register(s, AgentConfig, agents)
        existing = {
            (r.regime_id, r.agent_config_id, r.seed): r.id
            for r in s.execute(
                select(Job.id, Job.regime_id, Job.agent_config_id, Job.seed).where(
                    Job.regime_id.in_(rids.values()), Job.agent_config_id.in_(aids.values()),
                    Job.episodes == grid.episodes, Job.eval_episodes == grid.eval_episodes,
                )  # fmt: skip
            )
        }
        keys = [(rids[r], aids[a], seed) for r, a, seed in grid.cells()]
        missing = [k for k in keys if k not in existing]
        if missing:
            now = utcnow()
            s.execute(insert(Job), [
                {"regime_id": r, "agent_config_id": a, "seed": seed, "episodes": grid.episodes,
                 "eval_episodes": grid.eval_episodes, "status": "pending", "attempt": 0, "failures": 0,
                 "episodes_done": 0, "created_at": now}
                for r, a, seed in missing
            ])  # fmt: skip
            for r in s.execute(select(Job.id, Job.regime_id, Job.agent_config_id, Job.seed).where(
                Job.regime_id.in_(rids.values()), Job.agent_config_id.in_(aids.values()),
                Job.episodes == grid.episodes, Job.eval_episodes == grid.eval_episodes,
            )):  # fmt: skip
                existing[(r.regime_id, r.agent_config_id, r.seed)] = r.id
        return [existing[k] for k in keys]


def reset_given_up(store: Store, job_ids: Sequence[int]) -> int:
    """``--retry-failed``: jobs of ``job_ids`` that failed :data:`MAX_FAILURES` times get their
    failure count reset (their last error stays until they succeed); how many."""
    with session_scope(store.engine) as s:
        return s.execute(
            update(Job).where(Job.id.in_(job_ids), Job.status == "failed", Job.failures >= MAX_FAILURES)
            .values(failures=0).execution_options(synchronize_session=False)
        ).rowcount  # fmt: skip


# --------------------------------------------------------------------------- claims
def _claimable(now) -> Any:
    stale = now - timedelta(seconds=STALE_AFTER_S)
    return or_(
        Job.status.in_(("pending", "interrupted")),
        and_(Job.status == "failed", Job.failures < MAX_FAILURES),
        and_(Job.status == "running", or_(Job.heartbeat_at.is_(None), Job.heartbeat_at < stale)),
    )


def count_claimable(store: Store, job_ids: Sequence[int]) -> int:
    """How many of ``job_ids`` a claim could take now."""
    with store.engine.connect() as conn:
        return len(conn.execute(select(Job.id).where(Job.id.in_(job_ids), _claimable(utcnow()))).all())


def claim_jobs(store: Store, job_ids: Sequence[int], exclude: set[int], n: int, owner: str) -> list[Job]:
    """Atomically take up to ``n`` runnable jobs of ``job_ids`` (not in ``exclude``) for
    ``owner``: status ``running``, owner token, fresh heartbeat, attempt + 1."""
    candidates = [j for j in job_ids if j not in exclude]
    if n <= 0 or not candidates:
        return []
    with session_scope(store.engine) as s:  # BEGIN IMMEDIATE on SQLite: one claimer at a time
        now = utcnow()
        ids = s.execute(select(Job.id).where(Job.id.in_(candidates), _claimable(now)).order_by(Job.id).limit(n)).scalars().all()
        if not ids:
            return []
        s.execute(
            update(Job).where(Job.id.in_(ids), _claimable(now)).values(
                status="running", owner=owner, heartbeat_at=now, started_at=now, finished_at=None,
                attempt=Job.attempt + 1, episodes_done=0, last_return=None, worker_pid=None,
            ).execution_options(synchronize_session=False)
        )  # fmt: skip
        return list(s.execute(select(Job).where(Job.id.in_(ids), Job.owner == owner, Job.status == "running")).scalars())


def held_elsewhere(store: Store, job_ids: Sequence[int], owner: str) -> tuple[int, datetime | None]:
    """How many of ``job_ids`` another driver is running (fresh heartbeat), and when the
    last of them becomes claimable if that driver's heartbeat stops now."""
    fresh = utcnow() - timedelta(seconds=STALE_AFTER_S)
    with store.engine.connect() as conn:
        beats = conn.execute(select(Job.heartbeat_at).where(
            Job.id.in_(job_ids), Job.status == "running", Job.owner != owner, Job.heartbeat_at >= fresh)).scalars().all()  # fmt: skip
    if not beats:
        return 0, None
    return len(beats), max(beats) + timedelta(seconds=STALE_AFTER_S)


def grid_counts(store: Store, job_ids: Sequence[int], owner: str) -> dict[str, int]:
    """Status counts of the grid's jobs, as this driver sees them at the end."""
    out = {"done": 0, "given_up": 0, "busy": 0}
    now = utcnow()
    with store.engine.connect() as conn:
        rows = conn.execute(select(Job.status, Job.failures, Job.owner, Job.heartbeat_at).where(Job.id.in_(job_ids))).all()
    for status, failures, job_owner, beat in rows:
        if status == "done":
            out["done"] += 1
        elif status == "failed" and failures >= MAX_FAILURES:
            out["given_up"] += 1
        elif status == "running" and job_owner != owner and beat is not None and beat >= now - timedelta(seconds=STALE_AFTER_S):
            out["busy"] += 1
    return out


# --------------------------------------------------------------------------- writes
def _episode_rows(job_id: int, phase: str, episodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    for ep in episodes:
        row = {"job_id": job_id, "phase": phase, "episode": int(ep["episode"])}
        for col in EPISODE_COLUMNS:
            row["ret" if col == "return" else col] = ep.get(col)
        rows.append(row)
    return rows


def store_result(store: Store, result: JobResult, owner: str, model_path: str | None) -> bool:
    """Write a finished job in one transaction: its episodes, evaluation steps, metadata and
    status ``done``. False (nothing written) if this driver no longer owns the job."""
    with session_scope(store.engine) as s:
        meta = {k: result.metadata[k] for k in METADATA_COLUMNS if k in result.metadata}
        if meta.get("platform"):
            meta["platform"] = str(meta["platform"])[:255]
        job = s.execute(select(Job).where(Job.id == result.job_id)).scalar_one()
        claimed = s.execute(
            update(Job).where(Job.id == result.job_id, Job.owner == owner, Job.status == "running").values(
                status="done", owner=None, heartbeat_at=utcnow(), episodes_done=job.episodes,
                model_path=result.model_path or model_path, error=None, **meta,
            ).execution_options(synchronize_session=False)
        ).rowcount  # fmt: skip
        if claimed != 1:
            return False
        rows = _episode_rows(result.job_id, "train", result.train) + _episode_rows(result.job_id, "eval", result.eval)
        if rows:
            s.execute(insert(Episode), rows)
        if result.eval_steps:
            s.execute(insert(EvalStep), [{"job_id": result.job_id, **{k: st[k] for k in STEP_COLUMNS}} for st in result.eval_steps])
        return True


def store_failure(store: Store, job_id: int, owner: str, error: str) -> None:
    """Status ``failed``, one more failure, the error text kept."""
    with session_scope(store.engine) as s:
        s.execute(
            update(Job).where(Job.id == job_id, Job.owner == owner).values(
                status="failed", failures=Job.failures + 1, error=error, owner=None, finished_at=utcnow(),
            ).execution_options(synchronize_session=False)
        )  # fmt: skip


def release_jobs(store: Store, job_ids: Sequence[int], owner: str, status: str = "interrupted") -> int:
    """Give back jobs this driver claimed (Ctrl-C, executor failure): no rows, new status."""
    if not job_ids:
        return 0
    with session_scope(store.engine) as s:
        return s.execute(
            update(Job).where(Job.id.in_(list(job_ids)), Job.owner == owner, Job.status == "running").values(
                status=status, owner=None, finished_at=utcnow(),
            ).execution_options(synchronize_session=False)
        ).rowcount  # fmt: skip


def flush_progress(store: Store, owner: str, live: dict[int, dict[str, Any]]) -> None:
    """Heartbeat every job this driver runs, with its episodes done and recent return."""
    if not live:
        return
    with session_scope(store.engine) as s:
        now = utcnow()
        for job_id, st in live.items():
            values: dict[str, Any] = {"heartbeat_at": now, "episodes_done": int(st.get("k", 0))}
            if st.get("ret") is not None:
                values["last_return"] = float(st["ret"])
            if st.get("pid") is not None:
                values["worker_pid"] = int(st["pid"])
            s.execute(update(Job).where(Job.id == job_id, Job.owner == owner).values(**values).execution_options(synchronize_session=False))


# --------------------------------------------------------------------------- helpers
def default_job_fn() -> JobFn:
    """``$NUTRIBENCH_JOB=fake`` (tests, dry runs): the synthetic job; else the real one."""
    choice = os.environ.get("NUTRIBENCH_JOB", "").strip()
    if choice == "fake":
        from nutribench.jobs.fake import fake_run_job

        return fake_run_job
    if choice not in ("", "real"):
        raise RunError(f"NUTRIBENCH_JOB={choice}: use 'fake' (synthetic jobs) or leave it unset")
    try:
        from nutribench.jobs.run import run_job
    except ImportError as e:
        raise RunError(f"the training job cannot be imported ({e}): is nutribench fully installed?") from None
    return run_job


def default_models_dir(store: Store) -> Path:
    """``models/`` next to a SQLite file, else in the current folder."""
    path = sqlite_path(store.url)
    return (path.parent if path is not None else Path.cwd()) / "models"


def model_path(models_dir: Path, regime: _Config, agent: _Config, seed: int, episodes: int) -> Path:
    """``<models>/<regime>-v<rv>/<algo>-v<av>/seed<seed>-ep<episodes>.zip``."""
    return models_dir / f"{regime.name}-v{regime.version}" / f"{agent.name}-v{agent.version}" / f"seed{seed}-ep{episodes}.zip"


def driver_token() -> str:
    return f"{socket.gethostname()[:80]}:{os.getpid()}:{uuid.uuid4().hex[:12]}"


def _error_text(exc: BaseException) -> str:
    if isinstance(exc, JobFailed):
        return f"{exc}\n{exc.traceback_text}".strip()
    return f"{type(exc).__name__}: {exc}"


# --------------------------------------------------------------------------- the run
class _Run:
    """State of one driver loop (in flight futures, live progress, counters)."""

    def __init__(self, store: Store, grid: Grid, job_ids: list[int], specs: Callable[[Job], JobSpec],
                 handle: ExecutorHandle, job_fn: JobFn, owner: str, view: Any):  # fmt: skip
        self.store, self.grid, self.job_ids, self.make_spec = store, grid, job_ids, specs
        self.handle, self.job_fn, self.owner, self.view = handle, job_fn, owner, view
        self.in_flight: dict[Future, JobSpec] = {}
        self.live: dict[int, dict[str, Any]] = {}
        self.attempted: set[int] = set()
        self.exhausted = False
        self.planned = 0  # jobs runnable when the run started (for the ETA)
        self.summary = RunSummary(total=len(job_ids))

    def fill(self) -> None:
        free = self.handle.slots - len(self.in_flight)
        if free <= 0 or self.exhausted:
            return
        jobs = claim_jobs(self.store, self.job_ids, self.attempted, free, self.owner)
        if len(jobs) < free:
            self.exhausted = True
        for job in jobs:
            spec = self.make_spec(job)
            self.attempted.add(job.id)
            self.live[job.id] = {"spec": spec, "k": 0, "n": spec.episodes, "ret": None, "t0": time.monotonic()}
            self.in_flight[self.handle.executor.submit(execute, self.job_fn, spec, self.handle.sink)] = spec

    def finish(self, future: Future) -> None:
        spec = self.in_flight[future]
        self._settle(future, spec)
        # forgotten only once its outcome is stored: a Ctrl-C meanwhile still releases the job
        self.in_flight.pop(future, None)
        self.live.pop(spec.job_id, None)

    def _settle(self, future: Future, spec: JobSpec) -> None:
        try:
            result = future.result()
        except BaseException as e:  # noqa: BLE001 - JobFailed, WorkerDied, pickling errors, cancel
            store_failure(self.store, spec.job_id, self.owner, _error_text(e))
            self.summary.failed += 1
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            self.summary.errors.append(f"{spec.label}: {first}")
            self.view.log(f"[red]failed[/] {spec.label}: {first}")
            return
        if store_result(self.store, result, self.owner, spec.model_path):
            self.summary.done += 1
            self.view.log(f"[green]done[/] {spec.label} ({result.metadata.get('wall_seconds', 0.0):.1f} s)")

    def events(self) -> None:
        for ev in self.handle.drain():
            st = self.live.get(ev.get("job_id"))
            if st is None:
                continue
            for key in ("k", "ret", "pid"):
                if ev.get(key) is not None:
                    st[key] = ev[key]

    def loop(self) -> None:
        last_flush = time.monotonic()
        while True:
            self.fill()
            if not self.in_flight:
                return
            finished, _ = wait(list(self.in_flight), timeout=0.25, return_when=FIRST_COMPLETED)
            self.events()
            for f in finished:
                self.finish(f)
            if time.monotonic() - last_flush >= FLUSH_EVERY_S:
                flush_progress(self.store, self.owner, self.live)
                last_flush = time.monotonic()
            self.view.update(self)

    def wait_for_others(self) -> None:
        """Jobs of the grid held by another driver: wait until that driver has finished them,
        or, if its heartbeat stops (a crashed driver), take them over once they are
        :data:`STALE_AFTER_S` old, so that a re-run after a crash finishes the grid."""
        said = None
        while True:
            held, claimable_at = held_elsewhere(self.store, self.job_ids, self.owner)
            if count_claimable(self.store, [j for j in self.job_ids if j not in self.attempted]):
                self.exhausted = False
                self.loop()
                continue
            if not held:
                return
            if held != said:  # once per change: a live driver moves claimable_at at every heartbeat
                self.view.log(f"waiting for {held} job{'s' if held != 1 else ''} held by another driver: done there, "
                              f"or taken over here from {claimable_at:%H:%M:%S} UTC if its heartbeat stops")  # fmt: skip
                said = held
            time.sleep(WAIT_POLL_S)
            self.view.update(self)

    def interrupt(self) -> None:
        """Ctrl-C (or SIGTERM, SIGHUP): stop the workers, mark their jobs interrupted, write
        nothing else. A second signal meanwhile is ignored, so the cleanup finishes."""
        previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in STOP_SIGNALS} if _main_thread() else None
        try:
            try:
                self.handle.terminate_running()
            finally:  # whatever stopping the workers did, their jobs are given back
                self.summary.interrupted = release_jobs(self.store, [s.job_id for s in self.in_flight.values()], self.owner)
            self.summary.user_interrupt = True
            self.in_flight.clear()
            self.live.clear()
        finally:
            for sig, handler in (previous or {}).items():
                signal.signal(sig, handler)


#: Signals that stop a run as Ctrl-C does: a batch system's preemption (SIGTERM) and a closed
#: terminal (SIGHUP) release the running jobs as ``interrupted`` at once.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _raise_keyboard_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


class _StopSignalsAsCtrlC:
    """Within the block, SIGTERM and SIGHUP raise KeyboardInterrupt as SIGINT does (main
    thread only; elsewhere signal handlers cannot be set)."""

    def __enter__(self) -> None:
        self.previous = {}
        if _main_thread():
            for sig in STOP_SIGNALS[1:]:
                self.previous[sig] = signal.signal(sig, _raise_keyboard_interrupt)

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def run_grid(
    db: str | os.PathLike[str],
    regimes: Sequence[str],
    algos: Sequence[str],
    seeds: Sequence[int],
    episodes: int,
    eval_episodes: int = 5,
    workers: int | None = None,
    executor: str = "local",
    job_fn: JobFn | None = None,
    models_dir: str | os.PathLike[str] | None = None,
    display: bool = True,
    retry_failed: bool = False,
) -> RunSummary:
    """Run every job of the grid regime x algo x seed that is not done yet (see the module
    docstring). Returns counts; ``summary.exit_code`` is what ``nutribench run`` exits with.
    ``retry_failed``: jobs that failed :data:`MAX_FAILURES` times are tried again.

    Raises ConfigError (bad config file), StoreError (bad database), ExecutorError (bad
    ``executor``) or RunError (config changed without a version bump), all one line.
    """
    from nutribench.scheduler.progress import make_view

    grid = Grid(tuple(regimes), tuple(algos), tuple(seeds), episodes, eval_episodes)
    job_fn = job_fn or default_job_fn()
    regime_cfgs, agent_cfgs = load_grid_configs(grid)  # before the database file is created
    probe_executor(executor)  # likewise: an unreachable cluster writes nothing
    store = open_store(db, writer=True)
    try:
        job_ids = register_grid(store, grid, regime_cfgs, agent_cfgs)
        if retry_failed:
            reset_given_up(store, job_ids)
        runnable = count_claimable(store, job_ids)
        owner = driver_token()
        out = Path(models_dir) if models_dir is not None else default_models_dir(store)
        by_id = {r.name: r for r in regime_cfgs}, {a.name: a for a in agent_cfgs}
        with store.engine.connect() as conn:
            rid = dict(conn.execute(select(RegimeConfig.id, RegimeConfig.name).where(
                RegimeConfig.name.in_(grid.regimes))).all())  # fmt: skip
            aid = dict(conn.execute(select(AgentConfig.id, AgentConfig.name).where(AgentConfig.name.in_(grid.algos))).all())

        def make_spec(job: Job) -> JobSpec:
            r, a = by_id[0][rid[job.regime_id]], by_id[1][aid[job.agent_config_id]]
            path = model_path(out, r, a, job.seed, job.episodes)
            return JobSpec(job.id, r.name, r.version, r.sha256, a.name, a.version, a.sha256, job.seed, job.episodes,
                           job.eval_episodes, str(path), r.obj, a.obj, attempt=job.attempt)  # fmt: skip

        summary = RunSummary(total=len(job_ids))
        held, _ = held_elsewhere(store, job_ids, owner)
        if runnable or held:
            handle, note = make_executor(executor, workers, max(runnable, held))
            view = make_view(display, grid, len(job_ids), handle.description, note)
            run = _Run(store, grid, job_ids, make_spec, handle, job_fn, owner, view)
            run.planned = runnable
            view.start(run)
            try:
                with _StopSignalsAsCtrlC():
                    run.loop()
                    run.wait_for_others()
            except KeyboardInterrupt:
                run.interrupt()
            finally:
                view.stop(run)
                handle.close()
            summary = run.summary
        counts = grid_counts(store, job_ids, owner)
        summary.skipped = max(0, counts["done"] - summary.done)
        summary.given_up, summary.busy = counts["given_up"], counts["busy"]
        return summary
    finally:
        store.dispose()
