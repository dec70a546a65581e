"""``nutribench leaderboard``: every agent of a results database (or of a folder of archives)
in one ranked table, budgets and seeds honest (a thin layer over
:mod:`nutribench.report.leaderboard`)."""

from __future__ import annotations

from pathlib import Path

from nutribench.cli.common import (
    DbOption,
    KeptRepsOption,
    UserError,
    console,
    folder_option,
    option,
    path_flag,
    progress,
    say_err,
    user_errors,
)

FORMATS = ("markdown", "csv", "latex", "json")


@user_errors
def leaderboard_cmd(
    db: DbOption = "nutribench.db",
    archives_given: path_flag(
        "--archives", "a folder of archives (*.npz, `nutribench db export`) instead of --db"
    ) = None,
    out_given: path_flag("--out", "also write leaderboard.md, .tex and .csv into this folder") = None,
    fmt: option(str, "what to print: markdown, csv, latex or json", "--format") = "markdown",
    reps: KeptRepsOption = 2000,
    verify_given: path_flag(
        "--verify",
        "a folder of the jobs' trained models as `nutribench run --models-dir` writes it "
        "(<regime>-v<rv>/<agent>-v<av>/seed<seed>-ep<budget>.zip): each model supplied is loaded as data, "
        "played greedily on its job's test days and compared action for action (the `checked` column)",
    ) = None,
) -> None:
    """Every agent ranked by the IQM of its share of the never -> planner gap (95 % interval)
    over the regimes it covers, with its per-regime shares, budget, seeds, engine, protocol and
    code version; rows off the reference grid (5000 days, seeds 0, 21, 9, 2003, 1997, every
    regime) are flagged. With --archives, an archive that fails a check is refused (named,
    with its reason, on stderr and in the caption) and the others are ranked. With --verify,
    the entries whose models are supplied are re-run: `verified (re-run)` or `re-run: differs`
    (such a row is set apart: listed after the ranked rows, not ranked, with the reason);
    the others stay `replayed, not re-run`."""
    from nutribench.report.leaderboard import check_reps, leaderboard_from_archives, leaderboard_from_db
    from nutribench.report.output import write_table

    # '' is refused, as --db '' is (typer would make it the current folder)
    archives, out, verify = (
        folder_option(v, o)
        for v, o in ((archives_given, "--archives"), (out_given, "--out"), (verify_given, "--verify"))
    )
    if fmt not in FORMATS:
        raise UserError(f"--format {fmt}: give one of {', '.join(FORMATS)}")
    check_reps(reps)  # a trillion resamples would be a MemoryError after minutes of reading
    _check_folders(verify, out)
    ranking = "ranking"
    with progress(None, "leaderboard", text=ranking) as advance:
        steps = _steps(archives, ranking, advance)

        def log(msg: str) -> None:
            say_err(msg, style="dim")
            steps(msg)

        source, build = (archives, leaderboard_from_archives) if archives is not None else (db, leaderboard_from_db)
        table = build(source, reps, log, verify)
    writers = {"markdown": table.to_markdown, "csv": table.to_csv, "latex": table.to_latex}
    text = _json(table) if fmt == "json" else writers[fmt]()
    console.print(text, end="" if text.endswith("\n") else "\n", highlight=False, soft_wrap=True, markup=False)
    if out is not None:
        for path in write_table(table, out, "leaderboard"):
            say_err(str(path))


def _check_folders(verify: Path | None, out: Path | None) -> None:
    """``--verify`` a folder, ``--out`` one that can hold the three files, one line each: checked
    before the table is computed (it takes a while)."""
    from nutribench.report.output import TABLE_SUFFIXES
    from nutribench.safe_write import check_folder_target, check_regular_file

    if verify is not None and not verify.is_dir():
        raise UserError(f"--verify {verify}: not a folder (give the folder `nutribench run --models-dir` wrote)")
    if out is not None:
        check_folder_target(out, "--out")
        for suffix in TABLE_SUFFIXES:
            check_regular_file(out / f"leaderboard.{suffix}", "--out", UserError)


def _steps(folder: Path | None, ranking: str, advance):
    """The progress line's steps from the log of :func:`~nutribench.report.leaderboard.leaderboard_from_archives`
    (``imported NAME`` after each archive, ``refused: ...`` once all are read): importing k of
    n, then the ranking; archive 1's step is shown at once."""
    names = [p.name for p in sorted(folder.glob("*.npz"))] if folder is not None and folder.is_dir() else []
    n = len(names)

    def step(k: int) -> None:  # k archives read
        advance(f"importing {k + 1} of {n}: {names[k]}" if k < n else ranking, k, n + 1)

    if names:
        step(0)

    def seen(msg: str) -> None:
        name = msg.removeprefix("imported ")
        if name != msg and name in names:
            step(names.index(name) + 1)
        elif msg.startswith("refused: ") and names:
            step(n)

    return seen


def _json(table) -> str:
    """``--format json``: the caption and the rows' numbers (shares as fractions), for scripts."""
    import json

    rows = json.loads(table.raw.to_json(orient="records"))
    return json.dumps({"caption": table.title, "rows": rows}, indent=2) + "\n"
