"""One interface to every agent: train, evaluate, save, load.

::

    from nutribench.agents import train, evaluate, eval_food_streams
    agent = train("run0", "ppo", seed=0, episodes=300, on_episode=print)
    streams = eval_food_streams("run0", job_seed=0)          # 5 days, the same for every algo
    result = evaluate(agent, "run0", streams)                 # greedy, one row per day
    agent.save("models/ppo-run0-seed0.zip")

Training runs on one environment (one day at a time), so ``episodes`` days are exactly
``episodes * horizon`` env steps, and every finished training day is reported with the
per-day metrics (:data:`~nutribench.env.metrics.METRIC_KEYS`, plus ``episode`` and
``entropy``: the mean policy entropy over the day's steps, None for DDQN).

Reproducible: torch runs single-threaded while training (jobs run side by side in a process
pool; the caller's thread count is restored afterwards: :func:`single_threaded`), and
the seed fixes network initialisation, exploration and the env's food stream, so the same
call twice gives identical metrics on the same machine.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize

from nutribench.agents.algos import episode_entropy
from nutribench.agents.config import agent_config_content, load_agent_config, parse_agent_config
from nutribench.agents.days import EVAL_STREAM_SALT, eval_food_streams, validation_food_streams  # noqa: F401 (the API)
from nutribench.agents.model_files import (
    ModelFileError,
    load_saved_model,
    read_sidecar,
    spaces_record,
    vec_normalize_path,
    vec_normalize_stats,
    write_model_atomically,
)
from nutribench.agents.registry import algorithm, algorithms, loader_entry_point, make_model
from nutribench.agents.training_log import TrainingDiagnostics, plugin_logger
from nutribench.agents.validation import (
    DEFAULT_VAL_EPISODES,
    ValidationCallback,
    ValidationFn,
    Validator,
    check_eval_every,
)
from nutribench.config import EnvConfig, load_env_config
from nutribench.env.metrics import EpisodeRecorder
from nutribench.env.sb3 import NutriRLSB3VecEnv
from nutribench.env.vector_env import NutriRLVectorEnv

CLIP_OBS = 10.0
NORM_EPS = 1e-8


@dataclass
class TrainedAgent:
    """A trained SB3 model plus the observation statistics it was trained with.

    ``act`` takes raw observations (it normalises them itself) and is greedy.
    """

    model: BaseAlgorithm
    algo: str
    config: Any
    obs_mean: np.ndarray | None = None
    obs_var: np.ndarray | None = None
    train_episodes: list[dict[str, Any]] = field(default_factory=list)
    #: the ``VecNormalize`` the model was trained in (saved beside the model for plain SB3)
    vec_normalize: VecNormalize | None = None
    #: a loaded agent's ``.vecnormalize.pkl``: saving the agent again copies it (never unpickled)
    vec_normalize_file: Path | None = None
    #: a loaded agent's ``VecNormalize`` statistics, as its sidecar's JSON holds them
    vec_normalize_stats: dict[str, Any] | None = None
    #: where the model came from: regime, regime_version, regime_sha256, seed, episodes
    provenance: dict[str, Any] = field(default_factory=dict)
    #: one row per training update (:mod:`nutribench.diagnostics`); empty for plug-ins and loaded agents
    diagnostics: list[dict[str, float]] = field(default_factory=list)
    #: one row per validation day of each evaluation during training (:mod:`nutribench.agents.validation`)
    validation: list[dict[str, Any]] = field(default_factory=list)

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """Observations as the policy saw them in training (VecNormalize's formula)."""
        if self.obs_mean is None:
            return np.asarray(obs, dtype=np.float32)
        x = (obs - self.obs_mean) / np.sqrt(self.obs_var + NORM_EPS)
        return np.clip(x, -CLIP_OBS, CLIP_OBS).astype(np.float32)

    def act(
        self, obs: np.ndarray, state: Any = None, episode_start: np.ndarray | None = None
    ) -> tuple[np.ndarray, Any]:
        """Greedy actions for a batch of raw observations ``(n, obs_dim)``; ``state`` is the
        recurrent state (GRU-PPO; None elsewhere), reset where ``episode_start`` is true."""
        x = self.normalize(obs)
        return self.model.predict(x, state=state, episode_start=episode_start, deterministic=True)

    def save(self, path: str | Path) -> Path:
        """Write the model the SB3 way, loadable without nutribench's own code paths:

        * ``path`` (.zip): the SB3 model (the registry's ``plain`` class, e.g. ``PPO.load(path)``;
          an external agent's own ``save``);
        * ``path`` with ``.vecnormalize.pkl``: the observation (and reward) normaliser, as
          ``VecNormalize.save`` writes it (rl-zoo3's habit), if the config normalises;
        * ``path`` with ``.json``: algo, the class that loads the model with plain SB3, the agent
          config, the spaces, the observation statistics and ``VecNormalize``'s as JSON, and where
          the model came from (regime name, version and content hash, seed, training days,
          nutribench version, git commit): what :meth:`load` reads, never unpickling anything.
        """
        from nutribench.provenance import collect_metadata

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # each file written to a temporary name beside it, then renamed: never a partial file
        if not write_model_atomically(path if path.suffix else Path(f"{path}.zip"), self.model.save):  # SB3 adds .zip
            self.model.save(path)  # a save that names its own file (an external agent's): as it writes it
        target = vec_normalize_path(path)
        if self.vec_normalize is not None:
            write_model_atomically(target, lambda tmp: self.vec_normalize.save(str(tmp)))
        elif self.vec_normalize_file is not None and self.vec_normalize_file.resolve() != target.resolve():
            # a loaded agent's: its bytes copied, never unpickled
            write_model_atomically(target, lambda tmp: shutil.copyfile(self.vec_normalize_file, tmp))
        has_pickle = self.vec_normalize is not None or self.vec_normalize_file is not None
        stats = vec_normalize_stats(self.vec_normalize) if self.vec_normalize is not None else self.vec_normalize_stats
        meta = collect_metadata()
        side = {
            "algo": self.algo,
            "load_with": algorithm(self.config).plain or loader_entry_point(self.config),
            "vec_normalize": target.name if has_pickle else None,
            "vec_normalize_stats": stats,
            "config": agent_config_content(self.config),
            "spaces": spaces_record(self.model) if isinstance(self.model, BaseAlgorithm) else None,
            "obs_mean": None if self.obs_mean is None else self.obs_mean.tolist(),
            "obs_var": None if self.obs_var is None else self.obs_var.tolist(),
            "provenance": self.provenance | {k: meta[k] for k in ("nutribench_version", "git_commit", "git_dirty")},
        }
        write_model_atomically(path.with_suffix(".json"), lambda tmp: tmp.write_text(json.dumps(side, indent=1)))
        return path

    @classmethod
    def load(
        cls, path: str | Path, *, load_with: str | Callable[[str], Any] | None = None, trust: bool = False
    ) -> TrainedAgent:
        """Load what :meth:`save` wrote, as data: nothing in the files runs.

        A built-in algorithm's model is rebuilt from the agent config in the ``.json`` and gets
        the zip's weights (``torch.load(weights_only=True)``); the zip's pickled settings and the
        ``.vecnormalize.pkl`` are not read (:mod:`nutribench.agents.model_files`).

        :param load_with: a plug-in's loader, named by you (``"package.module:load"`` or the
            function): the entry point in the sidecar is never imported on its own.
        :param trust: let SB3 unpickle this file (one you made): needed for a sidecar with
            neither spaces nor a regime of this installation, or an SB3 class as ``load_with``.
        """
        path = Path(path)
        side = read_sidecar(path)
        algo = side["algo"]
        if algo not in algorithms():
            raise ModelFileError(f"{path.with_suffix('.json')}: algo {algo[:40]!r} is not a registered algorithm")
        config = parse_agent_config(side["config"], path.with_suffix(".json"))
        model = load_saved_model(path, side, config, load_with, trust)
        arr = lambda v: None if v is None else np.asarray(v, dtype=np.float64)  # noqa: E731
        agent = cls(model, algo, config, arr(side.get("obs_mean")), arr(side.get("obs_var")))
        agent.provenance = dict(side.get("provenance") or {})  # absent in files written before it was recorded
        agent.vec_normalize_stats = side.get("vec_normalize_stats")
        if side.get("vec_normalize") and vec_normalize_path(path).is_file():
            agent.vec_normalize_file = vec_normalize_path(path)
        return agent


@contextmanager
def single_threaded() -> Iterator[None]:
    """torch on one thread while the block runs (what makes a run reproducible), the caller's
    thread count restored afterwards, an exception or not: a library does not change its
    caller's process. Used as a decorator too (``@single_threaded()``)."""
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        yield
    finally:
        th.set_num_threads(threads)


# ---- how a training day is recorded: EpisodeMetrics (the SB3 callback of the built-in
# algorithms) and RecordingVecEnv (the env of a plug-in agent, whatever its ``learn`` does);
# both read the NutriRL adapter's raw rewards and info, not what ``VecNormalize`` scaled ----

EpisodeFn = Callable[[dict[str, Any]], None]


def finish_day(
    days: list[dict[str, Any]], metrics: dict[str, Any], model: Any, obs: list, on_episode: EpisodeFn | None
) -> None:
    """Append a finished day's row (its number, ``metrics`` and the entropy of ``model``'s policy
    over the day's observations ``obs``, None without a model) to ``days``, hand it to
    ``on_episode``, and forget ``obs``."""
    entropy = episode_entropy(model, np.stack(obs)) if model is not None else None
    obs.clear()
    days.append({"episode": len(days), **metrics, "entropy": entropy})
    if on_episode is not None:
        on_episode(days[-1])


class EpisodeMetrics(BaseCallback):
    """Records the per-day metrics (:data:`~nutribench.env.metrics.METRIC_KEYS`) of every
    finished training day and stops after ``episodes``.

    Reads the dones SB3 passes to callbacks and the raw rewards and batched info of the
    NutriRL SB3 adapter (not SB3's rewards, which ``VecNormalize`` may have scaled); the
    observation each action was taken at is ``model._last_obs`` during ``on_step`` (on- and
    off-policy SB3 update it after the callback).
    """

    def __init__(self, base_env: NutriRLSB3VecEnv, episodes: int, on_episode: EpisodeFn | None = None):
        super().__init__()
        self.base_env, self.n_episodes, self.on_episode = base_env, episodes, on_episode
        self.recorder = EpisodeRecorder(1)
        self.episodes: list[dict[str, Any]] = []
        self._obs: list[np.ndarray] = []

    def _on_step(self) -> bool:
        self._obs.append(np.array(self.model._last_obs[0], dtype=np.float32))
        for metrics in self.recorder.record(self.base_env.last_rewards, self.locals["dones"], self.base_env.last_info):
            finish_day(self.episodes, metrics, self.model, self._obs, self.on_episode)
        return len(self.episodes) < self.n_episodes or self._rollout_ends_here()

    def _rollout_ends_here(self) -> bool:
        """True on the last step of an on-policy rollout: there, stopping would make SB3 drop
        the rollout without its update, so training goes on and ``learn`` ends after the
        update (``total_timesteps`` is the budget). A budget that ends mid-rollout stops there:
        SB3 cannot update on a partial rollout, so those last days teach nothing."""
        n, n_rollout = self.locals.get("n_steps"), self.locals.get("n_rollout_steps")
        return isinstance(self.model, OnPolicyAlgorithm) and n is not None and n + 1 == n_rollout


class RecordingVecEnv(VecEnvWrapper):
    """The training env of a plug-in agent: records the per-day metrics of its first
    ``episodes`` finished days, whatever its ``learn`` does (no SB3 callback needed).

    Sits outside ``VecNormalize``, so the observations it keeps for the day's entropy are the
    ones the policy saw; the metrics are read from the NutriRL adapter's raw rewards and info.
    """

    def __init__(self, venv: VecEnv, base: NutriRLSB3VecEnv, episodes: int, on_episode: EpisodeFn | None = None):
        super().__init__(venv)
        self.base, self.n_episodes, self.on_episode = base, episodes, on_episode
        self.model: Any = None
        self.recorder = EpisodeRecorder(1)
        self.episodes: list[dict[str, Any]] = []
        self._obs: list[np.ndarray] = []

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        self.recorder.clear()
        self._obs = [np.array(obs[0], dtype=np.float32)]
        return obs

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        for metrics in self.recorder.record(self.base.last_rewards, dones, self.base.last_info):
            if len(self.episodes) < self.n_episodes:
                finish_day(self.episodes, metrics, self.model, self._obs, self.on_episode)
            self._obs.clear()
        self._obs.append(np.array(obs[0], dtype=np.float32))
        return obs, rewards, dones, infos

    def check_budget(self, cfg: Any) -> None:
        """A plug-in's ``learn(total_timesteps=days x horizon)`` must play its whole budget."""
        if len(self.episodes) < self.n_episodes:
            raise RuntimeError(
                f"{cfg.entry_point}: learn() played {len(self.episodes)} whole days of the {self.n_episodes} asked "
                "(it must honour total_timesteps)"
            )


def make_train_env(env_cfg: EnvConfig, cfg: Any) -> tuple[NutriRLSB3VecEnv, VecEnv]:
    """The single-day SB3 env a job trains on, and the same wrapped in ``VecNormalize``
    as the config asks (observations and/or rewards; SB3 sees scaled rewards, the
    recorded metrics stay raw because they are read from the base env)."""
    base = NutriRLSB3VecEnv(num_envs=1, regime=env_cfg)
    norms = dict(norm_obs=cfg.normalize_obs, norm_reward=cfg.normalize_reward)
    if not any(norms.values()):
        return base, base
    return base, VecNormalize(base, **norms, gamma=cfg.gamma, clip_obs=CLIP_OBS, epsilon=NORM_EPS)


@single_threaded()
def train(
    regime: str | EnvConfig,
    agent_config: Any,
    seed: int,
    episodes: int,
    on_episode: EpisodeFn | None = None,
    tensorboard: str | Path | None = None,
    diagnostics: bool = True,
    eval_every: int | None = None,
    val_episodes: int = DEFAULT_VAL_EPISODES,
    on_validation: ValidationFn | None = None,
) -> TrainedAgent:
    """Train ``agent_config`` (name, file or model) on ``regime`` for ``episodes`` days.

    :param on_episode: called with each finished training day's metrics dict.
    :param tensorboard: a folder for this run's TensorBoard events (an SB3 plug-in's own logger's too).
    :param diagnostics: record the training diagnostics (False: no callback, logger or gradient
        probe: what the benches of ``reports/diagnostics_cost`` compare against).
    :param eval_every: every so many training days, the greedy policy plays ``val_episodes``
        validation days (:mod:`nutribench.agents.validation`; built-in algorithms); None or 0: never.
    :param on_validation: called with ``(0, train_day, rows)`` after each such evaluation.
    :return: the trained agent; its ``train_episodes`` hold every day's metrics, its
        ``diagnostics`` one row per update (built-in algorithms; see :mod:`nutribench.diagnostics`),
        its ``validation`` one row per validation day of each evaluation.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    every = check_eval_every(eval_every, val_episodes)
    env_cfg = load_env_config(regime)
    cfg = load_agent_config(agent_config)
    horizon = env_cfg.reward.horizon
    base, env = make_train_env(env_cfg, cfg)
    recorded: TrainingDiagnostics | None = None
    validator = Validator(every, 1, on_validation) if every else None
    if algorithm(cfg).build is None:  # a plug-in: its days are recorded by the env
        if validator is not None:
            raise ValueError(f"{cfg.name}: evaluation during training needs a built-in algorithm's loop")
        recorder = RecordingVecEnv(env, base, episodes, on_episode)
        model = _train_plugin(cfg, recorder, seed, horizon, tensorboard)
    else:
        model = make_model(cfg, env, seed=seed, horizon=horizon)
        recorder = EpisodeMetrics(base, episodes, on_episode)
        callbacks = [recorder]
        if diagnostics or tensorboard is not None:
            recorded = TrainingDiagnostics(model, tensorboard)
            callbacks.append(recorded)
        if validator is not None:
            callbacks.append(_validation_callback(validator, model, cfg, env_cfg, seed, val_episodes))
        model.learn(total_timesteps=episodes * horizon, callback=CallbackList(callbacks))
    agent = TrainedAgent(model, cfg.algo, cfg, provenance=training_provenance(env_cfg, cfg, seed, episodes))
    if cfg.normalize_obs:
        agent.obs_mean, agent.obs_var = env.obs_rms.mean.copy(), env.obs_rms.var.copy()  # type: ignore[union-attr]
    agent.vec_normalize = env if isinstance(env, VecNormalize) else None
    agent.train_episodes = recorder.episodes
    agent.diagnostics = recorded.rows if recorded is not None else []
    agent.validation = validator.rows[0] if validator is not None else []
    return agent


def _train_plugin(cfg: Any, recorder: RecordingVecEnv, seed: int, horizon: int, tensorboard: str | Path | None) -> Any:
    """A plug-in's model trained on ``recorder`` (the env that records its days, not a callback:
    the plug-in's ``learn`` may take none) for the days the recorder asks."""
    model = recorder.model = make_model(cfg, recorder, seed=seed, horizon=horizon)
    plugin_logger(model, tensorboard)
    model.learn(total_timesteps=recorder.n_episodes * horizon)
    recorder.check_budget(cfg)
    return model


def _validation_callback(
    validator: Validator, model: BaseAlgorithm, cfg: Any, env_cfg: EnvConfig, seed: int, val_episodes: int
) -> ValidationCallback:
    """The callback that plays the validation days with the greedy policy of ``model`` as
    it stands, the observation statistics of that moment."""
    streams = validation_food_streams(env_cfg, seed, val_episodes)
    snapshot = lambda m, v: TrainedAgent(model, cfg.algo, cfg, m, v)  # noqa: E731
    play = lambda m, v: evaluate(snapshot(m, v), env_cfg, streams, record_steps=False).episodes  # noqa: E731
    return ValidationCallback(validator, play)


def training_provenance(env_cfg: EnvConfig, cfg: Any, seed: int, episodes: int) -> dict[str, Any]:
    """Where a trained model came from (its sidecar's ``provenance``): the regime's name,
    version and content hash, the agent config's name and version, the seed, the training days."""
    return {
        "regime": env_cfg.name,
        "regime_version": env_cfg.version,
        "regime_sha256": env_cfg.sha256,
        "agent_config": cfg.name,
        "agent_config_version": cfg.version,
        "seed": seed,
        "episodes": episodes,
    }


@dataclass
class EvalResult:
    """Evaluation of one agent: one metrics row per day and, if recorded, one row per step
    (``episode``, ``step`` 1..H, ``food`` offered, ``action``, ``C``/``F``/``P`` absorbed
    after the step, ``reward``)."""

    episodes: list[dict[str, Any]]
    steps: list[dict[str, Any]]


def evaluate(
    agent: TrainedAgent, regime: str | EnvConfig, food_streams: np.ndarray, record_steps: bool = True
) -> EvalResult:
    """Greedy play of ``agent`` on the given days ``(n, horizon)``, all days side by side."""
    env_cfg = load_env_config(regime)
    streams = np.asarray(food_streams)
    n, horizon = streams.shape
    venv = NutriRLVectorEnv(n, regime=env_cfg)
    obs, _ = venv.reset(options={"foods": streams})
    recorder = EpisodeRecorder(n)
    state, start = None, np.ones(n, dtype=bool)
    seen, finished, steps = [], [], []
    for t in range(horizon):
        seen.append(agent.normalize(obs))
        actions, state = agent.act(obs, state, start)
        actions = np.asarray(actions).reshape(n)
        obs, rewards, terminated, truncated, info = venv.step(actions)
        finished += recorder.record(rewards, terminated | truncated, info)
        start = np.zeros(n, dtype=bool)
        if record_steps:
            s = np.asarray(info["state"]).reshape(n, 3)
            steps += [
                {"episode": j, "step": t + 1, "food": int(streams[j, t]), "action": int(actions[j])}
                | {"C": float(s[j, 0]), "F": float(s[j, 1]), "P": float(s[j, 2]), "reward": float(rewards[j])}
                for j in range(n)
            ]
    seen_arr = np.stack(seen, axis=1)  # (n, H, obs_dim)
    rows = [{"episode": j, **m, "entropy": episode_entropy(agent.model, seen_arr[j])} for j, m in enumerate(finished)]
    return EvalResult(rows, steps)
