"""Saved models read as data: nothing in a model file, or in the files beside it, is executed.

An SB3 ``.zip`` holds its network weights as ``.pth`` tensors and its settings as JSON, some of
them pickled (``":serialized:"``: the policy class, the spaces, the schedules). Unpickling a
file runs whatever code it names, so nutribench never unpickles one it is merely asked to
load: :func:`rebuild_from_weights` builds the model from the agent config (the registry's
builder, or a plug-in's ``make_agent`` the *caller* names), on a stand-in environment with the
spaces the ``.json`` sidecar records, and copies the ``.pth`` tensors in with
``torch.load(weights_only=True)``; the zip's ``data`` entry is never read. The
``VecNormalize`` statistics are read from the sidecar's JSON (:func:`vec_normalize_from_stats`),
never from the ``.vecnormalize.pkl`` written beside the model for plain SB3.

The zip's members are sized from its directory before any is decompressed
(:data:`MAX_MODEL_BYTES` in all), so a zip bomb is refused before it is inflated.
"""

from __future__ import annotations

import glob
import io
import json
import os
import uuid
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize

from nutribench.errors import UserError
from nutribench.safe_write import check_regular_file

#: The most bytes a model zip's weight members may inflate to (their declared sizes, summed).
MAX_MODEL_BYTES = 1 << 30
#: The most bytes a sidecar ``.json`` may have.
MAX_SIDECAR_BYTES = 64 << 20


class ModelFileError(UserError):
    """A saved model that cannot be loaded as data (one line: which file, why, what to do)."""


def vec_normalize_path(model_path: str | Path) -> Path:
    """Where the ``VecNormalize`` statistics of a saved model live: ``m.zip`` -> ``m.vecnormalize.pkl``."""
    return Path(model_path).with_suffix(".vecnormalize.pkl")


def write_model_atomically(target: Path, write: Callable[[Path], Any]) -> bool:
    """``write(tmp)`` to a temporary name beside ``target`` (same suffix), then renamed over
    it, so that a write cut short (a full disk, a kill) never leaves a partial ``target``;
    whatever it left is deleted. False (nothing renamed) if ``write`` wrote no file at that name.
    A device node, a FIFO or a folder at ``target`` is refused first
    (:func:`nutribench.safe_write.check_regular_file`)."""
    check_regular_file(target, "model file", ModelFileError)
    tmp = target.with_name(f".{target.stem}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp{target.suffix}")
    try:
        write(tmp)
        if tmp.is_file():
            os.replace(tmp, target)
            return True
    finally:
        for p in target.parent.glob(glob.escape(tmp.name) + "*"):
            p.unlink(missing_ok=True)
    return False


def _one_line(e: BaseException, n: int = 200) -> str:
    text = " ".join(str(e).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def read_sidecar(path: str | Path) -> dict[str, Any]:
    """The ``.json`` beside model ``path``, parsed as plain data (a JSON object)."""
    side = Path(path).with_suffix(".json")
    if not side.is_file():
        raise ModelFileError(f"{path}: no {side.name} beside it (what TrainedAgent.save writes with every model)")
    if side.stat().st_size > MAX_SIDECAR_BYTES:
        raise ModelFileError(f"{side}: larger than {MAX_SIDECAR_BYTES >> 20} MiB, not a model's sidecar")
    try:
        data = json.loads(side.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise ModelFileError(f"{side}: not JSON ({type(e).__name__})") from None
    if not isinstance(data, dict) or not isinstance(data.get("algo"), str) or not isinstance(data.get("config"), dict):
        raise ModelFileError(f"{side}: not a model sidecar (an object with 'algo' and 'config')")
    return data


def sidecar_training_days(path: str | Path) -> int | None:
    """The training days the sidecar beside model ``path`` records (its provenance's
    ``episodes``, what :meth:`nutribench.agents.api.TrainedAgent.save` writes); None where
    there is no nutribench sidecar beside it (a model of another framework, a ``.json`` that is
    not a model's sidecar) or it records none (a file written before provenance was kept). A
    sidecar whose training days are not a whole number of days is a :class:`ModelFileError`."""
    try:
        side = read_sidecar(path)
    except ModelFileError:
        return None  # none, or not ours: it says nothing of the training
    provenance = side.get("provenance")
    days = provenance.get("episodes") if isinstance(provenance, dict) else None
    if days is None:
        return None
    if type(days) is not int or days < 0:
        raise ModelFileError(
            f"{Path(path).with_suffix('.json')}: provenance episodes {str(days)[:40]!r} is not a number of "
            "training days: fix or remove the sidecar"
        )
    return days or None


def spaces_record(model: BaseAlgorithm) -> dict[str, Any]:
    """The observation and action spaces of ``model``, as JSON (for :func:`stand_in_env`)."""
    return _spaces(model.observation_space, int(model.action_space.n))


def _spaces(obs: gym.spaces.Box, n_actions: int) -> dict[str, Any]:
    return {
        "obs_low": np.asarray(obs.low).tolist(),
        "obs_high": np.asarray(obs.high).tolist(),
        "obs_dtype": str(obs.dtype),
        "n_actions": n_actions,
    }


class _SpacesOnly(gym.Env):
    """An env that only has spaces: what a model is built on to receive saved weights."""

    def __init__(self, observation_space: gym.spaces.Box, action_space: gym.spaces.Discrete):
        self.observation_space, self.action_space = observation_space, action_space

    def step(self, *args: Any, **kwargs: Any) -> Any:  # pragma: no cover
        raise RuntimeError("a stand-in env for loading weights: it cannot be played")

    reset = step


def stand_in_env(spaces: Any, where: str) -> VecEnv:
    """A one-env ``VecEnv`` with the spaces :func:`spaces_record` wrote (checked as data)."""
    try:
        low = np.asarray(spaces["obs_low"], dtype=np.float64)
        high = np.asarray(spaces["obs_high"], dtype=np.float64)
        dtype = np.dtype(spaces["obs_dtype"])
        n = spaces["n_actions"]
        box_ok = low.ndim == 1 and low.shape == high.shape and 0 < len(low) <= 4096 and dtype.kind == "f"
        ok = box_ok and type(n) is int and 1 <= n <= 1024 and not np.isnan(low).any() and not np.isnan(high).any()
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise ModelFileError(f"{where}: its 'spaces' are not an observation box and a number of actions")
    box = gym.spaces.Box(low.astype(dtype), high.astype(dtype), dtype=dtype)
    return DummyVecEnv([lambda: _SpacesOnly(box, gym.spaces.Discrete(n))])


def read_weights(path: str | Path) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The ``.pth`` members of an SB3 zip (state dicts, and the ``pytorch_variables``), read
    with ``torch.load(weights_only=True)``; the pickled ``data`` member is not opened."""
    try:
        with zipfile.ZipFile(path) as zf:
            members = [i for i in zf.infolist() if i.filename.endswith(".pth")]
            declared = sum(i.file_size for i in members)
            if declared > MAX_MODEL_BYTES:
                raise ModelFileError(
                    f"{path}: its weights would inflate to {declared:,} bytes (more than {MAX_MODEL_BYTES:,}): not loaded"
                )
            params, variables = {}, None
            for info in members:
                with zf.open(info) as fh:
                    blob = fh.read(info.file_size + 1)
                if len(blob) != info.file_size:
                    raise ModelFileError(f"{path}: member {info.filename} is not the size its directory declares")
                tensors = th.load(io.BytesIO(blob), map_location="cpu", weights_only=True)
                name = info.filename[: -len(".pth")]
                if name in ("pytorch_variables", "tensors"):
                    variables = tensors
                else:
                    params[name] = tensors
    except ModelFileError:
        raise
    except Exception as e:  # noqa: BLE001 - bytes from anywhere: a bad zip, a planted pickle, a truncated tensor
        raise ModelFileError(
            f"{path}: its weights cannot be read as tensors ({type(e).__name__}: {_one_line(e)})"
        ) from None
    if "policy" not in params:
        raise ModelFileError(f"{path}: no policy weights (policy.pth) in it")
    return params, variables


def _is_width(v: Any) -> bool:
    return type(v) is int and v > 0


def _mlp_fewest(widths: Any) -> int:
    """The fewest weights an MLP with hidden layers ``widths`` holds: each layer's weights from
    the one before (at least one input, at least one output after the last); 0 if ``widths``
    is not a list of positive integers."""
    if not isinstance(widths, list) or not widths or not all(map(_is_width, widths)):
        return 0
    return widths[0] + sum(a * b for a, b in zip(widths, widths[1:])) + widths[-1]


def implied_parameters(config: Any) -> tuple[str, int]:
    """The layer sizes an agent config (a sidecar's ``config``, as data) names, and the fewest
    parameters a model built from them holds: the built-in agents' ``net_arch`` (an MLP) and
    ``hidden_size`` (a GRU: 3 x hidden x hidden recurrent weights), a plug-in's
    ``params.policy_kwargs.net_arch`` (SB3's: a list, or a table of lists such as ``pi``/``vf``).
    ``("", 0)`` when it names none."""
    if not isinstance(config, dict):
        return "", 0
    named, fewest = [], 0
    params = config.get("params")
    kwargs = params.get("policy_kwargs") if isinstance(params, dict) else None
    plugin_arch = kwargs.get("net_arch") if isinstance(kwargs, dict) else None
    for where, arch in (("net_arch", config.get("net_arch")), ("policy_kwargs.net_arch", plugin_arch)):
        lists = arch.values() if isinstance(arch, dict) else [arch]
        n = sum(_mlp_fewest(v) for v in lists)
        if n:
            named.append(f"{where} {arch}")
            fewest += n
    hidden = config.get("hidden_size")
    if _is_width(hidden):
        named.append(f"hidden_size {hidden}")
        fewest += 3 * hidden * hidden
    return ", ".join(named), fewest


def _numel(tensors: Any) -> int:
    if isinstance(tensors, th.Tensor):
        return tensors.numel()
    items = tensors.values() if isinstance(tensors, dict) else tensors if isinstance(tensors, (list, tuple)) else ()
    return sum(map(_numel, items))


def check_layer_sizes(path: str | Path, config: Any, policy: Any) -> None:
    """Refuse, in one line and before anything is built, a sidecar whose layer sizes
    (:func:`implied_parameters`) make more parameters than the zip's ``policy`` weights hold:
    ``net_arch = [40000, 40000, 40000]`` beside a small model was a network of 3.2 billion
    parameters allocated (a RuntimeError traceback, or the memory of the machine) before the
    weights were compared with it."""
    named, fewest = implied_parameters(config)
    held = _numel(policy)
    if fewest > held:
        raise ModelFileError(
            f"{Path(path).with_suffix('.json')}: its config's layers ({_one_line(named, 120)}) make at least {fewest:,} "
            f"parameters, but the weights of {Path(path).name} hold {held:,}: the sidecar does not describe "
            "this model; not built"
        )


def rebuild_from_weights(
    path: str | Path, build: Callable[[VecEnv], BaseAlgorithm], spaces: Any, config: Any = None
) -> BaseAlgorithm:
    """The model ``build(env)`` makes, on a stand-in env with ``spaces``, holding the weights
    of the SB3 zip ``path`` (exactly the tensors it was saved with). The weights are read
    first (their size is bounded), and ``config`` (the sidecar's agent config, as data) is
    checked against them before anything is built (:func:`check_layer_sizes`)."""
    env = stand_in_env(spaces, str(path))
    params, variables = read_weights(path)
    check_layer_sizes(path, config, params["policy"])
    model = build(env)
    try:
        model.set_parameters(params, exact_match=True, device="cpu")
    except (ValueError, RuntimeError, KeyError) as e:
        raise ModelFileError(f"{path}: its weights do not fit the model its config builds ({_one_line(e)})") from None
    for name, value in (variables or {}).items():
        if not isinstance(value, th.Tensor) or not isinstance(getattr(model, name, None), th.Tensor):
            raise ModelFileError(f"{path}: pytorch variable {name!r} is not one of the model's tensors")
        getattr(model, name).data = value.data
    return model


def load_plugin_model(path: str | Path, make_agent: Callable[[dict[str, Any], Any, int], Any]) -> Any:
    """A plug-in's saved model (SB3 algorithm), loaded without unpickling: ``make_agent`` (the
    plug-in's own builder, named by the code that calls this) is called with the params of the
    agent config in the sidecar, and the zip's weights are copied in. What a plug-in's
    ``load(path)`` can be: ``return load_plugin_model(path, make_agent)``."""
    side = read_sidecar(path)
    params = side["config"].get("params") or {}
    if not isinstance(params, dict):
        raise ModelFileError(f"{path}: its sidecar's params are not a table")
    if "spaces" not in side:
        raise ModelFileError(
            f"{path}: its sidecar records no spaces (saved by an older nutribench): load it with SB3 "
            "yourself if you trust the file"
        )
    return rebuild_from_weights(path, lambda env: make_agent(dict(params), env, 0), side["spaces"], side["config"])


#: ``VecNormalize``'s float settings, as its sidecar's JSON holds them
VEC_NORMALIZE_FLOATS = ("clip_obs", "clip_reward", "gamma", "epsilon")


def vec_normalize_stats(vn: VecNormalize) -> dict[str, Any]:
    """``VecNormalize``'s statistics and settings as JSON (what its pickle holds that matters)."""
    rms = lambda r: {"mean": np.asarray(r.mean).tolist(), "var": np.asarray(r.var).tolist(), "count": float(r.count)}  # noqa: E731
    return {
        "obs_rms": rms(vn.obs_rms) if vn.norm_obs else None,
        "ret_rms": rms(vn.ret_rms),
        "norm_obs": bool(vn.norm_obs),
        "norm_reward": bool(vn.norm_reward),
        **{name: float(getattr(vn, name)) for name in VEC_NORMALIZE_FLOATS},
    }


def vec_normalize_from_stats(stats: dict[str, Any], venv: VecEnv) -> VecNormalize:
    """A frozen ``VecNormalize`` around ``venv`` with the statistics :func:`vec_normalize_stats`
    wrote (evaluation: ``training=False``, raw rewards), rebuilt without a pickle."""
    floats = {name: float(stats[name]) for name in VEC_NORMALIZE_FLOATS}
    vn = VecNormalize(venv, training=False, norm_obs=bool(stats["norm_obs"]), norm_reward=False, **floats)
    for key in ("obs_rms", "ret_rms"):
        saved = stats.get(key)
        if saved is not None:
            rms = getattr(vn, key)
            for part in ("mean", "var"):
                setattr(rms, part, np.asarray(saved[part], dtype=np.float64).reshape(np.shape(getattr(rms, part))))
            rms.count = float(saved["count"])
    return vn


def _regime_spaces(side: dict[str, Any]) -> dict[str, Any] | None:
    """The spaces of the regime a sidecar's provenance names (a sidecar written before the
    spaces were recorded), if it is a regime of this installation; None otherwise. Only a
    name is looked up, never a path."""
    import re

    from nutribench.config.loading import ConfigError
    from nutribench.env.nutri_env import RegimeDynamics

    regime = (side.get("provenance") or {}).get("regime")
    if not isinstance(regime, str) or not re.fullmatch(r"[a-z][a-z0-9_]{0,63}", regime):
        return None
    try:
        dyn = RegimeDynamics(regime)
    except (ConfigError, OSError):
        return None
    return _spaces(dyn.observation_space, 2)


#: The horizon a model is rebuilt with: it sizes MC's rollout buffer only, never a weight.
LOAD_HORIZON = 50


def load_saved_model(
    path: Path, side: dict[str, Any], config: Any, load_with: str | Callable[[str], Any] | None, trust: bool
) -> Any:
    """The model of ``path`` (its sidecar ``side`` and agent ``config`` already read): a
    built-in algorithm rebuilt from weights; a plug-in's by the loader the caller names; SB3's
    unpickling ``load`` only where ``trust`` says so (see ``TrainedAgent.load``)."""
    from nutribench.agents.registry import get, import_entry_point, make_model

    entry = get(side["algo"])
    if entry.build is not None:
        spaces = side.get("spaces") or _regime_spaces(side)
        if spaces is not None:
            build = lambda env: make_model(config, env, seed=0, horizon=LOAD_HORIZON)  # noqa: E731
            return rebuild_from_weights(path, build, spaces, side["config"])
        if not trust:
            raise ModelFileError(
                f"{path}: its sidecar records no spaces nor a regime of this installation (saved by an older "
                "nutribench), so only SB3's unpickling load reads it: pass trust=True if you made this file yourself"
            )
        return call_loader(import_entry_point(entry.load), path)
    if load_with is None:
        raise ModelFileError(
            f"{path}: a plug-in's model: name its loader, TrainedAgent.load(path, load_with='my_agents:load') "
            "(the sidecar's entry point is never imported on its own)"
        )
    loader = import_entry_point(load_with) if isinstance(load_with, str) else load_with
    if isinstance(loader, type) and issubclass(loader, BaseAlgorithm) and not trust:
        raise ModelFileError(
            f"{path}: {loader.__name__}.load unpickles the zip: pass trust=True if you made this file yourself, "
            "or a load(path) function (nutribench.agents.model_files.load_plugin_model reads weights only)"
        )
    return call_loader(loader, path)


def call_loader(loader: Any, path: str | Path) -> Any:
    """The model ``loader`` loads from ``path``: a class's ``load(path)`` (an SB3 class's on
    the CPU) or the function's ``loader(path)``."""
    if isinstance(loader, type):
        return loader.load(str(path), device="cpu") if issubclass(loader, BaseAlgorithm) else loader.load(str(path))
    return loader(str(path))
