"""docs/leaderboard.md, run as a newcomer runs it: every bash and Python block in order, from
an empty folder, at a tiny budget (two training days, two regimes, two of the paper's
archives and one tuned one), and the leaderboard ranks the QRDQN plug-in and the recorded loop beside the
imported baselines, flagging their shorter budget."""

from __future__ import annotations

import csv
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_own_agent import _blocks

REPO = Path(__file__).resolve().parents[1]
GUIDE = REPO / "docs" / "leaderboard.md"
#: What makes the guide's flow tiny: the text the page shows -> what the test runs.
TINY = {
    '"$PAPER_DATA"/*.npz': '"$PAPER_DATA"/{mc,gru_ppo}.npz',  # two of the six archives
    '"$TUNED_DATA"/{mc,ppo,ddqn,gru_ppo,sac}_tuned_v2.npz': '"$TUNED_DATA"/ppo_tuned_v2.npz',  # one tuned
    "--regimes all": "--regimes run0,run3",
    "--days 5000": "--days 2",
    "--days 500 --val-episodes 5 --trials 8": "--days 2 --val-episodes 1 --trials 2",
    "DAYS = 5000": "DAYS = 2",
    'REGIMES = [f"run{i}" for i in range(7)]': 'REGIMES = ["run0", "run3"]',
}


def tiny(code: str) -> str:
    for shown, run in TINY.items():
        code = code.replace(shown, run)
    return code


def test_the_guide_is_made_tiny_by_substitutions_that_match():
    text = GUIDE.read_text()
    assert all(shown in text for shown in TINY), [s for s in TINY if s not in text]
    langs = [lang for lang, _ in _blocks(text)]
    assert langs.count("bash") >= 4 and langs.count("python") == 1


@pytest.mark.slow  # three archives imported (twice), 10 plug-in jobs, 10 recorded jobs, a report: a few minutes
def test_the_guide_ranks_a_plugin_and_a_recorded_loop_beside_the_imported_baselines(tmp_path: Path):
    pytest.importorskip("sb3_contrib")
    env = dict(os.environ, PYTHONPATH=str(REPO), PAPER_DATA=str(REPO / "reports" / "paper" / "data"))
    env["TUNED_DATA"] = str(REPO / "reports" / "tuned_v2" / "data")
    for key in ("NUTRIBENCH_JOB", "NUTRIBENCH_DB", "NUTRIBENCH_AGENTS"):
        env.pop(key, None)
    outputs = []
    for k, (lang, code) in enumerate(_blocks(GUIDE.read_text())):
        cwd = tmp_path if k == 0 else tmp_path / "my-board"
        code = tiny(code)
        if lang == "python":
            (cwd / "reinforce.py").write_text(code)  # the page says: save this as reinforce.py
            continue
        script = re.sub(r"(?<![\w/.-])python ", f"{sys.executable} ", code)
        script = re.sub(r"(?<![\w/.-])nutribench ", f"{sys.executable} -m nutribench.cli ", script)
        res = subprocess.run(
            ["bash", "-euo", "pipefail", "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=900
        )
        assert res.returncode == 0, f"block {k}:\n{script}\n{res.stdout}\n{res.stderr}"
        outputs.append(res.stdout)
    board = tmp_path / "my-board"
    rows = {
        r["algo"]: r for r in csv.DictReader(io.StringIO((board / "reports" / "board" / "leaderboard.csv").read_text()))
    }
    # the references above the planner, unranked under the agents (regimes/references.csv: the paper's seeds)
    for ref in ("lookahead", "clairvoyant"):
        assert rows.pop(ref)["rank"] == "" and rows  # they follow the agents
    assert {"mc", "gru_ppo", "ppo_tuned_v2", "qrdqn_mine", "qrdqn_mine_tuned", "reinforce_loop"} == set(rows)
    for mine in ("qrdqn_mine", "qrdqn_mine_tuned", "reinforce_loop"):
        assert rows[mine]["budget"] == "2" and "budget 2 days (reference 5000)" in rows[mine]["flags"]
        assert rows[mine]["seeds"] == "0 9 21 1997 2003" and "seeds" not in rows[mine]["flags"]  # --seeds paper
        assert "ranked on run0, run3 only" in rows[mine]["flags"] and rows[mine]["regimes"] == "2"
    assert rows["qrdqn_mine"]["protocol"] == "plug-in" and rows["reinforce_loop"]["protocol"] == "recorded"
    assert rows["qrdqn_mine_tuned"]["protocol"] == "tuned"  # tuned through the plug-in's own space file
    header = (board / "tuned_agents" / "qrdqn_mine_tuned.toml").read_text()
    assert "each agent scored once, after its last day, on 1 validation day (a plug-in's own loop)" in header
    for base in ("mc", "gru_ppo"):
        assert rows[base]["flags"] == "" and rows[base]["protocol"] == "paper config" and rows[base]["regimes"] == "7"
    assert rows["ppo_tuned_v2"]["flags"] == "" and rows["ppo_tuned_v2"]["protocol"] == "tuned"
    assert rows["ppo_tuned_v2"]["regimes"] == "7"
    assert sorted(int(r["rank"]) for r in rows.values()) == [1, 2, 3, 4, 5, 6]
    # the shared archives, ranked by whoever receives them: the same table
    table = lambda out: [ln for ln in out.splitlines() if ln.startswith("| ")]  # noqa: E731
    assert table(outputs[-1]) == table((board / "reports" / "board" / "leaderboard.md").read_text())
    assert (board / "reports" / "board" / "fig5_aggregate.png").is_file()
