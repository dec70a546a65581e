"""Every trial of the tuned grid's studies as one CSV (the plan's "What is kept"), and a
Markdown summary per study, and each study's optimisation history as a figure:
``python reports/tuned/trials.py`` (reads reports/tuned/data/tuning.db, writes
reports/tuned/trials.csv and fig_studies.png, and prints the summary)."""

from __future__ import annotations

import json
from pathlib import Path

import optuna
import pandas as pd

HERE = Path(__file__).resolve().parent
DB = f"sqlite:///{HERE / 'data' / 'tuning.db'}"


def trials() -> pd.DataFrame:
    rows = []
    for summary in sorted(optuna.get_all_study_summaries(DB, include_best_trial=False), key=lambda s: s.study_name):
        study = optuna.load_study(study_name=summary.study_name, storage=DB)
        for t in study.trials:
            wall = (t.datetime_complete - t.datetime_start).total_seconds() if t.datetime_complete else None
            rows.append(
                {
                    "study": summary.study_name,
                    "number": t.number,
                    "state": t.state.name,
                    "value": t.value,
                    "last_day": max(t.intermediate_values) if t.intermediate_values else None,
                    "last_value": t.intermediate_values[max(t.intermediate_values)] if t.intermediate_values else None,
                    "params": json.dumps(t.params, sort_keys=True),
                    "shares": json.dumps(t.user_attrs.get("shares", {}), sort_keys=True),
                    "engine": t.user_attrs.get("engine"),
                    "device": t.user_attrs.get("device"),
                    "wall_seconds": wall,
                }
            )
    return pd.DataFrame(rows)


def summary(df: pd.DataFrame) -> str:
    lines = [
        "| study | complete | pruned | failed | running | best value (trial) | median value of complete trials | trial time (sum) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, g in df.groupby("study"):
        done, counts = g[g.state == "COMPLETE"], g.state.value_counts()
        best = done.loc[done.value.idxmax()] if len(done) else None
        lines.append(
            f"| {name} | {len(done)} | {counts.get('PRUNED', 0)} | {counts.get('FAIL', 0)} | {counts.get('RUNNING', 0)} | "
            + (f"{best.value:+.3f} ({best.number})" if best is not None else "-")
            + (f" | {done.value.median():+.3f}" if len(done) else " | -")
            + f" | {g.wall_seconds.sum():.0f} s |"
        )
    return "\n".join(lines)


ALGOS = ("mc", "ppo", "ddqn", "gru_ppo", "sac")


def figure(df: pd.DataFrame, path: Path) -> None:
    """One panel per algorithm, both sets of studies: each trial's value against its number
    (complete: filled; pruned: hollow, at its last reported value; failed: a cross on the
    axis), and the running best of the complete trials."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, len(ALGOS), figsize=(4 * len(ALGOS), 4.2))
    for ax, algo in zip(axes, ALGOS, strict=True):
        for study, colour in ((f"tuned_{algo}", "tab:grey"), (f"tuned2_{algo}", "tab:blue")):
            g = df[df.study == study].sort_values("number")
            if g.empty:
                continue
            done, pruned, failed = (g[g.state == s] for s in ("COMPLETE", "PRUNED", "FAIL"))
            ax.plot(done.number, done.value, "o", color=colour, ms=4)
            if len(pruned):
                ax.plot(pruned.number, pruned.last_value, "o", mfc="none", color=colour, ms=4)
            if len(failed):
                ax.plot(failed.number, [0.0] * len(failed), "x", color=colour, ms=5)
            best = g.value.where(g.state == "COMPLETE").cummax().ffill()
            ax.step(g.number, best, where="post", color=colour, lw=1)
        ax.set_title(algo)
        ax.set_xlabel("trial number")
        ax.axhline(0, color="k", lw=0.5, ls=":")
    axes[0].set_ylabel("IQM share of the gap, validation days, day 500")
    keys = [
        Line2D([], [], color="tab:grey", marker="o", ls="", label="first set (tuned_<algo>)"),
        Line2D([], [], color="tab:blue", marker="o", ls="", label="second set (tuned2_<algo>: the grid's)"),
        Line2D([], [], color="k", marker="o", ls="", label="complete"),
        Line2D([], [], color="k", marker="o", mfc="none", ls="", label="pruned (last value)"),
        Line2D([], [], color="k", marker="x", ls="", label="failed"),
        Line2D([], [], color="k", lw=1, label="running best"),
    ]
    fig.legend(handles=keys, loc="lower center", ncol=len(keys), fontsize=8)
    fig.suptitle("Tuning studies: every trial (pruned at their last value), and the running best", fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    table = trials()
    table.to_csv(HERE / "trials.csv", index=False)
    figure(table, HERE / "fig_studies.png")
    print(summary(table))
