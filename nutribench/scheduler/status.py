"""``nutribench status``: what is done, running, failed and pending, per regime x algo, and
how long the rest will take.

Only the ``jobs`` table (with the two config tables joined in) is read, never ``episodes``,
so the answer is instant however many episode rows the database holds. It reads while a
driver writes (SQLite WAL: readers never wait for the writer).

A ``running`` job whose heartbeat is older than the stale limit is counted as ``pending``
(:func:`nutribench.store.models.job_state`, the rule the driver claims by) (and in ``totals["orphaned"]``): its driver is gone and the next ``run`` takes
it over.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import asdict, dataclass, field
from datetime import datetime
from typing import Any

from sqlalchemy import select

from nutribench.scheduler.lifecycle import MAX_FAILURES
from nutribench.store import AgentConfig, Job, RegimeConfig, open_store, utcnow
from nutribench.store.engine import db_now
from nutribench.store.models import job_state

COUNTS = ("done", "running", "failed", "pending")
#: the ``jobs`` columns of a job tuple :func:`summarize` reads, after its regime and agent config
#: (name and version of each): those it needs, then those it may be given
JOB_COLUMNS = ("seed", "episodes", "status", "heartbeat_at", "wall_seconds", "episodes_done", "failures", "error")
JOB_COLUMNS += ("owner", "worker_pid", "started_at")


@dataclass
class StatusRow:
    """One regime x algo (config name and version) cell of the grid."""

    regime: str
    regime_version: int
    algo: str
    algo_version: int
    budget: int
    done: int = 0
    running: int = 0
    failed: int = 0
    pending: int = 0
    wall_seconds: float = 0.0  # used by the done jobs
    remaining_seconds: float | None = None  # of work left (one worker), see :func:`summarize`


@dataclass
class StatusReport:
    """The whole status: rows, totals, the ETA and the last error of each failed job."""

    rows: list[StatusRow]
    totals: dict[str, int]
    wall_seconds: float
    workers: int  # worker processes running jobs now (fresh heartbeat; a batch is one)
    eta_seconds: float | None  # remaining work / max(workers, 1)
    errors: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """Plain data for ``--json``: every field, the rows as dicts."""
        return asdict(self)


def _last_line(text: str | None) -> str:
    lines = [ln for ln in (text or "").strip().splitlines() if ln.strip()]
    # a traceback's last line is the exception; a one-line error is itself
    return lines[-1].strip()[:300] if lines else ""


def status_table(db: str | os.PathLike[str]) -> StatusReport:
    """Counts per regime x algo x budget, wall time used, remaining work and ETA, and the
    last error of every failed job. Raises StoreError (one line) for a bad database."""
    configs = (RegimeConfig.name, RegimeConfig.version, AgentConfig.name, AgentConfig.version)
    q = select(*configs, *(getattr(Job, c) for c in JOB_COLUMNS))
    q = q.join(RegimeConfig, RegimeConfig.id == Job.regime_id)
    q = q.join(AgentConfig, AgentConfig.id == Job.agent_config_id).order_by(*configs, Job.episodes, Job.seed)
    with open_store(db) as store, store.engine.connect() as conn:
        jobs = conn.execute(q).all()
        now = db_now(conn)
    return summarize(jobs, now)


def _mean(values: list[float] | None) -> float | None:
    return sum(values) / len(values) if values else None


def summarize(jobs: list, now: datetime | None = None) -> StatusReport:
    """The report of job tuples (regime, rv, algo, av, seed, episodes, status, heartbeat,
    wall, episodes_done, failures, error[, owner, worker_pid, started_at]); ``now`` (the
    database's clock, default this host's) judges heartbeats.

    Work left is priced in worker-seconds per training episode of the done jobs: of the same
    cell (regime x algo config), else of the same algo config in any regime (the algorithm,
    not the regime, sets the cost: a SAC day costs about nine MC days), else of the running
    jobs of that algo config (their training seconds so far / episodes done, where the worker
    reports them: a batch's share, the runs before a resume from a checkpoint included; else
    time since claimed / episodes done, shared among the jobs of one batch: one worker
    process), else of its orphaned jobs (``running`` with a stopped heartbeat: the training
    seconds / episodes their worker last reported, a measure of the config's cost though the
    job itself counts as pending, whole), else of every done job. The workers are the distinct
    worker processes of the running jobs (a batch of the batched engine is one).
    """
    now = now or utcnow()
    tally = _Tally()
    for n, job in enumerate(jobs):
        tally.add(n, job, now)
    running_rates, sharing = _running_rates(tally.running, now)
    remaining, unknown = tally.price(running_rates)
    rows = list(tally.rows.values())
    totals = {c: sum(getattr(r, c) for r in rows) for c in COUNTS} | {"jobs": len(jobs), "orphaned": tally.orphaned}
    eta = None if unknown else remaining / max(len(sharing), 1)
    return StatusReport(rows, totals, sum(r.wall_seconds for r in rows), len(sharing), eta, tally.errors)


@dataclass
class _Tally:
    """The jobs counted into rows, with what pricing the work left needs."""

    rows: dict[tuple, StatusRow] = field(default_factory=dict)
    rates: dict[tuple, list[float]] = field(default_factory=dict)  # seconds per episode of done jobs, per cell
    left: dict[tuple, float] = field(default_factory=dict)  # jobs' worth of work left
    errors: list[dict[str, Any]] = field(default_factory=list)
    orphaned: int = 0  # `running` with a stopped heartbeat: counted as pending, and said so
    # (algo, av), episodes done, claimed, worker, training seconds so far
    running: list[tuple[tuple, int, datetime | None, tuple, float | None]] = field(default_factory=list)
    orphan_rates: dict[tuple, list[float]] = field(default_factory=dict)  # (algo, av) -> seconds per day reported

    def add(self, n: int, job: tuple, now: datetime) -> None:
        """Count the ``n``-th job tuple (see :func:`summarize`) into its row."""
        regime, rv, algo, av, seed, budget, status, beat, wall, k, failures, error, *more = job
        owner, pid, started = (list(more) + [None, None, None])[:3]
        key = (regime, rv, algo, av, budget)
        row = self.rows.setdefault(key, StatusRow(regime, rv, algo, av, budget))
        state = job_state(status, beat, now)
        orphan = status == "running" and state == "pending"
        self.orphaned += orphan
        if orphan and k and wall is not None:
            self.orphan_rates.setdefault((algo, av), []).append(wall / k)
        setattr(row, state, getattr(row, state) + 1)
        if state == "done" and wall is not None:
            row.wall_seconds += wall
            self.rates.setdefault(key, []).append(wall / max(budget, 1))
        elif state == "running":
            self.left[key] = self.left.get(key, 0.0) + max(0.0, 1.0 - (k or 0) / max(budget, 1))
            worker = (owner, pid) if pid is not None else ("job", n)
            self.running.append(((algo, av), k or 0, started, worker, wall))
        elif state in ("pending",) or (state == "failed" and failures < MAX_FAILURES):
            self.left[key] = self.left.get(key, 0.0) + 1.0
        if state == "failed":
            self.errors.append(
                {"regime": regime, "algo": algo, "seed": seed, "budget": budget, "failures": failures}
                | {"retried": failures < MAX_FAILURES, "error": _last_line(error)}
            )

    def price(self, running_rates: dict[tuple, list[float]]) -> tuple[float, bool]:
        """(worker-seconds of work left, whether some row's work left has no price): each row's
        ``remaining_seconds`` set by the first rate known, in :func:`summarize`'s order."""
        per_algo: dict[tuple, list[float]] = {}
        for (_, _, algo, av, _), rs in self.rates.items():
            per_algo.setdefault((algo, av), []).extend(rs)
        overall = _mean([r for rs in self.rates.values() for r in rs])
        remaining, unknown = 0.0, False
        for key, row in self.rows.items():
            config = (row.algo, row.algo_version)
            known = (
                self.rates.get(key),
                per_algo.get(config),
                running_rates.get(config),
                self.orphan_rates.get(config),
            )
            rate = next((_mean(rates) for rates in known if rates), overall)
            jobs_left = self.left.get(key, 0.0)
            if jobs_left and rate is None:
                unknown = True
                continue
            row.remaining_seconds = jobs_left * row.budget * rate if rate is not None else 0.0
            remaining += row.remaining_seconds
        return remaining, unknown


def _running_rates(running: list[tuple], now: datetime) -> tuple[dict[tuple, list[float]], Counter]:
    """(seconds per episode of the running jobs, per agent config; the jobs per worker process):
    the worker's reported training seconds where it reports them (resumed days priced by their
    own time), else the time since claimed shared among the jobs of one worker."""
    sharing = Counter(worker for *_, worker, _ in running)
    rates: dict[tuple, list[float]] = {}
    for config, k, started, worker, wall in running:
        if k > 0 and wall is not None:
            rates.setdefault(config, []).append(wall / k)
        elif k > 0 and started is not None:
            elapsed = max(0.0, (now - started).total_seconds())
            rates.setdefault(config, []).append(elapsed / (k * sharing[worker]))
    return rates, sharing
