"""The yardsticks a report sets beside the agents: the simple policies (random, never,
always, full-information planner) played afresh from the regime files, never cached; and the
two above the planner (lookahead, clairvoyant), read from ``regimes/references.csv``
(:mod:`nutribench.report.headroom`).

* :func:`simple_policy_references`: the reference lines of Figures 3/4 (fixed days, one seed);
* :func:`eval_day_references`: ``never`` and ``planner`` on exactly the days each job was
  evaluated on, for the results table's share of the never -> planner gap, with
  ``lookahead`` and ``clairvoyant`` where the committed file holds the day.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import pandas as pd

from nutribench.config import ConfigError
from nutribench.report.data import Log, quiet


def simple_policy_references(
    regimes: Iterable[str], episodes: int = 200, seed: int = 0, log: Log | None = None
) -> pd.DataFrame:
    """Reference lines of Figures 3/4: the mean metrics of the four simple policies (random,
    never, always, full-information planner) per regime, on the same ``episodes`` food
    streams drawn with ``seed``. Regimes without a regime file are left out (logged).

    Columns: regime, policy, return, foods, final_distance, overshoot_ratio.
    """
    from nutribench.baselines import baseline_table

    rows = []
    for regime in regimes:
        try:
            rows += baseline_table([regime], episodes=episodes, seed=seed)
        except ConfigError as e:
            if log:
                log(f"no reference lines for {regime}: {e}")
    return pd.DataFrame(rows, columns=["regime", "policy", "return", "foods", "final_distance", "overshoot_ratio"])


def eval_day_references(ev: pd.DataFrame, log: Log | None = None) -> pd.DataFrame:
    """The ``never`` and ``planner`` returns on every evaluation day of ``ev``: a job of seed
    ``s`` evaluates on ``eval_food_streams(regime, s, n)``, so the yardsticks play exactly
    those days. Only where the database's regime version is the regime file's (the days and
    the reward are the file's); other regimes are left out (logged).

    Columns: regime, seed, episode, never, planner, lookahead, clairvoyant (the last two NaN
    on a day ``regimes/references.csv`` lacks).
    """
    from nutribench.agents import eval_food_streams
    from nutribench.baselines import day_yardsticks
    from nutribench.config import load_env_config
    from nutribench.report.headroom import with_strong_references

    log = log or quiet
    rows: list[dict[str, Any]] = []
    for (regime, version, seed), days in ev.groupby(["regime", "regime_version", "seed"]):
        try:
            cfg = load_env_config(regime)
        except ConfigError as e:
            log(f"no never/planner yardsticks for {regime}: {e}")
            continue
        if int(cfg.version) != int(version):
            log(f"no never/planner yardsticks for {regime} v{version}: the regime file is v{cfg.version}")
            continue
        streams = eval_food_streams(regime, int(seed), int(days["episode"].max()) + 1)
        rows += [{"regime": regime, "seed": seed, **d} for d in day_yardsticks(regime, streams)]
    return with_strong_references(pd.DataFrame(rows, columns=["regime", "seed", "episode", "never", "planner"]), log)
