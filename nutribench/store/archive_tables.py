"""The tables a results archive carries (``nutribench db export`` / ``db import``, see
:mod:`nutribench.store.archive`), and how their rows go between an archive's column arrays
and the database: :data:`TABLES`, the columns each has in an archive (:func:`archive_table`),
the rows read for an export (:func:`archive_rows`) and the rows an import writes
(:func:`database_rows`).

Every table travels as its columns, but ``diagnostics``: the database holds it long (one row
per job, update and quantity, schema revision 0007), an archive wide, one row per update
(:func:`diagnostics_layout`), as it was written since revision 0005, so every archive reads as
it did; a quantity of a plug-in's is one more column, under its name.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from sqlalchemy import Column, Float, Integer, MetaData, Table, select

from nutribench.diagnostics import QUANTITIES, TIMESTEP
from nutribench.diagnostics import valid_name as valid_quantity
from nutribench.store.models import Diagnostic, Episode, EvalStep, ValidationEpisode, diagnostic_rows

#: The tables of a job an archive carries, by name.
TABLES = {
    "episodes": Episode,
    "eval_steps": EvalStep,
    "diagnostics": Diagnostic,
    "validation_episodes": ValidationEpisode,
}
#: tables an archive written before them lacks: read as empty (revision 0005: diagnostics;
#: 0006: validation_episodes)
OPTIONAL_TABLES = ("diagnostics", "validation_episodes")


def columns(table: Any) -> list[Any]:
    """The columns of ``table`` (an ORM model or a :class:`~sqlalchemy.Table`) but ``job_id``."""
    return [c for c in getattr(table, "__table__", table).columns if c.name != "job_id"]


def diagnostics_layout(extra: Sequence[str] = ()) -> Table:
    """The columns of an archive's ``diagnostics``: one row per update, wide (as the table was
    before schema revision 0007, so that every archive written since revision 0005 reads as it
    was): ``update``, ``timestep``, the quantities of :data:`nutribench.diagnostics.QUANTITIES`,
    then ``extra``, the names of a plug-in's own quantities (float, NULL where absent)."""
    return Table(
        "diagnostics",
        MetaData(),
        Column("job_id", Integer, nullable=False),
        Column("update", Integer, nullable=False),
        Column(TIMESTEP, Integer, nullable=False),
        *(Column(q, Float) for q in (*QUANTITIES, *extra)),
    )


def archive_table(name: str, arrays: dict[str, np.ndarray]) -> Any:
    """What table ``name`` of :data:`TABLES` holds in an archive: the database table's columns,
    but ``diagnostics`` in :func:`diagnostics_layout`, with the plug-in quantities ``arrays`` has
    a column of (a name :func:`nutribench.diagnostics.valid_name` allows; another is an array
    that is not part of the format)."""
    if name != "diagnostics":
        return TABLES[name]
    have = {k[len("diagnostics.") :].removesuffix(".null") for k in arrays if k.startswith("diagnostics.")}
    extra = have - {"job", "update", TIMESTEP, *QUANTITIES}
    return diagnostics_layout(sorted(e for e in extra if valid_quantity(e)))


def wide_diagnostics(session: Any, job_ids: list[int]) -> tuple[Table, list[tuple[Any, ...]]]:
    """The long ``diagnostics`` rows of jobs ``job_ids`` as an archive holds them: its layout
    (:func:`diagnostics_layout`, with every other name they have) and one tuple per update
    (``job_id``, then the layout's columns; None where the update has no such quantity),
    ordered by job and update."""
    by: dict[tuple[int, int], dict[str, float]] = {}
    query = (
        select(Diagnostic.job_id, Diagnostic.update, Diagnostic.name, Diagnostic.value)
        .where(Diagnostic.job_id.in_(job_ids))
        .order_by(Diagnostic.job_id, Diagnostic.update, Diagnostic.name)
    )
    for job, update, name, value in session.execute(query):
        by.setdefault((job, update), {})[name] = value
    extra = sorted({n for values in by.values() for n in values} - {TIMESTEP, *QUANTITIES})
    layout = diagnostics_layout(extra)
    names = [c.name for c in columns(layout)][1:]
    rows = []
    for (job, update), values in by.items():
        step = values.get(TIMESTEP)
        values[TIMESTEP] = None if step is None else int(step)
        rows.append((job, update, *(values.get(n) for n in names)))
    return layout, rows


def archive_rows(session: Any, name: str, job_ids: list[int]) -> tuple[list[Any], list[Any]]:
    """Table ``name`` of jobs ``job_ids`` as an archive holds it: its columns (but ``job_id``)
    and its rows, each ``job_id`` first, by primary key (``diagnostics``: :func:`wide_diagnostics`)."""
    if name == "diagnostics":
        layout, rows = wide_diagnostics(session, job_ids)
        return columns(layout), rows
    t = TABLES[name].__table__
    cols = columns(t)
    query = select(t.c.job_id, *[t.c[c.name] for c in cols]).where(t.c.job_id.in_(job_ids))
    return cols, session.execute(query.order_by(*t.primary_key.columns)).all()


def database_rows(
    name: str, arrays: dict[str, np.ndarray], rows: np.ndarray, job_id: int
) -> tuple[int, list[dict[str, Any]]]:
    """Rows ``rows`` (positions) of the archive's table ``name`` as insert dicts of job
    ``job_id`` for :func:`~nutribench.store.models.insert_rows`: how many archive rows, and the
    dicts (``diagnostics``: one per update and quantity, :func:`~nutribench.store.models.diagnostic_rows`)."""
    table = TABLES[name]
    layout = archive_table(name, arrays)
    cols = {}
    for col in columns(layout):
        values = arrays[f"{name}.{col.name}"][rows].tolist()
        null = arrays.get(f"{name}.{col.name}.null")
        if null is not None:
            values = [None if n else v for v, n in zip(values, null[rows].tolist(), strict=True)]
        cols[table.__mapper__.get_property_by_column(col).key if layout is table else col.name] = values
    keys = list(cols)
    decoded = [dict(zip(keys, vals, strict=True)) for vals in zip(*cols.values(), strict=True)]
    if name == "diagnostics":
        return len(decoded), diagnostic_rows(job_id, decoded)
    return len(decoded), [{"job_id": job_id, **r} for r in decoded]
