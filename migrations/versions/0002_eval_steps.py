"""Per-step evaluation trajectories: the eval_steps table and the eval_trajectories view.

Revision ID: 0002
Revises: 0001
Create Date: 2026-01-02
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None

EVAL_TRAJECTORIES_SQL = """
CREATE VIEW eval_trajectories AS
SELECT r."name" AS "regime", r."version" AS "regime_version",
       a."name" AS "algo", a."version" AS "algo_version",
       j."seed" AS "seed", j."episodes" AS "budget",
       s."episode" AS "episode", s."step" AS "step", s."food" AS "food", s."action" AS "action",
       s."C" AS "C", s."F" AS "F", s."P" AS "P", s."reward" AS "reward",
       s."job_id" AS "job_id"
FROM eval_steps s
JOIN jobs j ON j."id" = s."job_id"
JOIN regimes r ON r."id" = j."regime_id"
JOIN agent_configs a ON a."id" = j."agent_config_id"
"""


def upgrade() -> None:
    op.create_table(
        "eval_steps",
        sa.Column("job_id", sa.Integer(), nullable=False),
        sa.Column("episode", sa.Integer(), nullable=False),
        sa.Column("step", sa.Integer(), nullable=False),
        sa.Column("food", sa.Integer(), nullable=False),
        sa.Column("action", sa.Integer(), nullable=False),
        sa.Column("C", sa.Float(), nullable=False),
        sa.Column("F", sa.Float(), nullable=False),
        sa.Column("P", sa.Float(), nullable=False),
        sa.Column("reward", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], name=op.f("fk_eval_steps_job_id_jobs"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("job_id", "episode", "step", name=op.f("pk_eval_steps")),
    )
    op.execute(EVAL_TRAJECTORIES_SQL)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS eval_trajectories")
    op.drop_table("eval_steps")
