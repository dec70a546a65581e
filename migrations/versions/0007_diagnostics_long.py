"""Training diagnostics as a long table: ``diagnostics`` becomes one row per (job, update,
name) with its value, so that a new algorithm's quantity is a new name, not a new column.

Upgrade copies every row of the wide table (one per update: ``timestep`` and thirteen
quantity columns, NULL where absent) into long rows: the update's ``timestep`` as the name
``timestep``, each non-NULL quantity under its column's name; a NULL has no row. The
``training_diagnostics`` view keeps its columns (the long rows pivoted back, one per update),
and the new ``diagnostic_values`` view reads the long rows with the names joined in (every
name, a plug-in's too). Downgrade pivots back into the wide table; a name that is not one of
the thirteen columns (a plug-in's) has nowhere to go there and is dropped.

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-01
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None

# The wide table's quantity columns (revision 0005), frozen.
QUANTITIES = (
    "policy_loss",
    "value_loss",
    "entropy_loss",
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "grad_norm",
    "learning_rate",
    "epsilon",
    "q_mean",
    "actor_loss",
    "ent_coef",
    "return_scale",
)

_JOIN = """
FROM diagnostics g
JOIN jobs j ON j."id" = g."job_id"
JOIN regimes r ON r."id" = j."regime_id"
JOIN agent_configs a ON a."id" = j."agent_config_id"
WHERE j."fake" = false
"""
_NAMES = """r."name" AS "regime", r."version" AS "regime_version",
       a."name" AS "algo", a."version" AS "algo_version",
       j."seed" AS "seed", j."episodes" AS "budget", j."engine" AS "engine","""

# Frozen copies of the views as of this revision.
# Grouped by the ids (so SQLite walks the primary key's index without a sort) and by the name
# columns (so that a filter on them, `WHERE algo = 'ppo'`, is pushed into the view);
# FILTER (SQLite 3.30, PostgreSQL 9.4) is a third faster than MAX(CASE ...) here.
TRAINING_DIAGNOSTICS_SQL = f"""
CREATE VIEW training_diagnostics AS
SELECT {_NAMES}
       g."update" AS "update",
       CAST(MAX(g."value") FILTER (WHERE g."name" = 'timestep') AS INTEGER) AS "timestep",
       {", ".join(f'MAX(g."value") FILTER (WHERE g."name" = {q!r}) AS "{q}"' for q in QUANTITIES)},
       g."job_id" AS "job_id"
{_JOIN}
GROUP BY g."job_id", g."update", j."id", r."id", a."id",
         r."name", r."version", a."name", a."version", j."seed", j."episodes", j."engine"
"""

DIAGNOSTIC_VALUES_SQL = f"""
CREATE VIEW diagnostic_values AS
SELECT {_NAMES}
       g."update" AS "update", g."name" AS "name", g."value" AS "value", g."job_id" AS "job_id"
{_JOIN}
"""

# revision 0005's view, for the downgrade
WIDE_VIEW_SQL = f"""
CREATE VIEW training_diagnostics AS
SELECT {_NAMES}
       g."update" AS "update", g."timestep" AS "timestep",
       {", ".join(f'g."{q}" AS "{q}"' for q in QUANTITIES)},
       g."job_id" AS "job_id"
{_JOIN}
"""

_KEEP = "_diagnostics_0007"  # the old rows while the table is rebuilt (no constraints: CREATE TABLE AS)


def _wide_table() -> None:
    op.create_table(
        "diagnostics",
        sa.Column("job_id", sa.Integer(), nullable=False),
        sa.Column("update", sa.Integer(), nullable=False),
        sa.Column("timestep", sa.Integer(), nullable=False),
        *(sa.Column(q, sa.Float(), nullable=True) for q in QUANTITIES),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], name=op.f("fk_diagnostics_job_id_jobs"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("job_id", "update", name=op.f("pk_diagnostics")),
    )


def upgrade() -> None:
    op.execute("DROP VIEW IF EXISTS training_diagnostics")
    op.execute(f"CREATE TABLE {_KEEP} AS SELECT * FROM diagnostics")
    op.drop_table("diagnostics")
    op.create_table(
        "diagnostics",
        sa.Column("job_id", sa.Integer(), nullable=False),
        sa.Column("update", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("value", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], name=op.f("fk_diagnostics_job_id_jobs"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("job_id", "update", "name", name=op.f("pk_diagnostics")),
    )
    parts = [f'SELECT "job_id", "update", \'timestep\', CAST("timestep" AS FLOAT) FROM {_KEEP}']
    parts += [f'SELECT "job_id", "update", \'{q}\', "{q}" FROM {_KEEP} WHERE "{q}" IS NOT NULL' for q in QUANTITIES]
    op.execute(f'INSERT INTO diagnostics ("job_id", "update", "name", "value") {" UNION ALL ".join(parts)}')
    op.execute(f"DROP TABLE {_KEEP}")
    op.execute(TRAINING_DIAGNOSTICS_SQL)
    op.execute(DIAGNOSTIC_VALUES_SQL)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS diagnostic_values")
    op.execute("DROP VIEW IF EXISTS training_diagnostics")
    op.execute(f"CREATE TABLE {_KEEP} AS SELECT * FROM diagnostics")
    op.drop_table("diagnostics")
    _wide_table()
    cols = ", ".join(f'MAX(CASE WHEN "name" = {q!r} THEN "value" END)' for q in QUANTITIES)
    op.execute(
        f'INSERT INTO diagnostics ("job_id", "update", "timestep", {", ".join(chr(34) + q + chr(34) for q in QUANTITIES)}) '
        f'SELECT "job_id", "update", CAST(MAX(CASE WHEN "name" = \'timestep\' THEN "value" END) AS INTEGER), {cols} '
        f'FROM {_KEEP} GROUP BY "job_id", "update"'
    )
    op.execute(f"DROP TABLE {_KEEP}")
    op.execute(WIDE_VIEW_SQL)
