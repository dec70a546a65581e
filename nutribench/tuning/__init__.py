"""Tuning under the project's protocol: search spaces (:mod:`~nutribench.tuning.space`,
versioned files in ``regimes/search/``), the objective on validation days and tuning seeds
(:mod:`~nutribench.tuning.objective`), Optuna studies in the results database
(:mod:`~nutribench.tuning.study`) and the best trial as a new agent file
(:mod:`~nutribench.tuning.export`). ``nutribench tune`` is the command; docs/tuning.md the guide.
"""
