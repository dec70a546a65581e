"""``nutribench report``: figures and tables of the paper regenerated from the results database.

Pandas and matplotlib are imported only when the command runs, so the CLI starts fast.
"""

from __future__ import annotations

from typing import Annotated, Optional

import typer

from nutribench.cli.common import DbOption, folder_option, progress, say, say_err, user_errors
from nutribench.safe_write import check_folder_target

_Fig = Annotated[
    Optional[list[str]],
    typer.Option(
        "--fig",
        help="figure 1-4, 5 (aggregate scores over regimes and seeds) or 6 / 'learning' (learning curves of "
        "the evaluations during training, run --eval-every) (repeat or comma list; 'all')",
    ),
]
_Table = Annotated[
    Optional[list[str]],
    typer.Option(
        "--table",
        help="table 1-6, 7... (the database's other agent configs; or a config's name), 'results', 'training' or 'aggregate' (repeat or comma list; 'all')",
    ),
]
_Algos = Annotated[
    Optional[str],
    typer.Option(
        "--algos",
        help="agent configs drawn in the figures and tables, comma list (default: every config in the database)",
    ),
]
_Pair = Annotated[
    Optional[str], typer.Option("--pair", help="the two agent configs of figure 4, comma list (default: ppo,gru_ppo)")
]
_Trajectory = Annotated[
    bool, typer.Option("--trajectory", help="one evaluation episode's trajectory (needs --algo --regime --seed)")
]
_Diagnostics = Annotated[
    bool,
    typer.Option(
        "--diagnostics",
        help="the training diagnostics of one agent config on one regime, one line per seed (needs --algo --regime)",
    ),
]
_Seed = Annotated[Optional[int], typer.Option(help="seed of the trajectory's job (--diagnostics: only this seed)")]
_Out = Annotated[str, typer.Option("--out", metavar="PATH", help="folder the files are written to")]
_ReferenceDays = Annotated[
    int, typer.Option(min=1, help="episodes per simple policy and regime for the reference lines of figures 3/4")
]


@user_errors
def report_cmd(
    fig: _Fig = None,
    table: _Table = None,
    all_: Annotated[bool, typer.Option("--all", help="every figure and table the database supports")] = False,
    algos: _Algos = None,
    pair: _Pair = None,
    trajectory: _Trajectory = False,
    diagnostics: _Diagnostics = False,
    algo: Annotated[Optional[str], typer.Option(help="agent config of the trajectory or diagnostics, e.g. ppo")] = None,
    regime: Annotated[Optional[str], typer.Option(help="regime of the trajectory or diagnostics, e.g. run3")] = None,
    seed: _Seed = None,
    episode: Annotated[int, typer.Option(min=0, help="evaluation episode of the trajectory")] = 0,
    db: DbOption = "nutribench.db",
    out_given: _Out = "reports",
    reference_episodes: _ReferenceDays = 200,
) -> None:
    """Regenerate the paper's figures (PNG + PDF) and tables (Markdown, LaTeX, CSV) from the database."""
    from nutribench.report.request import ReportRequest

    out = folder_option(out_given, "--out")  # '' is refused, as --db '' is (not the current folder)
    request = ReportRequest.parse(
        fig, table, all_, algos, pair, trajectory, diagnostics, algo, regime, seed, episode, reference_episodes
    )
    check_folder_target(out, "--out")
    log = lambda msg: say_err(msg, style="yellow")  # noqa: E731
    for p in request.build(db, out, log, lambda what, text: progress(None, what, text=text, lines=True)):
        say(str(p))
