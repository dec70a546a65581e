"""The third addendum's reading: DDQN's control rerun with the training diagnostics.

(1) The check: the rerun's training rows (return, foods, final distance, entropy per day)
against the `ddqn` level's archive (data/ddqn.npz, imported into --control-db).
(2) Per regime (run3, run6) and window (the 100 training days before day 500, 1000, 2000,
3000, 4000, 5000): foods a day, training return and the diagnostics q_mean, value_loss,
grad_norm, epsilon, learning_rate; the IQM over seeds with a 95 % interval over seeds
(nutribench.stats.iqm_runs_ci, the trimmed t; fourth addendum), as analyse.py.
(3) fig_ddqn_diagnostics.png: those quantities against training day, one line per seed.

    python reports/sensitivity/ddqn_diagnostics.py --db /tmp/sens2/ddqn_diag.db \
        --control-db /tmp/sens2_an/ddqn_control.db --out reports/sensitivity
"""

from __future__ import annotations

import argparse
import sqlite3
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from nutribench.stats import iqm_runs_ci  # noqa: E402

HERE = Path(__file__).resolve().parent
WINDOWS = [500, 1000, 2000, 3000, 4000, 5000]
WIDTH = 100
QUANTITIES = ["foods", "return", "q_mean", "value_loss", "grad_norm", "epsilon", "learning_rate"]
KEY = ["regime", "seed", "episode"]
COMPARED = ["return", "foods", "final_distance", "entropy"]


def train_rows(db: str, budget: int) -> pd.DataFrame:
    con = sqlite3.connect(db)
    q = f"select * from episode_metrics where phase = 'train' and algo = 'ddqn' and budget = {int(budget)}"
    return pd.read_sql(q, con)


def check(run: pd.DataFrame, control: pd.DataFrame) -> pd.DataFrame:
    both = run.merge(control, on=KEY, suffixes=("", "_c"))
    row = {"rows": len(run), "control_rows": len(control), "matched": len(both)}
    for c in COMPARED:
        a, b = both[c].to_numpy(float), both[c + "_c"].to_numpy(float)
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        row[f"{c}_equal"] = int(same.sum())
        row[f"{c}_max_abs_diff"] = float(np.nanmax(np.abs(a - b))) if len(both) else float("nan")
    return pd.DataFrame([row])


def per_day(db: str, tr: pd.DataFrame) -> pd.DataFrame:
    """One row per (regime, seed, training day): foods, return and that day's diagnostics
    (a DDQN row closes each training day with gradient steps; its timestep is the day's end)."""
    budget = int(tr["budget"].iloc[0])
    q = f"select * from training_diagnostics where algo = 'ddqn' and budget = {budget}"
    diag = pd.read_sql(q, sqlite3.connect(db))
    diag["episode"] = diag["timestep"] // 50 - 1
    cols = ["regime", "seed", "episode", "q_mean", "value_loss", "grad_norm", "epsilon", "learning_rate"]
    return tr[["regime", "seed", "episode", "foods", "return"]].merge(diag[cols], on=KEY, how="left")


def windows(days: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for regime in ["run3", "run6"]:
        for end in WINDOWS:
            w = days[(days.regime == regime) & (days.episode >= end - WIDTH) & (days.episode < end)]
            per_seed = w.groupby("seed")[QUANTITIES].mean()
            row = {"regime": regime, "day": end}
            for qn in QUANTITIES:
                vals = per_seed[qn].dropna().to_numpy()
                if len(vals) == 0:
                    continue
                point, lo, hi = iqm_runs_ci([vals.astype(float)])
                row[qn] = point
                row[f"{qn}_lo"], row[f"{qn}_hi"] = lo, hi
                row[f"{qn}_seeds"] = " ".join(f"{v:.3g}" for v in vals)
            rows.append(row)
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame) -> str:
    head = "| regime | day | foods a day | training return | q_mean | value_loss (TD) | grad_norm | epsilon |"
    lines = [head, "|---" * 8 + "|"]
    for _, r in table.iterrows():
        cells = [f"{r[q]:.3g} [{r[q + '_lo']:.3g}, {r[q + '_hi']:.3g}]" for q in QUANTITIES[:5]]
        lines.append(f"| {r.regime} | {r.day} | " + " | ".join(cells) + f" | {r.epsilon:.3g} |")
    return "\n".join(lines) + "\n"


def figure(days: pd.DataFrame, out: Path) -> None:
    shown = [
        ("foods", "foods a day"),
        ("return", "training return a day"),
        ("q_mean", "q_mean (Q of replayed actions)"),
        ("value_loss", "value_loss (TD, Huber)"),
    ]
    fig, axes = plt.subplots(2, len(shown), figsize=(18, 8), sharex=True)
    for i, regime in enumerate(["run3", "run6"]):
        for j, (col, label) in enumerate(shown):
            ax = axes[i, j]
            for seed, s in days[days.regime == regime].groupby("seed"):
                s = s.sort_values("episode")
                ax.plot(s.episode, s[col].rolling(WIDTH, min_periods=1).mean(), lw=1, label=f"seed {seed}")
            ax.set_title(f"{regime}: {label}", fontsize=10)
            if i == 1:
                ax.set_xlabel("training day")
            if j == 0 and i == 0:
                ax.legend(fontsize=7)
    fig.suptitle(
        "DDQN (shipped ddqn v2), the `ddqn` level rerun with its training diagnostics: 100-day moving means per seed"
    )
    fig.tight_layout()
    fig.savefig(out / "fig_ddqn_diagnostics.png", dpi=100)
    print(f"wrote {out / 'fig_ddqn_diagnostics.png'}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--db", required=True, help="the rerun's database")
    ap.add_argument("--control-db", required=True, help="data/ddqn.npz imported")
    ap.add_argument("--out", default=str(HERE))
    ap.add_argument("--budget", type=int, default=5000, help="training days of the jobs read")
    a = ap.parse_args()
    out = Path(a.out)
    tr = train_rows(a.db, a.budget)
    c = check(tr, train_rows(a.control_db, a.budget))
    c.to_csv(out / "ddqn_diag_check.csv", index=False)
    print(c.T.to_string())
    days = per_day(a.db, tr)
    table = windows(days)
    table.to_csv(out / "table_ddqn_diagnostics.csv", index=False, float_format="%.5g")
    (out / "table_ddqn_diagnostics.md").write_text(markdown(table))
    print(markdown(table))
    figure(days, out)


if __name__ == "__main__":
    main()
