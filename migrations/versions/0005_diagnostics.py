"""Training diagnostics: the diagnostics table (one row per training update of a job) and
the training_diagnostics view (names joined in, dry-run jobs left out).

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-26
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None

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

# Frozen copy of the view as of this revision.
TRAINING_DIAGNOSTICS_SQL = f"""
CREATE VIEW training_diagnostics AS
SELECT r."name" AS "regime", r."version" AS "regime_version",
       a."name" AS "algo", a."version" AS "algo_version",
       j."seed" AS "seed", j."episodes" AS "budget", j."engine" AS "engine",
       g."update" AS "update", g."timestep" AS "timestep",
       {", ".join(f'g."{q}" AS "{q}"' for q in QUANTITIES)},
       g."job_id" AS "job_id"
FROM diagnostics g
JOIN jobs j ON j."id" = g."job_id"
JOIN regimes r ON r."id" = j."regime_id"
JOIN agent_configs a ON a."id" = j."agent_config_id"
WHERE j."fake" = false
"""


def upgrade() -> None:
    op.create_table(
        "diagnostics",
        sa.Column("job_id", sa.Integer(), nullable=False),
        sa.Column("update", sa.Integer(), nullable=False),
        sa.Column("timestep", sa.Integer(), nullable=False),
        *(sa.Column(q, sa.Float(), nullable=True) for q in QUANTITIES),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], name=op.f("fk_diagnostics_job_id_jobs"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("job_id", "update", name=op.f("pk_diagnostics")),
    )
    op.execute(TRAINING_DIAGNOSTICS_SQL)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS training_diagnostics")
    op.drop_table("diagnostics")
