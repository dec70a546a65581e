"""``nutribench bench tune``: tuning trials per hour, stacked in batched processes against one
SB3 process per trial, the same trials in one run (:mod:`nutribench.bench.tune`)."""

from __future__ import annotations

from typing import Annotated, Optional

import typer

from nutribench.cli.common import console, old_spelling, print_table, split_csv, user_errors


@user_errors
def bench_tune_cmd(
    space: Annotated[
        Optional[str],
        typer.Option(
            "--space",
            help="search space whose trials are drawn (an algorithm with per-agent settings: ppo, mc, gru_ppo, sac) [default: ppo]",
        ),
    ] = None,
    algo: Annotated[Optional[str], typer.Option("--algo", hidden=True)] = None,
    trials: Annotated[int, typer.Option(min=1, help="trials, the same in both arms")] = 8,
    days: Annotated[int, typer.Option(min=1, help="training days per agent")] = 20,
    regimes: Annotated[str, typer.Option(help="tuning regimes, comma-separated")] = "run0,run3",
    seeds: Annotated[str, typer.Option(help="tuning seeds, comma-separated")] = "101,102",
    eval_every: Annotated[int, typer.Option(min=1, help="days between validation evaluations")] = 10,
    val_episodes: Annotated[int, typer.Option(min=1, help="validation days per evaluation")] = 5,
    workers: Annotated[Optional[int], typer.Option(min=1, help="processes per arm (default: the cores)")] = None,
    repeats: Annotated[int, typer.Option(min=1, help="repeats of both arms, orders alternating")] = 1,
) -> None:
    """Trials per hour: stacked trials in batched processes vs one SB3 process per trial (rl-zoo3's way)."""
    space = old_spelling(space, algo, "--space", "--algo")  # as tune's --space; None: bench_tune's default
    from nutribench.bench.tune import bench_tune
    from nutribench.config import list_regimes
    from nutribench.scheduler.grid import parse_seeds

    names = tuple(split_csv(regimes, list_regimes(), "regime"))
    with console.status(f"training {trials} trials in each arm"):
        rows = bench_tune(
            **({"space": space} if space is not None else {}),
            trials=trials,
            days=days,
            regimes=names,
            seeds=tuple(parse_seeds(seeds)),
            eval_every=eval_every,
            val_episodes=val_episodes,
            workers=workers,
            repeats=repeats,
        )
    r0 = rows[0]
    title = f"{r0['space']}: {trials} trials x {r0['agents_per_trial']} agents x {days} days, {r0['workers']} processes"
    cells = [
        [r["arm"], f"{r['wall_s']:.1f}", " ".join(f"{w:.1f}" for w in r["walls"]), f"{r['trials_per_hour']:.0f}"]
        + [f"{r.get('ratio', 1.0):.1f}x"]
        for r in rows
    ]
    print_table(("arm", "wall s (median)", "walls", "trials/hour", "vs sb3"), cells, title)
