"""Paired comparison of two agent configs on the days they were both evaluated on
(``nutribench compare A B``).

Every agent of a seed plays the same evaluation days on a regime (episode ``k`` of seed
``s`` is the same food stream for every agent, :func:`nutribench.agents.eval_food_streams`),
so two agents' returns pair by (regime, seed, episode). Per regime and over groups of
regimes (``all`` compared regimes; the ``delayed`` ones, run1-run6, when run0 is among them):

* the mean paired difference ``A - B`` of the returns over the paired days, with a 95 %
  interval over **seeds** (:func:`nutribench.stats.paired_ci`, the method the coverage
  simulation chose): a seed's paired days count as one value, their mean (the days of one seed
  share one trained agent each, so they are not independent); over several regimes the
  interval is stratified by regime and the days of all regimes pooled;
* P(A > B): the share of paired days on which A's return is higher (a tie counts half),
  with an interval from the same resamples;
* how many seeds and days were paired.

DataFrame in, :class:`Comparison` out (:func:`compare_agents`; :func:`paired_days` is the
pairing alone); :func:`load_comparison` reads a results database, each side one entry (an
agent config's name, version and training budget, as the leaderboard's rows: ``ppo@v1@5000``;
by default the largest budget, then the newest version, and a note lists the others). Errors
a user can fix raise :class:`CompareError` (one line).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from nutribench.errors import UserError
from nutribench.report.aggregate import DELAYED_REGIMES, regime_span
from nutribench.report.figure_parts import UNRECORDED, budget_cell, budget_seeds_text, seed_list, sort_regimes
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos
from nutribench.report.tables import interval_cell, markdown_rows
from nutribench.stats import CHOSEN, CONFIDENCE, paired_ci
from nutribench.stats import caption as interval_caption

#: Bootstrap resamples of the seeds.
COMPARE_REPS = 10_000
COMPARE_COLUMNS = ["regime", "regimes", "seeds", "days", "a_mean", "b_mean", "diff", "diff_lo", "diff_hi"]
COMPARE_COLUMNS += ["p_a_better", "p_lo", "p_hi"]


class CompareError(UserError, ValueError):
    """Two agents that cannot be compared as asked; printed as one line."""


def paired_days(ev: pd.DataFrame, a: str, b: str, regimes: Sequence[str] | None = None) -> pd.DataFrame:
    """The evaluation days both ``a`` and ``b`` played: one row per (regime, seed, episode)
    with each one's return (columns regime, seed, episode, a, b), in that order. Rows pair by
    key, never by position; ``ev`` must hold one row per (regime, algo, seed, episode)."""
    ev = ev[ev["phase"] == "eval"] if "phase" in ev else ev
    if regimes is not None:
        ev = ev[ev["regime"].isin(list(regimes))]
    key = ["regime", "seed", "episode"]
    sides = []
    for name, col in ((a, "a"), (b, "b")):
        rows = ev[ev["algo"] == name]
        dup = rows.duplicated(key)
        if dup.any():
            r = rows[dup].iloc[0]
            raise ValueError(
                f"{name}: several rows for {r['regime']} seed {r['seed']} day {r['episode']}: pick one job per run first (report.build.prepare)"
            )
        sides.append(rows[key + ["return"]].rename(columns={"return": col}))
    out = sides[0].merge(sides[1], on=key, how="inner", validate="one_to_one")
    rank = {r: i for i, r in enumerate(sort_regimes(out["regime"]))}
    out = out.assign(_rank=out["regime"].map(rank)).sort_values(["_rank", "seed", "episode"])
    return out.drop(columns="_rank").reset_index(drop=True)


def _per_seed(days: pd.DataFrame) -> pd.DataFrame:
    """Per seed of one regime's paired days: the number of days, the sum of A - B, of A, of B
    and of the wins (1 when A is higher, 1/2 on a tie)."""
    d = days.assign(diff=days["a"] - days["b"], win=(days["a"] > days["b"]) + 0.5 * (days["a"] == days["b"]))
    return d.groupby("seed").agg(
        n=("diff", "size"), diff=("diff", "sum"), a=("a", "sum"), b=("b", "sum"), win=("win", "sum")
    )


def _summary(name: str, regimes: list[str], days: pd.DataFrame, reps: int, confidence: float) -> dict:
    """One row of the comparison: ``days`` (the paired days of ``regimes``) summarised, with
    intervals over seeds stratified by regime (:func:`paired_ci`)."""
    per = {r: _per_seed(days[days["regime"] == r]) for r in regimes}
    n = sum(p["n"].sum() for p in per.values())
    row = {
        "regime": name,
        "regimes": ",".join(regimes),
        "seeds": int(sum(len(p) for p in per.values())),
        "days": int(n),
        "a_mean": float(days["a"].mean()),
        "b_mean": float(days["b"].mean()),
        "diff": float((days["a"] - days["b"]).mean()),
        "p_a_better": float(sum(p["win"].sum() for p in per.values()) / n),
    }
    if max(len(p) for p in per.values()) < 2:  # one seed everywhere: nothing to resample
        return {**row, "diff_lo": float("nan"), "diff_hi": float("nan"), "p_lo": float("nan"), "p_hi": float("nan")}
    sizes = [p["n"].to_numpy(dtype=float) for p in per.values()]
    row["diff_lo"], row["diff_hi"] = paired_ci(
        [p["diff"].to_numpy() for p in per.values()], sizes, reps, None, confidence
    )
    lo, hi = paired_ci([p["win"].to_numpy() for p in per.values()], sizes, reps, None, confidence)
    row["p_lo"], row["p_hi"] = max(lo, 0.0), min(hi, 1.0)
    return row


@dataclass
class Comparison:
    """``a`` against ``b``: one row per regime, then the aggregated rows (``rows``, columns
    :data:`COMPARE_COLUMNS`; ``regime`` is ``all`` or ``delayed`` for those), the paired days, and
    notes (what could not be paired, what was left out of the database's rows)."""

    a: str
    b: str
    rows: pd.DataFrame
    days: pd.DataFrame
    reps: int
    notes: list[str] = field(default_factory=list)
    #: the training budgets and seeds of each agent's rows, for the header
    provenance: str = ""

    def title(self) -> str:
        la, lb = algo_label(self.a), algo_label(self.b)
        # how the intervals were made
        method = interval_caption("paired") + ("" if CHOSEN["paired"] == "t" else f", {self.reps} resamples")
        return (
            f"{la} - {lb}: mean paired difference of evaluation returns (same seed, same day), 95 % interval over "
            f"seeds ({method}; a seed's days kept together); P({la} > {lb}) over paired days (ties count half)"
        )

    def formatted(self) -> pd.DataFrame:
        """The rows as text: regime, seeds, days, means, difference [interval], P(A > B) [interval]."""
        la, lb = algo_label(self.a), algo_label(self.b)
        out = []
        for r in self.rows.itertuples(index=False):
            name = f"{r.regime} ({regime_span(r.regimes.split(','))})" if r.regime in ("all", "delayed") else r.regime
            pci = f" [{r.p_lo:.2f}, {r.p_hi:.2f}]" if np.isfinite(r.p_lo) else ""
            diff = interval_cell(r.diff, r.diff_lo, r.diff_hi, "{:+.2f}".format)
            out.append((name, r.seeds, r.days, f"{r.a_mean:.2f}", f"{r.b_mean:.2f}", diff, f"{r.p_a_better:.2f}{pci}"))
        return pd.DataFrame(
            out, columns=["regime", "seeds", "days", la, lb, f"{la} - {lb} [95% CI]", f"P({la} > {lb})"]
        )

    def to_markdown(self) -> str:
        head = [f"**{self.title()}**", "", *([self.provenance, ""] if self.provenance else [])]
        notes = ["", *map(_note_line, self.notes)] if self.notes else []
        return "\n".join([*head, *markdown_rows(self.formatted()), *notes]) + "\n"

    def to_text(self) -> str:
        fmt = self.formatted()
        rows = [list(fmt.columns), *fmt.itertuples(index=False)]  # the header, then the rows
        width = [max(len(str(row[k])) for row in rows) for k in range(len(fmt.columns))]
        just = [str.rjust if c in ("seeds", "days") else str.ljust for c in fmt.columns]
        table = ["  ".join(j(str(v), w) for j, v, w in zip(just, row, width)).rstrip() for row in rows]
        head = [self.title(), *([self.provenance] if self.provenance else []), ""]
        return "\n".join([*head, *table, *map(_note_line, self.notes)]) + "\n"


def _note_line(note: str) -> str:
    """A note as printed: a warning as ``warning: ...``, any other as ``note: ...``."""
    return note if note.startswith("warning: ") else f"note: {note}"


def compare_agents(
    ev: pd.DataFrame,
    a: str,
    b: str,
    regimes: Sequence[str] | None = None,
    reps: int = COMPARE_REPS,
    seed: int = 0,
    confidence: float = CONFIDENCE,
) -> Comparison:
    """``a`` against ``b`` on the evaluation episodes ``ev`` (columns of ``episode_metrics``;
    one job per run): per regime of ``regimes`` (default: every regime both played) and
    aggregated. ``seed``: kept for callers (the chosen interval, :data:`nutribench.stats.CHOSEN`,
    draws no resample). :class:`CompareError` when the two cannot be compared."""
    if a == b:
        raise CompareError(f"compare {a} {b}: give two different agent configs")
    ev = ev[ev["phase"] == "eval"] if "phase" in ev else ev
    _check_held(ev, (a, b))
    wanted = _wanted_regimes(ev, a, b, regimes)
    days = paired_days(ev, a, b, wanted)
    paired = sort_regimes(days["regime"])
    notes = [
        f"{r}: no common seed ({a}: seeds {_seeds_of(ev, a, r)}; {b}: seeds {_seeds_of(ev, b, r)})"
        for r in wanted
        if r not in paired
    ]
    if days.empty:
        raise CompareError(f"{a} and {b} share no seed on {', '.join(wanted)}: nothing to pair ({'; '.join(notes)})")
    for r in paired:
        partnered = set(days.loc[days["regime"] == r, "seed"])
        for name in (a, b):
            lost = set(ev.loc[(ev["algo"] == name) & (ev["regime"] == r), "seed"]) - partnered
            if lost:
                notes.append(f"{r}: seeds {seed_list(lost)} of {name} have no partner, left out")
    rows = [_summary(r, [r], days[days["regime"] == r], reps, confidence) for r in paired]
    if len(paired) > 1:
        rows.append(_summary("all", paired, days, reps, confidence))
        delayed = [r for r in paired if r in DELAYED_REGIMES]
        if len(delayed) > 1 and len(delayed) < len(paired):
            rows.append(_summary("delayed", delayed, days[days["regime"].isin(delayed)], reps, confidence))
    used = ev[ev["algo"].isin([a, b]) & ev["regime"].isin(paired)]
    budget_a, budget_b = (budget_cell(used[used["algo"] == n]) for n in (a, b))
    if budget_a != budget_b:
        both = f"{trained_text(algo_label(a), budget_a)}, {trained_text(algo_label(b), budget_b, verb='')}"
        notes.insert(0, f"warning: budgets differ ({both}): the difference is the agents' and their budgets' together")
    # the budgets and seeds line of the comparison, a budget of 0 days said as UNRECORDED
    header = budget_seeds_text(used).replace("budget 0 days", f"budget unknown ({UNRECORDED})")
    return Comparison(a, b, pd.DataFrame(rows, columns=COMPARE_COLUMNS), days, reps, notes, header)


def _check_held(ev: pd.DataFrame, names: Sequence[str]) -> None:
    """:class:`CompareError` naming the configs ``ev`` has days of, for ``names`` it has none of."""
    held = sort_algos(ev["algo"])
    unknown = [n for n in names if n not in held]
    if unknown:
        raise CompareError(
            f"{', '.join(unknown)}: no evaluation days in the database, which has them for {', '.join(held) or 'no agent config'}"
        )


def _wanted_regimes(ev: pd.DataFrame, a: str, b: str, regimes: Sequence[str] | None) -> list[str]:
    """The regimes to compare on: ``regimes`` (default every one both were evaluated on), checked."""
    both = sorted(set(ev.loc[ev["algo"] == a, "regime"]) & set(ev.loc[ev["algo"] == b, "regime"]))
    if regimes is not None:
        regimes = list(dict.fromkeys(regimes))
        absent = [r for r in regimes if r not in both]
        if absent:
            raise CompareError(
                f"--regimes {', '.join(absent)}: {a} and {b} were not both evaluated there "
                f"(both were on {', '.join(sort_regimes(both)) or 'no regime'})"
            )
    wanted = sort_regimes(both if regimes is None else regimes)
    if not wanted:
        raise CompareError(
            f"{a} and {b} were never evaluated on the same regime ({a}: {_regimes_of(ev, a)}; {b}: {_regimes_of(ev, b)})"
        )
    return wanted


def trained_text(label: str, budget: str, verb: str = "trained ") -> str:
    """``PPO trained 150 days`` (``verb`` ""): ``mine 50 days``); ``mine: training not
    recorded`` for a budget of 0 days (not "trained 0 days": an evaluated model was trained,
    elsewhere, for a time the database does not hold)."""
    parts = budget.split("/")
    if "0" not in parts:
        return f"{label} {verb}{budget} days"
    known = [p for p in parts if p != "0"]
    return f"{label}: {UNRECORDED}" + (f" for some seeds, {'/'.join(known)} days for the others" if known else "")


def _regimes_of(ev: pd.DataFrame, name: str) -> str:
    return ", ".join(sort_regimes(ev.loc[ev["algo"] == name, "regime"])) or "none"


def _seeds_of(ev: pd.DataFrame, name: str, regime: str) -> str:
    return seed_list(ev.loc[(ev["algo"] == name) & (ev["regime"] == regime), "seed"]) or "none"


@dataclass(frozen=True)
class EntrySpec:
    """An agent as ``compare`` is given it: ``NAME``, ``NAME@vVERSION``, ``NAME@DAYS`` or
    ``NAME@vVERSION@DAYS`` (``ppo``, ``ppo@v1``, ``ppo@5000``, ``ppo@v2@150``); what is left
    out is chosen by default (:func:`choose_entry`)."""

    name: str
    version: int | None = None
    budget: int | None = None

    @classmethod
    def parse(cls, text: str) -> EntrySpec:
        """The spec ``text`` names; :class:`CompareError` in one line for one it does not."""
        name, *parts = text.strip().split("@")
        version = budget = None
        for part in parts:
            m = re.fullmatch(r"v(\d+)|(\d+)d?", part.strip())
            if not name or not m or (m.group(1) and version is not None) or (m.group(2) and budget is not None):
                raise CompareError(
                    f"{text!r}: give an agent as NAME, NAME@vVERSION, NAME@DAYS or NAME@vVERSION@DAYS "
                    "(e.g. ppo, ppo@v1, ppo@5000, ppo@v2@150)"
                )
            version, budget = (int(m.group(1)), budget) if m.group(1) else (version, int(m.group(2)))
        return cls(name.strip(), version, budget)

    def __str__(self) -> str:
        version = f"@v{self.version}" if self.version is not None else ""
        return self.name + version + (f"@{self.budget}" if self.budget is not None else "")


def choose_entry(ev: pd.DataFrame, spec: EntrySpec) -> tuple[tuple[str, int, int], str | None]:
    """The entry (name, version, budget) of the evaluation rows ``ev`` that ``spec`` names, and
    a note when ``spec`` left a choice: by default the largest training budget, then the newest
    version of it (the published grid's 5000 days before a short run of one's own), the other
    entries listed with the spec that picks each. :class:`CompareError` naming what exists when
    none matches."""
    from nutribench.report.data import entries, entry_label

    held = entries(ev[ev["algo"] == spec.name])
    # entries() lists the largest budget, then the newest version, first
    match = [e for e in held if spec.version in (None, e[1]) and spec.budget in (None, e[2])]
    listed = "; ".join(f"{entry_label(e)} ({EntrySpec(*e)})" for e in held)
    if not match:
        raise CompareError(f"{spec}: no such entry in the database; {spec.name} has {listed}")
    chosen = match[0]
    note = None
    if len(held) > 1:
        how = "as asked" if len(match) == 1 else "by default the largest budget, then the newest version"
        others = "; ".join(f"{entry_label(e)} ({EntrySpec(*e)})" for e in held if e != chosen)
        note = f"{spec.name}: compared {entry_label(chosen)} ({how}); also in the database: {others}"
    return chosen, note


def load_comparison(db, a: str, b: str, regimes: Sequence[str] | None = None, reps: int = COMPARE_REPS) -> Comparison:
    """:func:`compare_agents` on the results database ``db``. ``a`` and ``b`` are agents as
    :class:`EntrySpec` reads them (``ppo``, ``ppo@v1``, ``ppo@5000``, ``ppo@v2@150``); each is
    one entry (name, version, training budget: :func:`choose_entry`), never a blend of
    several, and a note says which was compared and what else the database holds; per
    (regime, seed) its newest job (:func:`nutribench.report.data.prepare_entries`). Agent
    configs without evaluation days raise :class:`CompareError` naming those the database has."""
    from nutribench.report.data import entry_rows, prepare_entries, read_episodes

    spec_a, spec_b = EntrySpec.parse(a), EntrySpec.parse(b)
    if spec_a == spec_b:
        raise CompareError(f"compare {a} {b}: give two different agent configs")
    ev = read_episodes(db, "eval", CompareError)  # CompareError when it holds no evaluation days
    _check_held(ev, (spec_a.name, spec_b.name))
    data = prepare_entries(ev, [spec_a.name, spec_b.name])
    picked, notes = [], list(data.notes)
    for spec in (spec_a, spec_b):
        entry, note = choose_entry(data.eval, spec)
        picked.append(entry)
        if note and note not in notes:
            notes.append(note)
    if picked[0] == picked[1]:
        raise CompareError(f"compare {a} {b}: both name {EntrySpec(*picked[0])}; give two different entries")
    names = [spec_a.name, spec_b.name]
    if names[0] == names[1]:  # two entries of one config: each is named by its spec
        names = [str(EntrySpec(*e)) for e in picked]
    parts = [entry_rows(data.eval, entry).assign(algo=name) for entry, name in zip(picked, names)]
    res = compare_agents(pd.concat(parts, ignore_index=True), names[0], names[1], regimes, reps)
    res.notes = [*notes, *res.notes]
    return res
