"""reports/diagnostics_cost/lockstep.py (once ``bench train --diagnostics-cost --lockstep``): arms
trained side by side, a day each in turn. This study's own check:
``python -m pytest -p no:cacheprovider reports/diagnostics_cost``."""

from __future__ import annotations

import itertools
import random
import re
import threading
import types

import numpy as np
import pytest
import torch as th
from report_scripts import load_script

L = load_script("diagnostics_cost", "lockstep")
ORDERS = L.ORDERS


def fake_clock(monkeypatch) -> list[float]:
    """A wall clock that the runs move by hand, and a CPU clock at 90 % of it."""
    now = [0.0]
    monkeypatch.setattr(L, "time", types.SimpleNamespace(perf_counter=lambda: now[0], thread_time=lambda: 0.9 * now[0]))
    return now


def test_rounds_take_the_six_orders_and_pair_segment_by_segment(monkeypatch):
    """Each round runs every arm once, round r in ORDERS[r % 6]; a day "with" takes 1.1 s, one
    without 1 s: the cost is 1 - 1/1.1 in every block, the A/A control 0."""
    now = fake_clock(monkeypatch)
    log: list[str] = []

    def run(name: str, seconds: float, days: int = 12):
        def go(day_end):
            for d in range(days):
                log.append(name)
                now[0] += seconds
                day_end({"return": float(d)})
            log.append(name)  # after the last day: the run's end
            now[0] += seconds

        return go

    arms = L.lockstep({"with": run("with", 1.1), "without": run("without", 1.0), "again": run("again", 1.0)})
    names = ["with", "without", "again"]
    assert [len(a.wall) for a in arms] == [13, 13, 13] and [len(a.days) for a in arms] == [12, 12, 12]
    rounds = [log[3 * r : 3 * r + 3] for r in range(13)]
    assert rounds == [[names[k] for k in ORDERS[r % 6]] for r in range(13)]
    assert arms[0].wall == pytest.approx([1.1] * 13) and arms[2].cpu == pytest.approx([0.9] * 13)
    assert L.same_days(arms[0], arms[1])
    c = L.lockstep_cost(*arms, size=5, clock="cpu")
    assert c["blocks"] == 3  # 5 + 5 + 3 segments
    assert c["cost"] == pytest.approx(1 - 1 / 1.1) and c["cost_ci"] == pytest.approx((1 - 1 / 1.1,) * 2)
    assert c["aa"] == pytest.approx(0.0) and c["median_cost"] == pytest.approx(1 - 1 / 1.1)
    assert list(L.blocks([1, 2, 3, 4, 5], 2)) == [3, 7, 5]


def test_an_arm_that_ends_early_sits_out_and_days_that_differ_are_seen(monkeypatch):
    fake_clock(monkeypatch)

    def run(days: int, offset: float = 0.0):
        return lambda day_end: [day_end({"return": d + offset}) for d in range(days)]

    short, long_ = L.lockstep({"short": run(2), "long": run(5, offset=0.5)})
    assert (len(short.wall), len(long_.wall)) == (3, 6)
    assert not L.same_days(short, long_)


def test_each_arm_draws_the_random_numbers_it_would_draw_alone():
    """Python's, NumPy's and torch's global generators are the arm's own while it runs, and
    each arm starts from the caller's state (draws before any seeding included)."""

    def draws(day_end=None) -> list:
        out = [(random.random(), float(np.random.rand()), float(th.rand(1)))]  # the caller's state
        random.seed(7), np.random.seed(7), th.manual_seed(7)
        for _ in range(4):
            out.append((random.random(), float(np.random.rand()), float(th.rand(1))))
            if day_end is not None:
                day_end({"return": 0.0})
        return out

    state = (random.getstate(), np.random.get_state(), th.get_rng_state())
    alone = draws()
    random.setstate(state[0]), np.random.set_state(state[1]), th.set_rng_state(state[2])
    seen: dict[str, list] = {}

    def arm(name: str):
        def go(day_end):
            seen[name] = draws(day_end)

        return go

    before = np.random.get_state()[1].copy()
    L.lockstep({"a": arm("a"), "b": arm("b"), "c": arm("c")})
    assert seen["a"] == seen["b"] == seen["c"] == alone
    assert (np.random.get_state()[1] == before).all()  # the caller's state is given back


@pytest.mark.parametrize("broken_after", [0, 1])
def test_an_error_in_one_arm_stops_every_arm_and_is_raised(broken_after, monkeypatch):
    """An arm that fails (in its first segment, or later) stops the others at their next day's
    end, not at their run's: the error is raised, and every arm's thread has ended."""
    days: dict[str, int] = {"a": 0, "c": 0}

    def ok(name: str):
        def go(day_end):
            for _ in range(10):
                days[name] += 1
                day_end({"return": 0.0})

        return go

    def bad(day_end):
        for _ in range(broken_after):
            day_end({"return": 0.0})
        raise ValueError("arm b broke")

    n = threading.active_count()
    with pytest.raises(ValueError, match="arm b broke"):
        L.lockstep({"a": ok("a"), "b": bad, "c": ok("c")})
    assert threading.active_count() == n
    assert max(days.values()) <= broken_after + 2 < 10


@pytest.mark.parametrize("algo, days, blocks", [("mc", 3, 2), ("ppo", 11, 6)])  # PPO: one update after day 10
def test_bench_lockstep_trains_the_same_days_in_every_arm(algo, days, blocks):
    [row] = L.bench_diagnostics_lockstep([algo], episodes=days, block=2)
    assert row["identical"] and row["days"] == days
    assert row["wall"]["blocks"] == blocks and row["cpu"]["blocks"] == blocks  # days + 1 segments
    assert row["steps_per_s"] > 0 and -1 < row["cpu"]["cost"] < 1


def test_the_script_prints_the_table_and_refuses_bad_input_in_one_line(capsys):
    assert L.main(["--algos", "mc", "--days", "2", "--block", "1"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "lockstep" in out and "mc: 3 blocks; the three arms trained the same days: yes" in out
    assert len(re.findall(r"[+-]\d+\.\d %", out)) == 6  # cost, A/A and median ratio on both clocks
    assert L.main(["--algos", "nope"]) == 2
    assert capsys.readouterr().err.startswith("lockstep.py: unknown algorithm 'nope'")


def test_orders_never_run_an_arm_twice_in_a_row():
    """Across a round's end (the last round wrapping to the first) no arm runs twice in a row:
    lexicographic order would let two arms, never the third, run back to back with warm caches."""
    for n in (3, 4):
        orders = L.seamless_orders(n)
        assert sorted(orders) == sorted(itertools.permutations(range(n)))
        assert all(orders[i - 1][-1] != orders[i][0] for i in range(len(orders)))
    assert ORDERS == L.seamless_orders(3)
    # each arm first, second and last twice in 6 rounds
    assert all(sorted(o.index(a) for o in ORDERS) == [0, 0, 1, 1, 2, 2] for a in range(3))
    lexicographic = list(itertools.permutations(range(3)))
    assert sum(lexicographic[i - 1][-1] == lexicographic[i][0] for i in range(6)) == 2  # what it fixes
