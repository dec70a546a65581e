"""``nutribench bench engines``: do the batched engine's agents learn what the SB3 agents learn
(:mod:`nutribench.bench.engines`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from nutribench.cli.bench import check_engine_options
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
from nutribench.engines import Engine
from nutribench.safe_write import check_file_target


@user_errors
def bench_engines_cmd(
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
    and regime the IQM of the evaluation returns with a 95 % bootstrap interval over seeds;
    the two engines' intervals must overlap."""
    episodes = old_spelling(days, episodes_alias, "--days", "--episodes", 500)
    from nutribench.agents.registry import batched_names
    from nutribench.bench.engines import COLUMNS, bench_engines, row_cells
    from nutribench.config import list_regimes
    from nutribench.scheduler.grid import parse_seeds

    check_engine_options(Engine.BATCHED, device)
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
            on_done=_report_engine_run,
        )
    title = f"engines: SB3 vs batched, {episodes} days, seeds {seeds}"
    print_table(COLUMNS, [row_cells(r) for r in rows], title, markdown)
    walls = {r["engine"]: r["total_wall_seconds"] for r in rows}
    how = "a process per algorithm, beside the SB3 pool" if concurrent else "one process"
    console.print(
        f"wall time: SB3 {walls[Engine.SB3]:.0f} s (a process per job, one per core), batched {walls[Engine.BATCHED]:.0f} s ({how})",
        highlight=False,
    )


def _report_engine_run(engine: str, run) -> None:
    mean = sum(e["return"] for e in run.eval_rows) / len(run.eval_rows)
    console.print(
        f"{engine} {run.algo} {run.regime} seed {run.seed}: evaluation return {mean:.2f} (mean of "
        f"{len(run.eval_rows)} days), {run.wall_seconds:.0f} s of training",
        highlight=False,
    )
