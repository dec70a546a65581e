"""The flat SQL views, for one-line pandas queries.

They are created by the migrations (``migrations/versions``; views are not ORM models, and
each revision keeps a frozen copy of its view text). Columns:

``episode_metrics``
    regime, regime_version, algo (the agent config's name), algo_version, seed, budget
    (training episodes of the job), phase (train | eval), episode (0-based), return, foods,
    final_distance, overshoot_ratio, final_C, final_F, final_P, first_overshoot_step,
    entropy, job_id.
``eval_trajectories``
    regime, regime_version, algo, algo_version, seed, budget, episode, step (1..H), food
    (index offered), action (0/1), C, F, P (absorbed after the step), reward, job_id.
``training_diagnostics``
    regime, regime_version, algo, algo_version, seed, budget, engine (sb3 | batched), update
    (0-based), timestep, the quantities of :data:`nutribench.diagnostics.QUANTITIES`, job_id:
    one row per update, the long ``diagnostics`` table pivoted (a plug-in's own names are in
    ``diagnostic_values`` and in :func:`~nutribench.store.queries.read_training_diagnostics`).
``diagnostic_values``
    regime, regime_version, algo, algo_version, seed, budget, engine, update, name, value,
    job_id: the ``diagnostics`` table with the names joined in, every quantity's name.
``learning_curve``
    regime, regime_version, algo, algo_version, seed, budget, engine, train_day (training days
    before the evaluation), episode (the validation day, 0-based), the metrics of
    ``episode_metrics``, never and planner (their returns on that day), gap_closed (the day's
    share of the never -> planner gap; NULL where the two coincide), job_id.
"""

from __future__ import annotations

from nutribench.diagnostics import COLUMNS as DIAGNOSTIC_COLUMNS
from nutribench.store.models import EPISODE_METRICS, EVAL_STEP_COLUMNS, VALIDATION_COLUMNS

VIEWS = ("episode_metrics", "eval_trajectories", "training_diagnostics", "diagnostic_values", "learning_curve")

_JOB_COLUMNS = ("regime", "regime_version", "algo", "algo_version", "seed", "budget")
EPISODE_METRICS_COLUMNS = (*_JOB_COLUMNS, "phase", "episode", *EPISODE_METRICS, "job_id")
EVAL_TRAJECTORY_COLUMNS = (*_JOB_COLUMNS, *EVAL_STEP_COLUMNS, "job_id")
TRAINING_DIAGNOSTICS_COLUMNS = (*_JOB_COLUMNS, "engine", *DIAGNOSTIC_COLUMNS, "job_id")
DIAGNOSTIC_VALUES_COLUMNS = (*_JOB_COLUMNS, "engine", "update", "name", "value", "job_id")
LEARNING_CURVE_COLUMNS = (*_JOB_COLUMNS, "engine", *VALIDATION_COLUMNS, "gap_closed", "job_id")
