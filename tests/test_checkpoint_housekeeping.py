"""The batched engine's checkpoints folder is kept clean: a killed batch's manifest
(``*.jobs.json``) and checkpoint files are deleted by a run once every job they name is done,
whoever finished those jobs (here the SB3 engine's synthetic job); a manifest naming an
unfinished job, or a job of another database, stays."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pytest

from nutribench.scheduler.driver import GridSettings, run_grid
from nutribench.scheduler.synthetic import synthetic_job
from tests.fake_jobs import Faults

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def regimes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "regimes"
    shutil.copytree(REPO / "regimes", folder)
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(folder))
    monkeypatch.delenv("NUTRIBENCH_AGENTS", raising=False)
    return folder


class FailingJob:
    """The synthetic job, made to fail halfway (the tests' :class:`~tests.fake_jobs.Faults`)."""

    fake = True

    def __call__(self, spec, sink=None):
        return synthetic_job(spec, sink, Faults(fail="*"))


def grid(db: Path, models: Path, seeds=(0, 1), job_fn=synthetic_job):
    return run_grid(
        GridSettings(
            db, ["run0"], ["ppo"], list(seeds), 4, 1, workers=1, job_fn=job_fn, models_dir=models, display=False
        )
    )


def jobs_of(db: Path) -> list[dict]:
    """What a batch's manifest records of each job of ``db`` (as nutribench.scheduler.batched_job writes it)."""
    con = sqlite3.connect(db)
    try:
        rows = con.execute(
            "SELECT jobs.id, agent_configs.sha256, regimes.sha256, jobs.seed, jobs.episodes FROM jobs "
            "JOIN agent_configs ON agent_configs.id = jobs.agent_config_id JOIN regimes ON regimes.id = jobs.regime_id "
            "ORDER BY jobs.id"
        ).fetchall()
    finally:
        con.close()
    keys = ("job_id", "algo_sha256", "regime_sha256", "seed", "episodes")
    return [dict(zip(keys, r)) for r in rows]


def plant(folder: Path, stem: str, manifest: dict) -> list[Path]:
    """A killed batch's leftovers: its manifest, its checkpoint and the checkpoint's sidecar."""
    folder.mkdir(parents=True, exist_ok=True)
    files = [folder / f"{stem}.pt", folder / f"{stem}.pt.state.json", folder / f"{stem}.pt.jobs.json"]
    files[0].write_bytes(b"tensors")
    files[1].write_text("{}")
    files[2].write_text(json.dumps(manifest))
    return files


def test_a_killed_batchs_files_go_once_its_jobs_are_finished_by_another_engine(regimes, tmp_path) -> None:
    db, models = tmp_path / "r.db", tmp_path / "models"
    assert grid(db, models, job_fn=FailingJob()).failed == 2  # the jobs exist, none finished
    jobs = jobs_of(db)
    assert len(jobs) == 2
    folder = models / "checkpoints"
    killed = plant(folder, "ppo-v1-0123456789abcdef", {"job_ids": [j["job_id"] for j in jobs], "jobs": jobs})
    assert grid(db, models, seeds=(0,)).done == 1  # one of its jobs done; the other still failed
    assert all(p.exists() for p in killed), "a manifest naming an unfinished job is kept"
    assert grid(db, models).done == 1  # the other job, by the SB3 engine
    assert not [p for p in killed if p.exists()], sorted(p.name for p in folder.iterdir())


def test_manifests_of_other_databases_and_unreadable_ones_stay(regimes, tmp_path) -> None:
    db, models = tmp_path / "r.db", tmp_path / "models"
    assert grid(db, models).done == 2
    jobs = jobs_of(db)
    folder = models / "checkpoints"
    other_db = [dict(j, algo_sha256="0" * 64) for j in jobs]  # same ids, other jobs: another database's batch
    stays = [
        *plant(folder, "ppo-v1-aaaaaaaaaaaaaaaa", {"job_ids": [j["job_id"] for j in jobs], "jobs": other_db}),
        *plant(folder, "ppo-v1-bbbbbbbbbbbbbbbb", {"job_ids": [1, 999], "jobs": [jobs[0], dict(jobs[1], job_id=999)]}),
        *plant(folder, "ppo-v1-cccccccccccccccc", {"job_ids": "not a list"}),
        *plant(
            folder, "mc-v1-dddddddddddddddd", {"job_ids": [j["job_id"] for j in jobs]}
        ),  # old format, another config
    ]
    con = sqlite3.connect(db)
    (version,) = con.execute("SELECT version FROM agent_configs WHERE name = 'ppo'").fetchone()
    con.close()
    old_format = {"job_ids": [j["job_id"] for j in jobs]}  # an older nutribench's manifest: these jobs, by id
    goes = plant(folder, f"ppo-v{version}-eeeeeeeeeeeeeeee", old_format)
    grid(db, models)  # nothing to run: the housekeeping alone
    assert all(p.exists() for p in stays), [p.name for p in stays if not p.exists()]
    assert not [p for p in goes if p.exists()]
