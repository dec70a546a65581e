"""``nutribench compare A B``: two agent configs on the evaluation days they both played,
paired by seed and day (a thin layer over :mod:`nutribench.report.compare`)."""

from __future__ import annotations

import json
from typing import Optional

import typer

from nutribench.cli.common import (
    DbOption,
    KeptRepsOption,
    MarkdownOption,
    UserError,
    argument,
    console,
    option,
    user_errors,
)


@user_errors
def compare_cmd(
    a: argument(
        str,
        "agent A: a config name in the database (gru_ppo: its largest budget, then newest version), "
        "or one entry of it, NAME@vVERSION, NAME@DAYS or NAME@vVERSION@DAYS (ppo@v1, ppo@v2@150)",
    ),
    b: argument(str, "agent B, compared with A (the same forms)"),
    regimes: option(
        Optional[str], "regimes, comma list (default: every regime both were evaluated on)", "--regimes"
    ) = None,
    markdown: MarkdownOption = False,
    as_json: option(bool, "print JSON: the rows' numbers (differences in returns), the notes", "--json") = False,
    db: DbOption = "nutribench.db",
    reps: KeptRepsOption = 10_000,
) -> None:
    """A - B per regime and over regimes: the mean paired difference of evaluation returns
    (same seed, same day) with a 95 % t interval over seeds, P(A > B) over the paired
    days, and how many seeds were paired."""
    from nutribench.report.compare import load_comparison
    from nutribench.report.leaderboard import check_reps

    if as_json and markdown:
        raise UserError("--json and --markdown: give one (each is a whole output of its own)")
    check_reps(reps)  # bounded as leaderboard --reps is: 10^11 resamples were a MemoryError traceback
    names = None
    if regimes is not None:
        names = [r.strip() for r in regimes.split(",") if r.strip()]
        if not names:
            raise UserError("--regimes: give a comma list of regimes, e.g. --regimes run1,run3")
    res = load_comparison(db, a, b, regimes=names, reps=reps)
    if as_json:
        rows = json.loads(res.rows.to_json(orient="records"))
        typer.echo(json.dumps({"a": res.a, "b": res.b, "reps": res.reps, "rows": rows, "notes": res.notes}, indent=2))
        return
    text = res.to_markdown() if markdown else res.to_text()
    console.print(text, end="", highlight=False, soft_wrap=True, markup=False)
