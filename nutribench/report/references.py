"""The yardsticks a report sets beside the agents: the simple policies (random, never,
always, full-information planner) played afresh from the regime files, never cached; and the
two above the planner (lookahead, clairvoyant), read from ``regimes/references.csv``
(below).

* :func:`simple_policy_references`: the reference lines of Figures 3/4 (fixed days, one seed);
* :func:`eval_day_references`: ``never`` and ``planner`` on exactly the days each job was
  evaluated on, for the results table's share of the never -> planner gap, with
  ``lookahead`` and ``clairvoyant`` where the committed file holds the day.

The references above the 100 % mark, set beside the agents: ``lookahead`` and
``clairvoyant`` (:mod:`nutribench.env.policies`), on the gap scale every table uses (0 % =
never eat, 100 % = the greedy planner; neither mark moves).

Planning them takes minutes, so their returns on the paper's test days (seeds 0, 21, 9,
2003, 1997 x the 5 evaluation days of each, every regime) are committed in
``regimes/references.csv``, remade by ``nutribench baselines --test-days --out
regimes/references.csv``. A row counts only where its regime's content (``sha256``) is the
installed regime file's; days the file lacks (other seeds, more days) get no reference.

* :func:`committed_references`: the file's rows that hold;
* :func:`with_strong_references`: the day yardsticks of a report with the two columns added;
* :func:`reference_runs`: the two policies' run scores (one per regime and seed, as an
  agent's) on the days an evaluation frame holds;
* :func:`regime_shares`: per regime, their mean share over seeds (an agent's per-regime
  number in the leaderboard and Figure 3).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import pandas as pd

from nutribench.baselines import REFERENCE_COLUMNS, STRONG_POLICIES, baseline_table, day_yardsticks
from nutribench.config import ConfigError, load_env_config, regimes_dir
from nutribench.report.data import Log, quiet


def simple_policy_references(
    regimes: Iterable[str], episodes: int = 200, seed: int = 0, log: Log | None = None
) -> pd.DataFrame:
    """Reference lines of Figures 3/4: the mean metrics of the four simple policies (random,
    never, always, full-information planner) per regime, on the same ``episodes`` food
    streams drawn with ``seed``. Regimes without a regime file are left out (logged).

    Columns: regime, policy, return, foods, final_distance, overshoot_ratio.
    """
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


#: The file under ``regimes/`` that holds the test days' references.
REFERENCES_FILE = "references.csv"
#: Where the numbers come from, for captions.
SOURCE = "regimes/references.csv (nutribench baselines --test-days)"


def committed_references(log: Log | None = None) -> pd.DataFrame:
    """The rows of ``regimes/references.csv`` whose regime content is the installed regime
    file's; regimes whose file changed (or is gone) are left out, logged. Columns:
    :data:`~nutribench.baselines.REFERENCE_COLUMNS`."""
    path = regimes_dir() / REFERENCES_FILE
    if not path.is_file():
        if log:
            log(f"no lookahead/clairvoyant references: {path} is missing")
        return pd.DataFrame(columns=list(REFERENCE_COLUMNS))
    table = pd.read_csv(path)
    keep = []
    for regime, rows in table.groupby("regime", sort=False):
        try:
            sha = load_env_config(str(regime)).sha256
        except ConfigError:
            sha = None
        if sha is not None and set(rows["sha256"]) == {sha}:
            keep.append(rows)
        elif log:
            log(f"no lookahead/clairvoyant references for {regime}: {path.name} was made from another regime file")
    return pd.concat(keep, ignore_index=True) if keep else table.iloc[0:0]


def with_strong_references(day_references: pd.DataFrame, log: Log | None = None) -> pd.DataFrame:
    """``day_references`` (regime, seed, episode, never, planner) with ``lookahead`` and
    ``clairvoyant`` added from :func:`committed_references` (NaN on a day it lacks, or whose
    never/planner returns differ from the ones played here)."""
    out = day_references.copy()
    committed = committed_references(log)
    if committed.empty or out.empty:
        return out.assign(**dict.fromkeys(STRONG_POLICIES, np.nan))
    key = ["regime", "seed", "episode"]
    found = committed.set_index(key).reindex(pd.MultiIndex.from_frame(out[key].astype({"seed": int, "episode": int})))
    yard = ["never", "planner"]
    agree = np.isclose(found[yard].to_numpy(dtype=float), out[yard].to_numpy(dtype=float), atol=1e-9).all(axis=1)
    for p in STRONG_POLICIES:
        out[p] = np.where(agree, found[p].to_numpy(dtype=float), np.nan)
    return out


def reference_runs(ev: pd.DataFrame, day_references: pd.DataFrame) -> pd.DataFrame:
    """Per (regime, policy, seed) of the days ``ev`` holds: the share of the never -> planner
    gap the reference's mean return closes on that seed's days (an agent's run score,
    :func:`nutribench.report.scores.run_scores`); a run with a day lacking the reference is
    left out. ``day_references``: :func:`with_strong_references`'s columns. Columns: regime,
    policy, seed, score."""
    cols = ["regime", "policy", "seed", "score"]
    if ev.empty or not set(STRONG_POLICIES) <= set(day_references.columns):
        return pd.DataFrame(columns=cols)
    from nutribench.report.scores import run_scores

    key = ["regime", "seed", "episode"]
    days = ev[key].drop_duplicates()
    yard = day_references.set_index(key).reindex(pd.MultiIndex.from_frame(days)).reset_index()
    played = pd.concat([yard.assign(algo=p, **{"return": yard[p]}) for p in STRONG_POLICIES], ignore_index=True)
    runs = run_scores(played, day_references).rename(columns={"algo": "policy"})
    runs = runs[np.isfinite(runs["score"].to_numpy(dtype=float))]
    rank = runs["policy"].map({p: i for i, p in enumerate(STRONG_POLICIES)})
    return runs.assign(rank=rank).sort_values(["regime", "seed", "rank"])[cols].reset_index(drop=True)


def regime_shares(ev: pd.DataFrame, day_references: pd.DataFrame) -> pd.DataFrame:
    """Per regime and reference policy: the mean of its run scores over the seeds ``ev``
    holds (:func:`reference_runs`) and how many. Columns: regime, policy, share, seeds."""
    runs = reference_runs(ev, day_references)
    if runs.empty:
        return pd.DataFrame(columns=["regime", "policy", "share", "seeds"])
    g = runs.groupby(["regime", "policy"])["score"]
    return pd.DataFrame({"share": g.mean(), "seeds": g.size()}).reset_index()


def aggregate_points(ev: pd.DataFrame, day_references: pd.DataFrame, groups: dict[str, list[str]]) -> pd.DataFrame:
    """The two references' aggregates (IQM, median, mean: the agents' estimators,
    :func:`nutribench.report.aggregate.point_estimate`) of their run scores over each group's
    regimes (``groups``: group -> regimes, an :class:`~nutribench.report.aggregate.AggregateResult`'s
    ``regimes``); a group where a reference lacks a regime is left out. Columns: group,
    policy, aggregate, point."""
    from nutribench.report.aggregate import point_estimate

    runs = reference_runs(ev, day_references)
    rows = []
    for group, regimes in groups.items():
        for policy in STRONG_POLICIES:
            mine = runs[runs["policy"] == policy]
            per = [mine[mine["regime"] == r].sort_values("seed")["score"].to_numpy(dtype=float) for r in regimes]
            if not regimes or any(not len(x) for x in per):
                continue
            rows += [(group, policy, agg, point_estimate(agg, per)) for agg in ("iqm", "median", "mean")]
    return pd.DataFrame(rows, columns=["group", "policy", "aggregate", "point"])
