"""What every report figure shares: :class:`FigureResult` (a figure and the numbers it drew),
regime and seed formatting, the "budget ... days, seeds ..." line every figure states, each
agent's legend label (with its budget and seed count when the agents drawn differ in them),
and the title, notes and legend rows drawn around the panels."""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from itertools import groupby

import pandas as pd
from matplotlib.figure import Figure

from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos
from nutribench.scheduler.grid import PRESETS

#: The paper's seeds: a legend entry counts an agent's seeds when it has fewer.
PAPER_SEEDS: tuple[int, ...] = PRESETS["paper"].seeds


@dataclass
class FigureResult:
    figure: Figure
    data: pd.DataFrame  # what was drawn: one row per (panel, line, x)
    notes: list[str] = field(default_factory=list)


def regime_index(name: str) -> int | None:
    m = re.fullmatch(r"run(\d+)", str(name))
    return int(m.group(1)) if m else None


def sort_regimes(names) -> list[str]:
    return sorted(set(names), key=lambda r: (regime_index(r) is None, regime_index(r) or 0, str(r)))


def default_window(n_episodes: int) -> int:
    """Smoothing window: ~2 % of the episodes, at least 1, at most 100."""
    return int(min(100, max(1, round(n_episodes / 50))))


def wrap_text(text: str, fig: Figure, fontsize: float) -> str:
    """Wrap ``text`` (each of its lines) to the figure's width at ``fontsize``."""
    import textwrap

    chars = max(40, int(fig.get_figwidth() * 72 / (fontsize * 0.55)))
    return "\n".join(textwrap.fill(line, chars) for line in text.split("\n"))


def seed_list(seeds: Iterable[int]) -> str:
    """Seeds in increasing order, runs of three or more as ranges: ``0-9, 21, 1997``."""
    ordered = enumerate(sorted({int(s) for s in seeds}))
    runs = [[s for _, s in run] for _, run in groupby(ordered, lambda pair: pair[1] - pair[0])]
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) >= 3 else ", ".join(map(str, r)) for r in runs)


def _budget_seeds(cell: pd.DataFrame) -> str:
    """``budget 5000 days, seeds 0-9`` of one config's rows (no budget without the column)."""
    budgets = sorted({int(b) for b in cell["budget"]}) if "budget" in cell else []
    text = f"budget {'/'.join(map(str, budgets))} days, " if budgets else ""
    return text + f"seed{'s' if cell['seed'].nunique() > 1 else ''} {seed_list(cell['seed'])}"


def budget_seeds_text(df: pd.DataFrame) -> str:
    """The training budget (days) and seeds of the rows drawn: ``budget 5000 days, seeds 0,
    9, 21`` when every config has the same, else per config, configs alike together
    (``MC, PPO: budget 5000 days, seeds 0-9; a2c_mine: budget 1000 days, seed 0``)."""
    per = {a: _budget_seeds(df[df["algo"] == a]) for a in sort_algos(df["algo"])}
    texts = list(dict.fromkeys(per.values()))
    if len(texts) == 1:
        return texts[0]
    return "; ".join(f"{', '.join(algo_label(a) for a, t in per.items() if t == text)}: {text}" for text in texts)


def budgets_seeds_alike(df: pd.DataFrame) -> bool:
    """Whether every config of ``df`` has the same budget and the same seeds (one title line
    then says them for all)."""
    return len({_budget_seeds(df[df["algo"] == a]) for a in df["algo"].unique()}) <= 1


def agent_tag(cell: pd.DataFrame) -> str:
    """One config's budget and, when it has fewer seeds than the paper's five, its seed count:
    ``20 days, 1 seed`` (no budget without the ``budget`` column)."""
    parts = [f"{budget_cell(cell)} days"] if "budget" in cell and cell["budget"].notna().any() else []
    n = int(cell["seed"].nunique())
    if n < len(PAPER_SEEDS):
        parts.append(f"{n} seed{'s' if n != 1 else ''}")
    return ", ".join(parts)


def agent_labels(df: pd.DataFrame, labels: dict[str, str] | None = None) -> dict[str, str]:
    """The legend label of each config of ``df`` (``labels`` or the palette's): when the configs
    differ in budget or seeds, with its :func:`agent_tag`, ``trpo_mine_tuned (20 days, 1 seed)``,
    so that a 20-day agent beside 5000-day baselines says so where it is drawn."""
    names = sort_algos(df["algo"])
    base = {a: (labels or {}).get(a) or algo_label(a) for a in names}
    if budgets_seeds_alike(df):
        return base
    tags = {a: agent_tag(df[df["algo"] == a]) for a in names}
    return {a: f"{base[a]} ({tags[a]})" if tags[a] else base[a] for a in names}


def budget_seeds_line(df: pd.DataFrame) -> str:
    """The budget and seeds line of a figure's title: :func:`budget_seeds_text` when every
    config has the same; else one short line (each config's are in its legend entry,
    :func:`agent_labels`): ``budgets 20, 5000 days, seeds 0-2, 9 (per agent in the legend)``."""
    if budgets_seeds_alike(df):
        return budget_seeds_text(df)
    budgets = sorted({int(b) for b in df["budget"].dropna()}) if "budget" in df else []
    text = f"budgets {', '.join(map(str, budgets))} days, " if budgets else ""
    return text + f"seeds {seed_list(df['seed'])} (each agent's in its legend entry)"


#: What a budget of 0 days means: no training day was recorded with the job (a saved model
#: evaluated by ``nutribench evaluate`` with no sidecar that records its training days, a policy
#: recorded by ``nutribench.Recorder`` without training days): how long it was trained, the
#: database does not know.
UNRECORDED = "training not recorded"


def budget_cell(cell: pd.DataFrame) -> str:
    """The training budget(s) of one config's rows, in days (``5000``, ``50/5000``; ``?`` without
    the ``budget`` column): the budget column of the results and aggregate tables."""
    if "budget" not in cell or cell["budget"].isna().all():
        return "?"
    return "/".join(str(b) for b in sorted({int(b) for b in cell["budget"].dropna()}))


def budget_caption(df: pd.DataFrame) -> str:
    """The budget and seeds line of a table's caption; it warns when budgets differ."""
    text = budget_seeds_text(df)
    if "budget" in df and len({budget_cell(df[df["algo"] == a]) for a in df["algo"].unique()}) > 1:
        text = "budgets differ, compare across them with care: " + text
    return text


def count_span(counts: pd.Series) -> str:
    """``"3"`` when every group has 3, else ``"2-5"``."""
    lo, hi = int(counts.min()), int(counts.max())
    return f"{lo}" if lo == hi else f"{lo}-{hi}"


def set_title(fig: Figure, title: str, notes: list[str] | None = None) -> None:
    """The figure's title and caption (suptitle), wrapped to the figure's width, with ``notes``
    under it (:func:`draw_notes`; None: the notes drawn before are kept)."""
    fig._report_title = title  # type: ignore[attr-defined]
    draw_notes(fig, getattr(fig, "_report_notes", []) if notes is None else notes)


def draw_notes(fig: Figure, notes: list[str]) -> None:
    """Write ``notes`` (what was left out, which data was chosen) under the title and caption.

    They go in the suptitle, the one text besides the legend that the constrained layout
    keeps clear of the axes (a free ``fig.text`` ends up under the outside legend). Calling
    it again replaces the notes drawn before."""
    fig._report_notes = list(notes)  # type: ignore[attr-defined]
    title = getattr(fig, "_report_title", None)
    if title is None:
        title = fig.get_suptitle()
        fig._report_title = title  # type: ignore[attr-defined]
    text = title + "".join(f"\nnote: {n}" for n in notes)
    fig.suptitle(wrap_text(text, fig, 10), fontsize=10)


#: Most entries in one row of a figure legend.
LEGEND_COLS = 6


def legend_rows(fig: Figure, rows: list[tuple[list, list[str]]], fontsize: float = 9) -> None:
    """One figure legend under the panels with one row per group (learners, references).

    Matplotlib fills legend columns first, so the entries are interleaved column by column
    and short rows are padded with invisible entries; a group of more entries than fit across
    the figure (at most :data:`LEGEND_COLS`) takes several rows."""
    from matplotlib.lines import Line2D

    # as many columns as the figure's width holds at the longest label (agents' labels carry
    # their budgets), at most LEGEND_COLS
    longest = max((len(lab) for _, ls in rows for lab in ls), default=1)
    cap = max(1, min(LEGEND_COLS, int(fig.get_figwidth() * 72 / (fontsize * 0.6 * longest + 30))))
    rows = [(hs[k : k + cap], ls[k : k + cap]) for hs, ls in rows for k in range(0, len(ls), cap)]
    if not rows:
        return
    ncols = max(len(labels) for _, labels in rows)
    blank = Line2D([], [], alpha=0)
    cells = [(hs[c], ls[c]) if c < len(ls) else (blank, "") for c in range(ncols) for hs, ls in rows]
    handles, labels = (list(v) for v in zip(*cells))
    fig.legend(handles, labels, loc="outside lower center", ncols=ncols, fontsize=fontsize, frameon=False)


#: Legend text of the dashed "best" line of Figure 1 (its line keeps the short label).
BEST_TEXT = "{label}: highest point of any line in its panel"
#: Markers per line on a training curve (one every len/MARKS episodes).
MARKS = 8


def legend_entries(axes: Iterable) -> dict[str, object]:
    """Each label drawn in ``axes`` and its first handle, in the order first drawn."""
    found: dict[str, object] = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            found.setdefault(lab, h)
    return found


def training_legend(fig: Figure, axes: list, learners: list[str]) -> None:
    """The legend of Figures 1/2 and 6: the configs' labels in palette order, then the "best"
    line, explained (:data:`BEST_TEXT`), in a row of its own."""
    found = legend_entries(axes)
    learners = [lab for lab in learners if lab in found]
    rest = [lab for lab in found if lab not in learners]
    text = {lab: BEST_TEXT.format(label=lab) if lab.startswith("best") else lab for lab in found}
    groups = [learners, rest] if rest else [learners]
    legend_rows(fig, [([found[lab] for lab in g], [text[lab] for lab in g]) for g in groups])
