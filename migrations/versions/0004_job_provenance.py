"""Where a job's numbers came from, and dry runs kept apart.

* ``jobs.fake``: a synthetic job of a dry run (``NUTRIBENCH_JOB=fake``); never a result. The
  views leave such jobs out, so nothing that reads them (the report, pandas) draws one.
* ``jobs.batch_id`` / ``jobs.batch_size`` / ``jobs.device``: the batched engine's batch (its
  jobs train side by side, K of them), and the device it trained on; a batched job's numbers
  depend on both through float rounding.
* ``jobs.source`` / ``jobs.source_sha256``: for jobs whose agent came from outside
  nutribench (``engine = 'external'``: a plug-in entry point, a recorded training loop, a
  saved model), what made them: the entry point or calling script, and its content hash.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None

# Frozen copies of the views as of this revision (fake jobs left out).
EPISODE_METRICS_SQL = """
CREATE VIEW episode_metrics AS
SELECT r."name" AS "regime", r."version" AS "regime_version",
       a."name" AS "algo", a."version" AS "algo_version",
       j."seed" AS "seed", j."episodes" AS "budget",
       e."phase" AS "phase", e."episode" AS "episode",
       e."return" AS "return", e."foods" AS "foods", e."final_distance" AS "final_distance",
       e."overshoot_ratio" AS "overshoot_ratio",
       e."final_C" AS "final_C", e."final_F" AS "final_F", e."final_P" AS "final_P",
       e."first_overshoot_step" AS "first_overshoot_step", e."entropy" AS "entropy",
       e."job_id" AS "job_id"
FROM episodes e
JOIN jobs j ON j."id" = e."job_id"
JOIN regimes r ON r."id" = j."regime_id"
JOIN agent_configs a ON a."id" = j."agent_config_id"
WHERE j."fake" = false
"""

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
WHERE j."fake" = false
"""


def upgrade() -> None:
    op.execute("DROP VIEW IF EXISTS episode_metrics")
    op.execute("DROP VIEW IF EXISTS eval_trajectories")
    # plain ADD COLUMN, never a batch (copy-and-move) table rebuild: on SQLite that drops the
    # old jobs table, and its ON DELETE CASCADE would take every episode with it
    op.add_column("jobs", sa.Column("fake", sa.Boolean(), nullable=False, server_default=sa.false()))
    op.add_column("jobs", sa.Column("batch_id", sa.String(length=64), nullable=True))
    op.add_column("jobs", sa.Column("batch_size", sa.Integer(), nullable=True))
    op.add_column("jobs", sa.Column("device", sa.String(length=32), nullable=True))
    op.add_column("jobs", sa.Column("source", sa.Text(), nullable=True))
    op.add_column("jobs", sa.Column("source_sha256", sa.String(length=64), nullable=True))
    op.execute(EPISODE_METRICS_SQL)
    op.execute(EVAL_TRAJECTORIES_SQL)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS episode_metrics")
    op.execute("DROP VIEW IF EXISTS eval_trajectories")
    with op.batch_alter_table("jobs") as batch:
        for name in ("source_sha256", "source", "device", "batch_size", "batch_id", "fake"):
            batch.drop_column(name)
    # the views as revisions 0001 and 0002 made them (every job)
    op.execute(EPISODE_METRICS_SQL.replace('WHERE j."fake" = false\n', ""))
    op.execute(EVAL_TRAJECTORIES_SQL.replace('WHERE j."fake" = false\n', ""))
