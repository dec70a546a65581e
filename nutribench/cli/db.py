"""``nutribench db copy``: move a results database, e.g. from SQLite into PostgreSQL."""

from __future__ import annotations

from pathlib import Path

from nutribench.cli.common import UserError, argument, command_group, console, option, progress, user_errors

db_app = command_group("Results databases: copy one into another, export finished jobs to a file, import such a file.")


@db_app.command("copy")
@user_errors
def db_copy_cmd(
    src: argument(str, "source: a SQLite file or SQLAlchemy URL, at the newest schema"),
    dst: argument(
        str | None,
        "destination: a new, empty database (file or URL); its schema is created [default: $NUTRIBENCH_DB]",
        envvar="NUTRIBENCH_DB",
        show_default=False,
    ) = None,
) -> None:
    """Copy every config, job, episode and evaluation step of SRC into the empty DST, keeping ids.
    DST defaults to $NUTRIBENCH_DB, the database the other commands' --db reads."""
    from nutribench.store.copy import copy_database

    if not dst:
        raise UserError("db copy: no destination: give DST or set NUTRIBENCH_DB to the database to copy into")
    counts = copy_database(src, dst, on_table=lambda name, n: console.print(f"{name}: {n:,} rows", highlight=False))
    console.print(f"copied {sum(counts.values()):,} rows; {counts.get('jobs', 0)} jobs", highlight=False)


@db_app.command("export")
@user_errors
def db_export_cmd(
    out: argument(Path, "archive to write (.npz)"),
    db: option(str, "database to read: a SQLite file or SQLAlchemy URL", envvar="NUTRIBENCH_DB") = "nutribench.db",
    algos: option(str | None, "only these agent configs (comma-separated names); default: all") = None,
    regimes: option(str | None, "only these regimes (comma-separated names); default: all") = None,
) -> None:
    """Write DB's done jobs (configs, job rows, episodes, evaluation steps, training diagnostics) to one portable file."""
    from nutribench.store.archive import export_results

    def listed(text: str | None) -> list[str] | None:
        return [a.strip() for a in text.split(",") if a.strip()] if text else None

    counts = export_results(db, out, listed(algos), listed(regimes))
    size = out.stat().st_size / 1e6
    console.print(
        f"{out}: {counts['jobs']} jobs, {counts['episodes']:,} episodes, {counts['eval_steps']:,} evaluation steps, "
        f"{counts.get('diagnostics', 0):,} training diagnostics rows, "
        f"{counts.get('validation_episodes', 0):,} validation days ({size:.1f} MB)",
        highlight=False,
    )


@db_app.command("import")
@user_errors
def db_import_cmd(
    archive: argument(Path, "archive written by `nutribench db export`"),
    db: option(
        str, "database to merge into (created if missing): a SQLite file or URL", envvar="NUTRIBENCH_DB"
    ) = "nutribench.db",
) -> None:
    """Merge an archive's jobs into DB: new jobs are added, pending ones take the archived
    result, jobs DB already has done are kept as they are. The archive is checked whole
    first: one that is damaged or was changed is refused, and nothing is written."""
    from nutribench.store.archive import import_results
    from nutribench.store.engine import database_url, display_url

    with progress(None, f"db import {archive.name}") as advance:
        counts = import_results(
            archive, db, on_step=lambda phase, done, total: advance(_step(phase, done, total), done, total or None)
        )
    # the database as display_url shows it: a URL's password is never printed
    console.print(
        f"{archive} -> {display_url(database_url(db))}: {counts['imported']} jobs imported ({counts['episodes']:,} episodes, "
        f"{counts['eval_steps']:,} evaluation steps), {counts['kept']} already done there and kept; "
        f"{counts.get('diagnostics', 0):,} training diagnostics rows, "
        f"{counts.get('validation_episodes', 0):,} validation days",
        highlight=False,
    )


def _step(phase: str, done: int, total: int) -> str:
    """What ``db import`` is doing, for its progress line (:func:`nutribench.store.archive.import_results`'s steps)."""
    if phase == "checking":
        return "checking, replaying the evaluation days"
    return f"writing job {done + 1} of {total}"
