"""Learnability benchmark: does each agent learn the task, and how much of it?

``python benchmarks/learn.py`` trains every agent config on run0 (and, for the record, on
delayed regimes) for a fixed budget over several seeds, plays each trained agent greedily
on the job seed's fixed evaluation days (:func:`~nutribench.agents.eval_food_streams`,
the days every algorithm of that seed is evaluated on), and states the result against the
reference policies played on the very same days:

    gap closed = (return - return of never) / (return of planner - return of never)

0 is "never eat", 1 the full-information greedy planner (which is not optimal, so a
learner may exceed 1). A benchmark, not a test: it takes minutes per algorithm. A
developer's script, not part of the installed package: run it from a checkout,
``python benchmarks/learn.py --help`` for its options.

::

    from learn import learn_benchmark, summarize_runs   # with benchmarks/ on sys.path
    runs = learn_benchmark(["ppo"], ["run0"], seeds=[0, 1, 2], budgets={"ppo": 500})
    print(summarize_runs(runs))
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Annotated, Any, Optional

import numpy as np
import typer

from nutribench.baselines import day_yardsticks, gap_closed
from nutribench.cli.common import (
    DEVICE_HELP,
    EvalDaysOption,
    MarkdownOption,
    UserError,
    WorkersOption,
    console,
    old_spelling,
    print_table,
    split_csv,
    user_errors,
)
from nutribench.engines import Engine
from nutribench.stats import iqm

#: The run0 target of every agent: the share of the never -> planner gap it closes, and the foods a day.
TARGET_GAP = 0.75
TARGET_FOODS = (3.0, 6.0)
DEFAULT_BUDGET = 500
LEARN_EVAL_EPISODES = 10


def default_budgets() -> dict[str, int]:
    """The algorithms whose registry entry gives a budget of its own (``bench_days``: DDQN's
    epsilon schedule and 10k-step warm-up, the paper's Table 3, make it slower by design)."""
    from nutribench.agents.registry import algorithms

    return {a: e.bench_days for a, e in algorithms().items() if e.bench_days is not None}


@dataclass(frozen=True)
class LearnRun:
    """One trained agent, evaluated: per evaluation day its metrics, and the reference
    policies' returns on the same days."""

    algo: str
    regime: str
    seed: int
    episodes: int
    wall_seconds: float
    eval_rows: list[dict[str, Any]]
    never_returns: list[float]
    planner_returns: list[float]


def one_run(config: Any, regime: str, seed: int, episodes: int, eval_episodes: int) -> LearnRun:
    """One learnability run: ``config`` trained on ``regime`` with ``seed`` for ``episodes``
    days (SB3 engine), then played greedily on the seed's first ``eval_episodes`` evaluation
    days; its :class:`LearnRun` (returns, share of the gap, wall time)."""
    from nutribench.agents import train

    start = time.perf_counter()
    agent = train(regime, config, seed=seed, episodes=episodes)
    return evaluated(agent, config.name, regime, seed, episodes, time.perf_counter() - start, eval_episodes)


def evaluated(
    agent: Any, name: str, regime: str, seed: int, episodes: int, wall: float, eval_episodes: int
) -> LearnRun:
    """``agent`` (config ``name``, trained ``episodes`` days in ``wall`` seconds) played greedily
    on the first ``eval_episodes`` evaluation days of ``seed``, and the reference policies on them."""
    from nutribench.agents import eval_food_streams, evaluate

    streams = eval_food_streams(regime, seed, eval_episodes)
    rows = evaluate(agent, regime, streams, record_steps=False).episodes
    ref = day_yardsticks(regime, streams)
    return LearnRun(name, regime, seed, episodes, wall, rows, [d["never"] for d in ref], [d["planner"] for d in ref])


def batched_runs(
    config: Any, regimes: list[str], seeds: list[int], episodes: int, eval_episodes: int, device: str = "cpu"
) -> list[LearnRun]:
    """Every (regime, seed) of ``config`` trained at once by the batched engine on ``device``, then evaluated."""
    from nutribench.agents import load_agent_config
    from nutribench.engine.train import train_batched

    cfg = load_agent_config(config)
    jobs = [(r, s) for r in regimes for s in seeds]
    start = time.perf_counter()
    agents = train_batched(jobs, cfg, episodes, device=device)
    wall = (time.perf_counter() - start) / len(jobs)
    return [evaluated(agent, cfg.name, r, s, episodes, wall, eval_episodes) for (r, s), agent in zip(jobs, agents)]


def budget_for(name: str, algo: str, budgets: dict[str, int], default: int) -> int:
    """The budget of config ``name`` (algorithm ``algo``): by name, then by algorithm."""
    return budgets.get(name, budgets.get(algo, default))


def learn_benchmark(
    configs: Iterable[str | Any],
    regimes: Iterable[str],
    seeds: Iterable[int],
    budgets: dict[str, int] | None = None,
    default_budget: int = DEFAULT_BUDGET,
    eval_episodes: int = LEARN_EVAL_EPISODES,
    workers: int | None = None,
    on_done: Callable[[LearnRun, int, int], None] | None = None,
    engine: str = Engine.SB3,
    device: str = "cpu",
) -> list[LearnRun]:
    """Train and evaluate every (config, regime, seed) on a process pool (one torch thread
    each); ``budgets`` maps a config name or algorithm to its training days.
    ``on_done(run, k, total)`` is called as each finishes. ``engine="batched"``: each
    config's jobs trained at once by the batched engine, in this process, on ``device``
    (the SB3 engine trains on the CPU)."""
    from nutribench.agents import load_agent_config

    budgets = dict(default_budgets() if budgets is None else budgets)
    cfgs = [load_agent_config(c) for c in configs]
    regimes, seeds = list(regimes), list(seeds)
    if engine == Engine.BATCHED:
        out: list[LearnRun] = []
        for c in cfgs:
            out += batched_runs(
                c, regimes, seeds, budget_for(c.name, c.algo, budgets, default_budget), eval_episodes, device
            )
            if on_done is not None:
                on_done(out[-1], len(out), len(cfgs) * len(regimes) * len(seeds))
        return out
    if engine != Engine.SB3:
        raise ValueError(f"engine {engine!r}: use 'sb3' or 'batched'")
    jobs = [
        (c, r, s, budget_for(c.name, c.algo, budgets, default_budget)) for c in cfgs for r in regimes for s in seeds
    ]
    # the longest first, so that no long job starts last
    from nutribench.agents.registry import get

    jobs.sort(key=lambda j: -j[3] * get(j[0].algo).cost)
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    runs: list[LearnRun] = []
    # forkserver, as the scheduler's pool: a child forked from a parent that touched CUDA
    # fails at its first CUDA call (even torch's CPU Adam asks), seen on a GPU machine
    context = multiprocessing.get_context(
        "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
    )
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        futures = [pool.submit(one_run, c, r, s, n, eval_episodes) for c, r, s, n in jobs]
        for fut in as_completed(futures):
            runs.append(fut.result())
            if on_done is not None:
                on_done(runs[-1], len(runs), len(jobs))
    names = [c.name for c in cfgs]
    return sorted(runs, key=lambda x: (regimes.index(x.regime), names.index(x.algo), seeds.index(x.seed)))


def summarize_runs(runs: list[LearnRun]) -> list[dict[str, Any]]:
    """One row per (regime, config) over its seeds x evaluation days: return (mean, IQM),
    foods, final distance, overshoot ratio, the never and planner returns on those days, the
    gap closed (of the means; and its lowest seed), wall seconds per job, and, on run0,
    whether the run0 target (:data:`TARGET_GAP`, :data:`TARGET_FOODS`) holds."""
    groups: dict[tuple[str, str], list[LearnRun]] = {}
    for run in runs:
        groups.setdefault((run.regime, run.algo), []).append(run)
    rows = []
    for (regime, algo), rs in groups.items():
        ret = np.array([e["return"] for r in rs for e in r.eval_rows])
        never = float(np.mean([x for r in rs for x in r.never_returns]))
        planner = float(np.mean([x for r in rs for x in r.planner_returns]))
        per_seed = [
            gap_closed(
                np.mean([e["return"] for e in r.eval_rows]), np.mean(r.never_returns), np.mean(r.planner_returns)
            )
            for r in rs
        ]
        foods = float(np.mean([e["foods"] for r in rs for e in r.eval_rows]))
        gap = gap_closed(float(ret.mean()), never, planner)
        row = {
            "regime": regime,
            "algo": algo,
            "episodes": rs[0].episodes,
            "seeds": len(rs),
            "return": float(ret.mean()),
            "return_iqm": iqm(ret),
            "foods": foods,
            "final_distance": float(np.mean([e["final_distance"] for r in rs for e in r.eval_rows])),
            "overshoot_ratio": float(np.mean([e["overshoot_ratio"] for r in rs for e in r.eval_rows])),
            "never": never,
            "planner": planner,
            "gap_closed": gap,
            "gap_closed_min_seed": float(min(per_seed)),
            "wall_seconds": float(np.median([r.wall_seconds for r in rs])),
        }
        row["target_met"] = (
            (gap >= TARGET_GAP and TARGET_FOODS[0] <= foods <= TARGET_FOODS[1]) if regime == "run0" else None
        )
        rows.append(row)
    return rows


#: Columns of the summary tables (Markdown and the terminal's), one cell each per row.
LEARN_COLUMNS = (
    "regime",
    "algo",
    "days",
    "seeds",
    "return",
    "IQM",
    "foods",
    "final distance",
    "overshoot ratio",
    "never",
    "planner",
    "gap closed",
    "lowest seed",
    "target",
)


def row_cells(r: dict[str, Any]) -> list[str]:
    """One summary row as the text of each of :data:`LEARN_COLUMNS`."""
    return [
        r["regime"],
        r["algo"],
        str(r["episodes"]),
        str(r["seeds"]),
        f"{r['return']:.2f}",
        f"{r['return_iqm']:.2f}",
        f"{r['foods']:.2f}",
        f"{r['final_distance']:.3f}",
        f"{r['overshoot_ratio']:.3f}",
        f"{r['never']:.2f}",
        f"{r['planner']:.2f}",
        f"{100 * r['gap_closed']:.0f} %",
        f"{100 * r['gap_closed_min_seed']:.0f} %",
        "" if r["target_met"] is None else ("met" if r["target_met"] else "not met"),  # no target but on run0
    ]


def markdown_table(
    rows: list[dict[str, Any]], columns: Sequence[str] = LEARN_COLUMNS, cells: Callable[[dict], list[str]] | None = None
) -> str:
    """The summary as a Markdown table (what the README records); ``columns`` and ``cells``
    (one row's texts, :func:`row_cells` by default) for another bench's rows."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join((cells or row_cells)(r)) + " |" for r in rows]
    return "\n".join(lines)


def learn_cmd(
    algos: Annotated[str, typer.Option(help="'all' or comma-separated agent config names")] = "all",
    regimes: Annotated[
        str, typer.Option(help="'all' or comma-separated regimes; run0 carries the targets")
    ] = "run0,run3,run6",
    seeds: Annotated[str, typer.Option(help="comma-separated training seeds")] = "0,1,2",
    days: Annotated[
        Optional[str],
        typer.Option(
            "--days", help="training days: a default, then NAME=N for a config or algorithm [default: 500,ddqn=2000]"
        ),
    ] = None,
    episodes_alias: Annotated[Optional[str], typer.Option("--episodes", hidden=True)] = None,
    eval_episodes: EvalDaysOption = 10,
    workers: WorkersOption = None,
    markdown: MarkdownOption = False,
    engine: Annotated[
        str,
        typer.Option(
            help="'sb3' (the reference), or 'batched' (every config's seeds and regimes at once: fast sweeps)"
        ),
    ] = Engine.SB3.value,
    device: Annotated[str, typer.Option(help=f"--engine batched: {DEVICE_HELP} (the SB3 engine: the CPU)")] = "auto",
) -> None:
    """Train every agent for a budget over several seeds, evaluate greedily on the fixed
    evaluation days, and state each as the share of the never -> planner gap it closes
    (run0 target: at least 75 % with 3-6 foods a day)."""
    episodes = old_spelling(days, episodes_alias, "--days", "--episodes", "500,ddqn=2000")
    from nutribench.agents.config import list_agent_configs, where_agents_are
    from nutribench.config import list_regimes
    from nutribench.scheduler.grid import parse_seeds

    known = list_agent_configs()[:5] if algos == "all" else list_agent_configs()
    names = split_csv(algos, known, "agent config", where_agents_are())
    regime_names = split_csv(regimes, list_regimes(), "regime")
    seed_list = list(parse_seeds(seeds))
    default, budgets = parse_budgets(episodes, DEFAULT_BUDGET)
    check_learn(names, budgets, episodes, engine, device)
    with console.status("training") as status:
        runs = learn_benchmark(
            names,
            regime_names,
            seed_list,
            budgets=budgets,
            default_budget=default,
            eval_episodes=eval_episodes,
            workers=workers,
            on_done=lambda r, k, n: status.update(f"{k}/{n} done (last: {r.algo} {r.regime} seed {r.seed})"),
            engine=engine,
            device=device,
        )
    rows = summarize_runs(runs)
    cells = [row_cells(r) for r in rows]
    for r, c in zip(rows, cells, strict=True):
        if r["target_met"] is not None and not markdown:
            c[-1] = f"[{'green' if r['target_met'] else 'red'}]{c[-1]}"
    print_table(LEARN_COLUMNS, cells, f"learnability, seeds {seeds}, {eval_episodes} eval days each", markdown)


def check_learn(names: list[str], budgets: dict[str, int], given: str, engine: str, device: str) -> None:
    """A budget for no known config or algorithm, a bad engine or device, or a config the
    batched engine cannot train, one line each, before anything trains."""
    from nutribench.agents.config import list_agent_configs, load_agent_config
    from nutribench.agents.registry import batched_names
    from nutribench.agents.registry import names as algo_names
    from nutribench.scheduler.pools import check_engine

    unknown = sorted(set(budgets) - set(list_agent_configs()) - set(algo_names()))
    if unknown:
        raise UserError(
            f"--days {given!r}: no agent config or algorithm {', '.join(unknown)} (known: {', '.join(list_agent_configs())})"
        )
    check_engine(engine, 1, device)
    other = [n for n in names if load_agent_config(n).algo not in batched_names()] if engine == Engine.BATCHED else []
    if other:
        raise UserError(
            f"--engine batched trains {', '.join(batched_names())} configs, not {', '.join(other)}: use --engine sb3"
        )


def parse_budgets(value: str, default: int) -> tuple[int, dict[str, int]]:
    """``"500,ddqn=2000"`` -> ``(500, {"ddqn": 2000})``."""
    budgets: dict[str, int] = {}
    for item in (v.strip() for v in value.split(",") if v.strip()):
        name, _, n = item.rpartition("=")
        try:
            days = int(n)
        except ValueError:
            raise UserError(
                f"--days {item!r}: expected N or NAME=N with N a whole number of days, e.g. 500,ddqn=2000"
            ) from None
        if days < 1:
            raise UserError(f"--days {item!r}: the number of days must be >= 1")
        if name:
            budgets[name] = days
        else:
            default = days
    return default, budgets


#: ``python benchmarks/learn.py [OPTIONS]``: the command (``nutribench bench learn`` until it
#: moved out of the installed package with the other developer's benchmarks)
app = typer.Typer(add_completion=False, rich_markup_mode=None)
app.command()(user_errors(learn_cmd))

if __name__ == "__main__":
    app()
