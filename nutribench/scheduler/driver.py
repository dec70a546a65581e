"""The driver of ``nutribench run``: the only process that writes the results database.

One call of :func:`run_grid`:

1. opens (creates, upgrades) the database;
2. records the content of every regime and agent config of the grid (name, version,
   sha256, body); the same name and version with another hash is refused ("bump the
   version") before anything is written;
3. creates the missing job rows (unique on regime, agent config, seed, budget, eval
   episodes), so a re-run finds the done ones and skips them;
4. claims runnable jobs just in time, one short transaction per batch: ``pending``,
   ``interrupted``, ``failed`` below :data:`~nutribench.scheduler.lifecycle.MAX_FAILURES` failures, and ``running`` ones
   whose driver stopped heartbeating :data:`~nutribench.store.models.STALE_AFTER_S` ago. A claim sets status,
   owner token and heartbeat under the write lock, so two drivers never run one job;
5. keeps at most ``slots`` jobs in flight on the executor, shows their progress, writes
   progress and a heartbeat of its running jobs every :data:`FLUSH_EVERY_S` seconds;
6. stores each finished job (its episodes, evaluation steps, metadata, status ``done``)
   in ONE transaction; a failed job gets status ``failed``, ``failures + 1`` and its error;
7. on Ctrl-C (a KeyboardInterrupt) or its ``stop`` event stops the workers and marks their
   jobs ``interrupted`` (no rows are written for them: rows are only written when a job completes);
8. at its start and end, deletes the batched engine's checkpoints whose jobs are all done (:mod:`nutribench.scheduler.pools`).

Storing finished jobs when the database pushes back:

- A lock held past the busy timeout ("database is locked": another writer holds SQLite's one
  write lock for long; PostgreSQL's lock timeouts) is not the job's fault: its result is kept
  in memory (:class:`HeldResults`) and stored again with a growing pause until it succeeds or
  the run stops, the job heartbeating meanwhile so that no other driver takes it over. A
  heartbeat or a claim that meets the lock is simply tried again later.
- Any other operational error while writing (disk full, I/O error, a read-only file, the
  server gone) stops the run with one line (:func:`stop_line`): its jobs are released if the
  database still takes that write, else left to the stale rule; the next run resumes them.

What a run uses when not told: the job function (:func:`~nutribench.scheduler.settings.default_job_fn`), the
models folder :attr:`GridSettings.models <nutribench.scheduler.settings.GridSettings.models>`. No signal handler (``run``'s: :mod:`nutribench.cli.run`).
"""

from __future__ import annotations

import os
import socket
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from sqlalchemy.exc import OperationalError

from nutribench.engines import Engine
from nutribench.scheduler.executors import ExecutorHandle, make_executor, probe_executor
from nutribench.scheduler.grid import Grid
from nutribench.scheduler.lifecycle import (
    MAX_FAILURES,
    STALE_AFTER_S,
    check_not_mixed,
    claim_jobs,
    count_claimable,
    flush_progress,
    grid_counts,
    held_elsewhere,
    release_jobs,
    reset_given_up,
    store_failure,
    store_result,
)
from nutribench.scheduler.pools import Pool, batch_pools, check_engine, checkpointed_first, remove_finished_checkpoints
from nutribench.scheduler.progress import make_view, note_event
from nutribench.scheduler.registration import RunError, load_grid_configs, register_grid, spec_maker
from nutribench.scheduler.settings import GridSettings, default_batch_fn, default_job_fn
from nutribench.scheduler.worker import JobFailed, JobFn, JobResult, JobSpec, execute
from nutribench.store import Job, open_store
from nutribench.store.engine import StoreError
from nutribench.store.schema import Store

WAIT_POLL_S = 1.0  # how often a driver with nothing to run looks at jobs held by another
FLUSH_EVERY_S = 3.0  # progress + heartbeat writes


# --------------------------------------------------------------------------- a database that pushes back
RETRY_FIRST_S = 1.0  # the first pause before a held result is stored again; doubled each time
RETRY_MAX_S = 30.0
LOCK_WORDS = (
    "database is locked",
    "database table is locked",
    "lock timeout",
    "could not obtain lock",
    "deadlock detected",
)


def one_line(error: BaseException) -> str:
    """A database error's message on one line, without SQLAlchemy's statement and parameters."""
    return " ".join(str(getattr(error, "orig", None) or error).split()) or type(error).__name__


def is_lock_error(error: BaseException) -> bool:
    """A write that met another writer's lock for longer than the busy timeout."""
    return isinstance(error, OperationalError) and any(w in one_line(error).lower() for w in LOCK_WORDS)


def unless_locked(fn: Callable[..., Any], *args: Any, default: Any = None) -> Any:
    """``fn(*args)``, or ``default`` when it met the lock (another write is tried later)."""
    try:
        return fn(*args)
    except OperationalError as e:
        if not is_lock_error(e):
            raise
        return default


@dataclass
class Held:
    spec: Any
    result: Any
    due: float
    pause: float


class HeldResults(dict):
    """Finished jobs' results the database could not take yet (job id -> :class:`Held`)."""

    def hold(self, spec: Any, result: Any) -> float:
        """Keep ``result``; the pause until it is stored again (doubling up to RETRY_MAX_S)."""
        before = self.get(spec.job_id)
        pause = RETRY_FIRST_S if before is None else min(2 * before.pause, RETRY_MAX_S)
        self[spec.job_id] = Held(spec, result, time.monotonic() + pause, pause)
        return pause

    def due(self) -> list[Held]:
        now = time.monotonic()
        return [h for h in list(self.values()) if h.due <= now]

    def labels(self) -> str:
        return ", ".join(h.spec.label for h in self.values())


def released_text(released: int | str, n: int) -> str:
    if n == 0:
        return "no job was running: nothing was lost"
    if isinstance(released, int):
        return f"{released} running job{'s' if released != 1 else ''} released, the next run resumes them"
    return (
        f"its {n} running job{'s' if n != 1 else ''} could not be released either ({released}): the next run "
        f"takes them over once their heartbeat is {STALE_AFTER_S:.0f} s old"
    )


def stop_line(where: str, error: BaseException | None, released: int | str, n: int, held: HeldResults) -> str:
    """The line a stopped run ends with: stopped by a storage ``error``, that error, the ``n``
    running jobs ``released`` (how many, or why not) and the results lost; stopped by a signal
    (no ``error``), only what it adds: results still held (the lock never cleared), jobs not released."""
    if error is not None:
        lost = f"; the results of {held.labels()} could not be stored (trained again next run)" if held else ""
        return f"cannot write to {where}: {one_line(error)}: the run stopped; {released_text(released, n)}{lost}"
    lost = f"the results of {held.labels()} could not be stored (the database stayed locked): trained again next run"
    kept = "" if isinstance(released, int) else released_text(released, n)
    return "; ".join(t for t in (lost if held else "", kept) if t)


def first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


@dataclass
class RunSummary:
    """What one ``run`` did. ``skipped``: already done before it started; ``busy``: being
    run by another driver; ``given_up``: failed :data:`~nutribench.scheduler.lifecycle.MAX_FAILURES` times, not retried."""

    total: int = 0
    done: int = 0
    failed: int = 0
    skipped: int = 0
    busy: int = 0
    given_up: int = 0
    interrupted: int = 0
    user_interrupt: bool = False

    @property
    def exit_code(self) -> int:
        """130 after Ctrl-C, 1 if any job of the grid failed, else 0."""
        if self.user_interrupt:
            return 130
        return 1 if (self.failed or self.given_up) else 0

    def line(self) -> str:
        """The run's last line: ``N jobs: D done, F failed, S already done`` and what else happened."""
        parts = [f"{self.done} done", f"{self.failed} failed", f"{self.skipped} already done"]
        if self.busy:
            parts.append(f"{self.busy} running in another driver")
        if self.given_up:
            parts.append(
                f"{self.given_up} failed {MAX_FAILURES} times (not retried: see `nutribench status`; "
                "`--retry-failed` tries them again)"
            )
        if self.interrupted:
            parts.append(f"{self.interrupted} interrupted (the next run resumes them)")
        return f"{self.total} job{'' if self.total == 1 else 's'}: " + ", ".join(parts)


# --------------------------------------------------------------------------- the run
@dataclass(eq=False)
class _Run:
    """State of one driver loop (in flight futures, live progress, counters)."""

    store: Store
    grid: Grid
    job_ids: list[int]
    make_spec: Callable[[Job], JobSpec]
    handle: ExecutorHandle
    job_fn: JobFn
    owner: str
    view: Any
    pools: list[Pool] | None = None  # None: one pool of single jobs
    batch_fn: Callable | None = None
    in_flight: dict[Future, list[JobSpec]] = field(default_factory=dict)
    held: HeldResults = field(default_factory=HeldResults)  # results that met the write lock, stored later
    live: dict[int, dict[str, Any]] = field(default_factory=dict)
    resumed: dict[int, int] = field(default_factory=dict)  # job id -> days trained before this run (resumed batches)
    attempted: set[int] = field(default_factory=set)
    exhausted: bool = False
    planned: int = 0  # jobs this run runs: runnable at its start, and any it took over since
    stop: threading.Event = field(default_factory=threading.Event)  # set: stop as Ctrl-C does

    def __post_init__(self) -> None:
        self.pools = self.pools if self.pools is not None else [Pool(self.job_ids)]
        self.summary = RunSummary(total=len(self.job_ids))

    def fill(self) -> None:
        """Claim jobs for the free slots and start them: a single job per slot, or a batch of
        up to its pool's size per slot (the batched engine)."""
        free = self.handle.slots - len(self.in_flight)
        if free <= 0 or self.exhausted:
            return
        for pool in self.pools:
            while free > 0:
                want = pool.batch_size if pool.batched else free
                jobs = unless_locked(claim_jobs, self.store, pool.job_ids, self.attempted, want, self.owner, default=[])
                if not jobs:
                    break
                specs, now = [self.make_spec(job) for job in jobs], time.monotonic()
                for spec in specs:
                    self.attempted.add(spec.job_id)
                    self.live[spec.job_id] = {"spec": spec, "k": 0, "n": spec.episodes, "ret": None, "t0": now}
                self.planned = max(self.planned, len(self.attempted))  # a job taken over here: "3 done of 2 to run"
                # a batch is one unit of work on one slot, a single job one of its own
                fn, units = (self.batch_fn, [specs]) if pool.batched else (self.job_fn, [[s] for s in specs])
                for unit in units:
                    work = unit if pool.batched else unit[0]
                    self.in_flight[self.handle.executor.submit(execute, fn, work, self.handle.sink)] = unit
                free -= len(units)
                if len(jobs) < want:
                    break
        if free > 0:
            self.exhausted = True

    def finish(self, future: Future) -> None:
        specs = self.in_flight[future]
        self._settle(future, specs)
        # forgotten only once its outcome is stored: a Ctrl-C meanwhile still releases the jobs
        self.in_flight.pop(future, None)
        for spec in specs:
            if spec.job_id not in self.held:  # a held result's job keeps heartbeating
                self.live.pop(spec.job_id, None)

    def _settle(self, future: Future, specs: list[JobSpec]) -> None:
        try:
            outcome = future.result()
        except BaseException as e:  # noqa: BLE001 - JobFailed, WorkerDied, pickling errors, cancel
            if len(specs) > 1 and isinstance(e, Exception):
                # which job broke the batch is unknown: each goes back and is tried alone in this
                # run, so that only a job that fails by itself counts a failure
                ids = [spec.job_id for spec in specs]
                release_jobs(self.store, ids, self.owner, status="pending")
                self.attempted.difference_update(ids)
                self.resumed = {j: k0 for j, k0 in self.resumed.items() if j not in ids}  # they start over
                self.pools.insert(0, Pool(ids, True, 1))
                self.exhausted = False
                self.view.log(f"[yellow]batch failed[/] ({first_line(e)}): its {len(ids)} jobs are tried one by one")
                return
            for spec in specs:
                self._failed(spec, e)
            return
        results = {r.job_id: r for r in (outcome if isinstance(outcome, list) else [outcome])}
        for spec in specs:  # each job on its own: one that cannot be stored does not lose the others
            self._store(spec, results.get(spec.job_id))

    def _store(self, spec: JobSpec, result: JobResult | None) -> None:
        """Store a finished job, counted and shown once stored. A result that meets the write
        lock is held (:attr:`held`) and stored again later; another operational error (disk
        full, I/O error, read-only) is raised: the driver stops; anything else is the job's failure."""
        try:
            if result is None:
                raise JobFailed(f"{spec.label}: its batch returned no result for it")
            stored = store_result(self.store, result, self.owner, spec.model_path)
        except OperationalError as e:
            if not is_lock_error(e):
                raise
            self.view.log(
                f"[yellow]kept[/] {spec.label}: {one_line(e)}; stored again in {self.held.hold(spec, result):.0f} s"
            )
            return
        except Exception as e:  # noqa: BLE001 - recorded as the job's failure, the run goes on
            self._failed(spec, e, "could not be stored: ")
            stored = False
        if self.held.pop(spec.job_id, None) is not None:  # its job heartbeated while held
            self.live.pop(spec.job_id, None)
        if stored:
            self.summary.done += 1
            self.view.log(f"[green]done[/] {spec.label} ({result.metadata.get('wall_seconds', 0.0):.1f} s)")

    def _failed(self, spec: JobSpec, error: BaseException, shown: str = "") -> None:
        """Status ``failed`` with the error kept (the message, and the worker's traceback where
        there is one), counted and shown (after ``shown``)."""
        text = f"{type(error).__name__}: {error}"
        if isinstance(error, JobFailed):
            text = f"{error}\n{error.traceback_text}".strip()
        store_failure(self.store, spec.job_id, self.owner, text)
        self.summary.failed += 1
        self.view.log(f"[red]failed[/] {spec.label}: {shown}{first_line(error)}")

    def events(self) -> None:
        for ev in self.handle.drain():
            note_event(self.live, self.resumed, ev)

    def loop(self) -> None:
        last_flush = time.monotonic()
        while not self.stop.is_set():
            self.fill()
            for held in self.held.due():
                self._store(held.spec, held.result)
            if not self.in_flight and not self.held:
                return
            finished = (
                wait(list(self.in_flight), timeout=0.25, return_when=FIRST_COMPLETED)[0]
                if self.in_flight
                else time.sleep(0.25) or ()
            )
            self.events()
            for f in finished:
                self.finish(f)
            if time.monotonic() - last_flush >= FLUSH_EVERY_S:
                unless_locked(flush_progress, self.store, self.owner, self.live)
                last_flush = time.monotonic()
            self.view.update(self)

    def wait_for_others(self) -> None:
        """Jobs of the grid held by another driver: wait until that driver has finished them,
        or, if its heartbeat stops (a crashed driver), take them over once they are
        :data:`~nutribench.store.models.STALE_AFTER_S` old, so that a re-run after a crash finishes the grid."""
        said = None
        while not self.stop.is_set():
            held, claimable_at = held_elsewhere(self.store, self.job_ids, self.owner)
            claimable = count_claimable(self.store, [j for j in self.job_ids if j not in self.attempted])
            if claimable:  # taken over (a stopped heartbeat) or given back by the other driver
                # they are this run's to run now: those it ran and these (a job counted at the start, taken
                # by another driver and left again, counts once)
                self.planned = max(self.planned, len(self.attempted) + claimable)
                self.exhausted = False
                self.loop()
                continue
            if not held:
                return
            if held != said:  # once per change: a live driver moves claimable_at at every heartbeat
                self.view.log(
                    f"waiting for {held} job{'s' if held != 1 else ''} held by another driver: done there, "
                    f"or taken over here from {claimable_at:%H:%M:%S} UTC if its heartbeat stops"
                )
                said = held
            self.stop.wait(WAIT_POLL_S)
            self.view.update(self)

    def drive(self) -> RunSummary:
        """The driver loop of this run until every job is done or it is stopped (Ctrl-C, the
        ``stop`` event, a storage error: the running jobs given back)."""
        self.view.start(self)
        try:
            self.loop()
            self.wait_for_others()
            if self.stop.is_set():
                self.interrupt()
        except KeyboardInterrupt:
            self.interrupt()
        except OperationalError as e:  # disk full, I/O error, read-only file: one line, jobs given back
            raise StoreError(self.interrupt(e)) from None
        finally:
            self.view.stop(self)
            self.handle.close()
        return self.summary

    def interrupt(self, error: BaseException | None = None) -> str:
        """Ctrl-C (a KeyboardInterrupt), the ``stop`` event or a storage ``error`` (its one line is returned):
        stop the workers, mark their jobs (and held results' jobs) interrupted, write nothing else."""
        try:
            self.handle.terminate_running()
        finally:  # whatever stopping the workers did, their jobs are given back
            held = [s.job_id for specs in self.in_flight.values() for s in specs] + list(self.held)
            try:  # released as interrupted: how many, or why the database refused that too
                released: int | str = release_jobs(self.store, held, self.owner)
            except OperationalError as e:
                released = one_line(e)
        self.summary.interrupted = released if isinstance(released, int) else 0
        line = stop_line(self.store.display, error, released, len(held), self.held)
        if line and not error:
            self.view.log(f"[red]{line}[/]")
        self.summary.user_interrupt = error is None
        self.in_flight.clear()
        self.live.clear()
        return line


def driver_token() -> str:
    """A unique owner token for one driver: host, process id and a random part (the jobs it claims carry it)."""
    return f"{socket.gethostname()[:80]}:{os.getpid()}:{uuid.uuid4().hex[:12]}"


def run_grid(settings: GridSettings, stop: threading.Event | None = None) -> RunSummary:
    """Run every job of ``settings``' grid (regime x algo x seed) that is not done yet (see the
    module docstring and :class:`~nutribench.scheduler.settings.GridSettings`). Returns counts;
    ``summary.exit_code`` is what ``nutribench run`` exits with. ``stop``: an event that, once set
    (by another thread), stops the run as Ctrl-C does; no signal handler is set.
    Raises ConfigError (bad config file), StoreError (bad database), ExecutorError (bad ``executor``),
    DeviceError (bad ``device``) or RunError (config changed without a version bump), all one line.
    """
    s = settings
    check_engine(s.engine, s.max_batch, s.device)
    grid = s.grid
    job_fn = s.job_fn or default_job_fn()
    batch_fn = (s.batch_fn or default_batch_fn()) if s.engine == Engine.BATCHED else s.batch_fn
    regime_cfgs, agent_cfgs = load_grid_configs(grid)  # before the database file is created
    probe_executor(s.executor)  # likewise: an unreachable cluster writes nothing
    fake = bool(getattr(job_fn, "fake", False) or getattr(batch_fn, "fake", False))
    store = open_store(s.db, writer=True)
    try:
        check_not_mixed(store, fake)
        job_ids = register_grid(store, grid, regime_cfgs, agent_cfgs, fake=fake)
        if s.retry_failed:
            reset_given_up(store, job_ids)
        runnable = count_claimable(store, job_ids)
        owner, checkpoints = driver_token(), s.models / "checkpoints"
        remove_finished_checkpoints(store, checkpoints)  # killed batches whose jobs are done since
        summary = RunSummary(total=len(job_ids))
        held, _ = held_elsewhere(store, job_ids, owner)
        if runnable or held:
            make_spec = spec_maker(s, job_ids, regime_cfgs, agent_cfgs)
            handle, note = make_executor(s.executor, s.workers, max(runnable, held))
            view = make_view(s.display, grid, len(job_ids), handle.description, note, agent_cfgs)
            pools = _batched_pools(store, s, job_ids, regime_cfgs, agent_cfgs, handle.slots)
            run = _Run(store, grid, job_ids, make_spec, handle, job_fn, owner, view, pools, batch_fn, planned=runnable)
            run.stop = stop or run.stop
            summary = run.drive()
        remove_finished_checkpoints(store, checkpoints)  # those whose jobs this run finished otherwise
        counts = grid_counts(store, job_ids, owner)
        summary.skipped = max(0, counts["done"] - summary.done)
        summary.given_up, summary.busy = counts["given_up"], counts["busy"]
        return summary
    except OperationalError as e:  # a write refused before any job was claimed (a read-only file)
        why = f"cannot write to {store.display}: {one_line(e)}: no job was claimed; the next run resumes"
        raise StoreError(why) from None
    finally:
        store.dispose()


def _batched_pools(
    store: Store, s: GridSettings, job_ids: list[int], regime_cfgs: list, agent_cfgs: list, slots: int
) -> list[Pool] | None:
    """The batched engine's pools (an agent config's jobs in batches, checkpointed ones first);
    None for the SB3 engine (one pool of single jobs)."""
    if s.engine != Engine.BATCHED:
        return None
    algo_of = {a.name: a.algo for a in agent_cfgs}
    shapes = {r.name: (r.obj.reward.horizon, len(r.obj.catalog.food)) for r in regime_cfgs}
    pools = batch_pools(job_ids, s.grid.cells(), algo_of, shapes, partial(count_claimable, store), slots, s.max_batch)
    return checkpointed_first(pools, s.models / "checkpoints")


__all__ = ["GridSettings", "RunError", "RunSummary", "run_grid"]
