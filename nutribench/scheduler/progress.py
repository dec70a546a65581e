"""What ``nutribench run`` shows while it works: a rich Live panel (overall jobs done of
total with an ETA, one line per running job: regime, algo, seed, episode k/n, recent
return) and one log line per finished or failed job. ``display=False`` shows nothing.
Without a terminal (stderr to a log file or a pipe), where the panel would show only at the
end, one plain progress line every :data:`NO_TERMINAL_EVERY_S` seconds instead.

The ETA: measured once a minute of training has passed since the run's first trained day, at
the rate of the days trained since then (:func:`eta_since`: starting the workers is not
priced into the rest). Before that, an estimate from the agents' relative costs
(:func:`estimate_seconds`: ``ETA ~4m (estimate)``) until a job of this run has finished, then
the time this run took for the days it trained (:func:`eta_seconds`)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

REFRESH_S = 0.5


def format_duration(seconds: float | None) -> str:
    """``1h02m``, ``4m05s``, ``12s``; ``?`` when unknown."""
    if seconds is None or seconds != seconds or seconds < 0:
        return "?"
    s = int(round(seconds))
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


def note_event(live: dict[int, dict[str, Any]], resumed: dict[int, int], ev: dict[str, Any]) -> None:
    """A worker's progress event ``ev`` into the driver's view of its running jobs: ``live``
    (days done ``k``, recent return, worker pid, training seconds ``wall``) and ``resumed``
    (days a batch resumed from a checkpoint had trained before this run: kept after the job
    ends, for :func:`eta_seconds`). Events of jobs not in ``live`` are not this run's."""
    st = live.get(ev.get("job_id"))
    if st is None:
        return
    st.update({key: ev[key] for key in ("k", "ret", "pid", "wall") if ev.get(key) is not None})
    if ev.get("k0") is not None:  # episode events only: a phase event says nothing of it
        resumed[ev["job_id"]] = int(ev["k0"])


def _days(run: Any) -> tuple[int, int, int]:
    """This run's days: planned, done (finished jobs their whole budget, running ones their
    progress) and trained here (done less what resumed batches had trained before this run)."""
    budget = run.grid.episodes
    planned = max(run.planned, len(run.attempted)) * budget
    done = (run.summary.done + run.summary.failed) * budget + sum(int(st.get("k", 0)) for st in run.live.values())
    return planned, done, done - sum(run.resumed.values())


def eta_seconds(run: Any, elapsed: float, days_before: int = 0, at_least: float = 0.0) -> float | None:
    """Remaining time of this run, from the episodes trained so far (finished jobs count
    their whole budget, running ones their progress) and the time this run took for those it
    trained itself (a batch resumed from a checkpoint did not train the days before it): those
    trained since ``days_before`` in ``elapsed`` seconds; ``None`` if not one or before
    ``at_least`` seconds."""
    planned, done, trained_here = _days(run)
    days = trained_here - days_before
    if elapsed < at_least or days <= 0 or planned <= 0:
        return None
    return elapsed * max(planned - done, 0) / days


#: Seconds of training after a run's first trained day before :func:`eta_since` prices the rest
MEASURE_AFTER_S = 60.0


def eta_since(run: Any, mark: tuple[float, int], now: float) -> float | None:
    """Remaining time of this run at the rate it has trained since ``mark`` (the time of its
    first trained day and the days trained then), so that starting the workers is not priced
    into the rest; ``None`` until :data:`MEASURE_AFTER_S` seconds have passed since the mark
    and a day more has been trained."""
    return eta_seconds(run, now - mark[0], mark[1], MEASURE_AFTER_S)


def estimate_seconds(run: Any, costs: dict[str, float], workers: int) -> float | None:
    """Remaining time of this run from the agents' relative costs (``costs``: agent config
    name -> its registry entry's ``cost``, PPO's day = 1) at
    :data:`~nutribench.scheduler.grid.SB3_SECONDS_PER_COST_DAY` a cost-day (the SB3 engine's
    calibration), shared by ``workers`` (at most one per job left): the running jobs' days still
    to train at their agent's cost, the jobs not started yet at the grid's mean cost."""
    from nutribench.scheduler.grid import SB3_SECONDS_PER_COST_DAY

    algos = list(getattr(run.grid, "algos", ())) or list(costs)
    if not algos:
        return None
    mean = sum(costs.get(a, 1.0) for a in algos) / len(algos)
    running = sum(
        max(st["spec"].episodes - int(st.get("k", 0)), 0) * costs.get(st["spec"].algo, mean) for st in run.live.values()
    )
    waiting = max(run.planned - len(run.attempted), 0)
    jobs_left = len(run.live) + waiting
    if jobs_left == 0:
        return 0.0
    cost_days = running + waiting * run.grid.episodes * mean
    return cost_days * SB3_SECONDS_PER_COST_DAY / max(1, min(workers, jobs_left))


def rough_duration(seconds: float) -> str:
    """An estimate, no more precise than it is: ``<1m``, ``~12m``, ``~1h05m``."""
    m = int(round(seconds / 60))
    return "<1m" if m == 0 else f"~{m}m" if m < 60 else f"~{m // 60}h{m % 60:02d}m"


def eta_text(
    run: Any,
    elapsed: float,
    costs: dict[str, float],
    workers: int,
    mark: tuple[float, int] | None = None,
    now: float = 0.0,
) -> str:
    """The ETA shown: measured from the days trained since ``mark`` (:func:`eta_since`) once
    a minute of training has passed; before that, :func:`estimate_seconds` (said to be one)
    until a job of this run has finished (done or failed), then :func:`eta_seconds`."""
    measured = eta_since(run, mark, now) if mark is not None else None
    if measured is not None:
        return format_duration(measured)
    if not run.summary.done and not run.summary.failed:
        estimate = estimate_seconds(run, costs, workers) if costs else None
        if estimate is not None:
            return f"{rough_duration(estimate)} (estimate)"
    return format_duration(eta_seconds(run, elapsed))


#: The width of the progress lines written where there is no terminal (a file, a pipe).
NO_TERMINAL_WIDTH = 240
#: Where there is no terminal (a log file, a pipe), one progress line this often (seconds)
NO_TERMINAL_EVERY_S = 300.0


class NullView:
    """No display (library use, tests)."""

    def start(self, run: Any) -> None: ...
    def update(self, run: Any) -> None: ...
    def log(self, message: str) -> None: ...
    def stop(self, run: Any) -> None: ...


class LiveView(NullView):
    """The rich Live panel on stderr."""

    def __init__(
        self,
        total: int,
        description: str,
        note: str | None,
        console: Console | None = None,
        costs: dict[str, float] | None = None,
    ):
        self.console = console or Console(stderr=True)
        self.costs = costs or {}  # agent config name -> relative cost of a day, for the first ETA
        if not self.console.is_terminal:  # a log file or a pipe: lines whole, not wrapped at 80 columns
            self.console.width = max(self.console.width, NO_TERMINAL_WIDTH)
        self.total, self.description, self.note = total, description, note
        self.t0 = time.monotonic()
        self._last = 0.0
        self._last_line = self.t0  # no terminal: the time of the last progress line
        self._mark: tuple[float, int] | None = None  # the first trained day's time and the days then
        self.live = Live(console=self.console, auto_refresh=False, transient=False)

    def start(self, run: Any) -> None:
        if self.note:
            self.console.print(f"[yellow]note:[/] {self.note}", highlight=False)
        self.console.print(
            f"{run.planned} of {run.summary.total} job{'' if run.summary.total == 1 else 's'} to run on {self.description}",
            highlight=False,
        )
        self.live.start()
        self.update(run, force=True)

    def head(self, run: Any) -> str:
        """The panel's first line: jobs done, failed, running and to run, elapsed time, ETA."""
        now = time.monotonic()
        elapsed = now - self.t0
        s = run.summary
        workers = getattr(getattr(run, "handle", None), "slots", 1)
        self.note_mark(run, now)
        eta = eta_text(run, elapsed, self.costs, workers, self._mark, now)
        return (
            f"jobs: {s.done} done, {s.failed} failed, {len(run.live)} running, of {run.planned} to run "
            f"(grid {s.total})   elapsed {format_duration(elapsed)}   ETA {eta}"
        )

    def note_mark(self, run: Any, now: float) -> None:
        """Keep the time of the run's first trained day and the days trained then."""
        if self._mark is None and (days := _days(run)[2]) > 0:
            self._mark = (now, days)

    def render(self, run: Any) -> Group:
        head = Text(self.head(run))
        if not run.live:
            return Group(head)
        table = Table("regime", "algo", "seed", "episode", "recent return", "time", box=None, pad_edge=False)
        for st in sorted(run.live.values(), key=lambda st: st["spec"].job_id):
            spec = st["spec"]
            ret = "" if st.get("ret") is None else f"{st['ret']:.2f}"
            took = format_duration(time.monotonic() - st["t0"])
            table.add_row(spec.regime, spec.algo, str(spec.seed), f"{st.get('k', 0)}/{spec.episodes}", ret, took)
        return Group(head, table)

    def line(self, run: Any) -> str:
        """The progress as one plain line (for a log file): the head and the running jobs' days."""
        text = self.head(run)
        days = [int(st.get("k", 0)) for st in run.live.values()]
        if days:
            budget = max(st["spec"].episodes for st in run.live.values())
            span = f"{min(days)}" if min(days) == max(days) else f"{min(days)}-{max(days)}"
            text += f"   running: day {span} of {budget}"
        return text

    def update(self, run: Any, force: bool = False) -> None:
        now = time.monotonic()
        self.note_mark(run, now)
        if not self.console.is_terminal:  # a log: Live draws nothing until the end, so a line now and then
            if now - self._last_line >= NO_TERMINAL_EVERY_S:
                self._last_line = now
                self.log(self.line(run))
            if not force:
                return
        if force or now - self._last >= REFRESH_S:
            self._last = now
            self.live.update(self.render(run), refresh=True)

    def log(self, message: str) -> None:
        self.live.console.print(message, highlight=False)

    def stop(self, run: Any) -> None:
        self.update(run, force=True)
        self.live.stop()
        if not self.console.is_terminal:  # rich leaves a non-terminal's last frame without its newline
            self.console.line()


def make_view(
    display: bool, grid: Any, total: int, description: str, note: str | None, agents: Sequence[Any] = ()
) -> NullView:
    """A :class:`LiveView` when ``display``, else a :class:`NullView`. ``agents``: the grid's
    agent configs as the driver loaded them (``.name``, ``.algo``), priced for the first ETA."""
    if not display:
        return NullView()
    from nutribench.agents import registry

    return LiveView(total, description, note, costs={a.name: registry.get(a.algo).cost for a in agents})
