"""Checkpoints of the batched engine: a batch stopped mid-way and started again on its
checkpoint ends exactly where an uninterrupted batch ends."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch as th

from nutribench.agents.config import load_agent_config
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.train import train_batched

JOBS = [("run0", 3), ("run6", 4)]


class Stopped(Exception):
    """Stands for the process being killed."""


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


@pytest.mark.parametrize("algo,days,stop_day", [("mc", 5, 3), ("ppo", 25, 17), ("gru_ppo", 20, 12), ("ddqn", 8, 5), ("sac", 6, 4)])
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
    resumed = train_batched(JOBS, cfg, days, on_episode=lambda j, row: seen.append((j, row["episode"])),
                            checkpoint=checkpoint)  # fmt: skip
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


def test_an_unreadable_checkpoint_is_ignored_with_a_warning(tmp_path):
    path = tmp_path / "batch.pt"
    path.write_bytes(b"not a checkpoint")
    with pytest.warns(UserWarning, match="unreadable checkpoint"):
        checkpoint = Checkpoint(path)
    assert checkpoint.state is None
    checkpoint.remove()
    assert not path.exists()


def test_run_batch_resumes_a_stopped_batch_and_removes_its_checkpoint(tmp_path, monkeypatch):
    """The worker end (``nutribench run --engine batched``): a batch killed mid-way leaves a
    checkpoint beside the models; the batch started again resumes from it, gives the results
    of an uninterrupted batch, and deletes it."""
    from functools import partial

    import nutribench.jobs.batch as batch
    from nutribench.agents.config import agent_config_sha256
    from nutribench.config import load_env_config
    from nutribench.jobs.spec import JobSpec
    from nutribench.jobs.worker import JobProgress

    cfg = load_agent_config("mc")

    def specs(models: str) -> list[JobSpec]:
        out = []
        for i, (regime, seed) in enumerate(JOBS):
            r = load_env_config(regime)
            path = tmp_path / models / f"{r.name}-v{r.version}" / f"mc-v{cfg.version}" / f"seed{seed}-ep5.zip"
            out.append(JobSpec(i + 1, r.name, r.version, r.sha256, cfg.name, cfg.version, agent_config_sha256(cfg),
                               seed, 5, 2, str(path), r, cfg))  # fmt: skip
        return out

    whole = batch.run_batch(specs("a"))

    class Killed(JobProgress):
        def episode(self, k_done: int, ret: float | None) -> None:
            if k_done == 4:
                raise Stopped

    monkeypatch.setattr(batch, "Checkpoint", partial(Checkpoint, every_seconds=0))
    monkeypatch.setattr(batch, "JobProgress", Killed)
    with pytest.raises(Stopped):
        batch.run_batch(specs("b"))
    files = list((tmp_path / "b" / "checkpoints").glob("mc-v*.pt"))
    assert len(files) == 1 and batch.checkpoint_path(specs("b")) == files[0]
    assert batch.checkpoint_path(specs("b")[:1]) != files[0]  # another batch: another file
    manifest = batch.manifest(files[0])
    assert json.loads(manifest.read_text()) == {"job_ids": [1, 2]}
    monkeypatch.setattr(batch, "JobProgress", JobProgress)
    again = batch.run_batch(specs("b"))
    assert [r.train for r in again] == [r.train for r in whole]
    assert [r.eval for r in again] == [r.eval for r in whole]
    assert not files[0].exists() and not manifest.exists()


def test_a_batch_that_left_a_checkpoint_is_claimed_first_and_whole(tmp_path):
    from nutribench.scheduler.batching import Pool, checkpointed_first

    folder = tmp_path / "checkpoints"
    folder.mkdir()
    (folder / "sac-v1-a.pt.jobs.json").write_text(json.dumps({"job_ids": [21, 22, 25]}))
    (folder / "sac-v1-b.pt.jobs.json").write_text(json.dumps({"job_ids": [90, 91]}))  # not in this grid
    (folder / "sac-v1-c.pt.jobs.json").write_text("{broken")
    pools = [Pool(list(range(1, 11)), True, 4), Pool(list(range(20, 30)), True, 4), Pool([40])]
    out = checkpointed_first(pools, folder)
    assert [(p.job_ids, p.batched, p.batch_size) for p in out] == [
        ([21, 22, 25], True, 3), (list(range(1, 11)), True, 4), ([20, 23, 24, 26, 27, 28, 29], True, 4), ([40], False, 1)]
    assert checkpointed_first(pools, tmp_path / "none") == pools
