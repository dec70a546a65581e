"""Initial schema: configs, jobs, episodes and the episode_metrics view.

Revision ID: 0001
Revises:
Create Date: 2026-01-01
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None

# Frozen copy of the view as of this revision (later revisions replace it, never edit it).
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
"""


def _config_table(name: str, *extra: sa.Column) -> None:
    op.create_table(
        name,
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        *extra,
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("body", sa.JSON(), nullable=False),
        sa.Column("source", sa.Text(), nullable=True),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f(f"pk_{name}")),
        sa.UniqueConstraint("name", "version", name=op.f(f"uq_{name}_name_version")),
    )


def upgrade() -> None:
    _config_table("regimes")
    _config_table("agent_configs", sa.Column("algo", sa.String(length=64), nullable=False))
    op.create_table(
        "jobs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("regime_id", sa.Integer(), nullable=False),
        sa.Column("agent_config_id", sa.Integer(), nullable=False),
        sa.Column("seed", sa.Integer(), nullable=False),
        sa.Column("episodes", sa.Integer(), nullable=False),
        sa.Column("eval_episodes", sa.Integer(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("attempt", sa.Integer(), nullable=False),
        sa.Column("failures", sa.Integer(), nullable=False),
        sa.Column("episodes_done", sa.Integer(), nullable=False),
        sa.Column("last_return", sa.Float(), nullable=True),
        sa.Column("owner", sa.String(length=128), nullable=True),
        sa.Column("heartbeat_at", sa.DateTime(), nullable=True),
        sa.Column("worker_pid", sa.Integer(), nullable=True),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.Column("started_at", sa.DateTime(), nullable=True),
        sa.Column("finished_at", sa.DateTime(), nullable=True),
        sa.Column("wall_seconds", sa.Float(), nullable=True),
        sa.Column("host", sa.String(length=255), nullable=True),
        sa.Column("platform", sa.String(length=255), nullable=True),
        sa.Column("python_version", sa.String(length=32), nullable=True),
        sa.Column("numpy_version", sa.String(length=32), nullable=True),
        sa.Column("torch_version", sa.String(length=32), nullable=True),
        sa.Column("sb3_version", sa.String(length=32), nullable=True),
        sa.Column("nutribench_version", sa.String(length=64), nullable=True),
        sa.Column("git_commit", sa.String(length=40), nullable=True),
        sa.Column("git_dirty", sa.Boolean(), nullable=True),
        sa.Column("model_path", sa.Text(), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.CheckConstraint(
            "status IN ('pending', 'running', 'done', 'failed', 'interrupted')", name=op.f("ck_jobs_status")
        ),
        sa.ForeignKeyConstraint(
            ["agent_config_id"], ["agent_configs.id"], name=op.f("fk_jobs_agent_config_id_agent_configs")
        ),
        sa.ForeignKeyConstraint(["regime_id"], ["regimes.id"], name=op.f("fk_jobs_regime_id_regimes")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_jobs")),
        sa.UniqueConstraint(
            "regime_id",
            "agent_config_id",
            "seed",
            "episodes",
            "eval_episodes",
            name=op.f("uq_jobs_regime_id_agent_config_id_seed_episodes_eval_episodes"),
        ),
    )
    op.create_index(op.f("ix_jobs_status"), "jobs", ["status"], unique=False)
    op.create_table(
        "episodes",
        sa.Column("job_id", sa.Integer(), nullable=False),
        sa.Column("phase", sa.String(length=8), nullable=False),
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
        sa.CheckConstraint("phase IN ('train', 'eval')", name=op.f("ck_episodes_phase")),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], name=op.f("fk_episodes_job_id_jobs"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("job_id", "phase", "episode", name=op.f("pk_episodes")),
    )
    op.execute(EPISODE_METRICS_SQL)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS episode_metrics")
    op.drop_table("episodes")
    op.drop_index(op.f("ix_jobs_status"), table_name="jobs")
    op.drop_table("jobs")
    op.drop_table("agent_configs")
    op.drop_table("regimes")
