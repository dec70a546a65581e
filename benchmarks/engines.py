"""``python benchmarks/engines.py``: do the batched engine's agents learn what the SB3 agents
learn? Both engines train the same agent config on the same regimes, seeds and budget;
each trained agent plays greedily on its seed's fixed evaluation days; per (algorithm,
regime, engine) the table gives the IQM over seeds of each agent's mean evaluation return
with the statistics module's trimmed-t interval (:func:`nutribench.stats.iqm_runs_ci`), the
share of the never -> planner gap,
and the wall time. The two engines' random streams differ (see
:mod:`nutribench.engine.train`), so the comparison is of distributions: the intervals of
the two engines must overlap.

The SB3 engine trains one job per process on a process pool (one per core); the batched
engine trains all of an algorithm's jobs in one process, on one core (or on ``device``).
With ``concurrent=True`` each algorithm's batched process runs beside the SB3 pool instead
of after it (for a machine with more cores than SB3 jobs); the results are the same, only
the wall time differs.

A developer's script, not part of the installed package: run it from a checkout
(``python benchmarks/engines.py --help`` for its options); it imports :mod:`learn` beside it.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Annotated, Any, Optional

import numpy as np
import typer
from learn import LearnRun, batched_runs, learn_benchmark, summarize_runs

from nutribench.agents.registry import batched_names
from nutribench.cli.common import (
    DEVICE_HELP,
    EpisodesAlias,
    EvalDaysOption,
    MarkdownOption,
    console,
    old_spelling,
    print_table,
    split_csv,
    user_errors,
)
from nutribench.engines import TRAINING_ENGINES, Engine
from nutribench.safe_write import atomic_write, check_file_target
from nutribench.stats import iqm_runs_ci


def _timed_batched_runs(
    algo: str, regimes: list[str], seeds: list[int], episodes: int, eval_episodes: int, device: str
) -> tuple[list[LearnRun], float]:
    start = time.perf_counter()
    runs = batched_runs(algo, regimes, seeds, episodes, eval_episodes, device)
    return runs, time.perf_counter() - start


def _save(path: Path | None, runs: dict[str, list[LearnRun]], episodes: int, device: str) -> None:
    if path is not None:
        records = [{"engine": e, **dataclasses.asdict(r)} for e in TRAINING_ENGINES for r in runs[e]]
        with atomic_write(path, "--save") as tmp:
            tmp.write_text(json.dumps({"episodes": episodes, "device": device, "runs": records}, default=float))


def bench_engines(
    algos: Iterable[str] | None = None,
    regimes: Iterable[str] = ("run0", "run6"),
    seeds: Iterable[int] = (0, 1, 2, 3, 4),
    episodes: int = 500,
    eval_episodes: int = 10,
    workers: int | None = None,
    device: str = "cpu",
    concurrent: bool = False,
    save: Path | None = None,
    on_done: Callable[[str, LearnRun], None] | None = None,
) -> list[dict[str, Any]]:
    """One row per (algorithm, regime, engine), and per (algorithm, regime) whether the two
    engines' intervals overlap (``overlap``, on the batched row). ``concurrent``: each
    algorithm's batched training runs in its own process beside the SB3 pool. ``save``: every
    trained agent's evaluation returns and the reference returns on its days, as JSON (the SB3
    engine's as soon as they are in, then all). ``on_done(engine, run)`` as each agent is in."""
    known = batched_names()
    algos, regimes, seeds = known if algos is None else list(algos), list(regimes), list(seeds)
    unknown = [a for a in algos if a not in known]
    if unknown:
        raise ValueError(f"the batched engine does not train {', '.join(unknown)} yet (it trains {', '.join(known)})")
    batched_args = (regimes, seeds, episodes, eval_episodes, device)
    pool = None
    if concurrent:  # spawn: a CUDA context does not survive fork
        pool = ProcessPoolExecutor(len(algos), mp_context=multiprocessing.get_context("spawn"))
        futures = [pool.submit(_timed_batched_runs, a, *batched_args) for a in algos]
    start = time.perf_counter()
    sb3_done = None if on_done is None else (lambda run, k, n: on_done(Engine.SB3, run))
    sb3_runs = learn_benchmark(
        algos, regimes, seeds, {}, episodes, eval_episodes=eval_episodes, workers=workers, on_done=sb3_done
    )
    sb3_wall = time.perf_counter() - start
    runs: dict[str, list[LearnRun]] = {Engine.SB3: sb3_runs, Engine.BATCHED: []}
    _save(save, runs, episodes, device)
    if pool is not None:
        timed = [future.result() for future in futures]
        pool.shutdown()
    else:
        timed = [_timed_batched_runs(algo, *batched_args) for algo in algos]
    runs[Engine.BATCHED] = [run for algo_runs, _ in timed for run in algo_runs]
    for run in runs[Engine.BATCHED] if on_done is not None else ():
        on_done(Engine.BATCHED, run)
    batched_wall = (max if concurrent else sum)(wall for _, wall in timed)
    _save(save, runs, episodes, device)
    rows = [row for algo in algos for regime in regimes for row in _engine_pair(runs, algo, regime, episodes)]
    for r in rows:
        r["total_wall_seconds"] = sb3_wall if r["engine"] == Engine.SB3 else batched_wall
    return rows


def _engine_pair(runs: dict[str, list[LearnRun]], algo: str, regime: str, episodes: int) -> list[dict[str, Any]]:
    """The SB3 and the batched row of one (algorithm, regime); the batched row says whether
    the two intervals overlap."""
    pair = []
    for engine in TRAINING_ENGINES:
        rs = [r for r in runs[engine] if r.algo == algo and r.regime == regime]
        point, lo, hi = iqm_runs_ci([np.array([np.mean([e["return"] for e in r.eval_rows]) for r in rs])])
        learned = summarize_runs(rs)[0]  # the gap, foods and wall time as benchmarks/learn.py states them
        pair.append(
            {"algo": algo, "regime": regime, "engine": engine, "seeds": len(rs), "episodes": episodes}
            | {"iqm": point, "ci_low": lo, "ci_high": hi, "gap_closed": learned["gap_closed"]}
            | {"foods": learned["foods"], "wall_seconds_per_job": learned["wall_seconds"], "overlap": None}
        )
    sb3, batched = pair
    batched["overlap"] = bool(sb3["ci_low"] <= batched["ci_high"] and batched["ci_low"] <= sb3["ci_high"])
    return pair


ENGINE_COLUMNS = (
    "algo",
    "regime",
    "engine",
    "seeds",
    "days",
    "IQM return [95 % CI]",
    "gap closed",
    "foods",
    "wall s per job",
    "intervals overlap",
)


def engine_cells(r: dict[str, Any]) -> list[str]:
    return [
        r["algo"],
        r["regime"],
        r["engine"],
        str(r["seeds"]),
        str(r["episodes"]),
        f"{r['iqm']:.2f} [{r['ci_low']:.2f}, {r['ci_high']:.2f}]",
        f"{100 * r['gap_closed']:.0f} %",
        f"{r['foods']:.2f}",
        f"{r['wall_seconds_per_job']:.1f}",
        "" if r["overlap"] is None else ("yes" if r["overlap"] else "NO"),
    ]


def engines_cmd(
    algos: Annotated[str, typer.Option(help="comma-separated algorithms the batched engine trains")] = "ppo",
    regimes: Annotated[str, typer.Option(help="comma-separated regimes")] = "run0,run6",
    seeds: Annotated[str, typer.Option(help="comma-separated training seeds")] = "0,1,2,3,4",
    days: Annotated[
        Optional[int], typer.Option("--days", min=1, help="training days per job, both engines [default: 500]")
    ] = None,
    episodes_alias: EpisodesAlias = None,
    eval_episodes: EvalDaysOption = 10,
    markdown: MarkdownOption = False,
    device: Annotated[
        str, typer.Option(help=f"the batched engine's: {DEVICE_HELP} (the SB3 engine: the CPU)")
    ] = "auto",
    concurrent: Annotated[
        bool,
        typer.Option(
            "--concurrent",
            help="train each algorithm's batched jobs beside the SB3 pool, not after it (cores to spare)",
        ),
    ] = False,
    workers: Annotated[Optional[int], typer.Option(min=1, help="SB3 jobs trained at once (default: the cores)")] = None,
    save: Annotated[
        Optional[Path], typer.Option(help="also write every agent's evaluation returns (JSON) to this file")
    ] = None,
) -> None:
    """Train with both engines (SB3 and batched) on the same seeds and budget; per algorithm
    and regime the IQM over seeds of each agent's mean evaluation return with its 95 %
    trimmed-t interval; the two engines' intervals must overlap."""
    episodes = old_spelling(days, episodes_alias, "--days", "--episodes", 500)
    from nutribench.config import list_regimes
    from nutribench.scheduler.grid import parse_seeds
    from nutribench.scheduler.pools import check_engine

    check_engine(Engine.BATCHED, 1, device)
    if save is not None:
        check_file_target(save, "--save")
    names = split_csv(algos, batched_names(), "algorithm for the batched engine")
    regime_names = split_csv(regimes, list_regimes(), "regime")
    with console.status("training with both engines"):
        rows = bench_engines(
            names,
            regime_names,
            list(parse_seeds(seeds)),
            episodes,
            eval_episodes,
            workers=workers,
            device=device,
            concurrent=concurrent,
            save=save,
            on_done=report_engine_run,
        )
    title = f"engines: SB3 vs batched, {episodes} days, seeds {seeds}"
    print_table(ENGINE_COLUMNS, [engine_cells(r) for r in rows], title, markdown)
    walls = {r["engine"]: r["total_wall_seconds"] for r in rows}
    how = "a process per algorithm, beside the SB3 pool" if concurrent else "one process"
    console.print(
        f"wall time: SB3 {walls[Engine.SB3]:.0f} s (a process per job, one per core), batched {walls[Engine.BATCHED]:.0f} s ({how})",
        highlight=False,
    )


def report_engine_run(engine: str, run: LearnRun) -> None:
    """One line as each trained agent is in: its engine, config, regime, seed and return."""
    mean = sum(e["return"] for e in run.eval_rows) / len(run.eval_rows)
    console.print(
        f"{engine} {run.algo} {run.regime} seed {run.seed}: evaluation return {mean:.2f} (mean of "
        f"{len(run.eval_rows)} days), {run.wall_seconds:.0f} s of training",
        highlight=False,
    )


#: ``python benchmarks/engines.py [OPTIONS]``: the command (``nutribench bench engines`` until it
#: moved out of the installed package with the other developer's benchmarks)
app = typer.Typer(add_completion=False, rich_markup_mode=None)
app.command()(user_errors(engines_cmd))

if __name__ == "__main__":
    app()
