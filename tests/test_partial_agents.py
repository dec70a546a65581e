"""One partial agent (a recorded agent run on one regime with one seed) beside complete ones
changes nobody's aggregate (issue 54): before, every agent was pooled over the regimes they
all shared, so GRU-PPO's IQM fell from 68 % to 56 % and the panels read "all regimes (run3)"."""

from __future__ import annotations

import numpy as np
import pandas as pd

from nutribench.report.aggregate import aggregate_scores, group_title
from nutribench.report.aggregate_view import aggregate_figure, aggregate_table

REGIMES = [f"run{i}" for i in range(7)]


def frame() -> pd.DataFrame:
    rng = np.random.default_rng(4)
    rows = [
        {"regime": r, "algo": a, "seed": s, "score": float(rng.normal(0.6 if a == "gru_ppo" else 0.2, 0.3))}
        for a in ("ppo", "gru_ppo")
        for r in REGIMES
        for s in (0, 21, 9)
    ]
    return pd.DataFrame(rows)


def test_a_partial_agent_is_apart_and_leaves_the_others_as_they_were() -> None:
    full = frame()
    alone = aggregate_scores(full, reps=200)
    partial = pd.concat([full, pd.DataFrame([{"regime": "run3", "algo": "torch_rand", "seed": 0, "score": -0.4}])])
    res = aggregate_scores(partial, reps=200)
    assert res.regimes == {"all": REGIMES, "delayed": REGIMES[1:]}  # not shrunk to run3
    both = res.intervals[res.intervals["algo"] != "torch_rand"].reset_index(drop=True)
    pd.testing.assert_frame_equal(both, alone.intervals.reset_index(drop=True))
    mine = res.intervals[res.intervals["algo"] == "torch_rand"]
    assert set(mine["group"]) == {"all", "delayed"} and (mine["regimes"] == 1).all() and (mine["runs"] == 1).all()
    assert res.partial == {"all": {"torch_rand": ["run3"]}, "delayed": {"torch_rand": ["run3"]}}
    assert set(res.improvement["x"]) == {"ppo", "gru_ppo"}  # not compared where it has no runs
    (note,) = [n for n in res.notes if "torch_rand" in n]
    assert "its own" in note and "run3" in note and "not comparable" in note
    assert group_title(res, "all", "torch_rand") == "all regimes (run3 only: this agent's)"
    assert group_title(res, "all", "ppo") == "all regimes (run0-run6)"


def test_the_figure_and_table_flag_the_partial_agent() -> None:
    partial = pd.concat([frame(), pd.DataFrame([{"regime": "run3", "algo": "torch_rand", "seed": 0, "score": -0.4}])])
    res = aggregate_scores(partial, reps=100)
    fig = aggregate_figure(res)
    labels = [t.get_text() for t in fig.figure.axes[0].get_yticklabels()]
    assert "torch_rand\n(own regimes: run3)" in labels, labels
    titles = [ax.get_title() for ax in fig.figure.axes] + [
        fig.figure._suptitle.get_text() if fig.figure._suptitle else ""
    ]
    assert not any("(run3)" in t for t in titles), titles  # the panels pool every regime, not the partial agent's one
    assert any("run0" in t for t in titles), titles
    assert {d["algo"] for d in fig.data.to_dict("records")} >= {"torch_rand", "ppo", "gru_ppo"}
    table = aggregate_table(res)
    rows = table.raw[table.raw["algo"] == "torch_rand"]
    assert set(rows["regimes"]) == {"run3"}
    assert table.raw[table.raw["algo"] == "ppo"]["regimes"].tolist() == [",".join(REGIMES), ",".join(REGIMES[1:])]
