"""The sensitivity study's table and figure from its database (the archives of data/ imported into
one) and the CSVs of evaluate_models.py.

Per level x regime x evaluation: the share of the never -> planner gap each seed's mean return
over its 5 evaluation days closes (never and the planner played on exactly those days, under
the regimes the level was evaluated under), the IQM over seeds with a 95 % interval over seeds
(nutribench.stats.iqm_runs_ci: the project's chosen trimmed t, no resamples; fourth addendum),
the mean return and foods a day. Training length: each seed's mean training return over the
100 days ending at day 500, 1000, 2000 and 5000 (IQM over seeds, same interval), and the
shorter PPO runs' training rows checked against the 5000-day control's first days
(prefix_check.csv). Levels are told apart by agent config, regime version and training days
(LEVELS).

    python reports/sensitivity/analyse.py --db /tmp/sens/rebuild.db \
        --csv reports/sensitivity/eval_control.csv --csv reports/sensitivity/eval_lo0_shipped.csv \
        --out reports/sensitivity
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

from nutribench.agents import eval_food_streams  # noqa: E402
from nutribench.baselines import gap_closed, play_simple_policy  # noqa: E402
from nutribench.config import load_env_config  # noqa: E402
from nutribench.stats import iqm_runs_ci  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
#: (agent config, regime version, training days) -> (level id, factor, level text, regimes folder it was trained under)
LEVELS = {
    ("ppo", 2, 5000): ("control", "none (shipped ppo v1)", "shipped", ROOT / "regimes"),
    ("ppo", 102, 5000): ("lo0", "overshoot weight", "lo 1 -> 1e-6 (off)", HERE / "regimes_lo0"),
    ("ppo_nonorm", 2, 5000): ("nonorm", "reward normalisation", "on -> off", ROOT / "regimes"),
    ("ppo_lr3e4", 2, 5000): ("lr3e4", "learning rate", "1e-3 -> 3e-4", ROOT / "regimes"),
    ("ppo_g095", 2, 5000): ("g095", "discount", "0.99 -> 0.95", ROOT / "regimes"),
    ("ppo", 103, 5000): ("clock", "clock in the observation", "none -> step of the day / 50", HERE / "regimes_clock"),
    ("ppo", 2, 500): ("len500", "training length", "5000 -> 500 days", ROOT / "regimes"),
    ("ppo", 2, 1000): ("len1000", "training length", "5000 -> 1000 days", ROOT / "regimes"),
    ("ppo", 2, 2000): ("len2000", "training length", "5000 -> 2000 days", ROOT / "regimes"),
    ("ddqn", 2, 5000): ("ddqn", "none (shipped ddqn v2)", "shipped", ROOT / "regimes"),
    ("ddqn_eps002", 2, 5000): ("ddqn_eps002", "DDQN final epsilon", "0.1 -> 0.02", ROOT / "regimes"),
    ("ddqn_tgt4000", 2, 5000): ("ddqn_tgt4000", "DDQN target copy", "every 1000 -> 4000 steps", ROOT / "regimes"),
    ("sac", 2, 5000): ("sac", "none (shipped sac v1)", "shipped", ROOT / "regimes"),
    ("sac_a005", 2, 5000): ("sac_a005", "SAC temperature", "fixed alpha 0.2 -> 0.05", ROOT / "regimes"),
    ("sac", 2, 1000): ("sac_1000", "none (shipped sac v1), 1000 days, CUDA", "shipped", ROOT / "regimes"),
    ("sac_a005", 2, 1000): (
        "sac_a005_1000",
        "SAC temperature, 1000 days, CUDA",
        "fixed alpha 0.2 -> 0.05",
        ROOT / "regimes",
    ),
}
ORDER = [
    "control",
    "lo0",
    "nonorm",
    "lr3e4",
    "g095",
    "clock",
    "len500",
    "len1000",
    "len2000",
    "ddqn",
    "ddqn_eps002",
    "ddqn_tgt4000",
    "sac",
    "sac_a005",
    "sac_1000",
    "sac_a005_1000",
]
PPO_LEVELS = ["control", "lo0", "nonorm", "lr3e4", "g095", "clock"]
LENGTHS = {"len500": 500, "len1000": 1000, "len2000": 2000, "control": 5000}
OTHER_LEVELS = ["ddqn", "ddqn_eps002", "ddqn_tgt4000", "sac", "sac_a005", "sac_1000", "sac_a005_1000"]
REGIMES = ["run0", "run3", "run6"]
WINDOWS = [500, 1000, 2000, 5000]
WIDTH = 100


def level_of(algo: str, version: int, budget: int) -> tuple[str, str, str, Path]:
    return LEVELS[(algo, int(version), int(budget))]


def yardsticks(folder: Path, regime: str, seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    cfg = load_env_config(folder / f"{regime}.toml")
    streams = eval_food_streams(cfg, seed, n)
    never = np.array([r["return"] for r in play_simple_policy("never", cfg, streams)])
    planner = np.array([r["return"] for r in play_simple_policy("planner", cfg, streams)])
    return never, planner


def summarise(per_seed: pd.DataFrame) -> dict:
    """per_seed: one row per seed with return, foods, share."""
    point, lo, hi = iqm_runs_ci([per_seed["share"].to_numpy(dtype=float)])
    return {
        "seeds": len(per_seed),
        "return_mean": per_seed["return"].mean(),
        "foods_mean": per_seed["foods"].mean(),
        "share_iqm": point,
        "share_lo": lo,
        "share_hi": hi,
        "share_min": per_seed["share"].min(),
        "share_max": per_seed["share"].max(),
        # the paper's reading: the share of the gap closed by the mean return over seeds x days
        "share_of_mean": gap_closed(per_seed["return"].mean(), per_seed["never"].mean(), per_seed["planner"].mean()),
    }


#: Every greedy-evaluated job's seed row (level, regime, seed, return, foods, share), filled by greedy_rows.
PER_SEED: list[dict] = []


def greedy_rows(ev: pd.DataFrame, steps: pd.DataFrame) -> list[dict]:
    rows = []
    for (algo, version, budget, regime), cell in ev.groupby(["algo", "regime_version", "budget", "regime"]):
        meals = steps[
            (steps.algo == algo)
            & (steps.regime_version == version)
            & (steps.budget == budget)
            & (steps.regime == regime)
            & (steps.action == 1)
        ]
        late = float((meals.step >= 46).mean()) if len(meals) else float("nan")
        level, factor, text, folder = level_of(algo, version, budget)
        per_seed = []
        for seed, days in cell.groupby("seed"):
            days = days.sort_values("episode")
            never, planner = yardsticks(folder, regime, int(seed), len(days))
            ret = days["return"].mean()
            per_seed.append(
                {
                    "seed": seed,
                    "return": ret,
                    "foods": days["foods"].mean(),
                    "never": never.mean(),
                    "planner": planner.mean(),
                    "share": gap_closed(ret, never.mean(), planner.mean()),
                }
            )
        per_seed = pd.DataFrame(per_seed)
        PER_SEED.extend({"level": level, "regime": regime, **r} for r in per_seed.to_dict("records"))
        evaluation = "greedy, own reward (lo off)" if version == 102 else "greedy"
        rows.append(
            {
                "level": level,
                "factor": factor,
                "value": text,
                "regime": regime,
                "evaluation": evaluation,
                **summarise(per_seed),
                "per_seed": " ".join(f"{100 * s:.0f}" for s in per_seed["share"]),
                "late_meals": late,
            }
        )
    return rows


def csv_rows(csv: pd.DataFrame) -> list[dict]:
    rows = []
    for (level, regime, rv, mode), cell in csv[~csv["mode"].isin(["never", "planner"])].groupby(
        ["level", "regime", "reward_version", "mode"]
    ):
        ys = csv[(csv.level == level) & (csv.regime == regime) & (csv.reward_version == rv)]
        per_seed = []
        for seed, days in cell.groupby("seed"):
            never = ys[(ys.seed == seed) & (ys["mode"] == "never")]["return"].mean()
            planner = ys[(ys.seed == seed) & (ys["mode"] == "planner")]["return"].mean()
            ret = days["return"].mean()  # over draws x days
            per_seed.append(
                {
                    "seed": seed,
                    "return": ret,
                    "foods": days["foods"].mean(),
                    "never": never,
                    "planner": planner,
                    "share": gap_closed(ret, never, planner),
                }
            )
        per_seed = pd.DataFrame(per_seed)
        factor, text = next((v[1], v[2]) for v in LEVELS.values() if v[0] == level)
        draws = cell["draw"].nunique()
        evaluation = mode + (f" ({draws} draws of the days)" if mode == "stochastic" else "")
        if rv == 2 and level == "lo0":
            evaluation += ", shipped reward"
        if mode == "greedy" and not (rv == 2 and level == "lo0"):
            continue  # the database's own greedy evaluation, replayed as a check (evaluate_models.py --check)
        rows.append(
            {
                "level": level,
                "factor": factor,
                "value": text,
                "regime": regime,
                "evaluation": evaluation,
                **summarise(per_seed),
                "per_seed": " ".join(f"{100 * s:.0f}" for s in per_seed["share"]),
            }
        )
    return rows


def training_rows(tr: pd.DataFrame, planner_mean: dict) -> list[dict]:
    rows = []
    for (algo, version, budget, regime), cell in tr.groupby(["algo", "regime_version", "budget", "regime"]):
        level = level_of(algo, version, budget)[0]
        if level in LENGTHS and level != "control":
            continue  # prefixes of the control's runs (checked by prefix_check)
        for day in WINDOWS:
            if cell["episode"].max() + 1 < day:
                continue
            w = cell[(cell["episode"] >= day - WIDTH) & (cell["episode"] < day)]
            per_seed = w.groupby("seed")[["return", "foods", "entropy"]].mean()
            point, lo, hi = iqm_runs_ci([per_seed["return"].to_numpy(dtype=float)])
            never, planner = planner_mean[(version, regime)]
            rows.append(
                {
                    "level": level,
                    "regime": regime,
                    "day": day,
                    "seeds": len(per_seed),
                    "return_iqm": point,
                    "return_lo": lo,
                    "return_hi": hi,
                    "foods_mean": per_seed["foods"].mean(),
                    "entropy_mean": per_seed["entropy"].mean(),
                    "share_of_iqm": gap_closed(point, never, planner),
                }
            )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--db", required=True)
    ap.add_argument("--csv", action="append", default=[])
    ap.add_argument("--out", default=str(HERE))
    a = ap.parse_args()
    out = Path(a.out)
    con = sqlite3.connect(a.db)
    df = pd.read_sql("select * from episode_metrics", con)
    known = [(x, v, b) in LEVELS for x, v, b in zip(df.algo, df.regime_version, df.budget)]
    df = df[known]
    ev, tr = df[df.phase == "eval"], df[df.phase == "train"]
    steps = pd.read_sql(
        "select algo, regime, regime_version, budget, step, action from eval_trajectories where action = 1", con
    )
    rows = greedy_rows(ev, steps)
    csv = pd.concat([pd.read_csv(p) for p in a.csv]) if a.csv else pd.DataFrame()
    if not csv.empty:
        rows += csv_rows(csv)
    table = pd.DataFrame(rows)
    table["_l"] = table["level"].map(ORDER.index)
    table = table.sort_values(["_l", "evaluation", "regime"]).drop(columns="_l")
    table.to_csv(out / "table_sensitivity.csv", index=False, float_format="%.4f")

    def late(v):
        return f"{100 * v:.0f} %" if isinstance(v, float) and np.isfinite(v) else ""

    def cell(r):
        return f"{100 * r.share_iqm:.0f} % [{100 * r.share_lo:.0f}, {100 * r.share_hi:.0f}]"

    lines = [
        "| level | factor: value | evaluation | regime | share of the gap, IQM [95 % CI] | seeds' shares (%) | share of the mean return | return (mean) | foods (mean) | meals in the last 5 steps |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in table.itertuples():
        lines.append(
            f"| {r.level} | {r.factor}: {r.value} | {r.evaluation} | {r.regime} | {cell(r)} | {r.per_seed} | {100 * r.share_of_mean:.0f} % | "
            f"{r.return_mean:.1f} | {r.foods_mean:.1f} | {late(r.late_meals)} |"
        )
    (out / "table_sensitivity.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))

    # training length: never / planner means over the regime's evaluation days of all seeds (the yardstick)
    planner_mean = {}
    folders = {2: ROOT / "regimes", 102: HERE / "regimes_lo0", 103: HERE / "regimes_clock"}
    for (version, regime), g in ev.groupby(["regime_version", "regime"]):
        folder = folders[int(version)]
        nv, pl = [], []
        for seed in sorted(g["seed"].unique()):
            n_, p_ = yardsticks(folder, regime, int(seed), 5)
            nv.append(n_.mean())
            pl.append(p_.mean())
        planner_mean[(version, regime)] = (float(np.mean(nv)), float(np.mean(pl)))
    trt = pd.DataFrame(
        training_rows(tr, planner_mean),
        columns=[
            "level",
            "regime",
            "day",
            "seeds",
            "return_iqm",
            "return_lo",
            "return_hi",
            "foods_mean",
            "entropy_mean",
            "share_of_iqm",
        ],
    )
    trt["_l"] = trt["level"].map(ORDER.index)
    trt = trt.sort_values(["_l", "regime", "day"]).drop(columns="_l")
    trt.to_csv(out / "table_training_length.csv", index=False, float_format="%.4f")
    lines = [
        "| level | regime | training day | training return, IQM [95 % CI] over seeds of the 100 days before it | foods a day (mean) | policy entropy (nats, mean) | share of the gap of the IQM |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in trt.itertuples():
        lines.append(
            f"| {r.level} | {r.regime} | {r.day} | {r.return_iqm:.1f} [{r.return_lo:.1f}, {r.return_hi:.1f}] | "
            f"{r.foods_mean:.1f} | {r.entropy_mean:.2f} | {100 * r.share_of_iqm:.0f} % |"
        )
    (out / "table_training_length.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(
        "yardsticks (never, planner) per regime:", {k: tuple(round(x, 2) for x in v) for k, v in planner_mean.items()}
    )

    prefix_check(tr, out)
    length_per_seed(out)
    figure(table, tr, planner_mean, out)


def length_per_seed(out: Path) -> None:
    """The shipped PPO's greedy evaluation per seed at each training length (the shorter runs are
    prefixes of the control's), and in how many seeds the 5000-day share is below the shorter one's."""
    ps = pd.DataFrame(PER_SEED)
    if ps.empty:
        return
    ps = ps[ps.level.isin(list(LENGTHS))].assign(days=lambda d: d.level.map(LENGTHS))
    if ps["days"].nunique() < 2:
        return
    share = ps.pivot_table(index=["regime", "seed"], columns="days", values="share")
    foods = ps.pivot_table(index=["regime", "seed"], columns="days", values="foods")
    days = list(share.columns)
    lines = [
        "| regime | seed | "
        + " | ".join(f"share at {d} days" for d in days)
        + " | "
        + " | ".join(f"foods at {d}" for d in days)
        + " |",
        "|---|---|" + "---|" * (2 * len(days)),
    ]
    for (regime, seed), r in share.iterrows():
        f = foods.loc[(regime, seed)]
        lines.append(
            f"| {regime} | {seed} | "
            + " | ".join(f"{100 * r[d]:.0f} %" for d in days)
            + " | "
            + " | ".join(f"{f[d]:.1f}" for d in days)
            + " |"
        )
    lines.append("")
    for regime, g in share.groupby(level="regime"):
        for d in days[:-1]:
            lower = int((g[days[-1]] < g[d]).sum())
            lines.append(
                f"- {regime}: the {days[-1]}-day share is below the {d}-day share in {lower} of {len(g)} seeds"
            )
    (out / "table_length_per_seed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def prefix_check(tr: pd.DataFrame, out: Path) -> None:
    """Each shorter PPO run's training rows against the 5000-day control's first days: the
    largest absolute difference per column, and how many rows are exactly equal."""
    key = ["regime", "seed", "episode"]
    cols = ["return", "foods", "final_distance", "entropy"]
    control = tr[(tr.algo == "ppo") & (tr.regime_version == 2) & (tr.budget == 5000)]
    rows = []
    for level, days in LENGTHS.items():
        if level == "control":
            continue
        run = tr[(tr.algo == "ppo") & (tr.regime_version == 2) & (tr.budget == days)]
        if run.empty or control.empty:
            continue
        both = run.merge(control[control.episode < days], on=key, suffixes=("", "_c"))
        row = {"level": level, "rows": len(run), "matched": len(both)}
        for c in cols:
            diff = np.abs(both[c].to_numpy(float) - both[c + "_c"].to_numpy(float))
            row[f"{c}_max_abs_diff"] = float(np.nanmax(diff)) if len(diff) else float("nan")
            row[f"{c}_equal"] = int(np.sum(diff == 0))
        rows.append(row)
    if rows:
        check = pd.DataFrame(rows)
        check.to_csv(out / "prefix_check.csv", index=False)
        print("prefix check (training rows of the shorter runs against the control's first days):")
        print(check.to_string(index=False))


def figure(table: pd.DataFrame, tr: pd.DataFrame, planner_mean: dict, out: Path) -> None:
    """(A) PPO levels' share of the gap; (B) PPO's greedy share against its training length;
    (C) DDQN's (and SAC's) levels; (D, E) PPO levels' training return in run3 and run6;
    (F) DDQN levels' training foods a day in run3 and run6."""
    fig, axes = plt.subplots(2, 3, figsize=(20, 12), gridspec_kw={"width_ratios": [1.5, 1, 1]})
    color = {lvl: f"C{i % 10}" for i, lvl in enumerate(ORDER)}
    color.update({"ddqn": "C0", "ddqn_eps002": "C1", "ddqn_tgt4000": "C2", "sac": "C3", "sac_a005": "C4"})

    def bars(ax, levels, title):
        sel = table[table.level.isin(levels)]
        if sel.empty:
            ax.text(
                0.5,
                0.5,
                "not run: no compute before the deadline (README)",
                ha="center",
                va="center",
                transform=ax.transAxes,
            )
            ax.set_title(title, fontsize=10)
            return
        series = [(lvl, ev_) for lvl, ev_ in sel[["level", "evaluation"]].drop_duplicates().itertuples(index=False)]
        width = 0.8 / max(len(series), 1)
        for i, (lvl, ev_) in enumerate(series):
            sub = sel[(sel.level == lvl) & (sel.evaluation == ev_)].set_index("regime").reindex(REGIMES)
            x = np.arange(len(REGIMES)) + (i - (len(series) - 1) / 2) * width
            y = 100 * sub["share_iqm"].to_numpy()
            err = np.abs(100 * np.vstack([sub["share_iqm"] - sub["share_lo"], sub["share_hi"] - sub["share_iqm"]]))
            odd = ev_.startswith("stochastic") or "own reward" in ev_
            ax.bar(
                x,
                y,
                width,
                yerr=err,
                capsize=2,
                color=color[lvl],
                alpha=0.45 if odd else 1.0,
                hatch="//" if odd else None,
                edgecolor="k",
                lw=0.3,
                label=f"{lvl}: {ev_}",
            )
        ax.axhline(0, color="k", lw=0.8)
        ax.axhline(100, color="k", lw=0.8, ls="--")
        ax.set_xticks(np.arange(len(REGIMES)), REGIMES)
        ax.set_ylabel("share of the never -> planner gap (%)\nIQM over 5 seeds, 95 % trimmed-t interval")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7, loc="lower left", ncol=2)

    bars(axes[0, 0], PPO_LEVELS, "(A) PPO, one factor at a time: evaluation on 5 fixed days per seed")
    ran = set(table.level)
    if ran & {"sac", "sac_a005"}:
        other = "DDQN and SAC"
    elif ran & {"sac_1000", "sac_a005_1000"}:
        other = "DDQN, and SAC at 1000 days"
    else:
        other = "DDQN (SAC not run)"
    bars(axes[0, 2], OTHER_LEVELS, f"(C) {other}: evaluation on 5 fixed days per seed")

    ax = axes[0, 1]
    greedy = table[(table.evaluation == "greedy") & table.level.isin(list(LENGTHS))]
    for k, regime in enumerate(REGIMES):
        sub = greedy[greedy.regime == regime].assign(days=lambda d: d.level.map(LENGTHS)).sort_values("days")
        if sub.empty:
            continue
        x = sub["days"].to_numpy() * (1 + 0.03 * (k - 1))
        err = np.abs(100 * np.vstack([sub["share_iqm"] - sub["share_lo"], sub["share_hi"] - sub["share_iqm"]]))
        ax.errorbar(x, 100 * sub["share_iqm"], yerr=err, marker="o", capsize=3, label=regime, color=f"C{k}")
    ax.set_xscale("log")
    ax.set_xticks([500, 1000, 2000, 5000], ["500", "1000", "2000", "5000"])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.axhline(0, color="k", lw=0.8)
    ax.axhline(100, color="k", lw=0.8, ls="--")
    ax.set_xlabel("training days (5000 = part 1's control)")
    ax.set_ylabel("share of the gap (%), greedy, IQM [95 % CI]")
    ax.set_title("(B) shipped PPO: greedy evaluation against training length", fontsize=10)
    ax.legend(fontsize=8)

    for ax, regime, tag in ((axes[1, 0], "run3", "D"), (axes[1, 1], "run6", "E")):
        for lvl in PPO_LEVELS:
            sub = tr[(tr.regime == regime)]
            sub = sub[[level_of(a_, v_, b_)[0] == lvl for a_, v_, b_ in zip(sub.algo, sub.regime_version, sub.budget)]]
            if sub.empty:
                continue
            curve = sub.groupby("episode")["return"].mean().rolling(100, min_periods=1).mean()
            ax.plot(
                curve.index + 1,
                curve.to_numpy(),
                lw=1.2,
                color=color[lvl],
                label=lvl + (" (its own reward, lo off)" if lvl == "lo0" else ""),
            )
        nv, pl = planner_mean.get((2, regime), (np.nan, np.nan))
        ax.axhline(nv, color="k", lw=0.8, ls=":", label="never")
        ax.axhline(pl, color="k", lw=0.8, ls="--", label="planner (eval days)")
        for d in WINDOWS[:-1]:
            ax.axvline(d, color="grey", lw=0.5, alpha=0.5)
        ax.set_title(f"({tag}) PPO levels, {regime}: training return (stochastic policy)", fontsize=10)
        ax.set_xlabel("training day")
        ax.set_ylabel("return a day (mean over 5 seeds, 100-day moving mean)")
        ax.legend(fontsize=7)

    ax = axes[1, 2]
    if not any(level_of(*k)[0] in OTHER_LEVELS for k in set(zip(tr.algo, tr.regime_version, tr.budget))):
        ax.text(
            0.5,
            0.5,
            "not run: no compute before the deadline (README)",
            ha="center",
            va="center",
            transform=ax.transAxes,
        )
    for lvl in OTHER_LEVELS:
        for regime, ls in (("run3", "-"), ("run6", "--")):
            sub = tr[(tr.regime == regime)]
            sub = sub[[level_of(a_, v_, b_)[0] == lvl for a_, v_, b_ in zip(sub.algo, sub.regime_version, sub.budget)]]
            if sub.empty:
                continue
            curve = sub.groupby("episode")["foods"].mean().rolling(100, min_periods=1).mean()
            ax.plot(curve.index + 1, curve.to_numpy(), lw=1.2, ls=ls, color=color[lvl], label=f"{lvl} {regime}")
    ax.set_title(f"(F) {other}: training foods a day (run3 solid, run6 dashed)", fontsize=10)
    ax.set_xlabel("training day")
    ax.set_ylabel("foods a day (mean over 5 seeds, 100-day moving mean)")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)
    fig.suptitle(
        "Sensitivity study: one factor at a time from the shipped agents (batched engine, seeds 0-4, 5000 days "
        "unless a training length or a level named _1000)"
    )
    fig.tight_layout()
    fig.savefig(out / "fig_sensitivity.png", dpi=110)
    print(f"wrote {out / 'fig_sensitivity.png'}")


if __name__ == "__main__":
    main()
