"""Issue 52, forged actions: ``nutribench leaderboard --verify MODELS`` re-runs an entry's trained
models (loaded as data) on its jobs' test days and compares them action for action with the
stored evaluation days, so the ``checked`` column tells what was re-run from what was only
replayed. A tiny real run (mc, 2 training days, 2 evaluation days) is verified; the same archive
with its stored actions replaced by the planner's (every step and day recomputed so that the
archive still imports: a forgery replay cannot catch) differs; without its model an entry stays
replayed, not re-run."""

from __future__ import annotations

import json
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from unittest import mock

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.report.leaderboard import REFERENCE_PROTOCOL
from tests.conftest import one_error_line

runner = CliRunner()


def _thread_executor(spec, workers, n_jobs):
    from nutribench.scheduler.executors import ExecutorHandle

    return ExecutorHandle(ThreadPoolExecutor(1), 1, "a thread (test)"), None


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A real run (mc on run0, seed 0, 2 training days, 2 evaluation days): its database
    ``r.db``, its models ``m/`` (as ``run --models-dir`` writes them) and its archive
    ``genuine/mc.npz``."""
    from nutribench.scheduler.driver import GridSettings, run_grid

    lab = tmp_path_factory.mktemp("verify")
    with mock.patch("nutribench.scheduler.driver.make_executor", _thread_executor):
        s = run_grid(GridSettings(lab / "r.db", ["run0"], ["mc"], [0], 2, 2, models_dir=lab / "m", display=False))
    assert s.done == 1, s
    assert (lab / "m" / "run0-v2" / "mc-v3" / "seed0-ep2.zip").is_file()
    (lab / "genuine").mkdir()
    res = runner.invoke(app, ["db", "export", str(lab / "genuine" / "mc.npz"), "--db", str(lab / "r.db")])
    assert res.exit_code == 0, res.output
    return lab


def _planner_forgery(archive: Path, out: Path) -> Path:
    """``archive`` with every evaluation day's actions replaced by the planner's on the same
    foods, and every stored step and day metric recomputed from them (hashes untouched: the
    configs are the genuine ones), so that replay passes."""
    from nutribench.config.loading import load_env_config
    from nutribench.env.metrics import METRIC_KEYS, EpisodeRecorder
    from nutribench.env.policies import PlannerPolicy
    from nutribench.env.vector_env import NutriRLVectorEnv

    with np.load(archive, allow_pickle=False) as z:
        a = {k: z[k].copy() for k in z.files}
    meta = json.loads(a["meta"].tobytes().decode())
    assert len(meta["jobs"]) == 1
    cfg = load_env_config("run0")
    H = cfg.reward.horizon
    order = np.lexsort((a["eval_steps.step"], a["eval_steps.episode"], a["eval_steps.job"]))
    n = len(order) // H
    rows = order.reshape(n, H)
    foods = a["eval_steps.food"][rows]
    venv, planner = NutriRLVectorEnv(n, regime=cfg), PlannerPolicy()
    venv.reset(options={"foods": foods})
    rec, days = EpisodeRecorder(n), []
    for t in range(H):
        act = np.asarray(planner(venv))
        _, r, term, trunc, info = venv.step(act)
        days += rec.record(r, term | trunc, info)
        state = np.asarray(info["state"]).reshape(n, 3)
        a["eval_steps.action"][rows[:, t]] = act
        a["eval_steps.reward"][rows[:, t]] = r
        for k, name in enumerate("CFP"):
            a[f"eval_steps.{name}"][rows[:, t]] = state[:, k]
    ev = np.flatnonzero(a["episodes.phase"] == "eval")
    ev = ev[np.argsort(a["episodes.episode"][ev])]
    for key in METRIC_KEYS:
        vals = [d[key] for d in days]
        if key == "first_overshoot_step":
            null = a.setdefault("episodes.first_overshoot_step.null", np.zeros(len(a["episodes.phase"]), dtype=bool))
            null[ev] = [v is None for v in vals]
            vals = [0 if v is None else v for v in vals]
        a[f"episodes.{key}"][ev] = vals
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **a)
    return out


@pytest.fixture(scope="module")
def forged(trained: Path) -> Path:
    from nutribench.store.archive import verify_archive

    path = _planner_forgery(trained / "genuine" / "mc.npz", trained / "forged" / "mc.npz")
    assert verify_archive(path)["jobs"] == 1  # replay cannot tell: the archive imports
    with np.load(trained / "genuine" / "mc.npz") as g, np.load(path) as f:
        assert (g["eval_steps.action"] != f["eval_steps.action"]).any()  # the planner plays otherwise
        assert f["episodes.return"][f["episodes.phase"] == "eval"].mean() > (
            g["episodes.return"][g["episodes.phase"] == "eval"].mean()
        )
    return path


def _board(*args: str) -> tuple[list[dict[str, str]], str]:
    """The leaderboard's rows (CSV cells by column) and its whole output."""
    import csv

    res = runner.invoke(app, ["leaderboard", *args, "--reps", "200", "--format", "csv"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("rank,"))
    end = next((i for i in range(k + 1, len(lines)) if not lines[i].strip()), len(lines))
    rows = list(csv.DictReader(lines[k:end]))
    return [r for r in rows if r["protocol"] != REFERENCE_PROTOCOL], res.output  # the agents' rows


def _checked(*args: str) -> str:
    """The ``checked`` cell of the leaderboard's single row: ranked first unless its models,
    re-run, do not reproduce its actions (then set apart, without a rank)."""
    rows, output = _board(*args)
    assert len(rows) == 1 and rows[0]["algo"] == "mc", rows
    cell = rows[0]["checked"]
    assert rows[0]["rank"] == ("" if cell.startswith(("re-run: differs", "re-run: failed")) else "1"), rows
    return cell


def test_an_archive_whose_models_are_supplied_is_verified_by_re_running_them(trained: Path):
    assert _checked("--archives", str(trained / "genuine"), "--verify", str(trained / "m")) == "verified (re-run)"
    assert _checked("--db", str(trained / "r.db"), "--verify", str(trained / "m")) == "verified (re-run)"


def test_the_planners_actions_written_into_the_archive_differ_from_the_model(trained: Path, forged: Path):
    cell = _checked("--archives", str(forged.parent), "--verify", str(trained / "m"))
    assert cell.startswith("re-run: differs (run0 x mc seed 0 day "), cell
    assert "stored action" in cell and "the model plays" in cell and "days match" in cell
    # without the model it ranks as before: only replayed
    assert _checked("--archives", str(forged.parent)) == "replayed, not re-run"


def test_without_its_model_an_entry_stays_replayed_not_re_run(trained: Path, tmp_path: Path):
    assert _checked("--archives", str(trained / "genuine")) == "replayed, not re-run"
    (tmp_path / "empty").mkdir()
    assert _checked("--archives", str(trained / "genuine"), "--verify", str(tmp_path / "empty")) == (
        "replayed, not re-run"
    )


def test_a_model_of_another_agent_config_is_not_verified(trained: Path, tmp_path: Path):
    """A sidecar whose agent config is not the entry's (another learning rate): failed, never verified."""
    models = tmp_path / "m"
    shutil.copytree(trained / "m", models)
    side = models / "run0-v2" / "mc-v3" / "seed0-ep2.json"
    data = json.loads(side.read_text())
    data["config"]["learning_rate"] = 0.5
    side.write_text(json.dumps(data))
    cell = _checked("--archives", str(trained / "genuine"), "--verify", str(models))
    assert cell.startswith("re-run: failed (run0 x mc seed 0: seed0-ep2.zip"), cell


def test_verify_needs_a_folder(trained: Path):
    line = one_error_line(
        runner.invoke(app, ["leaderboard", "--db", str(trained / "r.db"), "--verify", str(trained / "r.db")])
    )
    assert "--verify" in line and "not a folder" in line


def test_the_cell_of_an_entry_from_its_jobs():
    from nutribench.report.leaderboard_verify import JobCheck, entry_cell

    ok, missing = JobCheck("a", "match", 5, 5), JobCheck("b", "missing")
    bad = JobCheck("c", "differs", 5, 4, "c day 2 step 7: stored action 1, the model plays 0")
    assert entry_cell([ok, ok]) == "verified (re-run)"
    assert entry_cell([missing, missing]) == "replayed, not re-run"
    assert entry_cell([ok, missing]) == "replayed; re-run on 1 of 2 jobs: match"
    assert entry_cell([ok, bad, missing]) == (
        "re-run: differs (c day 2 step 7: stored action 1, the model plays 0; 9 of 10 days match)"
    )


def test_a_plug_ins_models_are_not_loaded_and_its_entry_says_why(tmp_path: Path):
    """A plug-in's model loads only through its own code, which the leaderboard never imports:
    its job is not re-run (no load tried), and the entry says replayed, not re-run, and why,
    not "re-run: failed"."""
    from nutribench.report.leaderboard_verify import PLUGIN_NOTE, JobCheck, entry_cell, rerun_job

    model = tmp_path / "seed0-ep50.zip"
    model.write_bytes(b"not even a zip: never opened")
    job = {"regime": "run0", "algo": "qrdqn_mine", "seed": 0, "eval_episodes": 2}
    with mock.patch("nutribench.agents.api.TrainedAgent.load", side_effect=AssertionError("loaded")):
        check = rerun_job(model, job, {"plugin": True}, None, None)
    assert check.status == "plugin"
    cell = entry_cell([check, JobCheck("b", "missing")])
    assert cell == "replayed, not re-run" + PLUGIN_NOTE and "evaluate --entry-point" in cell
    assert entry_cell([JobCheck("a", "match", 5, 5), check]) == "replayed; re-run on 1 of 2 jobs: match"


def test_a_forged_row_under_verify_is_set_apart_not_ranked_first(trained: Path, forged: Path, tmp_path: Path):
    """Issue 74: the planner's actions in mc's archive rank it first at 100 %, above a genuine
    entry (a recorded agent's archive); with ``--verify`` its model plays other actions, and the
    row is listed apart, after the ranked ones, without a rank, the reason in its flags and in
    the caption; the genuine entry ranks first."""
    from nutribench.report.leaderboard import leaderboard_from_archives
    from tests.recorded import recorded_archive

    shared = tmp_path / "shared"
    shared.mkdir()
    shutil.copy(forged, shared / "mc.npz")
    _, other = recorded_archive(tmp_path)
    shutil.copy(other, shared / "eat_early.npz")

    def ranks(raw) -> list[tuple[int | None, str]]:  # the agents' rows (lookahead and clairvoyant follow them)
        agents = raw[raw["protocol"] != REFERENCE_PROTOCOL]
        return [(None if pd.isna(r) else int(r), a) for r, a in zip(agents["rank"], agents["algo"])]

    plain = leaderboard_from_archives(shared, reps=200).raw
    assert ranks(plain) == [(1, "mc"), (2, "eat_early")], plain
    assert plain["iqm"][0] > 0.99 > plain["iqm"][1]  # the planner's actions: 100 %

    table = leaderboard_from_archives(shared, reps=200, verify=trained / "m")
    rows = table.raw.to_dict("records")
    assert ranks(table.raw) == [(1, "eat_early"), (None, "mc")], table.raw
    assert rows[1]["checked"].startswith("re-run: differs (run0 x mc seed 0 day "), rows[1]
    assert rows[1]["flags"].startswith("not ranked: its models, re-run, do not reproduce its stored actions"), rows[1]
    assert "MC v3 (2 days) is set apart, not ranked: re-run: differs (run0 x mc seed 0 day " in table.title, table.title
    assert rows[0]["checked"] == "replayed, not re-run" and "not ranked" not in rows[0]["flags"]
    assert table.formatted["rank"].tolist() == [1, "", "", ""]  # the printed table shows no rank either
