"""``nutribench report``: figures and tables of the paper regenerated from the results database.

Pandas and matplotlib are imported only when the command runs, so the CLI starts fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from nutribench.cli.common import (
    UserError,
    check_out_dir,
    check_range,
    console,
    err_console,
    folder_option,
    progress,
    user_errors,
)


def _split(values: list[str] | None) -> list[str]:
    """Repeated options and comma lists, flattened: ``--fig 1 --fig 3,4`` -> 1, 3, 4."""
    return [v.strip() for value in values or [] for v in value.split(",") if v.strip()]


def parse_figs(values: list[str] | None) -> list[int]:
    """``--fig`` values as figure numbers (``all`` = every figure; ``aggregate`` = 5, ``learning``
    = 6); bad values raise UserError."""
    from nutribench.report.build import FIGURE_NAMES, FIGURES

    items = [str(FIGURE_NAMES.get(v, v)) for v in _split(values)]
    if "all" in items:
        return list(FIGURES)
    bad = [v for v in items if not (v.isdigit() and int(v) in FIGURES)]
    if bad:
        raise UserError(
            f"--fig {', '.join(bad)}: the figures are {', '.join(map(str, FIGURES))} "
            f"({', '.join(f'{n} = {k}' for n, k in FIGURE_NAMES.items())}; repeat --fig or give a comma list)"
        )
    return list(dict.fromkeys(int(v) for v in items))


def parse_tables(values: list[str] | None) -> list[str]:
    """``--table`` values: 1-6, results, training, all, or a number from 7 / a config name for
    the database's other agent configs (those are checked against the database when it is read)."""
    return list(dict.fromkeys(_split(values)))


def parse_algos(value: str | None) -> list[str] | None:
    """``--algos a,b,c`` as names (None: every config of the database)."""
    if value is None:
        return None
    names = list(dict.fromkeys(_split([value])))
    if not names:
        raise UserError("--algos: give a comma list of agent config names, e.g. --algos ppo,sac")
    return names


def parse_pair(value: str | None) -> list[str] | None:
    """``--pair a,b``: Figure 4's two agent configs (None: ppo,gru_ppo)."""
    if value is None:
        return None
    names = _split([value])
    if len(names) != 2 or names[0] == names[1]:
        raise UserError(f"--pair {value}: give two different agent configs, e.g. --pair ppo,gru_ppo")
    return names


@user_errors
def report_cmd(
    fig: Annotated[
        Optional[list[str]],
        typer.Option(
            "--fig",
            help="figure 1-4, 5 (aggregate scores over regimes and seeds) or 6 / 'learning' (learning curves of "
            "the evaluations during training, run --eval-every) (repeat or comma list; 'all')",
        ),
    ] = None,
    table: Annotated[
        Optional[list[str]],
        typer.Option(
            "--table",
            help="table 1-6, 7... (the database's other agent configs; or a config's name), 'results', 'training' or 'aggregate' (repeat or comma list; 'all')",
        ),
    ] = None,
    all_: Annotated[bool, typer.Option("--all", help="every figure and table the database supports")] = False,
    algos: Annotated[
        Optional[str],
        typer.Option(
            "--algos",
            help="agent configs drawn in the figures and tables, comma list (default: every config in the database)",
        ),
    ] = None,
    pair: Annotated[
        Optional[str],
        typer.Option("--pair", help="the two agent configs of figure 4, comma list (default: ppo,gru_ppo)"),
    ] = None,
    trajectory: Annotated[
        bool, typer.Option("--trajectory", help="one evaluation episode's trajectory (needs --algo --regime --seed)")
    ] = False,
    diagnostics: Annotated[
        bool,
        typer.Option(
            "--diagnostics",
            help="the training diagnostics of one agent config on one regime, one line per seed (needs --algo --regime)",
        ),
    ] = False,
    algo: Annotated[Optional[str], typer.Option(help="agent config of the trajectory or diagnostics, e.g. ppo")] = None,
    regime: Annotated[Optional[str], typer.Option(help="regime of the trajectory or diagnostics, e.g. run3")] = None,
    seed: Annotated[
        Optional[int], typer.Option(help="seed of the trajectory's job (--diagnostics: only this seed)")
    ] = None,
    episode: Annotated[int, typer.Option(min=0, help="evaluation episode of the trajectory")] = 0,
    db: Annotated[
        str, typer.Option(envvar="NUTRIBENCH_DB", help="results database: a file path or a SQLAlchemy URL")
    ] = "nutribench.db",
    out_given: Annotated[
        str, typer.Option("--out", metavar="PATH", help="folder the files are written to")
    ] = "reports",
    reference_episodes: Annotated[
        int, typer.Option(min=1, help="episodes per simple policy and regime for the reference lines of figures 3/4")
    ] = 200,
) -> None:
    """Regenerate the paper's figures (PNG + PDF) and tables (Markdown, LaTeX, CSV) from the database."""
    from nutribench.report.build import build_report, build_trajectory

    out = folder_option(out_given, "--out")  # '' is refused, as --db '' is (not the current folder)
    figs, tables = parse_figs(fig), parse_tables(table)
    selected, pair_names = parse_algos(algos), parse_pair(pair)
    if not (figs or tables or all_ or trajectory or diagnostics):
        raise UserError(
            "nothing to build: pass --fig, --table, --all, --trajectory or --diagnostics (see nutribench report --help)"
        )
    if trajectory and diagnostics:
        raise UserError("--trajectory and --diagnostics each take --algo --regime: build one at a time")
    if (selected or pair_names) and not (figs or tables or all_):
        raise UserError("--algos and --pair select what figures and tables draw: add --fig, --table or --all")
    if trajectory:
        missing = [o for o, v in (("--algo", algo), ("--regime", regime), ("--seed", seed)) if v is None]
        if missing:
            raise UserError(f"--trajectory needs {', '.join(missing)}")
    elif diagnostics:
        missing = [o for o, v in (("--algo", algo), ("--regime", regime)) if v is None]
        if missing:
            raise UserError(f"--diagnostics needs {', '.join(missing)}")
    elif algo is not None or regime is not None or seed is not None:
        raise UserError(
            "--algo, --regime and --seed pick a trajectory or diagnostics: add --trajectory or --diagnostics"
        )
    from nutribench.scheduler.grid import MAX_EPISODES, MAX_SEED

    if seed is not None:  # past the database's integer: an OverflowError traceback where it was compared
        check_range("--seed", seed, 0, MAX_SEED)
    check_range("--episode", episode, 0, MAX_EPISODES - 1, "an evaluation episode's number as the database holds it")
    check_out_dir(out)
    log = lambda msg: err_console.print(msg, style="yellow", highlight=False, soft_wrap=True)  # noqa: E731
    paths: list[Path] = []
    if figs or tables or all_:
        with progress(None, "report", text="reading the database", lines=True) as advance:
            paths += build_report(
                db,
                out,
                figs=figs,
                tables=tables,
                all=all_,
                reference_episodes=reference_episodes,
                log=log,
                algos=selected,
                pair=pair_names,
                progress=lambda msg: advance(msg, *_counted(msg)),
            )
    if trajectory:
        paths += build_trajectory(db, algo, regime, seed, episode=episode, out=out)
    if diagnostics:
        from nutribench.report.diagnostics import build_diagnostics

        paths += build_diagnostics(db, algo, regime, seeds=None if seed is None else [seed], out=out)
    for p in paths:
        console.print(str(p), highlight=False, soft_wrap=True)


def _counted(msg: str) -> tuple[int | None, int | None]:
    """Items done and items in all of ``build_report``'s ``[3/14] figure 3``: (2, 14)."""
    import re

    m = re.match(r"\[(\d+)/(\d+)\]", msg)
    return (int(m[1]) - 1, int(m[2])) if m else (None, None)
