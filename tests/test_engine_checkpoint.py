"""Checkpoints of the batched engine: a batch stopped mid-way and started again on its
checkpoint ends exactly where an uninterrupted batch ends."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import torch as th

from nutribench.agents.config import load_agent_config
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.train import train_batched

JOBS = [("run0", 3), ("run6", 4)]


class Stopped(Exception):
    """Stands for the process being killed."""


def batch_specs(models, jobs=JOBS, episodes: int = 5, first_id: int = 1):
    """The JobSpecs of a batch of MC jobs whose models go to ``models`` (as ``nutribench run`` makes them)."""
    from nutribench.agents.config import agent_config_sha256
    from nutribench.config import load_env_config
    from nutribench.scheduler.worker import JobSpec

    cfg = load_agent_config("mc")
    out = []
    for i, (regime, seed) in enumerate(jobs):
        r = load_env_config(regime)
        path = models / f"{r.name}-v{r.version}" / f"mc-v{cfg.version}" / f"seed{seed}-ep{episodes}.zip"
        out.append(
            JobSpec(
                first_id + i,
                r.name,
                r.version,
                r.sha256,
                cfg.name,
                cfg.version,
                agent_config_sha256(cfg),
                seed,
                episodes,
                2,
                str(path),
                r,
                cfg,
            )
        )
    return out


def small(algo: str):
    """The agent file, with DDQN's warm-up and target interval shortened so that updates,
    target copies and the epsilon schedule all happen within a few days."""
    cfg = load_agent_config(algo)
    if algo == "ddqn":
        cfg = cfg.model_copy(update=dict(learning_starts=60, target_update_interval=40, buffer_size=300))
    return cfg


def same_agents(a, b) -> None:
    for x, y in zip(a, b, strict=True):
        assert x.train_episodes == y.train_episodes
        sx, sy = x.model.policy.state_dict(), y.model.policy.state_dict()
        assert sx.keys() == sy.keys()
        for key in sx:
            assert th.equal(sx[key], sy[key]), key
        if x.obs_mean is not None:
            np.testing.assert_array_equal(x.obs_mean, y.obs_mean)


@pytest.mark.parametrize(
    "algo,days,stop_day",
    [
        ("mc", 5, 3),
        pytest.param("ppo", 25, 17, marks=pytest.mark.slow),
        pytest.param("gru_ppo", 20, 12, marks=pytest.mark.slow),
        ("ddqn", 8, 5),
        pytest.param("sac", 6, 4, marks=pytest.mark.slow),
    ],
)  # MC and DDQN (one on-policy loop, one off-policy) in the fast run
def test_a_stopped_batch_resumes_from_its_checkpoint_and_ends_as_an_uninterrupted_one(algo, days, stop_day, tmp_path):
    cfg = small(algo)
    whole = train_batched(JOBS, cfg, days)

    def kill(j: int, row: dict) -> None:
        if row["episode"] == stop_day:
            raise Stopped

    path = tmp_path / "batch.pt"
    with pytest.raises(Stopped):
        train_batched(JOBS, cfg, days, on_episode=kill, checkpoint=Checkpoint(path, every_seconds=0))
    checkpoint = Checkpoint(path, every_seconds=0)
    assert checkpoint.state is not None and 0 < checkpoint.state["steps"] <= stop_day * 50
    seen: list[tuple[int, int]] = []
    resumed = train_batched(
        JOBS, cfg, days, on_episode=lambda j, row: seen.append((j, row["episode"])), checkpoint=checkpoint
    )
    same_agents(whole, resumed)
    # the resumed process trained only the days after the checkpoint
    first = checkpoint.state["steps"] // 50
    assert sorted(seen) == [(j, d) for j in range(len(JOBS)) for d in range(first, days)]


def test_a_checkpoint_of_other_jobs_is_refused(tmp_path):
    path = tmp_path / "batch.pt"

    def kill(j: int, row: dict) -> None:
        if row["episode"] == 2:
            raise Stopped

    with pytest.raises(Stopped):
        train_batched(JOBS, "mc", 4, on_episode=kill, checkpoint=Checkpoint(path, every_seconds=0))
    with pytest.raises(ValueError, match="other jobs"):
        train_batched([("run0", 3), ("run6", 5)], "mc", 4, checkpoint=Checkpoint(path, every_seconds=0))


@pytest.mark.parametrize("tamper", ["a key missing", "a network of another shape"])
def test_a_checkpoint_whose_state_does_not_fit_is_refused_in_one_line_and_the_batch_starts_over(
    tamper, tmp_path, caplog
):
    """A checkpoint that reads (its format, its hash) but whose state does not fit the batch's
    algorithm is refused in one line; the batch trains from the start and ends as a batch
    that found nothing."""
    path = tmp_path / "batch.pt"

    def kill(j: int, row: dict) -> None:
        if row["episode"] == 2:
            raise Stopped

    with pytest.raises(Stopped):
        train_batched(JOBS, "mc", 4, on_episode=kill, checkpoint=Checkpoint(path, every_seconds=0))
    sidecar = path.with_name("batch.pt.state.json")
    meta = json.loads(sidecar.read_text())
    if tamper == "a key missing":
        del meta["state"]["start_of_day"]
    else:
        meta["state"]["params"] = meta["state"]["params"][:-2]
    sidecar.write_text(json.dumps(meta))
    caplog.clear()
    again = train_batched(JOBS, "mc", 4, checkpoint=Checkpoint(path, every_seconds=0))
    err = [r.getMessage() for r in caplog.records if "checkpoint" in r.getMessage()]
    assert len(err) == 1 and "checkpoint refused (its state does not fit this batch" in err[0], err
    same_agents(train_batched(JOBS, "mc", 4), again)


def test_an_unreadable_checkpoint_is_refused_in_one_line(tmp_path, caplog):
    path = tmp_path / "batch.pt"
    path.write_bytes(b"not a checkpoint")
    checkpoint = Checkpoint(path)
    assert checkpoint.state is None
    (record,) = caplog.records
    err = record.getMessage()
    assert record.levelname == "WARNING" and record.name == "nutribench.engine.checkpoint"
    assert len(err.splitlines()) == 1 and "checkpoint refused" in err and "the batch starts over" in err, err
    checkpoint.remove()
    assert not path.exists()


def test_run_batch_resumes_a_stopped_batch_and_removes_its_checkpoint(tmp_path, monkeypatch):
    """The worker end (``nutribench run --engine batched``): a batch killed mid-way leaves a
    checkpoint beside the models; the batch started again resumes from it, gives the results
    of an uninterrupted batch, and deletes it."""
    from functools import partial

    import nutribench.scheduler.batched_job as batch
    from nutribench.scheduler.worker import JobProgress, JobSpec

    def specs(models: str) -> list[JobSpec]:
        return batch_specs(tmp_path / models)

    whole = batch.run_batch(specs("a"))

    class Killed(JobProgress):
        def episode(self, k_done: int, ret: float | None) -> None:
            if k_done == 2:
                time.sleep(0.5)  # training seconds the checkpoint keeps, for the resumed run's progress
            if k_done == 4:
                raise Stopped

    monkeypatch.setattr(batch, "Checkpoint", partial(Checkpoint, every_seconds=0))
    monkeypatch.setattr(batch, "JobProgress", Killed)
    # one set of specs for both runs: the checkpoint's name hashes the regime files, read anew by each specs()
    b = specs("b")
    with pytest.raises(Stopped):
        batch.run_batch(b)
    files = list((tmp_path / "b" / "checkpoints").glob("mc-v*.pt"))
    assert len(files) == 1 and batch.checkpoint_path(b) == files[0]
    assert batch.checkpoint_path(b[:1]) != files[0]  # another batch: another file
    manifest = batch.manifest(files[0])
    assert json.loads(manifest.read_text())["job_ids"] == [1, 2]
    seen: list[int] = []

    class Counted(JobProgress):
        def episode(self, k_done: int, ret: float | None) -> None:
            seen.append(k_done)
            super().episode(k_done, ret)

    monkeypatch.setattr(batch, "JobProgress", Counted)
    events: list[dict] = []
    before = Checkpoint(files[0]).seconds_before
    t0 = time.perf_counter()
    again = batch.run_batch(b, events.append)
    elapsed = time.perf_counter() - t0
    assert seen and min(seen) > 1  # it resumed: only the days after the checkpoint were trained
    # its progress says from which day it trained, and its training seconds, the killed run's included
    days = [e for e in events if e["kind"] == "episode"]
    assert days and {e["k0"] for e in days} == {min(seen) - 1}
    assert before >= 0.5 and all(before / len(b) <= e["wall"] <= (before + elapsed) / len(b) for e in days)
    assert [r.train for r in again] == [r.train for r in whole]
    assert [r.eval for r in again] == [r.eval for r in whole]
    assert not files[0].exists() and not manifest.exists()
    assert list((tmp_path / "b" / "checkpoints").iterdir()) == []  # nothing left: the JSON half, temporary files


def test_a_batch_that_left_a_checkpoint_is_claimed_first_and_whole(tmp_path):
    from nutribench.scheduler.pools import Pool, checkpointed_first

    folder = tmp_path / "checkpoints"
    folder.mkdir()
    (folder / "sac-v1-a.pt.jobs.json").write_text(json.dumps({"job_ids": [21, 22, 25]}))
    (folder / "sac-v1-b.pt.jobs.json").write_text(json.dumps({"job_ids": [90, 91]}))  # not in this grid
    (folder / "sac-v1-c.pt.jobs.json").write_text("{broken")
    pools = [Pool(list(range(1, 11)), True, 4), Pool(list(range(20, 30)), True, 4), Pool([40])]
    out = checkpointed_first(pools, folder)
    assert [(p.job_ids, p.batched, p.batch_size) for p in out] == [
        ([21, 22, 25], True, 3),
        (list(range(1, 11)), True, 4),
        ([20, 23, 24, 26, 27, 28, 29], True, 4),
        ([40], False, 1),
    ]
    assert checkpointed_first(pools, tmp_path / "none") == pools


# --------------------------------------------------------------------------- no pickle
class Planted:
    """A pickle payload: unpickling it creates ``marker`` (as the audit's ran ``os.system``)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        import os

        return (os.mkdir, (self.marker,))


def plant(path, marker, forged_sidecar: bool) -> None:
    """A hostile checkpoint at ``path``: a pickle (``torch.save`` of an object), and with
    ``forged_sidecar`` a JSON half of the right format naming its hash, so that the reader
    goes as far as ``torch.load`` on it."""
    import hashlib

    path.parent.mkdir(parents=True, exist_ok=True)
    th.save({"model": Planted(marker), "seconds": 1.0}, path)
    if forged_sidecar:
        from nutribench.engine.checkpoint import CHECKPOINT_FORMAT

        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        sidecar = path.with_name(path.name + ".state.json")
        sidecar.write_text(
            json.dumps({"format": CHECKPOINT_FORMAT, "tensors_sha256": digest, "state": {"dict": [], "id": 0}})
        )


@pytest.mark.parametrize("forged_sidecar", [False, True])
def test_a_planted_pickle_checkpoint_never_runs_and_the_batch_completes(tmp_path, caplog, forged_sidecar):
    """A pickle planted in ``<models>/checkpoints/`` under the name the batch reads
    is refused in one line (its code never runs: no marker); the batch trains from the start,
    gives the results of a batch that found nothing, and leaves no checkpoint file behind."""
    import nutribench.scheduler.batched_job as batch

    whole = batch.run_batch(batch_specs(tmp_path / "a"))
    specs = batch_specs(tmp_path / "b")
    path = batch.checkpoint_path(specs)
    marker = tmp_path / "pwned"
    plant(path, marker, forged_sidecar)
    caplog.clear()
    try:
        again = batch.run_batch(specs)
    finally:
        assert not marker.exists(), "the planted pickle ran"
    err = [r.getMessage() for r in caplog.records if "checkpoint" in r.getMessage()]
    assert len(err) == 1 and "checkpoint refused" in err[0] and str(path) in err[0], err
    assert [r.train for r in again] == [r.train for r in whole]
    assert [r.eval for r in again] == [r.eval for r in whole]
    assert list(path.parent.iterdir()) == []


def test_a_checkpoint_naming_a_class_is_refused(tmp_path, caplog):
    """The JSON half is plain data: a crafted one naming a class (here ``os.system``, as the
    older format named the engine's classes) is refused in one line, and nothing is called."""
    import hashlib

    from nutribench.engine.checkpoint import CHECKPOINT_FORMAT

    path = tmp_path / "batch.pt"
    th.save({"t0": th.zeros(2)}, path)
    state = {"seconds": 1.0, "x": {"$object": "system", "attrs": {"command": "touch pwned"}}}
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    path.with_name("batch.pt.state.json").write_text(
        json.dumps({"format": CHECKPOINT_FORMAT, "tensors_sha256": digest, "state": state})
    )
    assert Checkpoint(path).state is None
    err = caplog.text
    assert len(err.splitlines()) == 1 and "unknown node '$object'" in err, err
    assert not (tmp_path / "pwned").exists()


def test_a_checkpoint_of_the_older_format_is_refused_in_one_line(tmp_path, caplog):
    """A checkpoint an older nutribench wrote (its reflective format) is refused: the batch restarts."""
    path = tmp_path / "batch.pt"
    Checkpoint(path).save(steps=1)
    sidecar = path.with_name("batch.pt.state.json")
    meta = json.loads(sidecar.read_text())
    sidecar.write_text(json.dumps({**meta, "format": "nutribench-checkpoint/2"}))
    assert Checkpoint(path).state is None
    err = caplog.text
    assert len(err.splitlines()) == 1 and "is not of format nutribench-checkpoint/3" in err, err


def test_a_checkpoint_is_a_dict_of_tensors_and_json_and_reads_back_what_was_saved(tmp_path):
    """The two halves read without pickle (weights_only, plain JSON) and give back the state
    saved: tensors, arrays of their dtype, an optimiser's state_dict (int keys, tuples) that
    loads and steps as the original, a numpy generator's state that goes on where it was,
    non-finite floats; anything but plain data is not saved."""
    w = th.randn(3, 2, requires_grad=True)
    opt = th.optim.Adam([w], lr=0.01)
    w.sum().backward()
    opt.step()
    rng = np.random.default_rng(7)
    path = tmp_path / "batch.pt"
    days = [np.arange(3), np.arange(3) + 1]
    rows = [{"episode": 0, "return": -1.5, "first_overshoot_step": None}]
    Checkpoint(path).save(
        params=[w],
        optimizer=opt.state_dict(),
        rng=rng.bit_generator.state,
        counts={1: 2, "n": np.int64(3)},
        inf=float("inf"),
        days=days,
        rows=rows,
        pair=(1, "a"),
    )
    tensors = th.load(path, weights_only=True)
    assert isinstance(tensors, dict) and all(isinstance(t, th.Tensor) for t in tensors.values())
    meta = json.loads((tmp_path / "batch.pt.state.json").read_text())
    assert meta["format"].startswith("nutribench-checkpoint/")
    state = Checkpoint(path).state
    w2 = th.zeros(3, 2, requires_grad=True)
    with th.no_grad():
        w2.copy_(state["params"][0])
    opt2 = th.optim.Adam([w2], lr=0.5)
    opt2.load_state_dict(state["optimizer"])
    assert th.equal(w2, w) and opt2.param_groups[0]["lr"] == 0.01 and opt2.param_groups[0]["betas"] == (0.9, 0.999)
    for p, o in ((w, opt), (w2, opt2)):
        o.zero_grad()
        p.pow(2).sum().backward()
        o.step()
    assert th.equal(w2, w)
    again = np.random.Generator(np.random.PCG64())
    again.bit_generator.state = state["rng"]
    assert again.random() == rng.random()
    assert state["counts"] == {1: 2, "n": 3} and state["inf"] == float("inf") and state["pair"] == (1, "a")
    assert [d.tolist() for d in state["days"]] == [[0, 1, 2], [1, 2, 3]] and state["days"][0].dtype == days[0].dtype
    assert state["rows"] == rows
    with pytest.raises(TypeError, match="plain data only"):
        Checkpoint(tmp_path / "other.pt").save(rng=rng)


def test_a_save_killed_between_its_two_renames_is_finished_by_the_next_read(tmp_path, monkeypatch):
    import nutribench.engine.checkpoint as ckpt

    path = tmp_path / "batch.pt"
    Checkpoint(path).save(steps=1, x=np.zeros(3))
    real, calls = ckpt.os.replace, []

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:  # the JSON renamed, the tensors not yet
            raise Stopped
        real(src, dst)

    monkeypatch.setattr(ckpt.os, "replace", replace)
    with pytest.raises(Stopped):
        Checkpoint(path).save(steps=2, x=np.ones(3))
    monkeypatch.setattr(ckpt.os, "replace", real)
    state = Checkpoint(path).state
    assert state["steps"] == 2 and state["x"].tolist() == [1, 1, 1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["batch.pt", "batch.pt.state.json"]


def test_a_save_that_finds_the_disk_full_keeps_the_previous_checkpoint(tmp_path, monkeypatch, caplog):
    import errno

    import nutribench.engine.checkpoint as ckpt

    path = tmp_path / "batch.pt"
    Checkpoint(path).save(steps=1, x=np.zeros(3))

    def full(obj, f, *a, **k):
        open(f, "wb").write(b"PK\x03")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(ckpt.th, "save", full)
    Checkpoint(path).save(steps=2, x=np.ones(3))  # says so, does not raise: training goes on
    assert "checkpoint not saved (OSError: [Errno 28] No space left on device)" in caplog.text
    monkeypatch.undo()
    assert Checkpoint(path).state["steps"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["batch.pt", "batch.pt.state.json"]


def write_manifest(path, specs) -> None:
    """``<checkpoint>.jobs.json`` as run_batch writes it: the job ids, and what each job is."""
    jobs = [
        {
            "job_id": s.job_id,
            "algo_sha256": s.algo_sha256,
            "regime_sha256": s.regime_sha256,
            "seed": s.seed,
            "episodes": s.episodes,
        }
        for s in specs
    ]
    path.with_name(path.name + ".jobs.json").write_text(
        json.dumps({"job_ids": [s.job_id for s in specs], "jobs": jobs})
    )


def test_a_finished_batch_removes_the_checkpoints_other_batches_left_of_its_jobs(tmp_path):
    """A batch killed, then formed otherwise (another code version, other batch sizes),
    would leave its files forever: once its jobs are done, the finished batch deletes them;
    a checkpoint of other jobs stays."""
    import nutribench.scheduler.batched_job as batch

    specs = batch_specs(tmp_path / "m")
    folder = batch.checkpoint_path(specs).parent
    name = f"mc-v{specs[0].algo_version}-"
    # a killed batch of job 2 and job 7 under another name (as another code version names it)
    old = batch_specs(tmp_path / "m", jobs=[("run6", 4), ("run0", 9)], first_id=2)
    old[1] = batch_specs(tmp_path / "m", jobs=[("run0", 9)], first_id=7)[0]
    Checkpoint(folder / f"{name}0ld.pt").save(steps=1)
    write_manifest(folder / f"{name}0ld.pt", old)
    # an older nutribench's manifest (job ids only) of jobs 1 and 8, and a batch of other jobs
    (folder / f"{name}0lder.pt.jobs.json").write_text(json.dumps({"job_ids": [1, 8]}))
    (folder / f"{name}0lder.pt").write_bytes(b"old")
    others = batch_specs(tmp_path / "m", jobs=[("run0", 5), ("run6", 6)], first_id=3)
    Checkpoint(folder / f"{name}0ther.pt").save(steps=1)
    write_manifest(folder / f"{name}0ther.pt", others)
    batch.run_batch(specs)
    assert sorted(p.name for p in folder.iterdir()) == [
        f"{name}0ther.pt",
        f"{name}0ther.pt.jobs.json",
        f"{name}0ther.pt.state.json",
    ]


def test_a_model_save_cut_short_leaves_the_previous_model_whole(tmp_path, monkeypatch):
    """A model file cut short by a full disk is not left in place: each file is written to a
    temporary name and renamed."""
    import errno

    agent = train_batched([("run0", 3)], "mc", 1)[0]
    path = tmp_path / "m" / "seed3-ep1.zip"
    agent.save(path)
    before = {p.name: p.read_bytes() for p in path.parent.iterdir()}
    assert set(before) == {"seed3-ep1.zip", "seed3-ep1.json", "seed3-ep1.vecnormalize.pkl"}

    def full(where, *a, **k):
        with open(where, "wb") as f:
            f.write(b"PK\x03\x04 half a model")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(agent.model, "save", full)
    with pytest.raises(OSError):
        agent.save(path)
    assert {p.name: p.read_bytes() for p in path.parent.iterdir()} == before
    monkeypatch.undo()
    assert type(agent).load(path).algo == "mc"


def test_checkpoint_seconds_from_the_environment(monkeypatch):
    """``$NUTRIBENCH_CHECKPOINT_SECONDS`` sets the seconds between saves; a bad value is one line."""
    from nutribench.engine.checkpoint import DEFAULT_EVERY_SECONDS, every_seconds_from_env

    monkeypatch.delenv("NUTRIBENCH_CHECKPOINT_SECONDS", raising=False)
    assert every_seconds_from_env() == DEFAULT_EVERY_SECONDS
    monkeypatch.setenv("NUTRIBENCH_CHECKPOINT_SECONDS", "60")
    assert every_seconds_from_env() == 60.0
    for bad in ("0", "-5", "soon", "inf", "nan"):
        monkeypatch.setenv("NUTRIBENCH_CHECKPOINT_SECONDS", bad)
        with pytest.raises(ValueError, match="NUTRIBENCH_CHECKPOINT_SECONDS=.*positive number"):
            every_seconds_from_env()


def test_run_refuses_a_bad_checkpoint_interval(tmp_path, monkeypatch):
    """``nutribench run`` says so in one line (exit 2) before the database is made."""
    from typer.testing import CliRunner

    from nutribench.cli import app

    monkeypatch.setenv("NUTRIBENCH_CHECKPOINT_SECONDS", "soon")
    db = tmp_path / "r.db"
    result = CliRunner().invoke(
        app, ["run", "--regimes", "run0", "--algos", "mc", "--seeds", "1", "--episodes", "2", "--db", str(db)]
    )
    assert result.exit_code == 2, result.output
    assert "NUTRIBENCH_CHECKPOINT_SECONDS='soon'" in result.output
    assert not db.exists()


def test_a_checkpoint_saves_as_often_as_the_environment_says(tmp_path, monkeypatch):
    monkeypatch.setenv("NUTRIBENCH_CHECKPOINT_SECONDS", "60")
    assert Checkpoint(tmp_path / "c.pt").every_seconds == 60.0
    assert Checkpoint(tmp_path / "c.pt", every_seconds=0).every_seconds == 0  # a caller's value wins
