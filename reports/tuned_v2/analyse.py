"""Protocol v2's pre-registered comparisons (README.md, "Pre-registered comparisons"), for the
v2 archives present: the paper protocol's archives (``reports/paper/data/``), v1's tuned grid's
(``reports/tuned/data/<agent>_tuned.npz``) and v2's (``data/<agent>_tuned_v2.npz``) in one
database, then ``results.md`` / ``results.csv``:

* per agent and regime, and over the delayed tuning regimes (run2, run4, run5) and the held-out
  ones (run1, run3, run6): the IQM over seeds of the share of the never -> planner gap with its
  95 % trimmed-t interval (stratified by regime), paper file, v1 file and v2 file side by side;
* G1 (v2 GRU-PPO - v2 PPO), G2 (v2 - paper), G3 (v2 - v1): mean paired differences of the
  share of the gap (by seed and test day) with 95 % t intervals over seeds;
* G4: each v2 file, per regime, "below never" only where the IQM's interval lies below 0;
* G5 (transfer): the mean share over the delayed tuning regimes minus the mean share over the
  held-out regimes, for the v2 file and for the paper file, each with its interval;
* part 3 (``data/part3_<agent>.npz``, run5 and run6 x seeds 3900-3909, read in a database of
  their own, since arm A's and arm D's names are also the grid's and the paper's): each arm's
  IQM per regime, and M1 (B - C), M2 (B - A), M3 (B - D) per regime, paired over the seeds.

Each comparison is computed where its archives are present and said "not yet run" otherwise.
The statistics are the project's own, through ``reports/tuned/analyse.py``'s helpers (the same
code as v1's analysis): ``run_scores``, rliable's IQM with the trimmed t,
``compare_agents`` on each day's share of the gap.

    python reports/tuned_v2/analyse.py [--db KEEP.db] [--out reports/tuned_v2]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from nutribench.stats import contrast_ci

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
_spec = importlib.util.spec_from_file_location("tuned_v1_analyse", ROOT / "reports" / "tuned" / "analyse.py")
v1 = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(v1)

ALGOS = ("mc", "ddqn", "ppo", "sac", "gru_ppo")
REGIMES = tuple(f"run{i}" for i in range(7))
TUNING_DELAYED = ("run2", "run4", "run5")  # the tuning regimes with a delay (run0 has none)
HELD_OUT = ("run1", "run3", "run6")
#: part 3's arms (README.md, "Memory or settings?") and its comparisons, B minus each other arm
ARMS = {
    "A": "ppo_tuned_v2",
    "B": "gru_ppo_tuned_v2",
    "C": "gru_ppo_tuned_v2_nomem",
    "D": "gru_ppo",
}
PART3_REGIMES = ("run5", "run6")
MS = {
    "M1": ("B", "C", "memory at the v2 GRU-PPO's settings"),
    "M2": ("B", "A", "v2 GRU-PPO against v2 PPO"),
    "M3": ("B", "D", "v2 GRU-PPO against the paper's GRU-PPO"),
}
GROUPS = {
    "delayed tuning (run2, run4, run5)": TUNING_DELAYED,
    "held out (run1, run3, run6)": HELD_OUT,
    "delayed (run1-run6, README.md's column)": REGIMES[1:],
}


def names(algo: str) -> dict[str, str]:
    return {"paper": algo, "v1": f"{algo}_tuned", "v2": f"{algo}_tuned_v2"}


def transfer(scores: pd.DataFrame, name: str) -> dict | None:
    """G5: mean share over the delayed tuning regimes minus the mean over the held-out ones
    (each regime's mean over seeds), with its 95 % interval (Welch's t over the regimes' means)."""
    tuning, held = v1.covered(scores, name, TUNING_DELAYED), v1.covered(scores, name, HELD_OUT)
    if not tuning or not held:
        return None
    # each set read apart: score_set sorts the regimes it is given (run1 before run2), so one
    # call over both sets would interleave tuning and held-out regimes
    first = v1.runs_of(scores, name, tuning)
    runs = [*first, *v1.runs_of(scores, name, held)]
    return {**drop_interval(runs, len(first)), "partial": len(runs) < 6}


def drop_interval(runs: list[np.ndarray], k: int) -> dict:
    """The mean over the first ``k`` regimes' runs minus the mean over the rest (each regime's
    mean over seeds), with its 95 % interval: Welch's t over the regimes' means
    (``nutribench.stats.contrast_ci``; since the fourth addendum, in place of a percentile
    bootstrap)."""
    weights = [1.0 / k] * k + [-1.0 / (len(runs) - k)] * (len(runs) - k)
    point, lo, hi = contrast_ci(runs, weights)
    return {"point": point, "lo": lo, "hi": hi, "seeds": min(map(len, runs))}


def transfer_difference(scores: pd.DataFrame, a: str, b: str) -> dict | None:
    """G5 of ``a`` minus G5 of ``b`` (the v2 file's drop minus its paper file's), paired by seed:
    each run of ``a`` is taken with the run of ``b`` on the same regime and seed (the two grids
    share the paper's seeds and test days) and the pairs are redrawn together within each
    regime. None unless both files have the same seeds on every tuning and held-out regime."""
    regimes = [*TUNING_DELAYED, *HELD_OUT]
    if set(v1.covered(scores, a, regimes)) != set(regimes) or set(v1.covered(scores, b, regimes)) != set(regimes):
        return None
    runs = []
    for r in regimes:  # in the order given (tuning first), one regime at a time
        pair = scores[(scores["regime"] == r) & scores["algo"].isin([a, b])].pivot(
            index="seed", columns="algo", values="score"
        )
        if pair.isna().to_numpy().any():
            return None  # a seed one file played and the other did not
        runs.append((pair[a] - pair[b]).to_numpy(dtype=float))
    return drop_interval(runs, len(TUNING_DELAYED))


def drop_reading(lo: float, hi: float) -> str:
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "no interval (one seed)"
    if lo > 0:
        return "lower on the held-out regimes (interval above 0)"
    if hi < 0:
        return "higher on the held-out regimes (interval below 0)"
    return "holds 0: not distinguishable"


def difference_reading(lo: float, hi: float) -> str:
    if lo > 0:
        return "the v2 file drops more than its paper file (interval above 0)"
    if hi < 0:
        return "the v2 file drops less than its paper file (interval below 0)"
    return "holds 0: not distinguishable"


def paired_cells(ev, shares, held: set, rows: list[dict], q: str, a: str, b: str, regs: Sequence[str], label: str):
    """One comparison's table row (and its results.csv row): ``a - b`` paired over seeds and days."""
    if a not in held or b not in held:
        return [q, label, v1.needs(a, b, held=held), ""]
    p = v1.paired(ev, shares, a, b, regs)
    if p is None:
        return [q, label, "no regime both played", ""]
    s = p["share"]
    seeds = int(s["seeds"]) // len(p["regimes"])
    rows.append({"what": q, "agent": a, "protocol": b, "regimes": ",".join(p["regimes"]), **s})
    text = v1.interval_text(s["diff"], s["diff_lo"], s["diff_hi"], signed=True)
    return [q, label, f"{text} ({seeds} seeds)", v1.paired_reading(s["diff_lo"], s["diff_hi"], seeds, a, b)]


def read_scores(db: str):
    """The eval rows of ``db`` with their per-run scores and per-day shares of the gap."""
    from nutribench.report.references import eval_day_references

    ev, notes, _ = v1.read_db(db)
    refs = eval_day_references(ev, log=print)
    return ev, notes, v1.run_scores(ev, refs), v1.day_shares(ev, refs)


def part3(db: str | None, rows: list[dict]) -> list[str]:
    """Part 3's section of results.md: the arms' IQMs per regime and M1-M3 (``db`` None: not yet run)."""
    lines = ["## Part 3: memory or settings? (run5, run6; seeds 3900-3909; 5000 days)", ""]
    if db is None:
        return [*lines, "Not yet run: no `data/part3_*.npz`.", ""]
    ev, _, scores, shares = read_scores(db)
    held = set(ev["algo"])
    lines += [f"Arms present: {', '.join(f'{k} {n}' for k, n in ARMS.items() if n in held) or 'none'}.", ""]
    table = []
    for key, name in ARMS.items():
        for r in PART3_REGIMES:
            c = v1.iqm_of(scores, name, (r,)) if name in held else None
            if c is not None:
                rows.append({"what": "part3 iqm", "agent": name, "protocol": key, "regimes": r, **c})
                table.append([f"{key} {name}", r, v1.iqm_text(c), v1.zero_reading(c["lo"], c["hi"])])
            else:
                table.append([f"{key} {name}", r, "not yet run", ""])
    lines += v1.md_table(["arm", "regime", "IQM", "against never"], table) + [""]
    comp = []
    for q, (a, b, what) in MS.items():
        for r in PART3_REGIMES:
            comp.append(paired_cells(ev, shares, held, rows, q, ARMS[a], ARMS[b], (r,), f"{a} - {b} ({what}), {r}"))
    return lines + v1.md_table(["", "comparison", "difference (points of the gap)", "reading"], comp) + [""]


def per_run(ev: pd.DataFrame, scores: pd.DataFrame, agents: Sequence[str]) -> list[str]:
    """Each v2 file's runs one by one, behind the IQMs: the share of the gap (%) and the foods
    eaten per test day, means over the run's test days, a row per regime and a column per seed;
    and how many delayed runs never ate on any test day (share exactly 0)."""
    lines = ["## Per run (v2 files): share of the gap in % (foods per test day)", ""]
    for name in agents:
        sc = scores[scores["algo"] == name].set_index(["regime", "seed"])["score"]
        foods = ev[ev["algo"] == name].groupby(["regime", "seed"])["foods"]
        eaten, most = foods.mean(), foods.max()
        seeds = sorted(sc.index.get_level_values("seed").unique())
        table = [
            [r, *(f"{100 * sc[r, s]:.0f} ({eaten[r, s]:.1f})" if (r, s) in sc.index else "" for s in seeds)]
            for r in REGIMES
        ]
        never = sum(most[r, s] == 0 for r, s in sc.index if r != REGIMES[0])
        delayed = sum(r != REGIMES[0] for r, _ in sc.index)
        lines += [f"**{name}**: {never} of {delayed} delayed runs ate nothing on every test day.", ""]
        lines += v1.md_table(["regime", *(f"seed {s}" for s in seeds)], table) + [""]
    return lines


def analyse(db: str, out: Path, db3: str | None = None) -> list[Path]:
    from nutribench.stats import caption as interval_caption

    ev, notes, scores, shares = read_scores(db)
    held = set(ev["algo"])
    lines = ["# Protocol v2: results of the pre-registered comparisons", ""]
    lines += [
        "Written by `python reports/tuned_v2/analyse.py`; shares of the never -> planner gap in %, "
        f"IQM over seeds [95 % {interval_caption('iqm')}; its standard error within regimes]; comparisons "
        f"are mean paired differences (by seed and test day) [95 % interval over seeds: {interval_caption('paired')}]; "
        "G5's drops: Welch's t over the regimes' means (nutribench.stats.contrast_ci; its coverage not simulated). "
        'Read by the plan\'s rules: an interval that holds 0 is "not distinguishable with N seeds", never "equal".',
        "",
        f"v2 files present: {', '.join(n for a in ALGOS if (n := names(a)['v2']) in held) or 'none'}; "
        f"absent: {', '.join(n for a in ALGOS if (n := names(a)['v2']) not in held) or 'none'}.",
        "",
    ]
    rows: list[dict] = []

    lines += ["## Scores per regime and group", ""]
    table = []
    for algo in ALGOS:
        for where, regs in [*((r, (r,)) for r in REGIMES), *GROUPS.items()]:
            cells = {}
            for proto, name in names(algo).items():
                c = v1.iqm_of(scores, name, regs) if name in held else None
                cells[proto] = v1.iqm_text(c, regs if len(regs) > 1 else ())
                if c is not None:
                    rows.append({"what": "iqm", "agent": name, "protocol": proto, "regimes": where, **c})
            table.append([algo, where, cells["paper"], cells["v1"], cells["v2"]])
    lines += v1.md_table(["agent", "regimes", "paper file", "v1 tuned", "v2 tuned"], table) + [""]

    def paired_row(q: str, a: str, b: str, regs: Sequence[str], label: str) -> list[str]:
        return paired_cells(ev, shares, held, rows, q, a, b, regs, label)

    lines += ["## G1-G3: paired comparisons", ""]
    comp = []
    g1 = ("gru_ppo_tuned_v2", "ppo_tuned_v2")
    for regs, label in [
        *(((r,), r) for r in REGIMES),
        (HELD_OUT, "held out, pooled"),
        (TUNING_DELAYED, "delayed tuning, pooled"),
    ]:
        comp.append(paired_row("G1", *g1, regs, f"v2 GRU-PPO - v2 PPO, {label}"))
    for algo in ALGOS:
        n = names(algo)
        comp.append(paired_row("G2", n["v2"], n["paper"], HELD_OUT, f"{algo}: v2 - paper, held out pooled"))
        for r in REGIMES:
            comp.append(paired_row("G2", n["v2"], n["paper"], (r,), f"{algo}: v2 - paper, {r}"))
        comp.append(paired_row("G3", n["v2"], n["v1"], HELD_OUT, f"{algo}: v2 - v1, held out pooled"))
    lines += v1.md_table(["", "comparison", "difference (points of the gap)", "reading"], comp) + [""]

    lines += ["## G4: below never (v2 files)", ""]
    below = []
    for algo in ALGOS:
        name = names(algo)["v2"]
        if name not in held:
            continue
        for r in REGIMES:
            c = v1.iqm_of(scores, name, (r,))
            if c is not None:
                below.append([name, r, v1.iqm_text(c), v1.zero_reading(c["lo"], c["hi"])])
    lines += v1.md_table(["agent", "regime", "IQM", "reading"], below) + [""]
    lines += per_run(ev, scores, [names(a)["v2"] for a in ALGOS if names(a)["v2"] in held])

    lines += ["## G5: transfer (delayed tuning regimes minus held-out regimes, mean share)", ""]
    tr = []
    for algo in ALGOS:
        if names(algo)["v2"] not in held:
            continue
        for proto in ("v2", "paper"):
            t = transfer(scores, names(algo)[proto]) if names(algo)[proto] in held else None
            if t is None:
                tr.append([algo, proto, "n/a", ""])
                continue
            rows.append(
                {
                    "what": "G5",
                    "agent": names(algo)[proto],
                    "protocol": proto,
                    **{k: t[k] for k in ("point", "lo", "hi", "seeds")},
                }
            )
            text = f"{v1.interval_text(t['point'], t['lo'], t['hi'], signed=True)} ({t['seeds']} seeds)"
            tr.append([algo, proto, text, drop_reading(t["lo"], t["hi"])])
        d = (
            transfer_difference(scores, names(algo)["v2"], names(algo)["paper"])
            if names(algo)["paper"] in held
            else None
        )
        if d is not None:
            rows.append({"what": "G5 v2 - paper", "agent": names(algo)["v2"], "protocol": "paper", **d})
            text = f"{v1.interval_text(d['point'], d['lo'], d['hi'], signed=True)} ({d['seeds']} seeds)"
            tr.append([algo, "v2 - paper", text, difference_reading(d["lo"], d["hi"])])
    lines += v1.md_table(["agent", "file", "drop from tuning to held-out regimes", "reading"], tr)
    lines += [
        "",
        "(G5 is read against the same agent's paper-file drop, not against 0: the row `v2 - paper` is the"
        " v2 file's drop minus the paper file's, paired by seed on the same regimes and test days.)",
        "",
    ]
    lines += part3(db3, rows)
    if notes:
        lines += ["## Notes from the data", "", *(f"- {n}" for n in notes), ""]
    (out / "results.md").write_text("\n".join(lines))
    pd.DataFrame(rows).to_csv(out / "results.csv", index=False, float_format="%.4f")
    return [out / "results.md", out / "results.csv"]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--db", default=None, help="import into this database and keep it (default: a temporary one)")
    ap.add_argument("--out", default=str(HERE), help="where results.md and results.csv go")
    a = ap.parse_args(argv)
    paper = sorted((ROOT / "reports" / "paper" / "data").glob("*.npz"))
    tuned_v1 = [ROOT / "reports" / "tuned" / "data" / f"{x}_tuned.npz" for x in ALGOS]
    tuned_v2 = [HERE / "data" / f"{x}_tuned_v2.npz" for x in ALGOS]  # the grid's (not part 3's: part3_*)
    try:
        out = v1.out_folder(Path(a.out))  # made before minutes of imports, as v1's analysis makes it
        with tempfile.TemporaryDirectory(prefix="nutribench-tuned-v2-") as tmp:
            db = a.db or str(Path(tmp) / "v2.db")
            have = set()
            if Path(db).exists():
                from nutribench.store import read_episode_metrics

                have = set(read_episode_metrics(db, phase="eval")["algo"].unique())
            todo = [p for p in [*paper, *tuned_v1, *tuned_v2] if p.is_file() and p.stem not in have]
            todo = [p for p in todo if not (p.stem.startswith("sac-") and "sac" in have)]
            v1.import_archives(todo, db)
            arms = sorted(HERE.glob("data/part3_*.npz"))
            db3 = str(Path(tmp) / "part3.db") if arms else None  # always afresh: four archives
            if arms:
                v1.import_archives(arms, db3)
            written = analyse(db, out, db3)
    except v1.UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for p in written:
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
