"""The trajectory view: one evaluation day, nutrients against target, meals and their
absorption curves. The picture that explains delayed transitions to a newcomer."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from nutribench.config import NUTRIENTS
from nutribench.env import RegimeDynamics
from nutribench.report.figure_parts import wrap_text

NUTRIENT_COLORS = {"C": "#4c72b0", "F": "#dd8452", "P": "#55a868"}
NUTRIENT_NAMES = {"C": "carbohydrate", "F": "fat", "P": "protein"}
#: How a meal's name is written above the top panel, at the step it was eaten.
MEAL_NAME_STYLE = dict(rotation=90, va="bottom", ha="center", fontsize=7, color="0.3", clip_on=False)


def trajectory_figure(steps: pd.DataFrame, dynamics: RegimeDynamics, title: str = "") -> Figure:
    """``steps``: one evaluation episode, columns ``step`` (1..H), ``food`` (index offered),
    ``action`` (0/1), ``C``, ``F``, ``P`` (absorbed state after the step).

    Top: absorbed nutrients per step against the target, with the meals eaten marked.
    Bottom: each meal's absorption curve per nutrient (what it delivers at each step), so the
    lag between a decision and its effect is visible.
    """
    steps = steps.sort_values("step")
    meals = steps[steps["action"] == 1]
    fig = Figure(figsize=(10, 6.4), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    _absorbed_panel(top, steps, meals, dynamics)
    # outside the axes (any spot inside would cover the curves on some day) and under the
    # panels: at the upper right it lay beside the title, and covered a long title's end
    fig.legend(*top.get_legend_handles_labels(), loc="outside lower center", ncols=4, fontsize=8, frameon=False)
    top.grid(alpha=0.3)
    if title:
        fig.suptitle(wrap_text(title, fig, 10), fontsize=10)
    _absorption_panel(bottom, meals, dynamics)
    if meals.empty:  # a policy that never eats: say so instead of drawing two empty panels
        for ax in (top, bottom):
            ax.text(
                0.5, 0.5, "no meal eaten on this day", transform=ax.transAxes, ha="center", va="center", color="0.4"
            )
    H = dynamics.horizon
    bottom.set_ylabel("delivered per step\n(x daily target)")
    bottom.set_xlabel(f"step (1 step ~ 30 min; day = {H} steps)")
    bottom.set_xlim(0, H + 0.5)
    bottom.grid(alpha=0.3)
    bottom.set_title("absorption of each meal eaten (one curve per meal and nutrient)", fontsize=9, loc="left")
    return fig


def _absorbed_panel(ax, steps: pd.DataFrame, meals: pd.DataFrame, dynamics: RegimeDynamics) -> None:
    """The absorbed nutrients per step against the daily target, each meal marked and named
    above the axes, in a strip of its own (inside, the names covered the curves)."""
    x = np.concatenate([[0], steps["step"].to_numpy()])
    for n in NUTRIENTS:
        y = np.concatenate([[0.0], steps[n].to_numpy()])
        ax.step(x, y, where="post", color=NUTRIENT_COLORS[n], lw=1.8, label=f"{NUTRIENT_NAMES[n]} ({n})")
    ax.axhline(1.0, color="k", ls="--", lw=1, label="daily target")
    for t, food in zip(meals["step"].astype(int), meals["food"].astype(int)):
        ax.axvline(t - 0.5, color="0.6", lw=0.8, ls=":")
        name = dynamics.food_names[food].replace("_", " ")
        ax.text(t - 0.5, 1.01, name, transform=ax.get_xaxis_transform(), **MEAL_NAME_STYLE)
    ax.set_ylim(0, max(1.2, float(steps[list(NUTRIENTS)].to_numpy().max()) * 1.08))
    ax.set_ylabel("absorbed (x daily target)")


def _absorption_panel(ax, meals: pd.DataFrame, dynamics: RegimeDynamics) -> None:
    """Each meal's absorption curves: a meal eaten at step t delivers schedule[food, k] at step t + k."""
    for t, food in zip(meals["step"].astype(int), meals["food"].astype(int)):
        k = np.arange(0, dynamics.horizon - t + 1)
        for j, n in enumerate(NUTRIENTS):
            amount = dynamics.schedule[food, k, j]
            if amount.sum() <= 0:
                continue
            ax.plot(t + k, amount, color=NUTRIENT_COLORS[n], lw=1, alpha=0.85, marker="." if len(k) < 3 else None)
        ax.axvline(t - 0.5, color="0.6", lw=0.8, ls=":")
