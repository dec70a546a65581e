"""``nutribench db copy``: move a results database, e.g. from SQLite into PostgreSQL."""

from __future__ import annotations

from typing import Annotated

import typer

from nutribench.cli.common import console, user_errors

db_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Results databases: copy one into another.")


@db_app.command("copy")
@user_errors
def db_copy_cmd(
    src: Annotated[str, typer.Argument(help="source: a SQLite file or SQLAlchemy URL, at the newest schema")],
    dst: Annotated[str, typer.Argument(help="destination: a new, empty database (file or URL); its schema is created")],
) -> None:
    """Copy every config, job, episode and evaluation step of SRC into the empty DST, keeping ids."""
    from nutribench.store.copy import copy_database

    counts = copy_database(src, dst, on_table=lambda name, n: console.print(f"{name}: {n:,} rows", highlight=False))
    console.print(f"copied {sum(counts.values()):,} rows; {counts.get('jobs', 0)} jobs", highlight=False)
