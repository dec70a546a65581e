"""The experiment grid: presets, parsing of the ``run`` options, and expansion into
regime x agent config x seed cells.

Presets fix the seeds and the training budget; explicit options override single fields::

    smoke   every regime, every algorithm, seeds 0,            20 episodes
    quick   every regime, every algorithm, seeds 0,21,         500 episodes
    paper   every regime, every algorithm, seeds 0,21,9,2003,1997, 5000 episodes

Every preset evaluates each trained agent on ``EVAL_EPISODES`` = 5 episodes.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from nutribench.errors import UserError

EVAL_EPISODES = 5
DEFAULT_PRESET = "paper"

#: CPU seconds of one training day of relative cost 1 (PPO's) with the SB3 engine, calibrated on
#: the paper grid's measured 30 CPU-hours (docs/reproduce.md: 35 regime-seed pairs x 5000 days x
#: the five agents' costs 1 + 1 + 1 + 5 + 5) on the project's 2-core machine
SB3_SECONDS_PER_COST_DAY = 30 * 3600 / (35 * 5000 * 13)


class GridError(UserError, ValueError):
    """A malformed grid option (seeds, preset, budget). One line for users."""


@dataclass(frozen=True)
class Preset:
    """Seeds and training budget of a named grid; regimes and algorithms are all."""

    seeds: tuple[int, ...]
    episodes: int
    eval_episodes: int = EVAL_EPISODES


PRESETS: dict[str, Preset] = {
    "smoke": Preset(seeds=(0,), episodes=20),
    "quick": Preset(seeds=(0, 21), episodes=500),
    "paper": Preset(seeds=(0, 21, 9, 2003, 1997), episodes=5000),
}


@dataclass(frozen=True)
class Grid:
    """What one ``run`` asks for: names of regimes and agent configs, seeds, budgets."""

    regimes: tuple[str, ...]
    algos: tuple[str, ...]
    seeds: tuple[int, ...]
    episodes: int
    eval_episodes: int

    def cells(self) -> list[tuple[str, str, int]]:
        """(regime, algo, seed) for every job of the grid, regime-major."""
        return list(itertools.product(self.regimes, self.algos, self.seeds))

    def cpu_hours(self, cost_of: Callable[[str], float]) -> float:
        """An estimate of the grid's CPU time with the SB3 engine: each job's days times its
        agent's relative cost (``cost_of(agent config name)``, PPO's day = 1) times
        :data:`SB3_SECONDS_PER_COST_DAY`."""
        units = sum(cost_of(algo) for _, algo, _ in self.cells()) * self.episodes
        return units * SB3_SECONDS_PER_COST_DAY / 3600

    def __len__(self) -> int:
        return len(self.regimes) * len(self.algos) * len(self.seeds)


#: the largest seed: what a database's integer column holds everywhere (PostgreSQL's INTEGER)
MAX_SEED = 2**31 - 1
#: the largest training or evaluation budget, in days: the same integer column
MAX_EPISODES = 2**31 - 1
#: the most evaluation days (or simple-policy days) one command plays side by side, every step
#: kept (``evaluate``, the recorder, ``train``, ``baselines``)
MAX_EVAL_DAYS = 10_000


#: Named seed sets for ``--seeds``: each preset's seeds (``paper``: the paper's 0, 21, 9, 2003,
#: 1997, so that a new agent pairs with the published baselines seed for seed).
SEED_SETS: dict[str, tuple[int, ...]] = {name: p.seeds for name, p in PRESETS.items()}


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0,21,9"`` -> ``(0, 21, 9)``; a name of :data:`SEED_SETS` (``"paper"``) -> its seeds;
    anything else (empty items, non-integers, negative numbers, seeds over :data:`MAX_SEED`,
    repeats) is a :class:`GridError` naming the offending item."""
    if text.strip() in SEED_SETS:
        return SEED_SETS[text.strip()]
    items = [s.strip() for s in text.split(",")]
    if not any(items):
        raise GridError(f"--seeds '{text}' is empty: give comma-separated non-negative integers, e.g. 0,21,9")
    seeds: list[int] = []
    for item in items:
        if not (item.isascii() and item.isdigit()):  # rejects '', '-1', '1.5', '0x10', ' 3a', '²'
            raise GridError(
                f"--seeds '{text}': '{item}' is not a non-negative integer: give e.g. 0,21,9, "
                f"or a named set ({', '.join(SEED_SETS)})"
            )
        if len(item) > 10 or int(item) > MAX_SEED:
            raise GridError(f"--seeds '{text}': seed {item[:24]} is too large: seeds go from 0 to {MAX_SEED}")
        value = int(item)
        if value in seeds:
            raise GridError(f"--seeds '{text}': seed {value} is given twice")
        seeds.append(value)
    return tuple(seeds)


def resolve_grid(
    *,
    preset: str | None,
    regimes: Sequence[str],
    algos: Sequence[str],
    seeds: str | None = None,
    episodes: int | None = None,
    eval_episodes: int | None = None,
) -> Grid:
    """The grid of ``preset`` (default :data:`DEFAULT_PRESET`) with the explicitly given
    fields replacing the preset's. ``regimes`` and ``algos`` are already-validated names."""
    name = preset or DEFAULT_PRESET
    if name not in PRESETS:
        raise GridError(f"unknown --preset '{name}': use one of {', '.join(PRESETS)}")
    base = PRESETS[name]
    grid = Grid(
        regimes=tuple(regimes),
        algos=tuple(algos),
        seeds=parse_seeds(seeds) if seeds is not None else base.seeds,
        episodes=base.episodes if episodes is None else episodes,
        eval_episodes=base.eval_episodes if eval_episodes is None else eval_episodes,
    )
    for option, value in (("--days", grid.episodes), ("--eval-episodes", grid.eval_episodes)):
        what = "training budget" if option == "--days" else "evaluation"
        if value < 1:
            raise GridError(f"{option} {value}: the {what} must be at least 1 episode (a day)")
        if value > MAX_EPISODES:
            raise GridError(f"{option} {str(value)[:24]}: too large: give at most {MAX_EPISODES} episodes")
    if not grid.regimes or not grid.algos:
        raise GridError("the grid is empty: give at least one regime and one algorithm")
    return grid
