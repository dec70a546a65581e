"""Results from anywhere (bsuite's idea): an agent trained by any loop, in any framework,
becomes a job of the results database, beside the built-in agents. In short:

    import nutribench

    with nutribench.Recorder(db="sqlite:///lab.db", name="my_agent", regime="run3", seed=0) as rec:
        env = rec.env              # a Gymnasium env: every whole day played on it is a training row
        ...                        # any training loop
        rec.evaluate(policy)       # the fixed evaluation days of (regime, seed), played greedily

``policy`` is a callable ``obs -> action`` or any object with SB3's ``predict`` (recurrent ones
included: their state is carried through each day and reset at its start). When the block
ends without an exception the job is written in one transaction: its training days, its
evaluation days and steps, and where it came from (``engine = 'external'``, the calling script
and its sha256, host, versions, git commit). An exception, or no ``evaluate``, writes nothing.

The agent is recorded as an agent config ``algo = "external"`` with no entry point (name,
version, description, params), hashed like every config: the same name and version with
other params is refused ("bump the version"), and a (regime, agent version, seed) that is
already in the database is refused rather than overwritten; both are checked as the ``with``
block opens, before the training loop runs, in one line naming agent, regime and seed.
"""

from __future__ import annotations

import inspect
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from nutribench.clock import utcnow
from nutribench.engines import Engine
from nutribench.errors import UserError
from nutribench.provenance import collect_metadata, file_sha256


class RecorderError(UserError):
    """A recording that cannot be written (one line)."""


class RecordingEnv(gym.Wrapper):
    """A NutriRL env that keeps the per-day metrics of every whole day played on it (a day cut
    short by ``reset`` is not a row)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        from nutribench.env.metrics import EpisodeRecorder

        self.recorder = EpisodeRecorder(1)
        self.days: list[dict[str, Any]] = []

    def reset(self, **kwargs: Any) -> Any:
        self.recorder.clear()
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        for metrics in self.recorder.record(np.array([reward]), np.array([terminated or truncated]), info):
            self.days.append({"episode": len(self.days), **metrics, "entropy": None})
        return obs, reward, terminated, truncated, info


class PolicyAgent:
    """Any policy, seen as the evaluator sees an agent: ``act`` on raw observations. What the
    policy returns is checked, not coerced: an action is 0 (skip) or 1 (eat), a number (``2``,
    ``0.9``, ``"1"`` are refused in one line, as the environment refuses ``0.5``); a policy that
    raises is a one-line :class:`RecorderError` too (its exception chained)."""

    def __init__(self, policy: Any):
        self.policy = policy
        self.model = policy if callable(getattr(policy, "predict", None)) else None
        self.step = 0

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(obs, dtype=np.float32)

    def act(
        self, obs: np.ndarray, state: Any = None, episode_start: np.ndarray | None = None
    ) -> tuple[np.ndarray, Any]:
        self.step = 1 if episode_start is not None and np.all(episode_start) else self.step + 1
        if self.model is None and not callable(self.policy):
            raise RecorderError(
                f"evaluate(policy): a {type(self.policy).__name__} is neither callable (obs -> action) nor has predict()"
            )
        try:
            if self.model is not None:
                out = self.model.predict(obs, state=state, episode_start=episode_start, deterministic=True)
                if not (isinstance(out, tuple) and len(out) == 2):
                    raise RecorderError(
                        f"evaluate(policy): {type(self.model).__name__}.predict returned a {type(out).__name__}, "
                        "not (actions, state) as SB3's predict does"
                    )
                actions, state = out
            else:
                actions = [self.policy(o) for o in obs]
        except RecorderError:
            raise
        except Exception as e:  # the user's policy: its failure in one line, its traceback chained
            raise RecorderError(
                f"evaluate(policy): the policy raised at step {self.step}: {type(e).__name__}: {e}"
            ) from e
        return self.check_actions(actions, len(obs)), state

    def check_actions(self, actions: Any, n: int) -> np.ndarray:
        """``actions`` as ``n`` integers 0 or 1; anything else a :class:`RecorderError` naming the step."""
        arr = np.asarray(actions) if not isinstance(actions, list) else np.asarray(actions, dtype=object)
        where = f"evaluate(policy): at step {self.step} the policy returned"
        if arr.size != n:
            raise RecorderError(f"{where} {arr.size} actions for {n} observations: return one action per observation")
        values = []
        for a in arr.reshape(n):
            if callable(getattr(a, "item", None)) and not isinstance(a, str):
                try:
                    a = a.item()  # a numpy scalar, a one-element array or tensor
                except (ValueError, RuntimeError):  # several elements: refused below
                    pass
            if not (isinstance(a, (bool, int, float)) and a in (0, 1)):
                raise RecorderError(f"{where} {a!r}: an action is 0 (skip) or 1 (eat), an integer")
            values.append(int(a))
        return np.array(values, dtype=np.int64)


def _caller_source(depth: int = 2) -> tuple[str | None, str | None]:
    """The file of the code that created the recorder, and its sha256 (None if not a file)."""
    path = Path(inspect.stack()[depth].filename)
    if not path.is_file():
        return None, None
    return str(path.resolve()), file_sha256(path)


class Recorder:
    """Records an agent trained outside nutribench as one job of the results database.

    :param db: database file or SQLAlchemy URL (created and upgraded if needed).
    :param name: the agent's name in the database (``[a-z][a-z0-9_]*``).
    :param regime: a regime name or regime file.
    :param seed: the job's seed: it seeds the training days' food stream (``env``'s first
        ``reset``) and picks the evaluation days, the same days every agent of that seed plays.
    :param version: the agent's version (bump it when the agent changes).
    :param params: the agent's settings, stored and hashed with its name and version.
    :param eval_episodes: how many fixed evaluation days (5: the paper's).
    :param source: what made the results (default: the calling script), recorded with its hash.
    :param trained_days: the training days of a model trained elsewhere, when no training day is
        played on ``env`` (``nutribench evaluate`` gives its sidecar's): the job's budget, with no
        training rows. None (the default): the budget is the training days played on ``env``, and
        with none, the training is not recorded (budget 0).
    """

    def __init__(
        self,
        db: str | Path = "nutribench.db",
        *,
        name: str,
        regime: str | Path = "run0",
        seed: int = 0,
        version: int = 1,
        description: str = "",
        params: dict[str, Any] | None = None,
        eval_episodes: int = 5,
        source: tuple[str | None, str | None] | None = None,
        trained_days: int | None = None,
    ):
        from nutribench.agents.config import parse_agent_config
        from nutribench.config import load_env_config
        from nutribench.scheduler.grid import MAX_EPISODES, MAX_EVAL_DAYS, MAX_SEED

        checked = [("seed", seed, 0, MAX_SEED), ("eval_episodes", eval_episodes, 1, MAX_EVAL_DAYS)]
        if trained_days is not None:
            checked.append(("trained_days", trained_days, 0, MAX_EPISODES))
        for what, value, low, high in checked:
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                raise RecorderError(f"Recorder({what}={value!r}): {what} is an integer, e.g. {what}={low}")
            if not low <= value <= high:
                raise RecorderError(f"Recorder({what}={value}): {what} goes from {low} to {high}")
        self.db, self.seed, self.eval_episodes = db, int(seed), int(eval_episodes)
        self.trained_days = int(trained_days or 0)
        self.regime_config = load_env_config(regime)
        body = {
            "algo": "external",
            "name": name,
            "version": version,
            "description": description or f"{name}, recorded",
            "params": dict(params or {}),
        }
        self.agent_config = parse_agent_config(body, f"Recorder(name={name!r})")
        self.source = source if source is not None else _caller_source()
        self._env: RecordingEnv | None = None
        self._eval: Any = None
        self._started, self._t0 = None, 0.0

    # ------------------------------------------------------------------ the with block
    def __enter__(self) -> Recorder:
        from nutribench.env.nutri_env import NutriRLEnv

        self._check_database()
        self._env = RecordingEnv(NutriRLEnv(regime=self.regime_config))
        self._env.reset(seed=self.seed)  # seeds the training days' stream: the user's resets continue it
        self._started, self._t0 = utcnow(), time.perf_counter()
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.save()

    def _in_block(self, what: str) -> RecordingEnv:
        if self._env is None:
            raise RecorderError(
                f"Recorder.{what}: use the recorder in a with block (with nutribench.Recorder(...) as rec:)"
            )
        return self._env

    @property
    def env(self) -> RecordingEnv:
        """The Gymnasium env to train on: every whole day played on it is a training row."""
        return self._in_block("env")

    def evaluate(self, policy: Any) -> list[dict[str, Any]]:
        """Play the fixed evaluation days of (regime, seed) greedily with ``policy`` (a
        callable ``obs -> action`` or an object with SB3's ``predict``); their metrics."""
        from nutribench.agents.api import eval_food_streams, evaluate

        self._in_block("evaluate")
        streams = eval_food_streams(self.regime_config, self.seed, self.eval_episodes)
        self._eval = evaluate(PolicyAgent(policy), self.regime_config, streams, record_steps=True)
        return self._eval.episodes

    # ------------------------------------------------------------------ the database
    def _check_database(self) -> None:
        """Refuse a database the job could not be written to, before the loop; a new SQLite
        file is only checked: it is created when the job is written (a failed recording leaves
        no empty database behind)."""
        from nutribench.scheduler.registration import check_external_entry
        from nutribench.store import StoreError, open_store
        from nutribench.store.engine import check_sqlite_file, database_url, in_memory, sqlite_path

        url = database_url(self.db)
        if in_memory(url):
            raise StoreError(
                f"Recorder(db={str(self.db)!r}): an in-memory SQLite database is lost with the process: give a file path"
            )
        path = sqlite_path(url)
        if path is not None and not path.exists():
            check_sqlite_file(path, create=True)
            return
        with open_store(self.db, writer=True) as store:
            # a dry run's database, a conflict or a duplicate found now, before the training loop, not after it
            check_external_entry(store, self.regime_config, self.agent_config, self.seed, self.eval_episodes)

    def save(self) -> int:
        """Write the job (called by the with block's end); its id."""
        self._in_block("save")
        if self._eval is None:
            raise RecorderError(
                f"Recorder {self.agent_config.name}: call rec.evaluate(policy) before the with block ends (nothing was written)"
            )
        from nutribench.scheduler.registration import store_external_job
        from nutribench.store import open_store

        if self.trained_days and self.env.days:
            raise RecorderError(
                f"Recorder {self.agent_config.name}: trained_days={self.trained_days} and {len(self.env.days)} "
                "training days played on rec.env: give one or the other (nothing was written)"
            )
        meta = collect_metadata() | {
            "started_at": self._started,
            "finished_at": utcnow(),
            "wall_seconds": time.perf_counter() - self._t0,
            "engine": Engine.EXTERNAL.value,
            "source": self.source[0],
            "source_sha256": self.source[1],
        }
        episodes = self.trained_days or len(self.env.days)
        with open_store(self.db, writer=True) as store:
            return store_external_job(
                store,
                env=self.regime_config,
                cfg=self.agent_config,
                seed=self.seed,
                episodes=episodes,
                train=self.env.days,
                evaluation=self._eval,
                metadata=meta,
            )
