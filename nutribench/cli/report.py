"""``nutribench report``: figures and tables of the paper regenerated from the results database.

Pandas and matplotlib are imported only when the command runs, so the CLI starts fast.
"""

from __future__ import annotations

from typing import Optional

from nutribench.cli.common import DbOption, folder_option, option, progress, say, say_err, user_errors
from nutribench.safe_write import check_folder_target

_Pair = option(Optional[str], "the two agent configs of figure 4, comma list (default: ppo,gru_ppo)", "--pair")
_Trajectory = option(bool, "one evaluation episode's trajectory (needs --algo --regime --seed)", "--trajectory")
_ReferenceDays = option(int, "episodes per simple policy and regime for the reference lines of figures 3/4", min=1)


@user_errors
def report_cmd(
    fig: option(
        Optional[list[str]],
        "figure 1-4, 5 (aggregate scores over regimes and seeds) or 6 / 'learning' (learning curves of "
        "the evaluations during training, run --eval-every) (repeat or comma list; 'all')",
        "--fig",
    ) = None,
    table: option(
        Optional[list[str]],
        "table 1-6, 7... (the database's other agent configs; or a config's name), 'results', 'training' or 'aggregate' (repeat or comma list; 'all')",
        "--table",
    ) = None,
    all_: option(bool, "every figure and table the database supports", "--all") = False,
    algos: option(
        Optional[str],
        "agent configs drawn in the figures and tables, comma list (default: every config in the database)",
        "--algos",
    ) = None,
    pair: _Pair = None,
    trajectory: _Trajectory = False,
    diagnostics: option(
        bool,
        "the training diagnostics of one agent config on one regime, one line per seed (needs --algo --regime)",
        "--diagnostics",
    ) = False,
    algo: option(Optional[str], "agent config of the trajectory or diagnostics, e.g. ppo") = None,
    regime: option(Optional[str], "regime of the trajectory or diagnostics, e.g. run3") = None,
    seed: option(Optional[int], "seed of the trajectory's job (--diagnostics: only this seed)") = None,
    episode: option(int, "evaluation episode of the trajectory", min=0) = 0,
    db: DbOption = "nutribench.db",
    out_given: option(str, "folder the files are written to", "--out", metavar="PATH") = "reports",
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
