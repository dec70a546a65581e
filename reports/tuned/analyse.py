"""The tuned grid's analysis (README.md: the plan, addenda 1 and 2): the paper protocol's
archives (``reports/paper/data/``) and the tuned grid's (``data/<agent>.npz``, those present)
imported into one temporary database, then:

* ``table_protocols.md/.csv``: per algorithm and regime, the IQM over seeds of the share of the
  never -> planner gap with its 95 % interval over seeds, paper protocol beside tuned
  protocol (``mc_tuned_set1``, addendum 2's exploratory arm, as its own rows), and the same
  over the delayed regimes (run1-run6) and the held-out ones (run3, run5, run6);
* ``table_questions.md/.csv``: the plan's 38 named comparisons, each computed where its archives
  are present, else "not yet run: needs <agent>";
* ``fig_protocols.png``: per algorithm and regime, paper against tuned (IQM with interval);
* ``fig_learning_curves.png``: the tuned grid's validation learning curves (``--eval-every 250``).

Every statistic is the project's own: a run (one seed on one regime) is scored by
``nutribench.report.scores.run_scores`` (the share of the gap its mean return closes on its own
test days, never and planner played on those days by
``nutribench.report.references.eval_day_references``); IQMs and their intervals are
``nutribench.report.aggregate.interval_estimates`` (rliable's IQM; the trimmed t interval,
stratified by regime); paired comparisons are ``nutribench.report.compare.compare_agents`` (what ``nutribench
compare`` prints), run once on the returns and once on each day's share of the gap (a day's
return on its seed's yardstick, so that a seed's mean is its run score); the drop under delay
and the held-out-against-tuning contrast are Welch t intervals (``nutribench.stats.contrast_ci``,
``welch_t``): since addendum 3 every interval is of the project's chosen method, none drawn
from resamples. "Apart" is the plan's rule: two 95 %
intervals that do not overlap; overlapping ones are "not distinguishable with N seeds".

    python reports/tuned/analyse.py [--archives-dir reports/tuned/data] [--out reports/tuned]
        [--paper-dir reports/paper/data] [--db KEEP.db]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from nutribench.errors import UserError  # noqa: E402
from nutribench.report.aggregate import interval_estimates, point_estimate, run_scores, score_set  # noqa: E402
from nutribench.report.compare import compare_agents  # noqa: E402
from nutribench.report.figure_parts import set_title  # noqa: E402
from nutribench.report.palette import BUILTIN_COLORS, USER_COLORS, Palette  # noqa: E402
from nutribench.report.palette import label as algo_label  # noqa: E402
from nutribench.stats import caption, contrast_ci, trimmed_se, welch_t  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
#: The five algorithms: paper agent file -> tuned agent file (the grid's, addendum 1).
ALGOS: tuple[str, ...] = ("mc", "ddqn", "ppo", "sac", "gru_ppo")
TUNED: dict[str, str] = {a: f"{a}_tuned" for a in ALGOS}
#: Addendum 2's exploratory arm: reported beside its algorithm, never used to answer a question.
EXPLORATORY: dict[str, str] = {"mc_tuned_set1": "mc"}
REGIMES: tuple[str, ...] = tuple(f"run{i}" for i in range(7))
DELAYED: tuple[str, ...] = REGIMES[1:]
HELD_OUT: tuple[str, ...] = ("run3", "run5", "run6")
TUNING: tuple[str, ...] = ("run0", "run1", "run2", "run4")
#: The rows of the protocols table: each regime, then the two groups.
GROUPS: dict[str, tuple[str, ...]] = {
    **{r: (r,) for r in REGIMES},
    "delayed (run1-run6)": DELAYED,
    "held-out (run3, run5, run6)": HELD_OUT,
}


class AnalysisError(UserError):
    """A bad path or nothing to analyse: printed as one line."""


# --------------------------------------------------------------------------- reading
def archives_in(folder: Path, option: str) -> list[Path]:
    if not folder.exists():
        raise AnalysisError(f"{option} {folder}: no such folder")
    if not folder.is_dir():
        raise AnalysisError(f"{option} {folder}: not a folder")
    return sorted(folder.glob("*.npz"))


def out_folder(out: Path) -> Path:
    """``--out``: made if not there yet (its parents too), refused as one line if a file is in the way."""
    if out.exists() and not out.is_dir():
        raise AnalysisError(f"--out {out}: not a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


def import_archives(paths: Sequence[Path], db: str) -> None:
    from nutribench.store.archive import import_results

    for path in paths:
        counts = import_results(path, db)
        print(f"imported {path} ({counts['imported']} jobs, {counts['kept']} already there)")


def read_db(db: str) -> tuple[pd.DataFrame, list[str], pd.DataFrame]:
    """The evaluation episodes a report draws (one job per run), the notes on what that left
    out, and the ``learning_curve`` rows."""
    from nutribench.report.data import check_names, prepare
    from nutribench.store import read_episode_metrics, read_learning_curve

    ev = read_episode_metrics(db, phase="eval")
    if ev.empty:
        raise AnalysisError(f"{db}: no evaluation days in the archives imported")
    check_names(ev["algo"].unique(), "agent config", db)
    check_names(ev["regime"].unique(), "regime", db)
    data = prepare(ev)
    return data.eval, data.notes, read_learning_curve(db)


def day_shares(ev: pd.DataFrame, refs: pd.DataFrame) -> pd.DataFrame:
    """``ev`` with each day's return replaced by its share of the gap on its run's yardstick
    (the mean never and planner returns over the run's own days, as ``run_scores`` takes
    them): a run's mean over its days is its score, and two agents' days pair as their
    returns do."""
    key = ["regime", "seed", "episode"]
    d = ev.merge(refs[key + ["never", "planner"]], on=key, how="inner", validate="many_to_one")
    run = ["regime", "algo", "seed"]
    never = d.groupby(run)["never"].transform("mean")
    planner = d.groupby(run)["planner"].transform("mean")
    return d.assign(**{"return": (d["return"] - never) / (planner - never)}).drop(columns=["never", "planner"])


# --------------------------------------------------------------------------- statistics
def covered(scores: pd.DataFrame, name: str, regimes: Sequence[str]) -> list[str]:
    """The regimes of ``regimes`` on which ``name`` has a finite score."""
    mine = scores[(scores["algo"] == name) & np.isfinite(scores["score"].to_numpy(dtype=float))]
    return [r for r in regimes if r in set(mine["regime"])]


def iqm_of(scores: pd.DataFrame, name: str, regimes: Sequence[str]) -> dict | None:
    """The IQM of ``name``'s run scores over ``regimes`` (those it has) and its 95 %
    interval over seeds (the trimmed t, stratified by regime); None where it has none of them."""
    have = covered(scores, name, regimes)
    if not have:
        return None
    iv = interval_estimates(score_set(scores, have, [name]))
    r = iv[iv["aggregate"] == "iqm"].iloc[0]
    return {
        "iqm": float(r["point"]),
        "lo": float(r["lo"]),
        "hi": float(r["hi"]),
        "runs": int(r["runs"]),
        "covered": have,
        "partial": len(have) < len(regimes),
    }


def seeds_in(scores: pd.DataFrame, names: Sequence[str], regimes: Sequence[str]) -> int:
    """The fewest seeds any of ``names`` has on any of ``regimes`` it was scored on."""
    counts = [
        int(np.isfinite(scores.loc[(scores.algo == n) & (scores.regime == r), "score"].to_numpy(dtype=float)).sum())
        for n in names
        for r in regimes
    ]
    return min([c for c in counts if c] or [0])


def runs_of(scores: pd.DataFrame, name: str, regimes: Sequence[str]) -> list[np.ndarray]:
    ss = score_set(scores, regimes, [name])
    return ss.runs[name]


def drop_runs(scores: pd.DataFrame, name: str) -> tuple[list[np.ndarray], list[float], list[str]] | None:
    """``name``'s runs on run0 and on each delayed regime it has, and the contrast's weights
    (run0's mean minus the mean over the delayed regimes of each regime's mean)."""
    have = covered(scores, name, REGIMES)
    delayed = [r for r in have if r in DELAYED]
    if "run0" not in have or not delayed:
        return None
    return runs_of(scores, name, ["run0", *delayed]), [1.0] + [-1.0 / len(delayed)] * len(delayed), delayed


def drop_under_delay(scores: pd.DataFrame, name: str) -> dict | None:
    """run0's mean share minus the mean over run1-run6 of each regime's mean share, with its
    95 % interval over seeds (``nutribench.stats.contrast_ci``: Welch's t over the regimes'
    means, addendum 3); the runs and weights kept for a contrast. None without run0 or without
    any delayed regime."""
    got = drop_runs(scores, name)
    if got is None:
        return None
    runs, weights, delayed = got
    point, lo, hi = contrast_ci(runs, weights)
    return {
        "point": point,
        "lo": lo,
        "hi": hi,
        "runs": runs,
        "weights": weights,
        "delayed": delayed,
        "seeds": min(map(len, runs)),
    }


def drop_difference(t: dict, p: dict) -> tuple[float, float, float]:
    """One drop minus another (``drop_under_delay``'s results), the two files' runs taken as
    independent samples: Welch's t over all their regimes' means."""
    return contrast_ci([*t["runs"], *p["runs"]], [*t["weights"], *(-w for w in p["weights"])])


def held_out_vs_tuning(scores: pd.DataFrame, name: str) -> dict | None:
    """The IQM over the held-out regimes minus the IQM over the tuning regimes, with a 95 %
    interval (``nutribench.stats.welch_t`` of the two trimmed-t standard errors, stratified by
    regime: the two sets of regimes are disjoint, so independent; addendum 3); both IQMs with
    their intervals."""
    held, tuning = iqm_of(scores, name, HELD_OUT), iqm_of(scores, name, TUNING)
    if held is None or tuning is None:
        return None
    parts = []
    for c in (held, tuning):
        runs = runs_of(scores, name, c["covered"])
        se, df = trimmed_se(np.concatenate(runs), [len(x) for x in runs])
        parts.append((point_estimate("iqm", runs), float(se), float(df)))
    (a, se_a, df_a), (b, se_b, df_b) = parts
    point, lo, hi = welch_t([a, b], [se_a, se_b], [df_a, df_b], [1.0, -1.0])
    return {"held": held, "tuning": tuning, "point": point, "lo": lo, "hi": hi}


def paired(ev: pd.DataFrame, shares: pd.DataFrame, a: str, b: str, regimes: Sequence[str]) -> dict | None:
    """``a`` against ``b`` paired by seed and day on those of ``regimes`` both played: the
    pooled row of ``compare_agents`` on the day shares (mean paired difference of the share of
    the gap) and on the returns (``nutribench compare``)."""
    both = [
        r
        for r in regimes
        if not ev[(ev.algo == a) & (ev.regime == r)].empty and not ev[(ev.algo == b) & (ev.regime == r)].empty
    ]
    if not both:
        return None
    out = {"regimes": both, "partial": len(both) < len(regimes), "notes": []}
    for what, frame in (("share", shares), ("return", ev)):
        res = compare_agents(frame, a, b, regimes=both)
        row = res.rows[res.rows["regime"] == ("all" if len(both) > 1 else both[0])].iloc[0]
        out[what] = row.to_dict()
        out["notes"] += [f"{a} - {b}: {n}" for n in res.notes if f"{a} - {b}: {n}" not in out["notes"]]
    return out


# --------------------------------------------------------------------------- formatting
def pct(v: float, signed: bool = False) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    return f"{100 * v:+.0f}" if signed else f"{100 * v:.0f}"


def interval_text(point: float, lo: float, hi: float, signed: bool = False, percent: bool = True) -> str:
    """``55 [47, 63]`` (shares, in %) or ``+1.75 [-0.44, +3.92]`` (returns, ``percent=False``)."""
    if not np.isfinite(point):
        return "n/a"
    if percent:
        p, a, b = pct(point, signed), pct(lo, signed), pct(hi, signed)
    else:
        p, a, b = (f"{v:+.2f}" if np.isfinite(v) else "n/a" for v in (point, lo, hi))
    return f"{p} [{a}, {b}]" if np.isfinite(lo) else f"{p} [single seed]"


def iqm_text(c: dict | None, group: Sequence[str] = ()) -> str:
    if c is None:
        return "not yet run"
    text = interval_text(c["iqm"], c["lo"], c["hi"])
    if c["partial"] and group:
        text += f" (on {', '.join(c['covered'])} only)"
    return text


def apart(a_lo: float, a_hi: float, b_lo: float, b_hi: float, seeds: int) -> str:
    """The plan's reading of two 95 % intervals, the first against the second."""
    if not all(np.isfinite(v) for v in (a_lo, a_hi, b_lo, b_hi)):
        return "no interval (one seed)"
    if a_lo > b_hi:
        return "higher (intervals apart)"
    if a_hi < b_lo:
        return "lower (intervals apart)"
    return f"overlap: not distinguishable with {seeds} seeds"


def zero_reading(lo: float, hi: float) -> str:
    """Question 2's rule: "below never" only where the interval's upper end is below 0,
    "not distinguishable from never" where it holds 0."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "no interval (one seed)"
    if hi < 0:
        return "below never"
    if lo > 0:
        return "above never"
    return "not distinguishable from never"


def paired_reading(lo: float, hi: float, seeds: int, a: str, b: str) -> str:
    """A paired difference A - B read against 0."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "no interval (one seed)"
    if lo > 0:
        return f"{a} ahead (interval above 0)"
    if hi < 0:
        return f"{b} ahead (interval below 0)"
    return f"holds 0: not distinguishable with {seeds} seeds"


def md_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> list[str]:
    return [
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(str(v) for v in r) + " |" for r in rows),
    ]


def needs(*names: str, held: set[str]) -> str:
    missing = [n for n in names if n not in held]
    return f"not yet run: needs {', '.join(missing)}"


# --------------------------------------------------------------------------- tables
def protocol_rows(scores: pd.DataFrame) -> pd.DataFrame:
    """Per algorithm (and the exploratory arm) and regime or group: paper and tuned IQM with
    intervals, and how the two intervals lie."""
    rows = []
    arms = [(a, TUNED[a], "pre-registered") for a in ALGOS]
    arms += [(base, name, "exploratory (addendum 2)") for name, base in EXPLORATORY.items()]
    for paper, tuned, role in arms:
        for group, regimes in GROUPS.items():
            p, t = iqm_of(scores, paper, regimes), iqm_of(scores, tuned, regimes)
            if p and t:
                reading = apart(t["lo"], t["hi"], p["lo"], p["hi"], seeds_in(scores, (paper, tuned), regimes))
            elif {paper, tuned} <= set(scores["algo"]):
                both = set(covered(scores, paper, regimes)) & set(covered(scores, tuned, regimes))
                reading = "not in the archives: " + ", ".join(r for r in regimes if r not in both)
            else:
                reading = needs(tuned, paper, held=set(scores["algo"]))
            rows.append(
                {
                    "algo": paper,
                    "tuned_agent": tuned,
                    "role": role,
                    "regime": group,
                    "regimes": ",".join(regimes),
                    **{f"paper_{k}": (p or {}).get(k, np.nan) for k in ("iqm", "lo", "hi", "runs")},
                    "paper_covered": ",".join((p or {}).get("covered", [])),
                    **{f"tuned_{k}": (t or {}).get(k, np.nan) for k in ("iqm", "lo", "hi", "runs")},
                    "tuned_covered": ",".join((t or {}).get("covered", [])),
                    "tuned_vs_paper": reading,
                }
            )
    return pd.DataFrame(rows)


def protocol_markdown(rows: pd.DataFrame) -> str:
    present = {
        name
        for side in ("paper", "tuned")
        for name in rows.loc[
            np.isfinite(rows[f"{side}_iqm"].to_numpy(dtype=float)), "algo" if side == "paper" else "tuned_agent"
        ]
    }

    def cell(r, side):
        if not np.isfinite(r[f"{side}_iqm"]):
            return "not in the archive" if r["algo" if side == "paper" else "tuned_agent"] in present else "not yet run"
        text = interval_text(r[f"{side}_iqm"], r[f"{side}_lo"], r[f"{side}_hi"])
        have, want = r[f"{side}_covered"].split(","), r["regimes"].split(",")
        return text + (f" (on {', '.join(have)} only)" if len(have) < len(want) else "")

    body = []
    for r in rows.to_dict("records"):
        agent = algo_label(r["algo"]) if r["role"] == "pre-registered" else f"{r['tuned_agent']} (exploratory)"
        body.append([agent, r["regime"], cell(r, "paper"), cell(r, "tuned"), r["tuned_vs_paper"]])
    lines = [
        "**Paper protocol against tuned protocol: share of the never -> planner gap (%) on the test days, IQM over "
        "seeds [95 % interval over seeds: " + caption("iqm") + "]** (0 = never eat, 100 = the full-information greedy "
        "planner; a run = one seed on one regime, scored on its own 5 test days; groups pool their regimes' runs). "
        "Paper: `reports/paper/data/` (the paper's agent files); tuned: `reports/tuned/data/<algo>_tuned.npz` "
        "(addendum 1). The last column reads the tuned interval against the paper one: a move only where they are "
        "apart. `mc_tuned_set1` is addendum 2's exploratory arm, against the paper's MC; it answers no question.",
        "",
        *md_table(["agent", "regime", "paper protocol", "tuned protocol", "tuned against paper"], body),
    ]
    return "\n".join(lines) + "\n"


def question_rows(ev: pd.DataFrame, shares: pd.DataFrame, scores: pd.DataFrame) -> list[dict]:
    """The plan's 38 named comparisons (and the exploratory arm's, marked), each a row:
    question, comparison, estimate, reading."""
    held = set(scores["algo"])
    rows: list[dict] = []

    def add(q, what, estimate, reading, pre=True, notes=()):
        rows.append(
            {
                "question": q,
                "comparison": what,
                "estimate": estimate,
                "reading": reading,
                "pre_registered": pre,
                "notes": "; ".join(notes),
            }
        )

    # 1: GRU-PPO against PPO, both tuned
    for name, regimes in (("delayed (run1-run6) pooled", DELAYED), ("held-out (run3, run5, run6)", HELD_OUT)):
        what = f"gru_ppo_tuned - ppo_tuned, {name}"
        res = (
            paired(ev, shares, "gru_ppo_tuned", "ppo_tuned", regimes)
            if {"gru_ppo_tuned", "ppo_tuned"} <= held
            else None
        )
        if res is None:
            add(1, what, needs("gru_ppo_tuned", "ppo_tuned", held=held), "")
            continue
        s, r = res["share"], res["return"]
        est = (
            f"share {interval_text(s['diff'], s['diff_lo'], s['diff_hi'], signed=True)} points; return "
            f"{interval_text(r['diff'], r['diff_lo'], r['diff_hi'], percent=False)} a day; P(A > B) {s['p_a_better']:.2f}"
        )
        if res["partial"]:
            est += f" (on {', '.join(res['regimes'])} only)"
        add(
            1,
            what,
            est,
            paired_reading(s["diff_lo"], s["diff_hi"], s["seeds"] // len(res["regimes"]), "GRU-PPO", "PPO"),
            notes=res["notes"],
        )

    # 2: below never eating, tuned PPO, DDQN, SAC per regime
    for algo in ("ppo", "ddqn", "sac"):
        name = TUNED[algo]
        for regime in REGIMES:
            what = f"{name}, {regime}: IQM share vs 0 (never)"
            if name not in held:
                add(2, what, needs(name, held=held), "")
                continue
            c = iqm_of(scores, name, [regime])
            if c is None:
                add(2, what, f"not in the archive: {name} has no {regime}", "")
                continue
            add(2, what, iqm_text(c) + " %", zero_reading(c["lo"], c["hi"]))

    # 3: drop under delay, paper against tuned
    arms = [(a, TUNED[a], True) for a in ALGOS] + [(b, n, False) for n, b in EXPLORATORY.items()]
    for paper, tuned, pre in arms:
        what = f"{algo_label(paper)}: drop under delay (run0 - mean of run1-run6), paper vs {tuned}"
        p, t = drop_under_delay(scores, paper), drop_under_delay(scores, tuned)
        if p is None or t is None:
            add(
                3,
                what,
                needs(paper, tuned, held=held) if not {paper, tuned} <= held else "needs run0 and a delayed regime",
                "",
                pre,
            )
            continue
        diff, lo, hi = drop_difference(t, p)
        est = (
            f"paper {interval_text(p['point'], p['lo'], p['hi'])}; tuned {interval_text(t['point'], t['lo'], t['hi'])}; "
            f"tuned - paper {interval_text(diff, lo, hi, signed=True)} points"
        )
        part = sorted(set(DELAYED) - set(t["delayed"]) | set(DELAYED) - set(p["delayed"]))
        if part:
            est += f" (delayed regimes lacking: {', '.join(part)})"
        seeds = min(p["seeds"], t["seeds"])
        reading = apart(t["lo"], t["hi"], p["lo"], p["hi"], seeds)
        if "apart" in reading:
            reading = "tuned drop " + reading.replace("higher", "larger").replace("lower", "smaller")
        add(3, what, est, reading, pre)

    # 4: transfer to the held-out regimes
    for paper, tuned, pre in arms:
        what = f"{tuned} - {paper}, held-out (run3, run5, run6), paired by seed and day"
        res = paired(ev, shares, tuned, paper, HELD_OUT) if {paper, tuned} <= held else None
        if res is None:
            add(
                4,
                what,
                needs(tuned, paper, held=held) if not {paper, tuned} <= held else "no held-out regime in both",
                "",
                pre,
            )
        else:
            s, r = res["share"], res["return"]
            est = (
                f"share {interval_text(s['diff'], s['diff_lo'], s['diff_hi'], signed=True)} points; return "
                f"{interval_text(r['diff'], r['diff_lo'], r['diff_hi'], percent=False)} a day; P(tuned > paper) {s['p_a_better']:.2f}"
            )
            if res["partial"]:
                est += f" (on {', '.join(res['regimes'])} only)"
            reading = paired_reading(s["diff_lo"], s["diff_hi"], s["seeds"] // len(res["regimes"]), "tuned", "paper")
            add(4, what, est, reading, pre, notes=res["notes"])
        what = f"{tuned}: held-out IQM (run3, run5, run6) vs tuning-regime IQM (run0, run1, run2, run4)"
        c = held_out_vs_tuning(scores, tuned) if tuned in held else None
        if c is None:
            add(
                4,
                what,
                needs(tuned, held=held) if tuned not in held else "needs a held-out and a tuning regime",
                "",
                pre,
            )
            continue
        h, g = c["held"], c["tuning"]
        est = (
            f"held-out {iqm_text(h, HELD_OUT)}; tuning {iqm_text(g, TUNING)}; "
            f"held-out - tuning {interval_text(c['point'], c['lo'], c['hi'], signed=True)} points"
        )
        seeds = min(h["runs"] // len(h["covered"]), g["runs"] // len(g["covered"]))
        reading = apart(h["lo"], h["hi"], g["lo"], g["hi"], seeds)
        add(4, what, est, ("held-out " + reading) if "apart" in reading else reading, pre)
    return rows


def questions_markdown(rows: list[dict], present: list[str], absent: list[str], notes: list[str]) -> str:
    pre = [r for r in rows if r["pre_registered"]]
    done = [
        r for r in pre if not r["estimate"].startswith(("not yet run", "not in the archive", "needs", "no held-out"))
    ]
    titles = {
        1: "1. GRU-PPO against PPO, both tuned (paired by seed and test day; A - B)",
        2: "2. Below never eating: tuned PPO, DDQN, SAC per regime (IQM share of the gap, %)",
        3: "3. Sensitivity to delay: drop = run0 share - mean share over run1-run6 (percentage points)",
        4: "4. Transfer to the held-out regimes",
    }
    lines = [
        "# The pre-registered questions (README.md), from the archives present",
        "",
        f"Tuned archives present: {', '.join(present) or 'none'}; absent: {', '.join(absent) or 'none'}. "
        f"{len(done)} of the plan's {len(pre)} named comparisons computed.",
        "",
        "Every interval is 95 %, over seeds (Student's t kinds, standard errors within each regime: the IQM's the "
        f"{caption('iqm')}; paired rows' the {caption('paired')}; drops and contrasts Welch's t, whose coverage was "
        "not simulated); they are read as intervals, not tests "
        "(no multiplicity correction: about two of 38 may miss by chance). A move needs intervals apart; overlapping "
        'ones are not distinguishable with the seeds there are, never "no effect". Shares are of the never -> '
        "planner gap on the test days (0 = never eat, 100 % = the planner). Paired rows: the mean paired difference "
        "of the share of the gap (each day on its seed's yardstick) and of the return a day (`nutribench compare`), "
        "P(A > B) over paired days, ties half.",
    ]
    if notes:
        lines += ["", *(f"note: {n}" for n in notes)]
    for q, title in titles.items():
        mine = [r for r in rows if r["question"] == q]
        lines += ["", f"## {title}", ""]
        lines += md_table(
            ["comparison", "estimate [95 % CI]", "reading"],
            [
                [
                    r["comparison"] + ("" if r["pre_registered"] else " **(exploratory, answers no question)**"),
                    r["estimate"],
                    r["reading"] or "-",
                ]
                for r in mine
            ],
        )
        found = list(dict.fromkeys(n for r in mine for n in r["notes"].split("; ") if n))
        if found:
            lines += ["", *(f"note: {n}" for n in found)]
        if q == 2:
            lines += [
                "",
                '"below never" only where the interval\'s upper end is below 0; "not distinguishable from never" where it holds 0.',
            ]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- figures
def protocol_figure(rows: pd.DataFrame, absent: list[str]) -> Figure:
    """One panel per algorithm: per regime and group, the paper protocol's IQM and the tuned
    protocol's side by side with their intervals, 0 (never) and 100 % (planner) drawn."""
    fig = Figure(figsize=(17, 9.5), layout="constrained")
    axes = fig.subplots(2, 3, squeeze=False).flat
    groups = list(GROUPS)
    ticks = [*REGIMES, "delayed\n1-6", "held-out\n3,5,6"]
    x0 = np.arange(len(groups))
    for ax, algo in zip(axes, ALGOS):
        sel = rows[rows["algo"] == algo]
        arms = [("paper", algo, "paper protocol", "o", "white", -0.22)]
        arms += [("tuned", n, f"tuned ({n})", "s", None, 0.0) for n in sel["tuned_agent"].unique() if n == TUNED[algo]]
        arms += [
            ("tuned", n, f"{n} (exploratory)", "D", None, 0.22) for n in sel["tuned_agent"].unique() if n in EXPLORATORY
        ]
        color = BUILTIN_COLORS.get(algo, "C0")
        for side, name, lab, marker, face, dx in arms:
            sub = sel[sel["tuned_agent"] == name] if side == "tuned" else sel[sel["tuned_agent"] == TUNED[algo]]
            sub = sub.set_index("regime").reindex(groups)
            y = 100 * sub[f"{side}_iqm"].to_numpy(dtype=float)
            if not np.isfinite(y).any():
                continue
            lo = 100 * sub[f"{side}_lo"].to_numpy(dtype=float)
            hi = 100 * sub[f"{side}_hi"].to_numpy(dtype=float)
            err = np.vstack([np.where(np.isfinite(lo), y - lo, 0), np.where(np.isfinite(hi), hi - y, 0)])
            c = USER_COLORS[0] if name in EXPLORATORY else color
            ax.errorbar(
                x0 + dx, y, yerr=err, fmt=marker, ms=6, capsize=3, color=c, mfc=face or c, mec=c, lw=1.2, label=lab
            )
        missing = [n for n in (TUNED[algo], *(n for n, b in EXPLORATORY.items() if b == algo)) if n in absent]
        ax.axhline(0, color="k", lw=0.9, ls=":", zorder=0)
        ax.axhline(100, color="k", lw=0.9, ls="--", zorder=0)
        ax.axvline(len(REGIMES) - 0.5, color="0.6", lw=0.8)
        ax.set_xticks(x0, ticks, fontsize=8)
        title = algo_label(algo) + (f"  (not yet run: {', '.join(missing)})" if missing else "")
        ax.set_title(title, fontsize=11, color="k" if not missing else "0.3")
        ax.set_ylabel("share of the never -> planner gap (%)\nIQM over seeds, 95 % trimmed-t interval", fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    last = list(fig.axes)[-1]
    last.axis("off")
    handles = [
        Line2D([], [], marker="o", ls="", color="0.3", mfc="white", label="paper protocol (reports/paper/data)"),
        Line2D([], [], marker="s", ls="", color="0.3", label="tuned protocol (<algo>_tuned)"),
        Line2D([], [], marker="D", ls="", color=USER_COLORS[0], label="mc_tuned_set1 (exploratory, addendum 2)"),
        Line2D([], [], color="k", ls=":", label="never eat (0 %)"),
        Line2D([], [], color="k", ls="--", label="full-information planner (100 %)"),
    ]
    last.legend(handles=handles, loc="upper left", fontsize=10, frameon=False)
    last.text(
        0.0,
        0.45,
        "Bars: 95 % trimmed-t interval over seeds. Tuned: one setting\n"
        "per algorithm, tuned on run0, run1, run2, run4 (README).\n"
        "Right of the grey line: the delayed regimes (run1-run6)\n"
        "pooled, and the held-out ones (run3, run5, run6) pooled.\n\n"
        "Tuned archives absent: " + (", ".join(absent) or "none"),
        va="top",
        fontsize=10,
        transform=last.transAxes,
    )
    fig.suptitle(
        "Paper protocol against tuned protocol: share of the never -> planner gap on the test days, per regime",
        fontsize=12,
    )
    return fig


def learning_figure(curve: pd.DataFrame, names: Sequence[str]):
    """The tuned grid's learning curves (``nutribench report --fig learning``'s figure) in the
    algorithms' colours; None without validation days."""
    from nutribench.report.learning import learning_curve_figure

    curve = curve[curve["algo"].isin(list(names))]
    if curve.empty:
        return None
    colors = {n: BUILTIN_COLORS[TUNED_BASE[n]] for n in names if n in TUNED_BASE}
    colors.update({n: USER_COLORS[0] for n in names if n in EXPLORATORY})
    res = learning_curve_figure(curve, Palette(colors), list(names))
    caption = getattr(res.figure, "_report_title", "").partition("\n")[2]
    set_title(res.figure, "The tuned grid: learning curves from the evaluations during training\n" + caption)
    return res.figure


TUNED_BASE = {v: k for k, v in TUNED.items()}


# --------------------------------------------------------------------------- main
def analyse(db: str, out: Path, expected_absent: list[str], present: list[str]) -> list[Path]:
    from nutribench.report.references import eval_day_references

    ev, notes, curve = read_db(db)
    refs = eval_day_references(ev, log=print)
    scores = run_scores(ev, refs)
    shares = day_shares(ev, refs)
    written = []

    rows = protocol_rows(scores)
    rows.to_csv(out / "table_protocols.csv", index=False, float_format="%.4f")
    (out / "table_protocols.md").write_text(protocol_markdown(rows))
    written += [out / "table_protocols.csv", out / "table_protocols.md"]

    qrows = question_rows(ev, shares, scores)
    pd.DataFrame(qrows).to_csv(out / "table_questions.csv", index=False)
    (out / "table_questions.md").write_text(questions_markdown(qrows, present, expected_absent, notes))
    written += [out / "table_questions.csv", out / "table_questions.md"]

    fig = protocol_figure(rows, expected_absent)
    fig.savefig(out / "fig_protocols.png", dpi=110)
    written.append(out / "fig_protocols.png")

    tuned_names = [n for n in (*TUNED.values(), *EXPLORATORY) if n in set(curve["algo"])]
    lc = learning_figure(curve, tuned_names)
    if lc is None:
        print("fig_learning_curves.png not drawn: no validation days of a tuned agent (run with --eval-every)")
    else:
        lc.savefig(out / "fig_learning_curves.png", dpi=110)
        written.append(out / "fig_learning_curves.png")
    return written


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--archives-dir", default=str(HERE / "data"), help="the tuned grid's archives (<agent>.npz)")
    ap.add_argument(
        "--paper-dir", default=str(ROOT / "reports" / "paper" / "data"), help="the paper protocol's archives"
    )
    ap.add_argument("--out", default=str(HERE), help="where the tables and figures go")
    ap.add_argument("--db", default=None, help="import into this database and keep it (default: a temporary one)")
    a = ap.parse_args(argv)
    try:
        tuned = archives_in(Path(a.archives_dir), "--archives-dir")
        paper = archives_in(Path(a.paper_dir), "--paper-dir")
        if not paper:
            raise AnalysisError(f"--paper-dir {a.paper_dir}: no archives (*.npz) there: the paper protocol is needed")
        out = out_folder(Path(a.out))
        expected = [*TUNED.values(), *EXPLORATORY]
        present = [n for n in expected if (Path(a.archives_dir) / f"{n}.npz").is_file()]
        absent = [n for n in expected if n not in present]
        other = [p.name for p in tuned if p.stem not in expected]
        print(f"tuned archives present: {', '.join(present) or 'none'}; absent: {', '.join(absent) or 'none'}")
        if other:
            print(f"other archives in {a.archives_dir}, imported too: {', '.join(other)}")
        with tempfile.TemporaryDirectory(prefix="nutribench-tuned-") as tmp:
            db = a.db or str(Path(tmp) / "tuned.db")
            import_archives([*paper, *tuned], db)
            written = analyse(db, out, absent, present)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for p in written:
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
