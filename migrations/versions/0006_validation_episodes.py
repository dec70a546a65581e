"""Evaluation during training: the validation_episodes table (one row per validation day of
each greedy evaluation a job made during its training, keyed by the training day it was
taken at) and the learning_curve view (names joined in, the share of the never -> planner
gap per day, dry-run jobs left out).

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-26
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None

# Frozen copy of the view as of this revision.
LEARNING_CURVE_SQL = """
CREATE VIEW learning_curve AS
SELECT r."name" AS "regime", r."version" AS "regime_version",
       a."name" AS "algo", a."version" AS "algo_version",
       j."seed" AS "seed", j."episodes" AS "budget", j."engine" AS "engine",
       v."train_day" AS "train_day", v."episode" AS "episode",
       v."return" AS "return", v."foods" AS "foods", v."final_distance" AS "final_distance",
       v."overshoot_ratio" AS "overshoot_ratio",
       v."final_C" AS "final_C", v."final_F" AS "final_F", v."final_P" AS "final_P",
       v."first_overshoot_step" AS "first_overshoot_step", v."entropy" AS "entropy",
       v."never" AS "never", v."planner" AS "planner",
       CASE WHEN v."planner" <> v."never"
            THEN (v."return" - v."never") / (v."planner" - v."never") END AS "gap_closed",
       v."job_id" AS "job_id"
FROM validation_episodes v
JOIN jobs j ON j."id" = v."job_id"
JOIN regimes r ON r."id" = j."regime_id"
JOIN agent_configs a ON a."id" = j."agent_config_id"
WHERE j."fake" = false
"""


def upgrade() -> None:
    op.create_table(
        "validation_episodes",
        sa.Column("job_id", sa.Integer(), nullable=False),
        sa.Column("train_day", sa.Integer(), nullable=False),
        sa.Column("episode", sa.Integer(), nullable=False),
        sa.Column("return", sa.Float(), nullable=False),
        sa.Column("foods", sa.Integer(), nullable=False),
        sa.Column("final_distance", sa.Float(), nullable=False),
        sa.Column("overshoot_ratio", sa.Float(), nullable=False),
        sa.Column("final_C", sa.Float(), nullable=False),
        sa.Column("final_F", sa.Float(), nullable=False),
        sa.Column("final_P", sa.Float(), nullable=False),
        sa.Column("first_overshoot_step", sa.Integer(), nullable=True),
        sa.Column("entropy", sa.Float(), nullable=True),
        sa.Column("never", sa.Float(), nullable=True),
        sa.Column("planner", sa.Float(), nullable=True),
        sa.ForeignKeyConstraint(
            ["job_id"], ["jobs.id"], name=op.f("fk_validation_episodes_job_id_jobs"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("job_id", "train_day", "episode", name=op.f("pk_validation_episodes")),
    )
    op.execute(LEARNING_CURVE_SQL)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS learning_curve")
    op.drop_table("validation_episodes")
