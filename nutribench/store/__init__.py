"""The results database: ORM models, engine and sessions (WAL, busy timeout), schema
versions (alembic), and query functions returning pandas DataFrames."""

from nutribench.store.engine import StoreError, database_url, make_engine, session_scope, utcnow
from nutribench.store.models import (
    JOB_STATUSES,
    AgentConfig,
    Base,
    Episode,
    EvalStep,
    Job,
    RegimeConfig,
)
from nutribench.store.queries import (
    read_episode_metrics,
    read_eval_trajectories,
    read_jobs,
    read_learning_curve,
    read_training_diagnostics,
)
from nutribench.store.schema import Store, head_revision, open_store

__all__ = [
    "JOB_STATUSES",
    "AgentConfig",
    "Base",
    "Episode",
    "EvalStep",
    "Job",
    "RegimeConfig",
    "Store",
    "StoreError",
    "database_url",
    "head_revision",
    "make_engine",
    "open_store",
    "read_episode_metrics",
    "read_eval_trajectories",
    "read_jobs",
    "read_learning_curve",
    "read_training_diagnostics",
    "session_scope",
    "utcnow",
]
