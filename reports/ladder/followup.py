"""Addenda 3 and 4's exploratory follow-up (README.md), each written before its runs: PPO
without observation normalisation (``agents/ppo_nonorm.toml``) and with five-day minibatches
(``agents/ppo_mb250.toml``), at level 4 against the plan's PPO at levels 4 and 3 (F1-F4,
addendum 3) and at level 1 against the plan's PPO and GRU-PPO there (F5-F7, addendum 4), on
run0, run3 and run6, with the plan's statistics and rule (``analyse.py``'s functions, unchanged):

* ``followup/table_followup.md/.csv``: the follow-up's arms and those they are compared with, as
  ``table_ladder``'s rows;
* ``followup/table_followup_comparisons.md/.csv``: F1-F7, as ``table_comparisons``'s;
* ``followup/fig_followup.png``: per regime, every arm's share of the gap (IQM, 95 % interval).

    python reports/ladder/followup.py [--archives-dir reports/ladder/data] [--out reports/ladder/followup]
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
# a copy of analyse.py of its own (its comparisons and labels are set to the follow-up's below)
_spec = importlib.util.spec_from_file_location("ladder_analyse_followup", HERE / "analyse.py")
ladder = sys.modules["ladder_analyse_followup"] = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ladder)

#: the follow-up's arms (addendum 3: level 4; addendum 4: level 1), then the plan's archives it is compared with
FOLLOW: tuple[tuple[str, int], ...] = (("ppo_nonorm", 4), ("ppo_mb250", 4), ("ppo_mb250", 1), ("ppo_nonorm", 1))
BASE: tuple[tuple[str, int], ...] = (("ppo", 4), ("ppo", 3), ("ppo", 1), ("gru_ppo", 1))
LABELS = {"ppo_nonorm": "PPO without obs. normalisation", "ppo_mb250": "PPO, 5-day minibatches"}
COMPARISONS = {
    "F1": (("ppo_nonorm", 4), ("ppo", 4), "is observation normalisation what costs PPO at level 4?"),
    "F2": (("ppo_mb250", 4), ("ppo", 4), "is the minibatch what costs PPO at level 4?"),
    "F3": (("ppo_nonorm", 4), ("ppo", 3), "without normalisation, does level 4 reach level 3?"),
    "F4": (("ppo_mb250", 4), ("ppo", 3), "with five-day minibatches, does level 4 reach level 3?"),
    "F5": (("ppo_mb250", 1), ("ppo", 1), "what five-day minibatches do at the paper's observation"),
    "F6": (("ppo_nonorm", 1), ("ppo", 1), "what observation normalisation does at the paper's observation"),
    "F7": (("gru_ppo", 1), ("ppo_mb250", 1), "GRU-PPO over PPO with the same minibatch (C6 without it)"),
}
TITLES = {
    "# The information ladder: share of the never -> planner gap (%), test days": (
        "# Addenda 3 and 4 (exploratory): PPO without observation normalisation / with 5-day minibatches,"
        " beside the plan's arms they are compared with"
    ),
    "Made by `python reports/ladder/analyse.py` from the archives in `data/`.": (
        "Made by `python reports/ladder/followup.py` from the archives in `data/`."
    ),
    "# The ladder's named comparisons (the plan's list; rule: two 95 % intervals apart)": (
        "# Addenda 3 and 4's comparisons F1-F7 (exploratory; the plan's rule: two 95 % intervals apart)"
    ),
}


def retitle(markdown: str) -> str:
    for old, new in TITLES.items():
        markdown = markdown.replace(old, new)
    return markdown


def followup(folder: Path, out: Path) -> list[Path]:
    ladder.LABELS.update(LABELS)
    ladder.COMPARISONS.clear()
    ladder.COMPARISONS.update(COMPARISONS)
    arms = [*FOLLOW, *BASE]
    present = [a for a in arms if (folder / f"{ladder.archive_name(a)}.npz").is_file()]
    absent = [ladder.archive_name(a) for a in arms if a not in present]
    if not any(a in present for a in FOLLOW):
        names = ", ".join(map(ladder.archive_name, FOLLOW))
        raise ladder.AnalysisError(f"{folder}: none of the follow-up's archives ({names})")
    print(f"archives present: {', '.join(map(ladder.archive_name, present))}; absent: {', '.join(absent) or 'none'}")
    batches = ladder.read_batches(folder, present)
    notes = [n for b in batches.values() for n in b.notes]
    cells, comps = ladder.tabulate(batches, list(COMPARISONS))
    written = ladder.write_tables(
        out,
        [
            ("table_followup", cells, retitle(ladder.ladder_markdown(cells, absent, notes))),
            ("table_followup_comparisons", comps, retitle(ladder.comparisons_markdown(comps))),
        ],
    )
    fig = figure(cells)
    fig.savefig(out / "fig_followup.png", dpi=110)
    ladder.plt.close(fig)
    return [*written, out / "fig_followup.png"]


def figure(cells: pd.DataFrame):
    """One panel per regime: each arm x level a row, its IQM share of the gap with the 95 % interval;
    never (0 %) and the planner (100 %) as lines; the follow-up's arms in orange, the plan's in blue."""
    plt = ladder.plt
    order = [(a, lv) for a, lv in [*FOLLOW, *BASE] if ((cells["arm"] == a) & (cells["level"] == lv)).any()]
    order.sort(key=lambda x: (x[1], x[0] not in dict(FOLLOW)))
    fig, axes = plt.subplots(1, len(ladder.REGIMES), figsize=(15, 0.45 * len(order) + 1.8), sharey=True)
    for ax, regime in zip(axes, ladder.REGIMES):
        for y, (arm, level) in enumerate(order):
            r = cells[(cells["arm"] == arm) & (cells["level"] == level) & (cells["regime"] == regime)].iloc[0]
            colour = "tab:orange" if (arm, level) in FOLLOW else "tab:blue"
            point = 100 * r["iqm"]
            err = [[point - 100 * r["lo"]], [100 * r["hi"] - point]]
            ax.errorbar(point, y, xerr=err, fmt="o", color=colour, capsize=3)
        ax.axvline(0, color="grey", ls="--", lw=1)
        ax.axvline(100, color="black", ls=":", lw=1)
        ax.set_title(f"{regime}: test days, IQM [95 % CI]")
        ax.set_xlabel("share of the never -> planner gap (%)")
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(range(len(order)), [f"{ladder.LABELS[a]}, level {lv}" for a, lv in order])
    axes[0].invert_yaxis()
    fig.suptitle("Addenda 3 and 4 (exploratory, orange) beside the plan's arms (blue): reports/ladder/")
    fig.tight_layout()
    return fig


def main(argv: Sequence[str] | None = None) -> int:
    return ladder.cli(argv, followup, __doc__.split("\n\n")[0], HERE / "followup")


if __name__ == "__main__":
    sys.exit(main())
