"""Drawing a regime's per-food delays from its ranges and seed, and writing the file.

The draw is: ``rng = numpy.random.default_rng(seed)``; ``tau = rng.uniform(low, high,
size=(N, 3))`` with the Table 1 bounds per nutrient column (C, F, P), then ``sigma`` the
same way; foods in catalog order; values rounded to 2 decimals (the file is what fixes the
dynamics, the rounding only keeps it readable). ``nutribench regimes generate`` re-runs
this draw, so the written values are reproducible and reviewable.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nutribench.config.models import NUTRIENTS, DelayRanges, FoodCatalog, Regime

DECIMALS = 2


def draw_delays(ranges: DelayRanges, seed: int, catalog: FoodCatalog) -> dict[str, dict]:
    """The per-food ``{"tau": {...}, "sigma": {...}}`` drawn from ``ranges`` with ``seed``."""
    rng = np.random.default_rng(seed)
    n = len(catalog.food)
    drawn = {}
    for what in ("tau", "sigma"):
        lo, hi = getattr(ranges, what).bounds()
        values = np.round(rng.uniform(lo, hi, size=(n, 3)), DECIMALS)
        drawn[what] = np.clip(values, lo, hi)
    return {
        key: {what: {nut: float(drawn[what][i, j]) for j, nut in enumerate(NUTRIENTS)} for what in ("tau", "sigma")}
        for i, key in enumerate(catalog.keys)
    }


def regenerate(regime: Regime, catalog: FoodCatalog) -> Regime:
    """The same regime with its ``foods`` table redrawn from its own ranges and seed."""
    data = regime.model_dump(mode="json")
    data["foods"] = draw_delays(regime.ranges, regime.seed, catalog)
    return Regime.model_validate(data)


def _num(x: float) -> str:
    return repr(float(x)) if x != int(x) else f"{int(x)}.0"


def _nutrients(d: dict[str, float]) -> str:
    return "{ " + ", ".join(f"{n} = {_num(d[n])}" for n in NUTRIENTS) + " }"


def _range_table(d: dict[str, dict[str, float]]) -> str:
    return "{ " + ", ".join(f"{n} = {{ low = {_num(d[n]['low'])}, high = {_num(d[n]['high'])} }}" for n in NUTRIENTS) + " }"


def regime_to_toml(regime: Regime) -> str:
    """TOML text of a regime, one line per food, in the layout of the shipped files."""
    d = regime.model_dump(mode="json")
    lines = [
        f"# Delay regime {d['name']}: {d['description']}.",
        "# The per-food values below were drawn by `nutribench regimes generate` from [ranges]",
        "# with `seed` (uniform, rounded to 2 decimals). They, not the ranges, fix the dynamics.",
        "# tau = mean absorption delay, sigma = spread, both in steps (1 step ~ 30 min).",
        f'name = "{d["name"]}"',
        f"version = {d['version']}",
        f'description = "{d["description"]}"',
        f"seed = {d['seed']}",
        f'catalog = "{d["catalog"]}"',
        f'reward = "{d["reward"]}"',
        "",
        "[ranges]",
        f"tau = {_range_table(d['ranges']['tau'])}",
        f"sigma = {_range_table(d['ranges']['sigma'])}",
        "",
        "[foods]",
    ]
    for key, delay in d["foods"].items():
        lines.append(f"{key} = {{ tau = {_nutrients(delay['tau'])}, sigma = {_nutrients(delay['sigma'])} }}")
    return "\n".join(lines) + "\n"


def write_regime(regime: Regime, path: Path) -> None:
    path.write_text(regime_to_toml(regime))
