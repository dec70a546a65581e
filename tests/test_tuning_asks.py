"""Issue 51, the cost of ``--stack N``: asking N stacked trials reads the storage in proportion
to N (not N squared), trains no SB3 model for a trial's score, and parses each config file once
(again when it changes)."""

from __future__ import annotations

import re
from pathlib import Path

import optuna
import pytest

from nutribench.agents.config import load_agent_config
from nutribench.config.loading import ConfigError, load_model
from nutribench.config.models import RewardConfig
from nutribench.engine.train import train_batched
from nutribench.tuning.objective import ValidationObjective
from nutribench.tuning.space import load_search_space
from nutribench.tuning.stack import StackedTrials
from nutribench.tuning.study import StudySettings, count_trials, open_study
from tests.conftest import tiny_study_settings


def settings(n_startup: int = 5) -> StudySettings:
    return tiny_study_settings(startup_trials=n_startup)


@pytest.fixture
def rows_read(monkeypatch) -> list[int]:
    """Counts the trials Optuna's RDB storage reads (every trial of every read: ``_get_trials``
    behind its cache, and ``get_trial``); ``rows_read[0]`` is the running total."""
    from optuna.storages import RDBStorage

    count = [0]
    get_trials, get_trial = RDBStorage._get_trials, RDBStorage.get_trial

    def counted_trials(self, *args, **kw):
        out = get_trials(self, *args, **kw)
        count[0] += len(out)
        return out

    def counted_trial(self, *args, **kw):
        count[0] += 1
        return get_trial(self, *args, **kw)

    monkeypatch.setattr(RDBStorage, "_get_trials", counted_trials)
    monkeypatch.setattr(RDBStorage, "get_trial", counted_trial)
    return count


def reads_to_ask(tmp_path: Path, rows_read: list[int], n: int, done: int) -> int:
    """Trials read while one stack of ``n`` is asked, on a study already holding ``done``
    finished trials (past TPE's random start: its model reads them)."""
    db = tmp_path / f"n{n}.db"
    study = open_study(db, "s", settings())
    for _ in range(done):
        trial = study.ask()
        study.tell(trial, load_search_space("ppo").suggest(trial)["learning_rate"])
    stack = StackedTrials(ValidationObjective(load_search_space("ppo"), settings()), n)
    before = rows_read[0]
    asked = stack.ask(study, n, done + n)
    assert len(asked) == n
    assert len({t.params["learning_rate"] for t, _ in asked}) == n  # n settings
    # each trial's structure drawn as a lone trial's (issue 73), not the stack's first one's
    assert len({repr(c.model_dump(exclude={"learning_rate"} | set(stack_fields(c)))) for _, c in asked}) > 1
    for trial, _ in asked:  # the trials are the study's: what they report lands in it
        trial.report(0.5, 1)
        study.tell(trial, 0.5)
    assert count_trials(study).complete == done + n
    return rows_read[0] - before


def stack_fields(cfg) -> tuple[str, ...]:
    from nutribench.tuning.stack import per_agent_fields

    return per_agent_fields(cfg)


def test_asking_a_stack_reads_in_proportion_to_its_size(tmp_path: Path, rows_read: list[int]) -> None:
    small = reads_to_ask(tmp_path, rows_read, 16, done=8)
    large = reads_to_ask(tmp_path, rows_read, 64, done=8)
    # linear: 64 / 16 = 4 times the reads (and the 8 finished trials read once each);
    # N squared would be about 16 times (every ask reading every running trial of the stack)
    assert large / small < 6, (small, large)


def test_a_tuning_batch_builds_no_sb3_model(monkeypatch) -> None:
    import nutribench.engine.algorithm as algorithm

    built: list[int] = []
    real = algorithm.build_model
    monkeypatch.setattr(algorithm, "build_model", lambda *a, **kw: built.append(1) or real(*a, **kw))
    rows: list[tuple[int, int, float]] = []

    def on_validation(j: int, day: int, r) -> None:
        rows.append((j, day, r[0]["return"]))

    cfg = load_search_space("ppo").base()
    kw = dict(eval_every=1, val_episodes=1, on_validation=on_validation)
    assert train_batched([("run3", 101)], cfg, 2, return_agents=False, **kw) == [] and not built
    without, rows[:] = list(rows), []
    (agent,) = train_batched([("run3", 101)], cfg, 2, **kw)  # the default: the agents, as before
    assert built == [1] and agent.model is not None
    assert rows == without  # the same training and scores either way


def test_a_config_file_is_parsed_once_and_again_when_it_changes(tmp_path: Path, monkeypatch) -> None:
    import nutribench.config.loading as loading

    src = Path(loading.regimes_dir()) / "reward.toml"
    if not src.is_file():
        src = next(Path(loading.regimes_dir()).glob("reward*.toml"))
    path = tmp_path / "reward.toml"
    path.write_bytes(src.read_bytes() + f"# {path}\n".encode())  # a content no other test parsed
    parsed: list[Path] = []
    real = loading.read_toml
    monkeypatch.setattr(loading, "read_toml", lambda p: parsed.append(p) or real(p))
    first = load_model(RewardConfig, path)
    assert load_model(RewardConfig, path) is first and len(parsed) == 1
    text = path.read_text()
    # the same size, within one tick of the file system's clock: another content all the same
    changed = re.sub(r"(?m)^horizon = (\d)", lambda m: f"horizon = {int(m.group(1)) % 9 + 1}", text, count=1)
    assert changed != text
    path.write_text(changed)
    assert load_model(RewardConfig, path).horizon != first.horizon and len(parsed) == 2
    path.write_text("horizon = [")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_model(RewardConfig, path)
    # agent files: one parse while unchanged, a new one when the file changes
    agent = tmp_path / "ppo.toml"
    agent.write_bytes((Path(loading.regimes_dir()) / "agents" / "ppo.toml").read_bytes() + b"# mine\n")
    a = load_agent_config(agent)
    assert load_agent_config(agent) is a
    agent.write_text(
        re.sub(r"(?m)^version = (\d)", lambda m: f"version = {int(m.group(1)) % 9 + 1}", agent.read_text())
    )
    assert load_agent_config(agent).version != a.version


def test_heartbeats_write_every_trial_in_one_transaction_and_read_no_trial(tmp_path: Path, monkeypatch) -> None:
    from nutribench.tuning.asking import beat, heartbeats

    monkeypatch.setenv("NUTRIBENCH_TUNE_HEARTBEAT", "1")
    monkeypatch.setenv("NUTRIBENCH_TUNE_GRACE", "2")
    study = open_study(tmp_path / "hb.db", "hb", settings())
    trials = [study.ask() for _ in range(5)]
    read: list[int] = []
    monkeypatch.setattr(optuna.storages.RDBStorage, "_get_trials", lambda *a, **kw: read.append(1) or [])
    with heartbeats(study, trials):
        pass
    beat(study._storage, [t._trial_id for t in trials])  # an update of the rows written
    assert not read
    backend = study._storage._backend
    assert not backend._get_stale_trial_ids(study._study_id)  # every trial beating
