"""Imported once by the local executor's fork server, so that every job process starts with
the heavy modules already loaded. Missing optional pieces are skipped."""

import os

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import nutribench.scheduler.worker  # noqa: E402,F401

try:  # the agents (torch, stable-baselines3); absent while they are being written
    import nutribench.agents.api  # noqa: F401
except Exception:  # pragma: no cover
    pass
