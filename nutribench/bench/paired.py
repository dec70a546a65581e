"""Paired timing: the cost of a change measured from runs timed with and without it.

:func:`paired_cost` is ``bench train --diagnostics-cost``'s statistic, and :data:`ORDERS` the
orders in which it runs its three arms (with, without, without again: the A/A control)."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from nutribench.stats import bootstrap


def seamless_orders(n: int) -> list[tuple[int, ...]]:
    """Every order of ``n`` arms, arranged so that no order starts with the arm that ended the
    one before (the last order wrapping round to the first): no arm ever runs twice in a row,
    in lockstep with warm caches of its own. Lexicographic order has two such seams for 3 arms
    (``(0, 2, 1) -> (1, 0, 2)``, ``(2, 1, 0) -> (0, 1, 2)``). Two arms cannot avoid one; then the
    plain order is returned."""
    perms = list(itertools.permutations(range(n)))

    def extend(path: list[tuple[int, ...]], left: list[tuple[int, ...]]) -> list[tuple[int, ...]] | None:
        if not left:
            return path if path[-1][-1] != path[0][0] else None
        for i, p in enumerate(left):
            if p[0] != path[-1][-1]:
                found = extend(path + [p], left[:i] + left[i + 1 :])
                if found is not None:
                    return found
        return None

    return (extend(perms[:1], perms[1:]) if n > 2 else None) or perms


#: The orders of the three arms of ``bench_train(diagnostics_cost=True)`` (with, without, again)
#: and of its lockstep: 6 rounds put each arm before each other equally often, each arm first,
#: second and last twice, and no arm twice in a row across a round's end.
ORDERS = seamless_orders(3)


def paired_cost(
    with_: Sequence[float], without: Sequence[float], reps: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """The share of time that the difference between paired runs takes: ``1 - median(without /
    with)`` over the pairs, with a 95 % percentile bootstrap interval resampling the pairs
    (``reps`` resamples, ``seed``). An interval wider than the cost asked of the code says the
    machine's noise does not resolve it."""
    ratios = np.asarray(without, dtype=float) / np.asarray(with_, dtype=float)
    point = 1 - float(np.median(ratios))
    boot = bootstrap(lambda r: 1 - np.median(r, axis=1), [ratios], reps, seed)
    return point, float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))


def total_cost(
    with_: Sequence[float], without: Sequence[float], reps: int = 4000, seed: int = 0
) -> tuple[float, float, float]:
    """The share of the total time that the difference takes: ``1 - sum(without) / sum(with)``
    over paired blocks of work, with a 95 % percentile bootstrap interval resampling the pairs
    (``reps`` resamples, ``seed``). The share of a training's time, each block weighted by its
    length (a block with an update counts for more than one without); the blocks' noise should
    be independent of one another (lockstep: a block's arms run within seconds of each other)."""
    w, wo = np.asarray(with_, dtype=float), np.asarray(without, dtype=float)
    point = 1 - float(wo.sum() / w.sum())
    boot = bootstrap(lambda a, b: 1 - b.sum(axis=1) / a.sum(axis=1), [w, wo], reps, seed)
    return point, float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))
