"""The paired statistics of the timing benches (:mod:`nutribench.bench.paired`): the orders
of three arms with no arm twice in a row, and the share of the total time. (The benches that
use them, lockstep and whole runs, are reports/diagnostics_cost's; they are checked there.)"""

from __future__ import annotations

import itertools

import pytest

from nutribench.bench.paired import ORDERS, seamless_orders


def test_orders_never_run_an_arm_twice_in_a_row():
    """Across a round's end (the last round wrapping to the first) no arm runs twice in a row:
    lexicographic order would let two arms, never the third, run back to back with warm caches."""
    for n in (3, 4):
        orders = seamless_orders(n)
        assert sorted(orders) == sorted(itertools.permutations(range(n)))
        assert all(orders[i - 1][-1] != orders[i][0] for i in range(len(orders)))
    assert ORDERS == seamless_orders(3)
    # each arm first, second and last twice in 6 rounds
    assert all(sorted(o.index(a) for o in ORDERS) == [0, 0, 1, 1, 2, 2] for a in range(3))
    lexicographic = list(itertools.permutations(range(3)))
    assert sum(lexicographic[i - 1][-1] == lexicographic[i][0] for i in range(6)) == 2  # what it fixes


def test_total_cost_weighs_each_block_by_its_length():
    """Two short blocks 10 % faster without, one long block equal: the share of the total time
    is 0.2 / 12, where the median of the blocks' ratios would say 10 %."""
    from nutribench.bench.paired import paired_cost, total_cost

    cost, lo, hi = total_cost([1.0, 1.0, 10.0], [0.9, 0.9, 10.0])
    assert cost == pytest.approx(0.2 / 12) and lo <= cost <= hi
    assert paired_cost([1.0, 1.0, 10.0], [0.9, 0.9, 10.0])[0] == pytest.approx(0.1)
