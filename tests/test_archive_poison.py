"""Issue 52, a leaderboard that cannot be poisoned: archives forged so that every check of
``db import`` before it passed (hashes recomputed, every step replayable) are refused, in one
line, exit status 2, nothing written; in ``leaderboard --archives`` a refused archive is listed
with its reason and the others are ranked.

* a regime (or its reward) with a shipped name and version but other content (other reward
  weights: the forged days were played on it, so they replay);
* evaluation days that are not the job seed's test days (easier ones, played for real);
* a zip with a member twice (a forged copy first, the genuine last);
* ``leaderboard --reps 1000000000000`` (a MemoryError);
* a NUL byte in a job's error text or a config's description (PostgreSQL's DataError).
"""

from __future__ import annotations

import io
import json
import shutil
import sqlite3
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from nutribench.config.loading import content_sha256, load_env_config, regimes_dir
from nutribench.store.archive import verify_archive
from nutribench.store.engine import StoreError
from tests.conftest import one_error_line

runner = CliRunner()


def _record(db: Path, name: str, regime: str = "run0", seeds=(0,)) -> None:
    """A recorded agent (real jobs, one evaluation day each): eats for its first 3 steps."""
    for seed in seeds:
        with nutribench.Recorder(db=db, name=name, regime=regime, seed=seed, eval_episodes=1) as rec:
            rec.env.reset()
            for t in range(50):
                rec.env.step(int(t < 3))
            rec.evaluate(lambda obs: int(obs[:3].sum() < 1.0))


def _export(db: Path, out: Path, *args: str) -> Path:
    res = runner.invoke(app, ["db", "export", str(out), "--db", str(db), *args])
    assert res.exit_code == 0, res.output
    return out


def _forged_regimes(tmp: Path, rename_run0: str | None = None) -> Path:
    """A copy of the installed regimes whose reward keeps its name and version (reward v2) but
    weighs progress 5 times as much; with ``rename_run0``, run0 is copied under that name."""
    folder = tmp / "forged_regimes"
    shutil.copytree(regimes_dir(), folder)
    reward = folder / "reward.toml"
    text = reward.read_text()
    lines = [("lp = 5.0" if ln.split("=")[0].strip() == "lp" else ln) for ln in text.splitlines()]
    assert lines != text.splitlines()
    reward.write_text("\n".join(lines) + "\n")
    if rename_run0:
        src = (folder / "run0.toml").read_text().replace('name = "run0"', f'name = "{rename_run0}"')
        (folder / f"{rename_run0}.toml").write_text(src)
    return folder


@pytest.fixture(scope="module")
def genuine(tmp_path_factory) -> Path:
    """An archive of a recorded agent on the installed run0, seeds 0 and 21."""
    folder = tmp_path_factory.mktemp("genuine")
    _record(folder / "g.db", "eat_early", seeds=(0, 21))
    return _export(folder / "g.db", folder / "eat_early.npz")


@pytest.fixture(scope="module")
def poison(tmp_path_factory) -> Path:
    """An archive played, for real, on a run0 v2 whose reward has other weights: its hashes are
    right and every step replays on the regime it carries."""
    folder = tmp_path_factory.mktemp("poison")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NUTRIBENCH_REGIMES", str(_forged_regimes(folder)))
        _record(folder / "p.db", "poison", seeds=(0, 21))
        return _export(folder / "p.db", folder / "poison.npz")


def _read(archive: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    with np.load(archive, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return json.loads(arrays.pop("meta").tobytes().decode()), arrays


def _save(path: Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    np.savez(path, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    return path


def _refused(archive: Path, db: Path, *words: str) -> str:
    line = one_error_line(runner.invoke(app, ["db", "import", str(archive), "--db", str(db)]))
    for w in words:
        assert w in line, line
    assert not db.exists()  # nothing written, no database created
    with pytest.raises(StoreError):
        verify_archive(archive)
    return line


# --------------------------------------------------------------------------- 1. regime content
def test_a_regime_with_a_shipped_name_and_version_but_other_content_is_refused(poison: Path, tmp_path: Path):
    meta, _ = _read(poison)
    assert [(r["name"], r["version"]) for r in meta["regimes"]] == [("run0", 2)]  # the shipped name and version
    line = _refused(poison, tmp_path / "x.db", "run0 v2", "other content than the installed regime run0 v2")
    assert "bumps its version" in line


def test_a_shipped_reward_with_other_content_under_another_regime_name_is_refused(tmp_path: Path):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NUTRIBENCH_REGIMES", str(_forged_regimes(tmp_path, rename_run0="myrun")))
        _record(tmp_path / "p.db", "poison", regime="myrun")
        archive = _export(tmp_path / "p.db", tmp_path / "myrun.npz")
    _refused(archive, tmp_path / "x.db", "regime 'myrun' v2's reward 'reward' v2", "installed reward reward v2")


def test_the_leaderboard_refuses_the_forged_archive_and_ranks_the_others(genuine: Path, poison: Path, tmp_path: Path):
    folder = tmp_path / "lb"
    folder.mkdir()
    shutil.copy(poison, folder / "aaa_poison.npz")  # first in the folder: it used to make the genuine one fail
    shutil.copy(genuine, folder / "eat_early.npz")
    res = runner.invoke(app, ["leaderboard", "--archives", str(folder), "--reps", "200", "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    assert "| 1 | eat_early |" in res.output and "| poison |" not in res.output
    refusal = [ln for ln in res.output.splitlines() if ln.startswith("refused: aaa_poison.npz ")]
    assert len(refusal) == 1 and "other content than the installed regime run0 v2" in refusal[0]
    assert (
        "(refused, not ranked: aaa_poison.npz is damaged or was changed: regime 'run0' v2 has other"
        in (tmp_path / "o" / "leaderboard.md").read_text()
    )
    # every archive refused: one line
    (folder / "eat_early.npz").unlink()
    line = one_error_line(runner.invoke(app, ["leaderboard", "--archives", str(folder), "--reps", "200"]))
    assert "every archive was refused" in line and "aaa_poison.npz" in line


def test_archives_that_disagree_on_an_unshipped_config_are_both_refused(genuine: Path, tmp_path: Path):
    """Two archives with the same recorded agent's name and version but other content: which is
    right cannot be told, so neither ranks (whichever file name sorts first used to win)."""
    folder = tmp_path / "lb"
    folder.mkdir()
    meta, arrays = _read(genuine)
    agent = meta["agent_configs"][0]
    agent["body"]["params"] = {"forged": 1}
    agent["sha256"] = content_sha256(agent["body"])
    _save(folder / "aaa.npz", meta, arrays)
    shutil.copy(genuine, folder / "eat_early.npz")
    _record(tmp_path / "o.db", "other")
    _export(tmp_path / "o.db", folder / "other.npz")
    res = runner.invoke(app, ["leaderboard", "--archives", str(folder), "--reps", "200"])
    assert res.exit_code == 0, res.output
    assert "| 1 | other |" in res.output and "| eat_early |" not in res.output
    for name in ("aaa.npz", "eat_early.npz"):
        assert f"refused: {name}: its agent config eat_early v1 has other content in" in res.output


def test_a_database_with_a_forged_regime_is_not_scored_on_the_installed_yardsticks(tmp_path: Path):
    db = tmp_path / "lab.db"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NUTRIBENCH_REGIMES", str(_forged_regimes(tmp_path)))
        _record(db, "poison")
    res = runner.invoke(app, ["leaderboard", "--db", str(db), "--reps", "200"])
    assert res.exit_code == 0, res.output
    assert "| poison | n/a |" in " ".join(res.output.split()).replace("| | poison", "| poison")
    assert "run0 v2 of this database has other content than the installed regime file" in " ".join(res.output.split())


# --------------------------------------------------------------------------- 2. the test days
def test_evaluation_days_that_are_not_the_seeds_test_days_are_refused(tmp_path: Path):
    """The agent played, for real, easier days than its seed's (every food the first one):
    every step replays, the foods are not the test days."""
    import nutribench.agents.api as api
    import nutribench.agents.days as days

    def easy(regime, job_seed, n=5):
        cfg = load_env_config(regime)
        return np.zeros((n, cfg.reward.horizon), dtype=np.int64)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(api, "eval_food_streams", easy)
        mp.setattr(days, "eval_food_streams", easy)
        _record(tmp_path / "e.db", "easy", seeds=(21,))
        archive = _export(tmp_path / "e.db", tmp_path / "easy.npz")
    _refused(archive, tmp_path / "x.db", "evaluation day 0", "not the test day 0 of seed 21")


def test_genuine_archives_pass(genuine: Path):
    assert verify_archive(genuine)["jobs"] == 2


# --------------------------------------------------------------------------- 3. a member twice
def test_a_zip_with_a_member_twice_is_refused(genuine: Path, tmp_path: Path):
    meta, _ = _read(genuine)
    meta["source"] = "forged"
    forged = io.BytesIO()
    np.lib.format.write_array(forged, np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
    out = tmp_path / "twice.npz"
    with (
        zipfile.ZipFile(genuine) as src,
        zipfile.ZipFile(out, "w") as dst,
        pytest.warns(UserWarning, match="Duplicate"),
    ):
        dst.writestr("meta.npy", forged.getvalue())  # the forged copy first, the genuine last
        for info in src.infolist():
            dst.writestr(info, src.read(info))
    assert zipfile.ZipFile(out).namelist().count("meta.npy") == 2
    _refused(out, tmp_path / "x.db", "member 'meta.npy' is there twice")


# --------------------------------------------------------------------------- 4. --reps
@pytest.mark.parametrize("reps", ["1000000000000", "99", "-5"])
def test_leaderboard_reps_out_of_bounds_is_one_line(genuine: Path, tmp_path: Path, reps: str):
    folder = tmp_path / "lb"
    folder.mkdir()
    shutil.copy(genuine, folder)
    for args in (["--archives", str(folder)], ["--db", str(tmp_path / "none.db")]):
        line = one_error_line(
            runner.invoke(app, ["leaderboard", *args, "--reps", reps, "--out", str(tmp_path / "out")])
        )
        assert f"--reps {int(reps):,}" in line and "100 to 100,000" in line
    assert not (tmp_path / "out").exists() and not (tmp_path / "none.db").exists()


# --------------------------------------------------------------------------- 5. NUL bytes
@pytest.mark.parametrize("where", ["job error", "agent description", "regime body"])
def test_a_nul_byte_in_a_text_is_refused_naming_the_field(genuine: Path, tmp_path: Path, where: str):
    meta, arrays = _read(genuine)
    if where == "job error":
        meta["jobs"][0]["error"] = "boom\x00 and more"
        words = ("job 0", "error holds a NUL byte (character 4)")
    elif where == "agent description":
        agent = meta["agent_configs"][0]
        agent["body"]["description"] = "mine\x00"
        agent["sha256"] = content_sha256(agent["body"])
        words = ("agent config 0", "body holds a NUL byte ('description' character 4)")
    else:
        regime = meta["regimes"][0]
        regime["body"]["regime"]["description"] = "\x00"
        regime["sha256"] = content_sha256(regime["body"])
        words = ("regime 0", "body holds a NUL byte ('regime' 'description' character 0)")
    archive = _save(tmp_path / "nul.npz", meta, arrays)
    _refused(archive, tmp_path / "x.db", *words)
    # an existing SQLite database is left as it was
    db = tmp_path / "have.db"
    _record(db, "mine_already")
    before = sqlite3.connect(db).execute("SELECT count(*) FROM jobs").fetchone()
    one_error_line(runner.invoke(app, ["db", "import", str(archive), "--db", str(db)]))
    assert sqlite3.connect(db).execute("SELECT count(*) FROM jobs").fetchone() == before


# --------------------------------------------------------------------------- 6. what was checked
def test_every_entry_says_it_was_replayed_not_re_run(genuine: Path, tmp_path: Path):
    folder = tmp_path / "lb"
    folder.mkdir()
    shutil.copy(genuine, folder)
    res = runner.invoke(app, ["leaderboard", "--archives", str(folder), "--reps", "200", "--format", "csv"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    header = next(k for k, ln in enumerate(lines) if ln.startswith("rank,"))
    header, row = lines[header], lines[header + 1]
    assert "checked" in header.split(",") and "replayed, not re-run" in row


@pytest.mark.parametrize("edit", ["settings", "description"])
def test_a_builtin_agent_config_with_its_shipped_version_keeps_the_shipped_settings(tmp_path: Path, edit: str):
    """mc v3 (shipped) with another learning rate, its hash recomputed: refused; with only
    another description (prose): imported, as the leaderboard calls it the paper config."""
    from nutribench.scheduler.driver import GridSettings, run_grid
    from nutribench.scheduler.synthetic import synthetic_job

    run_grid(
        GridSettings(
            tmp_path / "s.db",
            ["run0"],
            ["mc"],
            [0],
            2,
            1,
            job_fn=synthetic_job,
            models_dir=tmp_path / "m",
            display=False,
        )
    )
    meta, arrays = _read(_export(tmp_path / "s.db", tmp_path / "mc.npz"))
    agent = meta["agent_configs"][0]
    assert (agent["name"], agent["version"]) == ("mc", 3)
    if edit == "settings":
        agent["body"]["learning_rate"] = 0.5
    else:
        agent["body"]["description"] += " (edited)"
    agent["sha256"] = content_sha256(agent["body"])
    archive = _save(tmp_path / "edited.npz", meta, arrays)
    if edit == "settings":
        _refused(archive, tmp_path / "x.db", "agent config 'mc' v3 has other settings than the installed")
    else:
        assert verify_archive(archive)["jobs"] == 1
