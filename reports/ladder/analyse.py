"""The information ladder's analysis (README.md: the plan and addendum 1), written before any
archive of the plan was read: each archive ``data/obs<level>_<agent>.npz`` that is present is
imported into its own temporary database (the level variants share the regime names run0, run3
and run6 with other versions), its never and planner yardsticks played on its seeds' test days
with that level's regime files, and then:

* ``table_ladder.md/.csv``: one row per arm x level x regime: the IQM over seeds of the share of
  the never -> planner gap with its 95 % interval over seeds (``iqm_runs_ci``: the project's
  chosen trimmed t, addendum 3; no resamples, so no digit depends on a seed), the seeds' shares, the share of the mean
  return (the paper's reading), the mean return, foods a day, the share of meals eaten in the
  last 5 steps of the day, the device that trained it ("cuda to day N, then cpu" for a batch
  started on a lent GPU, addendum 2), and the learning-curve read-offs (the
  evaluation day of the highest validation IQM, that IQM and the day-5000 one with their
  intervals, "late drift" where the day-5000 interval lies wholly below the best one's);
* ``table_comparisons.md/.csv``: the plan's named comparisons C1-C11 and T1-T7 on each regime:
  both intervals and the plan's rule ("moves" only where they do not overlap, else "not
  distinguishable with N seeds"), the paired description (per-seed differences: median, how
  many seeds move in the direction of the IQM difference, IQM of the differences with its
  interval), the devices of the two arms (addendum 1); "not yet run: needs <archive>" where an
  archive is absent;
* ``fig_ladder.png``: per regime the share of the gap against the observation level (PPO and
  the tuned PPO as lines, GRU-PPO with and without memory as markers at levels 1 and 4, never
  and the planner as lines), and under it the learning curves on the validation days.

    python reports/ladder/analyse.py [--archives-dir reports/ladder/data] [--out reports/ladder]
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from nutribench.baselines import gap_closed  # noqa: E402
from nutribench.errors import UserError  # noqa: E402
from nutribench.stats import caption, iqm_runs_ci  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
#: arm -> its levels, in the plan's order of running
ARMS: dict[str, tuple[int, ...]] = {
    "ppo": (1, 4, 2, 3),
    "gru_ppo": (1, 4),
    "gru_ppo_nomem": (1, 4),
    "ppo_tuned": (1, 4, 2, 3),
}
LABELS = {"ppo": "PPO", "gru_ppo": "GRU-PPO", "gru_ppo_nomem": "GRU-PPO without memory", "ppo_tuned": "tuned PPO"}
REGIMES: tuple[str, ...] = ("run0", "run3", "run6")
SEEDS: tuple[int, ...] = tuple(range(3800, 3810))
HORIZON, LATE = 50, 5
PLANNER = ("planner", 0)
Arm = tuple[str, int]
#: the plan's named comparisons: id -> (A, B, question); B = PLANNER compares with 100 %
COMPARISONS: dict[str, tuple[Arm, Arm, str]] = {
    "C1": (("ppo", 2), ("ppo", 1), "what the clock closes"),
    "C2": (("ppo", 3), ("ppo", 2), "what the pending amount adds to the clock"),
    "C3": (("ppo", 4), ("ppo", 3), "what the schedule and the target add"),
    "C4": (("ppo", 4), ("ppo", 1), "the whole ladder"),
    "C5": (("ppo", 4), PLANNER, "does a Markov PPO reach the planner?"),
    "C6": (("gru_ppo", 1), ("ppo", 1), "what memory buys at the paper's observation"),
    "C7": (("gru_ppo", 1), ("gru_ppo_nomem", 1), "the memory ablation at the full budget"),
    "C8": (("gru_ppo", 4), ("gru_ppo_nomem", 4), "design check: memory with the state observed"),
    "C9": (("gru_ppo", 1), ("ppo", 2), "does memory recover the clock?"),
    "C10": (("gru_ppo", 1), ("ppo", 3), "does memory recover the clock and the pending amount?"),
    "C11": (("gru_ppo", 4), ("ppo", 4), "does the recurrent agent differ once the state is observed?"),
    "T1": (("ppo_tuned", 2), ("ppo_tuned", 1), "C1 for the tuned PPO"),
    "T2": (("ppo_tuned", 3), ("ppo_tuned", 2), "C2 for the tuned PPO"),
    "T3": (("ppo_tuned", 4), ("ppo_tuned", 3), "C3 for the tuned PPO"),
    "T4": (("ppo_tuned", 4), ("ppo_tuned", 1), "C4 for the tuned PPO"),
    "T5": (("ppo_tuned", 4), PLANNER, "C5 for the tuned PPO"),
    "T6": (("ppo_tuned", 1), ("ppo", 1), "tuned against shipped PPO, level 1"),
    "T7": (("ppo_tuned", 4), ("ppo", 4), "tuned against shipped PPO, level 4"),
}


class AnalysisError(UserError):
    """A bad path or an archive that is not the plan's: printed as one line."""


def archive_name(arm: Arm) -> str:
    return f"obs{arm[1]}_{arm[0]}"


def level_folder(level: int) -> Path:
    """The regime files of ``level`` (1: the shipped ones)."""
    return ROOT / "regimes" if level == 1 else HERE / f"regimes_obs{level}"


@contextmanager
def regimes_of(level: int) -> Iterator[None]:
    """``NUTRIBENCH_REGIMES`` pointing at ``level``'s regime files for the duration."""
    old = os.environ.get("NUTRIBENCH_REGIMES")
    os.environ["NUTRIBENCH_REGIMES"] = str(level_folder(level))
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("NUTRIBENCH_REGIMES", None)
        else:
            os.environ["NUTRIBENCH_REGIMES"] = old


# --------------------------------------------------------------------------- one batch
@dataclass
class Batch:
    """What the analysis reads of one (arm, level) archive."""

    arm: Arm
    per_seed: pd.DataFrame  # regime, seed, return, never, planner, score, foods, late
    learning: pd.DataFrame  # learning_points: regime, algo, train_day, iqm, lo, hi, seeds
    device: str
    notes: list[str] = field(default_factory=list)


def late_share(steps: pd.DataFrame) -> pd.DataFrame:
    """Per (regime, seed): the share of the eaten meals eaten in the last ``LATE`` steps of the
    day (steps are numbered 1..``HORIZON``); NaN for a seed that never ate."""
    meals = steps[steps["action"] == 1]
    late = (meals["step"] > HORIZON - LATE).groupby([meals["regime"], meals["seed"]]).mean()
    return late.rename("late").reset_index()


def expected_versions(arm: Arm) -> tuple[dict[str, int], int]:
    """The regime versions of ``arm``'s level (run0, run3, run6) and its agent file's version."""
    from nutribench.agents.config import load_agent_config
    from nutribench.config import load_env_config

    with regimes_of(arm[1]):
        regimes = {r: int(load_env_config(r).version) for r in REGIMES}
    return regimes, int(load_agent_config(HERE / "agents" / f"{arm[0]}.toml").version)


def check_archive(path: Path, arm: Arm, ev: pd.DataFrame) -> None:
    """One line (AnalysisError) unless ``ev`` is ``arm``'s agent file at ``arm``'s level."""
    algos = sorted(ev["algo"].unique())
    if algos != [arm[0]]:
        raise AnalysisError(f"{path}: holds agent(s) {', '.join(algos) or 'none'}, expected {arm[0]} (its name)")
    regimes, agent_version = expected_versions(arm)
    got = sorted({(r, int(v)) for r, v in zip(ev["regime"], ev["regime_version"]) if r in regimes})
    wrong = [f"{r} v{v}" for r, v in got if v != regimes[r]]
    if wrong:
        raise AnalysisError(
            f"{path}: regimes {', '.join(wrong)}, but level {arm[1]}'s files ({level_folder(arm[1])}) are "
            f"{', '.join(f'{r} v{v}' for r, v in regimes.items())}: the archive is not this level's"
        )
    versions = sorted({int(v) for v in ev["algo_version"]})
    if versions != [agent_version]:
        raise AnalysisError(
            f"{path}: {arm[0]} version(s) {versions}, but reports/ladder/agents/{arm[0]}.toml is v{agent_version}"
        )


def plan_notes(arm: Arm, ev: pd.DataFrame, per_seed: pd.DataFrame) -> list[str]:
    """Where the batch's jobs are not the plan's (regimes, seeds per regime, budget, test days),
    and seeds without a score or without a meal: notes, not errors (short test runs are not the plan's)."""
    name, notes = archive_name(arm), []
    extra = sorted(set(ev["regime"]) - set(REGIMES))
    if extra:
        notes.append(f"{name}: regimes outside the plan, left out: {', '.join(extra)}")
    for r in REGIMES:
        d = per_seed[per_seed["regime"] == r]
        if sorted(d["seed"]) != list(SEEDS):
            notes.append(f"{name}: not the plan's jobs on {r}: seeds {sorted(map(int, d['seed'])) or 'none'}")
        if (d["days"] != 10).any():
            notes.append(f"{name}: not the plan's jobs on {r}: {sorted(set(map(int, d['days'])))} test days, not 10")
        if d["score"].isna().any():
            notes.append(f"{name}: {int(d['score'].isna().sum())} seed(s) without a score on {r} (no yardsticks)")
        if d["late"].isna().any():
            notes.append(f"{name}: {int(d['late'].isna().sum())} seed(s) never ate on {r} (no late-meal share)")
    budgets = sorted({int(b) for b in ev["budget"]})
    if budgets != [5000]:
        notes.append(f"{name}: not the plan's jobs: budget {budgets} days, not 5000")
    return notes


def read_batch(path: Path, arm: Arm, db: str) -> Batch:
    """Import ``path`` into ``db`` and score it (the yardsticks with ``arm``'s level's regimes)."""
    from nutribench.report.data import prepare
    from nutribench.report.learning import learning_points, learning_scores, one_job_per_run
    from nutribench.report.references import eval_day_references
    from nutribench.report.scores import run_scores
    from nutribench.store import read_episode_metrics, read_eval_trajectories, read_jobs, read_learning_curve
    from nutribench.store.archive import import_results

    with regimes_of(arm[1]):
        import_results(path, db)
        ev = read_episode_metrics(db, phase="eval")
        check_archive(path, arm, ev)
        data = prepare(ev)
        evals = data.eval[data.eval["regime"].isin(REGIMES)]
        jobs = set(evals["job_id"])
        notes = [f"{archive_name(arm)}: {n}" for n in data.notes]
        log: list[str] = []
        refs = eval_day_references(evals, log=log.append)
        notes += [f"{archive_name(arm)}: {n}" for n in log]
        scores = run_scores(evals, refs)
        foods = evals.groupby(["regime", "seed"])["foods"].mean().rename("foods").reset_index()
        steps = read_eval_trajectories(db)
        per_seed = scores.merge(foods, on=["regime", "seed"]).merge(
            late_share(steps[steps["job_id"].isin(jobs)]), on=["regime", "seed"], how="left"
        )
        curve, more = one_job_per_run(read_learning_curve(db))
        curve = curve[curve["job_id"].isin(jobs)]
        learning = learning_points(learning_scores(curve)) if not curve.empty else pd.DataFrame()
        job_rows = read_jobs(db)
        devices = sorted(job_rows.loc[job_rows["id"].isin(jobs), "device"].dropna().astype(str).unique())
    notes += plan_notes(arm, ev, per_seed)
    device = started_on("/".join(devices) or "unknown", HERE / "logs" / f"{archive_name(arm)}.txt")
    return Batch(arm, per_seed, learning, device, notes + more)


def started_on(device: str, log: Path) -> str:
    """``device`` (where the jobs ended, as their rows say), preceded by where a batch started
    when its log says it began on a lent GPU and was resumed here (addendum 2)."""
    text = log.read_text(encoding="utf-8") if log.is_file() else ""
    day = re.search(r"\(day (\d+) of 5000\)", text)
    if "GPU start (addendum 2)" not in text or day is None:
        return device
    return f"cuda to day {day.group(1)}, then {device}"


# --------------------------------------------------------------------------- statistics
def interval(values: np.ndarray) -> tuple[float, float, float]:
    """IQM of one value per seed and its 95 % interval over seeds (the project's chosen method,
    ``nutribench.stats.iqm_runs_ci``: the trimmed t; addendum 3), over the finite values only (a
    seed without a score is left out, and noted by plan_notes): NaN for none, no interval for one."""
    finite = values[np.isfinite(values)]
    if not finite.size:
        return float("nan"), float("nan"), float("nan")
    return iqm_runs_ci([finite])


def text(point: float, lo: float, hi: float) -> str:
    """``55 [47, 63]`` in % of the gap."""
    if not np.isfinite(point):
        return "n/a"
    if not np.isfinite(lo):
        return f"{100 * point:.0f} [single seed]"
    return f"{100 * point:.0f} [{100 * lo:.0f}, {100 * hi:.0f}]"


def cell_row(batch: Batch, regime: str) -> dict:
    """The table_ladder row of ``batch`` on ``regime``."""
    arm, level = batch.arm
    d = batch.per_seed[batch.per_seed["regime"] == regime].sort_values("seed")
    point, lo, hi = interval(d["score"].to_numpy(dtype=float))
    scored = d[np.isfinite(d["score"].to_numpy(dtype=float))]
    row = dict(arm=arm, level=level, regime=regime, seeds=len(scored), iqm=point, lo=lo, hi=hi)
    row |= dict(
        share_of_mean=gap_closed(scored["return"].mean(), scored["never"].mean(), scored["planner"].mean())
        if len(scored)
        else float("nan"),
        per_seed=" ".join(pct(s) for s in d["score"]),
        mean_return=d["return"].mean(),
        foods=d["foods"].mean(),
        late_meals=d["late"].mean(),
        device=batch.device,
    )
    lc = batch.learning[batch.learning["regime"] == regime] if not batch.learning.empty else batch.learning
    if len(lc):
        best = lc.loc[lc["iqm"].idxmax()]
        last = lc.loc[lc["train_day"].idxmax()]
        row |= dict(best_day=int(best["train_day"]), best_iqm=best["iqm"], best_lo=best["lo"], best_hi=best["hi"])
        row |= dict(last_day=int(last["train_day"]), last_iqm=last["iqm"], last_lo=last["lo"], last_hi=last["hi"])
        row["late_drift"] = bool(last["hi"] < best["lo"])
    return row


def rule(a: tuple[float, float], b: tuple[float, float], seeds: int) -> str:
    """The plan's rule on two 95 % intervals (``b`` may be the planner's point, (1, 1))."""
    if not all(np.isfinite(v) for v in (*a, *b)):
        return "no interval (one seed)"
    if a[0] > b[1]:
        return "moves: higher (intervals apart)"
    if a[1] < b[0]:
        return "moves: lower (intervals apart)"
    return f"not distinguishable with {seeds} seeds"


def comparison_row(cid: str, regime: str, cells: dict[tuple[Arm, str], dict], batches: dict[Arm, Batch]) -> dict:
    """One named comparison on one regime (``cells``: table_ladder rows by (arm, regime))."""
    a, b, question = COMPARISONS[cid]
    row = dict(id=cid, regime=regime, a=f"{LABELS[a[0]]} level {a[1]}", question=question)
    row["b"] = "the planner (100 %)" if b == PLANNER else f"{LABELS[b[0]]} level {b[1]}"
    absent = [archive_name(x) for x in (a, b) if x != PLANNER and x not in batches]
    if absent:
        return row | dict(reading=f"not yet run: needs {', '.join(absent)}")
    ca = cells[(a, regime)]
    sa = batches[a].per_seed.query("regime == @regime").set_index("seed")["score"]
    if b == PLANNER:
        cb, sb, devices = dict(iqm=1.0, lo=1.0, hi=1.0), pd.Series(1.0, index=sa.index), batches[a].device
    else:
        cb = cells[(b, regime)]
        sb = batches[b].per_seed.query("regime == @regime").set_index("seed")["score"]
        devices = f"{batches[a].device} / {batches[b].device}"
    diffs = (sa - sb).dropna()
    sign = np.sign(ca["iqm"] - cb["iqm"])
    d_point, d_lo, d_hi = interval(diffs.to_numpy(dtype=float))
    return row | dict(
        a_text=text(ca["iqm"], ca["lo"], ca["hi"]),
        b_text=text(cb["iqm"], cb["lo"], cb["hi"]) if b != PLANNER else "100",
        reading=rule((ca["lo"], ca["hi"]), (cb["lo"], cb["hi"]), min(ca["seeds"], cb.get("seeds", ca["seeds"]))),
        paired_seeds=len(diffs),
        median_diff=float(diffs.median()) if len(diffs) else float("nan"),
        seeds_in_direction=int((np.sign(diffs) == sign).sum()) if sign != 0 else 0,
        diff_iqm=d_point,
        diff_lo=d_lo,
        diff_hi=d_hi,
        devices=devices,
    )


# --------------------------------------------------------------------------- tables
def md_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> list[str]:
    return [
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(map(str, r)) + " |" for r in rows),
    ]


def pct(v: object) -> str:
    return f"{100 * float(v):.0f}" if v is not None and np.isfinite(float(v)) else "n/a"


def ladder_markdown(cells: pd.DataFrame, absent: list[str], notes: list[str]) -> str:
    lines = [
        "# The information ladder: share of the never -> planner gap (%), test days",
        "",
        "Made by `python reports/ladder/analyse.py` from the archives in `data/`. IQM over seeds",
        f'[95 % interval over seeds: {caption("iqm")}]; "share of mean": the share closed by the',
        "mean return over seeds x days (the paper's reading); late meals: share of meals eaten in the",
        "last 5 steps of the day; learning curve: validation days, IQM [interval] at the best",
        "evaluation and at the last (late drift: the last interval wholly below the best one's; the",
        "best of 50 evaluations is selected, so this reading leans towards finding drift).",
        "",
    ]
    rows = []
    for r in cells.to_dict("records"):
        curve = "n/a"
        if np.isfinite(r.get("best_iqm", np.nan)):
            curve = (
                f"best day {r['best_day']}: {text(r['best_iqm'], r['best_lo'], r['best_hi'])}; "
                f"day {r['last_day']}: {text(r['last_iqm'], r['last_lo'], r['last_hi'])}"
                + ("; **late drift**" if r["late_drift"] else "")
            )
        rows.append(
            [
                LABELS[r["arm"]], r["level"], r["regime"], text(r["iqm"], r["lo"], r["hi"]), r["per_seed"],
                pct(r["share_of_mean"]), f"{r['mean_return']:.2f}", f"{r['foods']:.1f}", pct(r["late_meals"]),
                curve, r["device"],
            ]
        )  # fmt: skip
    header = ["arm", "level", "regime", "share IQM [95 % CI]", "seeds' shares", "share of mean", "mean return",
              "foods/day", "late meals %", "learning curve (validation)", "device"]  # fmt: skip
    lines += md_table(header, rows)
    if absent:
        lines += ["", f"Not yet run (no archive): {', '.join(absent)}."]
    if notes:
        lines += ["", "Notes:", *(f"- {n}" for n in notes)]
    return "\n".join(lines) + "\n"


def comparisons_markdown(comps: pd.DataFrame) -> str:
    lines = [
        "# The ladder's named comparisons (the plan's list; rule: two 95 % intervals apart)",
        "",
        "Shares of the gap in %; paired: per-seed differences A - B (median, seeds moving in the",
        "direction of the IQM difference, IQM of the differences [95 % CI]). Devices: where A and B",
        "trained (addendum 1: a difference of devices is float rounding, mixed into the arms';",
        "addendum 2: a batch started on a lent GPU and ended on the CPU says at which day).",
        "",
    ]
    rows = []
    for r in comps.to_dict("records"):
        if "a_text" not in r or not isinstance(r.get("a_text"), str):
            rows.append([r["id"], r["regime"], r["a"], r["b"], "", "", r["reading"], "", ""])
            continue
        paired = (
            f"median {100 * r['median_diff']:+.0f}, {int(r['seeds_in_direction'])}/{int(r['paired_seeds'])} seeds, "
            f"IQM {text(r['diff_iqm'], r['diff_lo'], r['diff_hi'])}"
        )
        rows.append(
            [r["id"], r["regime"], r["a"], r["b"], r["a_text"], r["b_text"], r["reading"], paired, r["devices"]]
        )
    lines += md_table(["id", "regime", "A", "B", "A: IQM [CI]", "B: IQM [CI]", "rule", "paired A - B", "devices"], rows)
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- figure
STYLE = {
    "ppo": ("tab:blue", "o"),
    "ppo_tuned": ("tab:cyan", "s"),
    "gru_ppo": ("tab:red", "D"),
    "gru_ppo_nomem": ("tab:orange", "v"),
}
OFFSET = {"ppo": -0.09, "ppo_tuned": -0.03, "gru_ppo": 0.03, "gru_ppo_nomem": 0.09}


def figure(cells: pd.DataFrame, batches: dict[Arm, Batch]):
    fig, axes = plt.subplots(2, len(REGIMES), figsize=(5 * len(REGIMES), 8.5), squeeze=False)
    for j, regime in enumerate(REGIMES):
        ax = axes[0, j]
        ax.axhline(0, color="0.4", lw=1, ls="--", label="never (0 %)")
        ax.axhline(100, color="0.2", lw=1, ls=":", label="planner (100 %)")
        for arm in ARMS:
            c = cells[(cells["arm"] == arm) & (cells["regime"] == regime)].sort_values("level")
            if c.empty:
                continue
            color, marker = STYLE[arm]
            x = c["level"].to_numpy() + OFFSET[arm]
            y, lo, hi = (100 * c[k].to_numpy(dtype=float) for k in ("iqm", "lo", "hi"))
            ax.errorbar(x, y, yerr=[y - lo, hi - y], color=color, marker=marker, capsize=3,
                        ls="-" if arm.startswith("ppo") else "none", label=LABELS[arm])  # fmt: skip
        ax.set_xticks([1, 2, 3, 4], ["1 paper", "2 +clock", "3 +pending", "4 full state"])
        ax.set_title(f"{regime}: test days, IQM over seeds [95 % CI]")
        ax.set_ylabel("share of the never -> planner gap (%)")
        ax = axes[1, j]
        for arm, batch in sorted(batches.items()):
            lc = batch.learning
            lc = lc[lc["regime"] == regime] if not lc.empty else lc
            if lc.empty:
                continue
            color = STYLE[arm[0]][0]
            shade, dash = {1: (1.0, "-"), 2: (0.8, "--"), 3: (0.7, "-."), 4: (0.6, ":")}[arm[1]]
            label = f"{LABELS[arm[0]]} L{arm[1]}"
            ax.plot(lc["train_day"], 100 * lc["iqm"], color=color, alpha=shade, ls=dash, lw=1.4, label=label)
            ax.fill_between(lc["train_day"], 100 * lc["lo"], 100 * lc["hi"], color=color, alpha=0.08, lw=0)
        ax.axhline(0, color="0.4", lw=1, ls="--")
        ax.axhline(100, color="0.2", lw=1, ls=":")
        ax.set_title(f"{regime}: validation days during training")
        ax.set_xlabel("training day")
        ax.set_ylabel("share of the gap (%)")
    for row in axes:
        handles, labels = row[0].get_legend_handles_labels()
        if handles:
            row[0].legend(fontsize=7, loc="lower right")
    fig.suptitle("The information ladder (reports/ladder/): what observing more of the state closes under delay")
    fig.tight_layout()
    return fig


# --------------------------------------------------------------------------- main
def read_batches(folder: Path, arms: Sequence[Arm]) -> dict[Arm, Batch]:
    """Each of ``arms``' archives in ``folder``, imported into its own temporary database and read."""
    with tempfile.TemporaryDirectory(prefix="nutribench-ladder-") as tmp:
        return {
            arm: read_batch(folder / f"{archive_name(arm)}.npz", arm, str(Path(tmp) / f"{archive_name(arm)}.db"))
            for arm in arms
        }


def tabulate(batches: dict[Arm, Batch], comparisons: Sequence[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The table_ladder rows of ``batches`` (arm by arm, regime by regime) and the rows of the
    comparisons whose ids (keys of :data:`COMPARISONS`) are ``comparisons``."""
    cell = {(arm, r): cell_row(batch, r) for arm, batch in batches.items() for r in REGIMES}
    comps = pd.DataFrame([comparison_row(c, r, cell, batches) for c in comparisons for r in REGIMES])
    return pd.DataFrame(list(cell.values())), comps


def write_tables(out: Path, tables: Sequence[tuple[str, pd.DataFrame, str]]) -> list[Path]:
    """Each ``(name, frame, markdown)`` as ``out/<name>.csv`` and ``out/<name>.md``."""
    written = []
    for name, frame, md in tables:
        frame.to_csv(out / f"{name}.csv", index=False, float_format="%.4f")
        (out / f"{name}.md").write_text(md)
        written += [out / f"{name}.csv", out / f"{name}.md"]
    return written


def analyse(folder: Path, out: Path) -> list[Path]:
    arms = [(agent, level) for agent, levels in ARMS.items() for level in sorted(levels)]
    present = [a for a in arms if (folder / f"{archive_name(a)}.npz").is_file()]
    absent = [archive_name(a) for a in arms if a not in present]
    other = sorted(p.name for p in folder.glob("*.npz") if p.stem not in {archive_name(a) for a in arms})
    if not present:
        raise AnalysisError(f"{folder}: none of the plan's archives (obs<level>_<agent>.npz) is there")
    print(f"archives present: {', '.join(map(archive_name, present))}; absent: {', '.join(absent) or 'none'}")
    batches = read_batches(folder, present)
    notes = [n for b in batches.values() for n in b.notes] + [f"not the plan's, left out: {o}" for o in other]
    cells, comps = tabulate(batches, list(COMPARISONS))
    written = write_tables(
        out,
        [
            ("table_ladder", cells, ladder_markdown(cells, absent, notes)),
            ("table_comparisons", comps, comparisons_markdown(comps)),
        ],
    )
    fig = figure(cells, batches)
    fig.savefig(out / "fig_ladder.png", dpi=110)
    plt.close(fig)
    return [*written, out / "fig_ladder.png"]


def cli(
    argv: Sequence[str] | None, run: Callable[[Path, Path], list[Path]], description: str, default_out: Path
) -> int:
    """The command line of this script and of ``followup.py``: ``run(archives_dir, out)``,
    a bad path or archive as one line (exit 2), then the files written."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--archives-dir", default=str(HERE / "data"), help="the archives (obs<level>_<agent>.npz)")
    ap.add_argument("--out", default=str(default_out), help="where the tables and the figure go")
    a = ap.parse_args(argv)
    try:
        folder, out = Path(a.archives_dir), Path(a.out)
        if not folder.is_dir():
            raise AnalysisError(f"--archives-dir {folder}: no such folder")
        if out.exists() and not out.is_dir():
            raise AnalysisError(f"--out {out}: not a folder")
        out.mkdir(parents=True, exist_ok=True)
        written = run(folder, out)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for p in written:
        print(f"wrote {p}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return cli(argv, analyse, __doc__.split("\n\n")[0], HERE)


if __name__ == "__main__":
    sys.exit(main())
