"""The committed tuning studies (reports/tuned/, protocol v1, and reports/tuned_v2/) resume
from their databases unchanged by the code that came after them: the same command with each
study's stored settings opens it (no "created with other settings"), counts its finished trials
and, asked for no more than it holds, trains nothing and writes nothing to its settings (a
setting added since, such as the sampler's constant liar, is not stamped onto an old study)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import optuna
import pytest
from typer.testing import CliRunner

from nutribench.cli import app

REPO = Path(__file__).resolve().parents[1]
DATABASES = [REPO / "reports" / "tuned" / "data" / "tuning.db", REPO / "reports" / "tuned_v2" / "data" / "tuning.db"]


def _read_only(db: Path) -> sqlite3.Connection:
    """The committed file opened immutable: nothing written beside it (no -wal or -shm files,
    which a WAL-mode database otherwise gets even when opened read-only)."""
    return sqlite3.connect(f"file:{db}?mode=ro&immutable=1", uri=True)


def _studies() -> list[tuple[Path, str]]:
    out = []
    for db in DATABASES:
        with _read_only(db) as conn:
            out += [(db, name) for (name,) in conn.execute("SELECT study_name FROM studies ORDER BY study_id")]
    return out


@pytest.mark.parametrize(("db", "name"), _studies(), ids=lambda v: v if isinstance(v, str) else v.parent.parent.name)
def test_a_committed_study_resumes_unchanged(tmp_path: Path, db: Path, name: str) -> None:
    copy = tmp_path / "tuning.db"
    with _read_only(db) as src, sqlite3.connect(copy) as dst:
        src.backup(dst)  # as committed (a backup copy)
    before = sorted(p.name for p in db.parent.iterdir())
    study = optuna.load_study(study_name=name, storage=f"sqlite:///{copy}")
    attr = dict(study.user_attrs["nutribench"])
    states = [t.state.name for t in study.trials]
    if "RUNNING" in states:  # a study still under way: its driver's rerun would retry those; opening it is checked
        from nutribench.tuning.study import open_study, stored_settings

        open_study(f"sqlite:///{copy}", name, stored_settings(study))  # no "created with other settings"
        after = optuna.load_study(study_name=name, storage=f"sqlite:///{copy}")
        assert dict(after.user_attrs["nutribench"]) == attr and [t.state.name for t in after.trials] == states
        return
    finished = states.count("COMPLETE") + states.count("PRUNED")
    args = [
        "tune", "--space", attr["space"], "--study", name, "--db", str(copy), "--trials", str(max(finished, 1)),
        "--regimes", ",".join(attr["regimes"]), "--seeds", ",".join(map(str, attr["seeds"])),
        "--days", str(attr["days"]), "--eval-every", str(attr["eval_every"]),
        "--val-episodes", str(attr["val_episodes"]), "--sampler-seed", str(attr["sampler_seed"]),
        "--pruner", attr["pruner"], "--startup-trials", str(attr.get("startup_trials", 5)),
        "--objective", attr.get("objective", "last"),
    ]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert f"holds {finished} finished trials" in res.output, res.output
    after = optuna.load_study(study_name=name, storage=f"sqlite:///{copy}")
    assert dict(after.user_attrs["nutribench"]) == attr
    assert [t.state.name for t in after.trials] == states
    assert sorted(p.name for p in db.parent.iterdir()) == before  # nothing written beside the committed file
