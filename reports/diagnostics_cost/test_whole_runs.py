"""reports/diagnostics_cost/whole_runs.py (once ``bench train --diagnostics-cost``): three arms
per repeat in every order, the cost and the A/A control paired repeat by repeat, and the
table. This study's own check: ``python -m pytest -p no:cacheprovider reports/diagnostics_cost``."""

from __future__ import annotations

import re

import pytest
from report_scripts import load_script

W = load_script("diagnostics_cost", "whole_runs")
ORDERS = W.ORDERS


def test_three_arms_in_every_order(monkeypatch):
    """Each repeat trains with, without and again without the diagnostics; 6 repeats take the
    6 orders, so each arm runs before each other 3 times; the cost pairs with/without and the
    A/A control without/again, repeat by repeat."""
    from nutribench.agents import api

    calls: list[bool] = []
    now = [0.0]

    def fake_train(*a, diagnostics=True, **k):  # a run with the diagnostics takes 1.1 s, without 1 s
        calls.append(diagnostics)
        now[0] += 1.1 if diagnostics else 1.0

    monkeypatch.setattr(api, "train", fake_train)
    monkeypatch.setattr(W.time, "perf_counter", lambda: now[0])
    [row] = W.bench_diagnostics_cost(["mc"], episodes=1, repeats=6)
    timed = calls[1:]  # after the untimed warm-up
    firsts = [timed[3 * r : 3 * r + 3].index(True) for r in range(6)]
    assert sorted(firsts) == [0, 0, 1, 1, 2, 2]  # "with" first, second and third twice each
    for a, b in [(0, 1), (0, 2), (1, 2)]:  # each arm before each other in half of the 6 orders
        assert sum(o.index(a) < o.index(b) for o in ORDERS) == 3
    assert row["diagnostics_cost"] == pytest.approx(1 - 1 / 1.1)  # 9.1 %
    assert row["aa_cost"] == pytest.approx(0.0)


def test_the_script_reports_the_cost_with_its_interval(capsys):
    assert W.main(["--algos", "mc", "--days", "2", "--repeats", "2"]) == 0
    out = " ".join(capsys.readouterr().out.split())  # rich wraps the table's cells
    assert "cost" in out and "A/A" in out
    assert len(re.findall(r"[+-]\d+\.\d %", out)) >= 2  # the cost's cell and the A/A control's
    assert re.search(r"\[[+-]\d+\.\d,", out)
    assert W.main(["--algos", "mc", "--days", "0"]) == 2
    assert capsys.readouterr().err.strip() == "whole_runs.py: --days and --repeats: 1 or more"
