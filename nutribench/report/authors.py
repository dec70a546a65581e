"""The authors' figures: the training results logged by the paper's authors, read from the
``results/Training/*.csv`` files of their public repository
(<https://github.com/CharithaPalika/NutriRL>): ``return_mean`` and ``foods_mean`` averaged
over the last 10 % of their 5000 training days. Their returns are in their own units
(nutrients divided by their catalog's column norms, overshoot weight 0 in the published
runs), where never eating scores about -21.5 a day; ours (reward version 2) give never
-21.6, so the two scales are comparable but not identical. Used by the report's training
table, beside our numbers (our own yardsticks are in :mod:`nutribench.report.references`)."""

from __future__ import annotations

REGIMES = ("run0", "run1", "run2", "run3", "run4", "run5", "run6")
#: algo -> (return, foods) per regime, run0..run6.
AUTHORS_LAST_10PCT: dict[str, tuple[tuple[float, float], ...]] = {
    "mc": ((-7.1, 4.8), (-8.4, 4.6), (-8.2, 4.6), (-9.8, 4.5), (-9.1, 4.8), (-11.6, 4.9), (-10.7, 5.6)),
    "ddqn": ((-10.1, 2.2), (-10.3, 2.6), (-11.2, 2.4), (-20.9, 0.3), (-13.2, 2.2), (-27.9, 13.4), (-17.8, 7.4)),
    "ppo": ((-5.9, 5.0), (-8.2, 5.1), (-8.6, 5.3), (-11.9, 7.7), (-8.8, 5.3), (-15.6, 9.8), (-12.6, 8.9)),
    "sac": ((-8.2, 5.6), (-38.9, 25.5), (-34.1, 22.1), (-35.8, 25.5), (-34.6, 25.7), (-31.0, 25.5), (-29.0, 25.3)),
    "gru_ppo": ((-5.9, 5.0), (-7.6, 4.7), (-7.0, 4.8), (-8.7, 4.8), (-8.1, 5.2), (-9.9, 5.5), (-10.4, 6.4)),
}
AUTHORS_BUDGET = 5000


def authors_training(algo: str, regime: str) -> tuple[float, float] | None:
    """The authors' (return, foods) of the last 10 % of training days, or None if not logged."""
    if algo not in AUTHORS_LAST_10PCT or regime not in REGIMES:
        return None
    return AUTHORS_LAST_10PCT[algo][REGIMES.index(regime)]
