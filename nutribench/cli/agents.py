"""``nutribench baselines`` and ``nutribench train``: the simple policies and one agent in the foreground."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from nutribench.cli.common import (
    EVAL_EVERY_HELP,
    VAL_EPISODES_HELP,
    UserError,
    check_range,
    check_tensorboard,
    console,
    folder_option,
    old_spelling,
    split_csv,
    user_errors,
)


@user_errors
def baselines(
    regimes: Annotated[str, typer.Option(help="'all' or comma-separated regime names")] = "all",
    episodes: Annotated[
        Optional[int], typer.Option("--eval-episodes", min=1, help="days played per policy and regime [default: 200]")
    ] = None,
    old_episodes: Annotated[Optional[int], typer.Option("--episodes", min=1, hidden=True)] = None,
    seed: Annotated[int, typer.Option(help="seed of the food streams (the same for every policy)")] = 0,
    strong_days: Annotated[
        int,
        typer.Option(
            min=0,
            help="days (the first of the same streams) that lookahead and clairvoyant play per regime; 0: neither",
        ),
    ] = 10,
    samples: Annotated[int, typer.Option(min=1, help="sampled futures a lookahead step weighs each action on")] = 64,
    test_days: Annotated[
        bool,
        typer.Option(
            "--test-days",
            help="instead: never, planner, lookahead (256 futures) and clairvoyant on the paper's test days "
            "(seeds 0,21,9,2003,1997 x their 5 evaluation days), the shares of the gap per regime",
        ),
    ] = False,
    out: Annotated[
        Optional[Path],
        typer.Option(help="with --test-days: write the per-day returns to this CSV (regimes/references.csv)"),
    ] = None,
    markdown: Annotated[bool, typer.Option(help="print a Markdown table instead of a rich one")] = False,
) -> None:
    """Mean return, foods eaten, final distance, overshoot ratio and share of the never -> planner
    gap of the reference policies (random, never, always, planner; lookahead and clairvoyant on
    the first --strong-days days)."""
    from nutribench.baselines import baseline_table
    from nutribench.config import list_regimes
    from nutribench.scheduler.grid import MAX_EVAL_DAYS, MAX_SEED

    episodes = old_spelling(episodes, old_episodes, "--eval-episodes", "--episodes", 200)
    check_range("--seed", seed, 0, MAX_SEED)
    check_range("--eval-episodes", episodes, 1, MAX_EVAL_DAYS, "the days are played side by side")
    names = split_csv(regimes, list_regimes(), "regime")
    if out is not None and not test_days:
        raise UserError("--out writes the test days' references: add --test-days")
    if test_days:
        return _test_day_table(names, out, markdown)
    rows = baseline_table(names, episodes=episodes, seed=seed, strong_days=strong_days, samples=samples)
    headers = [
        "regime",
        "policy",
        "days",
        "return",
        "foods",
        "final distance",
        "overshoot ratio",
        "gap closed",
        "search",
    ]
    cells = [
        [
            r["regime"],
            r["policy"],
            str(r["days"]),
            f"{r['return']:.2f}",
            f"{r['foods']:.2f}",
            f"{r['final_distance']:.3f}",
            f"{r['overshoot_ratio']:.3f}",
            f"{100 * r['gap']:.1f} %",
            r.get("search", ""),
        ]
        for r in rows
    ]
    title = (
        f"Reference policies on the days of seed {seed} (lookahead and clairvoyant on the first {strong_days}); means; "
        "gap closed: share of the never -> planner gap on the row's days"
    )
    _print_table(headers, cells, [r["regime"] for r in rows], title, markdown)


def _print_table(headers: list[str], cells: list[list[str]], groups: list[str], title: str, markdown: bool) -> None:
    """A Markdown table, or a rich one with a rule between ``groups``."""
    if markdown:
        typer.echo("| " + " | ".join(headers) + " |")
        typer.echo("|" + "---|" * len(headers))
        for c in cells:
            typer.echo("| " + " | ".join(c) + " |")
        return
    table = Table(*headers, title=title)
    for i, c in enumerate(cells):
        table.add_row(*c, end_section=i + 1 == len(cells) or groups[i + 1] != groups[i])
    console.print(table)


def _test_day_table(names: list[str], out: Path | None, markdown: bool) -> None:
    """``baselines --test-days``: the four yardsticks on the paper's test days, per regime."""
    import time

    import pandas as pd

    from nutribench.baselines import REFERENCE_COLUMNS, TEST_DAY_SAMPLES, gap_closed, test_day_references
    from nutribench.safe_write import atomic_write, check_file_target
    from nutribench.scheduler.grid import PRESETS

    seeds = PRESETS["paper"].seeds
    if out is not None:
        check_file_target(out, "--out")  # before the minutes of planning, not after
    rows, cells = [], []
    for regime in names:
        start = time.perf_counter()
        days = test_day_references(regime, seeds)
        wall = time.perf_counter() - start
        rows += days
        mean = {k: sum(d[k] for d in days) / len(days) for k in ("never", "planner", "lookahead", "clairvoyant")}
        exact = sum(d["search"] == "exact" for d in days)
        cells.append(
            [regime, str(len(days))]
            + [f"{mean[k]:.3f}" for k in ("never", "planner", "lookahead", "clairvoyant")]
            + [
                f"{100 * gap_closed(mean[k], mean['never'], mean['planner']):.1f} %"
                for k in ("lookahead", "clairvoyant")
            ]
            + [f"exact {exact}/{len(days)}", f"{wall:.0f} s"]
        )
    if out is not None:
        with atomic_write(out, "--out") as tmp:
            pd.DataFrame(rows, columns=list(REFERENCE_COLUMNS)).to_csv(tmp, index=False)
    headers = ["regime", "days", "never", "planner", "lookahead", "clairvoyant", "lookahead %", "clairvoyant %"]
    title = (
        f"The paper's test days (seeds {','.join(map(str, seeds))} x 5): mean returns; % = share of the never -> "
        f"planner gap; lookahead {TEST_DAY_SAMPLES} futures a step"
    )
    _print_table(headers + ["clairvoyant search", "time"], cells, names, title, markdown)


def validation_printer(out, env_cfg, seed: int, n: int):
    """``train``'s ``on_validation``: one line per evaluation during training (mean return on the
    validation days, the share of the never -> planner gap it closes there)."""
    from nutribench.baselines import gap_closed, validation_yardsticks

    yard = validation_yardsticks(env_cfg, seed, n)

    def show(_: int, day: int, rows: list[dict]) -> None:
        ret = sum(r["return"] for r in rows) / len(rows)
        share = gap_closed(ret, yard["never"], yard["planner"])
        out.print(f"validation after day {day}: return {ret:.2f} on {len(rows)} days, gap closed {share:.0%}")

    return show


@user_errors
def train_cmd(
    algo: Annotated[str, typer.Option(help="agent config name (regimes/agents/<name>.toml) or a .toml path")] = "ppo",
    regime: Annotated[str, typer.Option(help="regime name or file")] = "run0",
    seed: Annotated[int, typer.Option(help="training seed; the evaluation days derive from it")] = 0,
    days: Annotated[
        Optional[int], typer.Option("--days", min=1, help="training days (episodes of 50 steps) [default: 300]")
    ] = None,
    episodes_alias: Annotated[Optional[int], typer.Option("--episodes", min=1, hidden=True)] = None,
    eval_episodes: Annotated[int, typer.Option(min=1, help="greedy evaluation days")] = 5,
    save: Annotated[Optional[Path], typer.Option(help="save the trained model here (.zip + .json)")] = None,
    tensorboard_given: Annotated[
        Optional[str],
        typer.Option(
            "--tensorboard",
            metavar="PATH",
            help="also write the training diagnostics as TensorBoard events under this folder "
            "(run folder <algo>-<regime>-seed<seed>)",
        ),
    ] = None,
    eval_every: Annotated[int, typer.Option(min=0, help=EVAL_EVERY_HELP)] = 0,
    val_episodes: Annotated[int, typer.Option(min=1, help=VAL_EPISODES_HELP)] = 5,
) -> None:
    """Train one agent in the foreground, then evaluate it greedily and print the metrics."""
    episodes = old_spelling(days, episodes_alias, "--days", "--episodes", 300)
    tensorboard = folder_option(tensorboard_given, "--tensorboard")  # '' is refused, not the current folder
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from nutribench.agents import eval_food_streams, evaluate, load_agent_config, train
    from nutribench.agents.api import vec_normalize_path
    from nutribench.config import load_env_config
    from nutribench.safe_write import check_file_target
    from nutribench.scheduler.grid import MAX_EPISODES, MAX_EVAL_DAYS, MAX_SEED

    check_range("--seed", seed, 0, MAX_SEED)
    check_range("--days", episodes, 1, MAX_EPISODES)
    check_range("--eval-episodes", eval_episodes, 1, MAX_EVAL_DAYS, "the days are played side by side")
    env_cfg = load_env_config(regime)
    cfg = load_agent_config(algo)
    if save is not None and save.suffix != ".zip":
        raise UserError(f"--save {save}: the model file must end in .zip")
    if save is not None and not save.parent.is_dir():
        raise UserError(f"--save {save}: folder {save.parent} does not exist")
    if save is not None:
        for written in (save, vec_normalize_path(save), save.with_suffix(".json")):
            check_file_target(written, "--save", UserError)
    run_dir = None
    if tensorboard is not None:
        check_tensorboard(tensorboard)
        run_dir = tensorboard / f"{cfg.name}-{env_cfg.name}-seed{seed}"
    recent: list[dict] = []
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[stats]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console, transient=False) as progress:
        task = progress.add_task(f"{cfg.name} on {env_cfg.name}, seed {seed}", total=episodes, stats="")

        def on_episode(row: dict) -> None:
            recent.append(row)
            last = recent[-20:]
            ret = sum(r["return"] for r in last) / len(last)
            foods = sum(r["foods"] for r in last) / len(last)
            progress.update(task, advance=1, stats=f"return {ret:8.2f}  foods {foods:5.2f} (last {len(last)})")

        on_validation = validation_printer(progress.console, env_cfg, seed, val_episodes) if eval_every else None
        agent = train(
            env_cfg,
            cfg,
            seed=seed,
            episodes=episodes,
            on_episode=on_episode,
            tensorboard=run_dir,
            eval_every=eval_every,
            val_episodes=val_episodes,
            on_validation=on_validation,
        )
    result = evaluate(agent, env_cfg, eval_food_streams(env_cfg, seed, eval_episodes), record_steps=False)
    table = Table(
        "eval day", "return", "foods", "final distance", "overshoot ratio", "final C/F/P", title="greedy evaluation"
    )
    for r in result.episodes:
        table.add_row(
            str(r["episode"]),
            f"{r['return']:.2f}",
            str(r["foods"]),
            f"{r['final_distance']:.3f}",
            f"{r['overshoot_ratio']:.2f}",
            f"{r['final_C']:.2f} / {r['final_F']:.2f} / {r['final_P']:.2f}",
        )
    n = len(result.episodes)
    mean = lambda k: sum(r[k] for r in result.episodes) / n  # noqa: E731
    table.add_row(
        "mean",
        f"{mean('return'):.2f}",
        f"{mean('foods'):.2f}",
        f"{mean('final_distance'):.3f}",
        f"{mean('overshoot_ratio'):.2f}",
        "",
    )
    console.print(table)
    if save is not None:
        path = agent.save(save)
        extra = [p.name for p in (vec_normalize_path(path), path.with_suffix(".json")) if p.is_file()]
        console.print(
            f'model saved to {path} (+ {", ".join(extra)}; README "Agents" shows how to load it with plain SB3)'
        )
