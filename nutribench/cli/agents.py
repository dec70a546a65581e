"""``nutribench baselines`` and ``nutribench train``: the simple policies and one agent in the foreground."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

from rich.console import Console

from nutribench.cli.common import (
    EVAL_EVERY_HELP,
    EpisodesAlias,
    UserError,
    ValEpisodesOption,
    console,
    folder_option,
    old_spelling,
    option,
    path_flag,
    print_table,
    split_csv,
    user_errors,
)
from nutribench.errors import check_range

_EvalDays = option(Optional[int], "days played per policy and regime [default: 200]", "--eval-episodes", min=1)


@user_errors
def baselines(
    regimes: option(str, "'all' or comma-separated regime names") = "all",
    episodes: _EvalDays = None,
    old_episodes: EpisodesAlias = None,
    seed: option(int, "seed of the food streams (the same for every policy)") = 0,
    strong_days: option(
        int, "days (the first of the same streams) that lookahead and clairvoyant play per regime; 0: neither", min=0
    ) = 10,
    samples: option(int, "sampled futures a lookahead step weighs each action on", min=1) = 64,
    test_days: option(
        bool,
        "instead: never, planner, lookahead (256 futures) and clairvoyant on the paper's test days "
        "(seeds 0,21,9,2003,1997 x their 5 evaluation days), the shares of the gap per regime",
        "--test-days",
    ) = False,
    out: option(
        Optional[Path], "with --test-days: write the per-day returns to this CSV (regimes/references.csv)"
    ) = None,
    markdown: option(bool, "print a Markdown table instead of a rich one") = False,
) -> None:
    """Mean return, foods eaten, final distance, overshoot ratio and share of the never -> planner
    gap of the reference policies (random, never, always, planner; lookahead and clairvoyant on
    the first --strong-days days)."""
    from nutribench.baselines import BASELINE_HEADERS, baseline_cells, baseline_table
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
    title = (
        f"Reference policies on the days of seed {seed} (lookahead and clairvoyant on the first {strong_days}); means; "
        "gap closed: share of the never -> planner gap on the row's days"
    )
    print_table(BASELINE_HEADERS, baseline_cells(rows), title, markdown, [r["regime"] for r in rows])


def _test_day_table(names: list[str], out: Path | None, markdown: bool) -> None:
    """``baselines --test-days``: the four yardsticks on the paper's test days, per regime."""
    import pandas as pd

    from nutribench.baselines import REFERENCE_COLUMNS, TEST_DAY_HEADERS, TEST_DAY_SAMPLES, test_day_cells
    from nutribench.safe_write import atomic_write, check_file_target
    from nutribench.scheduler.grid import PRESETS

    seeds = PRESETS["paper"].seeds
    if out is not None:
        check_file_target(out, "--out")  # before the minutes of planning, not after
    rows, cells = test_day_cells(names, seeds)
    if out is not None:
        with atomic_write(out, "--out") as tmp:
            pd.DataFrame(rows, columns=list(REFERENCE_COLUMNS)).to_csv(tmp, index=False)
    title = (
        f"The paper's test days (seeds {','.join(map(str, seeds))} x 5): mean returns; % = share of the never -> "
        f"planner gap; lookahead {TEST_DAY_SAMPLES} futures a step"
    )
    print_table(TEST_DAY_HEADERS, cells, title, markdown, names)


@user_errors
def train_cmd(
    algo: option(str, "agent config name (regimes/agents/<name>.toml) or a .toml path") = "ppo",
    regime: option(str, "regime name or file") = "run0",
    seed: option(int, "training seed; the evaluation days derive from it") = 0,
    days: option(Optional[int], "training days (episodes of 50 steps) [default: 300]", "--days", min=1) = None,
    episodes_alias: EpisodesAlias = None,
    eval_episodes: option(int, "greedy evaluation days", min=1) = 5,
    save: option(Optional[Path], "save the trained model here (.zip + .json)") = None,
    tensorboard_given: path_flag(
        "--tensorboard",
        "also write the training diagnostics as TensorBoard events under this folder "
        "(run folder <algo>-<regime>-seed<seed>)",
    ) = None,
    eval_every: option(int, EVAL_EVERY_HELP, min=0) = 0,
    val_episodes: ValEpisodesOption = 5,
) -> None:
    """Train one agent in the foreground, then evaluate it greedily and print the metrics."""
    from nutribench.agents import train
    from nutribench.agents.foreground import EVALUATION_HEADERS, TrainRequest, validation_printer
    from nutribench.scheduler.grid import MAX_EPISODES, MAX_EVAL_DAYS, MAX_SEED

    episodes = old_spelling(days, episodes_alias, "--days", "--episodes", 300)
    tensorboard = folder_option(tensorboard_given, "--tensorboard")  # '' is refused, not the current folder
    check_range("--seed", seed, 0, MAX_SEED)
    check_range("--days", episodes, 1, MAX_EPISODES)
    check_range("--eval-episodes", eval_episodes, 1, MAX_EVAL_DAYS, "the days are played side by side")
    request = TrainRequest(algo, regime, seed, episodes, eval_episodes, save, tensorboard, eval_every, val_episodes)
    env_cfg, cfg, run_dir = request.configs()
    with _training_bar(f"{cfg.name} on {env_cfg.name}, seed {seed}", episodes) as (on_episode, shown):
        on_validation = validation_printer(shown.print, env_cfg, seed, val_episodes) if eval_every else None
        how = dict(on_episode=on_episode, tensorboard=run_dir, eval_every=eval_every, val_episodes=val_episodes)
        agent = train(env_cfg, cfg, seed=seed, episodes=episodes, on_validation=on_validation, **how)
    print_table(EVALUATION_HEADERS, request.evaluation_cells(agent, env_cfg), "greedy evaluation")
    if save is not None:
        console.print(request.saved(agent))


@contextmanager
def _training_bar(description: str, days: int) -> Iterator[tuple[Callable[[dict], None], Console]]:
    """A rich progress bar of the training days, with the mean return and foods of the last 20
    days; yields ``(on_episode, console)``: what each finished day calls, and where lines go."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
    columns += (TextColumn("{task.fields[stats]}"), TimeElapsedColumn(), TimeRemainingColumn())
    recent: list[dict] = []
    with Progress(*columns, console=console, transient=False) as progress:
        task = progress.add_task(description, total=days, stats="")

        def on_episode(row: dict) -> None:
            recent.append(row)
            last = recent[-20:]
            ret = sum(r["return"] for r in last) / len(last)
            foods = sum(r["foods"] for r in last) / len(last)
            progress.update(task, advance=1, stats=f"return {ret:8.2f}  foods {foods:5.2f} (last {len(last)})")

        yield on_episode, progress.console
