"""Imported once by the local executor's fork server, so that every job process starts with
the heavy modules already loaded. Missing optional pieces are skipped."""

import os

from nutribench.scheduler.worker import THREAD_VARIABLES  # imports no numerical library

for _var in THREAD_VARIABLES:  # before torch and numpy are imported below
    os.environ.setdefault(_var, "1")

try:  # the agents (torch, stable-baselines3); absent while they are being written
    import nutribench.agents.api  # noqa: F401
except Exception:  # pragma: no cover
    pass
