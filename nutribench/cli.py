"""The ``nutribench`` command line: a thin typer layer over the library.

Errors a user can fix (bad config files, unknown names, bad arguments) print one line and
exit with status 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.table import Table

from nutribench.config import ConfigError
from nutribench.store.engine import StoreError

app = typer.Typer(no_args_is_help=True, add_completion=False, rich_markup_mode=None, help="NutriRL: RL under delayed state transitions.")
regimes_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Inspect, check and regenerate the regime files.")
bench_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Benchmarks: env and training throughput, status speed, learnability.")
app.add_typer(regimes_app, name="regimes")
app.add_typer(bench_app, name="bench")

console = Console()
err_console = Console(stderr=True)


class UserError(Exception):
    """An error the user can fix; printed as one line."""


def user_errors(fn):
    """Turn ConfigError / UserError / StoreError from the library into one line + exit 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (ConfigError, UserError, StoreError) as e:
            err_console.print(f"[bold red]error:[/] {e}", highlight=False, soft_wrap=True)
            raise typer.Exit(2) from None

    return wrapper


def split_csv(value: str, known: list[str], what: str) -> list[str]:
    """``"all"`` or a comma-separated subset of ``known``; unknown names are a UserError."""
    if value.strip() == "all":
        return list(known)
    items = [v.strip() for v in value.split(",") if v.strip()]
    if not items:
        raise UserError(f"no {what} given: pass 'all' or a comma-separated list of {', '.join(known)}")
    unknown = [v for v in items if v not in known]
    if unknown:
        raise UserError(f"unknown {what} {', '.join(unknown)}: known are {', '.join(known)}")
    return items


# --------------------------------------------------------------------------- regimes
@regimes_app.command("list")
@user_errors
def regimes_list() -> None:
    """List the regimes with their delay ranges and content hash."""
    from nutribench.config import list_regimes, load_env_config

    table = Table("regime", "version", "description", "tau C/F/P", "sigma C/F/P", "sha256")
    for name in list_regimes():
        cfg = load_env_config(name)
        r = cfg.regime.ranges
        fmt = lambda nr: " / ".join(f"{x.low:g}-{x.high:g}" for x in (nr.C, nr.F, nr.P))  # noqa: E731
        table.add_row(name, str(cfg.version), cfg.regime.description, fmt(r.tau), fmt(r.sigma), cfg.sha256[:12])
    console.print(table)


@regimes_app.command("check")
@user_errors
def regimes_check(
    regimes: Annotated[str, typer.Option(help="'all' or comma-separated names or paths")] = "all",
) -> None:
    """Validate regime files and check that their drawn values equal a fresh draw from ranges + seed."""
    from nutribench.config import list_regimes, load_env_config
    from nutribench.config.generate import regenerate

    names = list_regimes() if regimes == "all" else [r.strip() for r in regimes.split(",")]
    bad = 0
    for name in names:
        cfg = load_env_config(name)
        fresh = regenerate(cfg.regime, cfg.catalog)
        if fresh.foods != cfg.regime.foods:
            bad += 1
            err_console.print(f"{cfg.path}: foods: values differ from a fresh draw with seed {cfg.regime.seed}")
        else:
            console.print(f"{cfg.path}: ok (sha256 {cfg.sha256[:12]})")
    if bad:
        raise typer.Exit(1)


@regimes_app.command("generate")
@user_errors
def regimes_generate(
    regime: Annotated[str, typer.Argument(help="regime name or path whose [foods] table is redrawn")],
    write: Annotated[bool, typer.Option(help="overwrite the file (else print it)")] = False,
) -> None:
    """Redraw a regime's per-food tau and sigma from its [ranges] and seed."""
    from nutribench.config import load_env_config
    from nutribench.config.generate import regenerate, regime_to_toml, write_regime

    cfg = load_env_config(regime)
    fresh = regenerate(cfg.regime, cfg.catalog)
    if write:
        write_regime(fresh, cfg.path)
        console.print(f"wrote {cfg.path}" + ("" if fresh == cfg.regime else " (values changed: bump its version)"))
    else:
        typer.echo(regime_to_toml(fresh), nl=False)


# --------------------------------------------------------------------------- baselines
@app.command()
@user_errors
def baselines(
    regimes: Annotated[str, typer.Option(help="'all' or comma-separated regime names")] = "all",
    episodes: Annotated[int, typer.Option(min=1, help="episodes per policy and regime")] = 200,
    seed: Annotated[int, typer.Option(help="seed of the food streams (the same for every policy)")] = 0,
    markdown: Annotated[bool, typer.Option(help="print a Markdown table instead of a rich one")] = False,
) -> None:
    """Mean return, foods eaten, final distance and overshoot ratio of the simple policies."""
    from nutribench.baselines import POLICY_ORDER, baseline_table
    from nutribench.config import list_regimes

    names = split_csv(regimes, list_regimes(), "regime")
    rows = baseline_table(names, episodes=episodes, seed=seed)
    headers = ["regime", "policy", "return", "foods", "final distance", "overshoot ratio"]
    cells = [
        [r["regime"], r["policy"], f"{r['return']:.2f}", f"{r['foods']:.2f}", f"{r['final_distance']:.3f}", f"{r['overshoot_ratio']:.3f}"]
        for r in rows
    ]
    if markdown:
        typer.echo("| " + " | ".join(headers) + " |")
        typer.echo("|" + "---|" * len(headers))
        for c in cells:
            typer.echo("| " + " | ".join(c) + " |")
        return
    table = Table(*headers, title=f"Simple policies, {episodes} episodes each (seed {seed}); means")
    for i, c in enumerate(cells):
        table.add_row(*c, end_section=(i + 1) % len(POLICY_ORDER) == 0)
    console.print(table)


# --------------------------------------------------------------------------- bench
@bench_app.command("env")
@user_errors
def bench_env_cmd(
    regimes: Annotated[str, typer.Option(help="comma-separated regimes")] = "run0,run6",
    sizes: Annotated[str, typer.Option(help="comma-separated vector env sizes")] = "1,64,1024,4096",
    repeats: Annotated[int, typer.Option(min=1, help="timed repeats; the median is reported")] = 5,
) -> None:
    """Env-steps per second of the single env and the vector env (random actions)."""
    from nutribench.bench import bench_env
    from nutribench.config import list_regimes

    names = split_csv(regimes, list_regimes(), "regime")
    try:
        ns = [int(s) for s in sizes.split(",")]
    except ValueError:
        raise UserError(f"--sizes must be comma-separated integers, got '{sizes}'") from None
    table = Table("regime", "env", "num_envs", "env-steps/s (median)")
    for r in bench_env(names, ns, repeats=repeats):
        table.add_row(r["regime"], r["env"], str(r["num_envs"]), f"{r['steps_per_s']:,.0f}")
    console.print(table)


# ---- agents (issue 3): train, bench train ----
@app.command("train")
@user_errors
def train_cmd(
    algo: Annotated[str, typer.Option(help="agent config name (regimes/agents/<name>.toml) or a .toml path")] = "ppo",
    regime: Annotated[str, typer.Option(help="regime name or file")] = "run0",
    seed: Annotated[int, typer.Option(help="training seed; the evaluation days derive from it")] = 0,
    episodes: Annotated[int, typer.Option(min=1, help="training days (episodes of 50 steps)")] = 300,
    eval_episodes: Annotated[int, typer.Option(min=1, help="greedy evaluation days")] = 5,
    save: Annotated[Optional[Path], typer.Option(help="save the trained model here (.zip + .json)")] = None,
) -> None:
    """Train one agent in the foreground, then evaluate it greedily and print the metrics."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from nutribench.agents import eval_food_streams, evaluate, load_agent_config, train
    from nutribench.agents.api import vec_normalize_path
    from nutribench.config import load_env_config

    env_cfg = load_env_config(regime)
    cfg = load_agent_config(algo)
    if save is not None and save.suffix != ".zip":
        raise UserError(f"--save {save}: the model file must end in .zip")
    if save is not None and not save.parent.is_dir():
        raise UserError(f"--save {save}: folder {save.parent} does not exist")
    recent: list[dict] = []
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[stats]}"),
               TimeElapsedColumn(), TimeRemainingColumn())  # fmt: skip
    with Progress(*columns, console=console, transient=False) as progress:
        task = progress.add_task(f"{cfg.name} on {env_cfg.name}, seed {seed}", total=episodes, stats="")

        def on_episode(row: dict) -> None:
            recent.append(row)
            last = recent[-20:]
            ret = sum(r["return"] for r in last) / len(last)
            foods = sum(r["foods"] for r in last) / len(last)
            progress.update(task, advance=1, stats=f"return {ret:8.2f}  foods {foods:5.2f} (last {len(last)})")

        agent = train(env_cfg, cfg, seed=seed, episodes=episodes, on_episode=on_episode)
    result = evaluate(agent, env_cfg, eval_food_streams(env_cfg, seed, eval_episodes), record_steps=False)
    table = Table("eval day", "return", "foods", "final distance", "overshoot ratio", "final C/F/P", title="greedy evaluation")
    for r in result.episodes:
        table.add_row(str(r["episode"]), f"{r['return']:.2f}", str(r["foods"]), f"{r['final_distance']:.3f}",
                      f"{r['overshoot_ratio']:.2f}", f"{r['final_C']:.2f} / {r['final_F']:.2f} / {r['final_P']:.2f}")  # fmt: skip
    n = len(result.episodes)
    mean = lambda k: sum(r[k] for r in result.episodes) / n  # noqa: E731
    table.add_row("mean", f"{mean('return'):.2f}", f"{mean('foods'):.2f}", f"{mean('final_distance'):.3f}", f"{mean('overshoot_ratio'):.2f}", "")
    console.print(table)
    if save is not None:
        path = agent.save(save)
        extra = [p.name for p in (vec_normalize_path(path), path.with_suffix(".json")) if p.is_file()]
        console.print(f"model saved to {path} (+ {', '.join(extra)}; README \"Agents\" shows how to load it with plain SB3)")


@bench_app.command("train")
@user_errors
def bench_train_cmd(
    algos: Annotated[str, typer.Option(help="'all' or comma-separated algorithms")] = "all",
    regime: Annotated[str, typer.Option(help="regime")] = "run0",
    episodes: Annotated[int, typer.Option(min=1, help="training days per timed run")] = 100,
    repeats: Annotated[int, typer.Option(min=1, help="timed repeats; the median is reported")] = 3,
) -> None:
    """Training env-steps per second of each algorithm, and of bare SB3 PPO / DQN on the same
    env (the overhead of nutribench's plumbing), with the paper grid's CPU-hours at that rate."""
    from nutribench.agents.config import ALGOS
    from nutribench.bench import bench_train
    from nutribench.config import load_env_config

    names = split_csv(algos, list(ALGOS), "algorithm")
    load_env_config(regime)
    rows = bench_train(names, regime=regime, episodes=episodes, repeats=repeats)
    table = Table("run", "env-steps/s (median)", "vs bare SB3 (paired median)", "paper grid CPU-hours",
                  title=f"training throughput, {regime}, {episodes} days x {repeats}")  # fmt: skip
    for r in rows:
        ratio = f"{r['vs_bare']:.3f}" if "vs_bare" in r else ""
        table.add_row(r["what"], f"{r['steps_per_s']:,.0f}", ratio, f"{r['paper_grid_cpu_hours']:.1f}")
    console.print(table)
    total = sum(r["paper_grid_cpu_hours"] for r in rows if not r["bare"])
    console.print(f"paper grid (7 regimes x 5 seeds x 5000 days per algorithm, all 5 algorithms): ~{total:.0f} CPU-hours")



@bench_app.command("learn")
@user_errors
def bench_learn_cmd(
    algos: Annotated[str, typer.Option(help="'all' or comma-separated agent config names")] = "all",
    regimes: Annotated[str, typer.Option(help="'all' or comma-separated regimes; run0 carries the targets")] = "run0,run3,run6",
    seeds: Annotated[str, typer.Option(help="comma-separated training seeds")] = "0,1,2",
    episodes: Annotated[str, typer.Option(help="training days: a default, then NAME=N for a config or algorithm")] = "500,ddqn=2000",
    eval_episodes: Annotated[int, typer.Option(min=1, help="greedy evaluation days per trained agent")] = 10,
    workers: Annotated[Optional[int], typer.Option(min=1, help="agents trained at once (default: the cores)")] = None,
    markdown: Annotated[bool, typer.Option("--markdown", help="print a Markdown table")] = False,
) -> None:
    """Train every agent for a budget over several seeds, evaluate greedily on the fixed
    evaluation days, and state each as the share of the never -> planner gap it closes
    (run0 target: at least 75 % with 3-6 foods a day)."""
    from nutribench.agents.config import ALGOS, list_agent_configs
    from nutribench.bench_learn import COLUMNS, DEFAULT_BUDGET, learn_benchmark, markdown_table, row_cells, summarize
    from nutribench.config import list_regimes
    from nutribench.scheduler.grid import GridError, parse_seeds

    names = split_csv(algos, list_agent_configs()[:5] if algos == "all" else list_agent_configs(), "agent config")
    regime_names = split_csv(regimes, list_regimes(), "regime")
    try:
        seed_list = list(parse_seeds(seeds))
    except GridError as e:
        raise UserError(str(e)) from None
    default, budgets = parse_budgets(episodes, DEFAULT_BUDGET)
    unknown = sorted(set(budgets) - set(list_agent_configs()) - set(ALGOS))
    if unknown:
        raise UserError(f"--episodes {episodes!r}: no agent config or algorithm {', '.join(unknown)} (known: {', '.join(list_agent_configs())})")
    with console.status("training") as status:
        runs = learn_benchmark(
            names, regime_names, seed_list, budgets=budgets, default_budget=default, eval_episodes=eval_episodes,
            workers=workers, on_done=lambda r, k, n: status.update(f"{k}/{n} done (last: {r.algo} {r.regime} seed {r.seed})"),
        )  # fmt: skip
    rows = summarize(runs)
    if markdown:
        console.print(markdown_table(rows), highlight=False, soft_wrap=True)
        return
    table = Table(*COLUMNS, title=f"learnability, seeds {seeds}, {eval_episodes} eval days each")
    for r in rows:
        cells = row_cells(r)
        if r["target_met"] is not None:
            cells[-1] = f"[{'green' if r['target_met'] else 'red'}]{cells[-1]}"
        table.add_row(*cells)
    console.print(table)


def parse_budgets(value: str, default: int) -> tuple[int, dict[str, int]]:
    """``"500,ddqn=2000"`` -> ``(500, {"ddqn": 2000})``."""
    budgets: dict[str, int] = {}
    for item in (v.strip() for v in value.split(",") if v.strip()):
        name, _, n = item.rpartition("=")
        try:
            days = int(n)
        except ValueError:
            raise UserError(f"--episodes {item!r}: expected N or NAME=N with N a whole number of days, e.g. 500,ddqn=2000") from None
        if days < 1:
            raise UserError(f"--episodes {item!r}: the number of days must be >= 1")
        if name:
            budgets[name] = days
        else:
            default = days
    return default, budgets


@bench_app.command("status")
@user_errors
def bench_status_cmd(
    db: Annotated[Optional[str], typer.Option(help="time this database instead of building a synthetic paper grid")] = None,
    repeats: Annotated[int, typer.Option(min=1, help="timed repeats; the median is reported")] = 5,
) -> None:
    """Time `nutribench status` on a database holding the full paper grid (175 jobs,
    875,000 training-day rows of synthetic jobs; building it takes a few minutes)."""
    from nutribench.bench import bench_status

    if db is None:
        console.print("building a synthetic paper-grid database (175 fake jobs x 5000 days) ...")
    r = bench_status(db, repeats=repeats)
    if r["build_seconds"] is not None:
        console.print(f"built {r['db']} in {r['build_seconds']:.0f} s")
    console.print(f"{r['jobs']} jobs, {r['episode_rows']:,} episode rows, {r['db_mb']:.0f} MB")
    console.print(f"status_table(): {r['status_table_s']:.3f} s   `nutribench status --json`: {r['status_cli_s']:.2f} s "
                  f"(medians of {repeats}; the CLI figure includes Python start-up)")


# ---- runs (issue 4): run, status ----
from nutribench.scheduler.cli_commands import run_cmd, status_cmd  # noqa: E402

app.command("run")(run_cmd)
app.command("status")(status_cmd)


def main() -> None:  # pragma: no cover
    app()


from nutribench.report.cli_commands import report_cmd  # noqa: E402  (issue 5)

app.command("report")(report_cmd)


if __name__ == "__main__":  # pragma: no cover
    main()
