"""Checkpoints of a batch in training, so that a stopped batch resumes instead of starting over.

A batch of the paper grid trains for hours (ten SAC agents: about two). Its jobs are stored
only when the whole batch ends, so without checkpoints a stopped process loses all of it.
With a :class:`Checkpoint`, the training loops save their whole state at a day boundary
(the off-policy loop) or a rollout boundary (the on-policy loop) every ``every_seconds``:
the K agents' networks and optimisers, replay buffers, observation and return statistics,
the envs and every random stream, the days recorded so far. A batch started again on the
same file carries on from there and ends exactly where an uninterrupted batch would
(tested: same metrics, same weights).

No pickle, so that a file planted in a shared models folder cannot run code. A checkpoint
is ``<name>.pt``, a plain dict of every tensor and numpy array of the state (``torch.save``,
read with ``torch.load(..., weights_only=True)``), and ``<name>.pt.state.json``, plain JSON
for the rest and the structure: numbers, strings, lists, dicts, numpy generators as their
bit generator's state, optimisers as their ``state_dict``, the engine's classes by name
(:func:`register`; rebuilt from their attributes, none of their code runs), each object
shared by several parts (a network and its optimiser's parameters) shared again when read.
Plain data (a day's metrics) goes to the JSON as it is, a list of like arrays (the days
drawn) to the ``.pt`` as one stacked array, read back as views of it. The JSON names the
sha256 of the ``.pt``. A save writes both to temporary names, then renames the JSON, then
the tensors; a process killed between the two renames leaves the new tensors at the
temporary name, and the next read puts them in place. A checkpoint that does not read this
way (a pickle, a damaged file, tensors that do not match their JSON, an unknown class) is
refused in one line on stderr and the batch starts over. A save that fails (a full disk)
says so in one line, the previous checkpoint stays whole, and training goes on.

Longer than 400 lines: the format is one piece (what the encoder writes, the decoder reads
and checks, and the file pair's writing, renaming and reading).

A checkpoint moves between devices: it is read onto the device the batch trains on
(:meth:`Checkpoint.read_onto`), so a batch stopped on a GPU resumes on the CPU and the other
way round; every torch tensor of the state (parameters, optimiser moments and steps, GRU
states) goes to that device, while the random streams (numpy generators) and the replay
buffers and statistics (numpy arrays) are the CPU's on every device. The resumed run then
goes on as a run on that device would, not bit for bit as the first device's would.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import pickle
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

#: how often a batch saves its state (seconds of wall time, checked at day boundaries)
DEFAULT_EVERY_SECONDS = 300.0

#: the ``format`` of the JSON half; a checkpoint of another format is refused
FORMAT = "nutribench-checkpoint/2"

#: the bit generators and optimisers a checkpoint may name (optimisers: rebuilt over the
#: restored parameters, then ``load_state_dict``)
_BIT_GENERATORS = {c.__name__: c for c in (np.random.PCG64, np.random.MT19937, np.random.Philox, np.random.SFC64)}
_OPTIMIZERS = {c.__name__: c for c in (th.optim.Adam, th.optim.AdamW, th.optim.SGD)}
#: the numpy dtypes of the arrays and scalars a checkpoint may hold (numbers), by ``dtype.str``
_DTYPES = {
    np.dtype(t).str: np.dtype(t)
    for t in (
        np.bool_,
        np.int8,
        np.uint8,
        np.int16,
        np.uint16,
        np.int32,
        np.uint32,
        np.int64,
        np.uint64,
        np.float16,
        np.float32,
        np.float64,
    )
}

_JSON_SCALARS = {type(None), bool, int, str}
_CLASSES: dict[str, type] = {}  # the engine's classes a checkpoint may hold, by name (:func:`register`)


def register(*classes: type) -> None:
    """Let checkpoints hold instances of ``classes`` (the engine's networks, replays and
    statistics): saved as their attribute dict, rebuilt by ``cls.__new__`` and that dict (no
    ``__init__`` or ``__setstate__`` runs). Each module registers its own; a checkpoint's
    objects are rebuilt when a trainer first reads :attr:`Checkpoint.state`, after its imports."""
    _CLASSES.update({c.__name__: c for c in classes})


_STATEFUL = {"AgentEnvs"}  # saved as their ``checkpoint_state()``, read back as that (``restore`` takes it)


def _as_tensor(a: np.ndarray) -> th.Tensor:
    """An array's tensor for ``torch.save`` (its memory, where it is contiguous and writable)."""
    return th.from_numpy(a if a.flags.c_contiguous and a.flags.writeable else np.array(a, order="C"))


class CheckpointRefused(Exception):
    """A checkpoint that is not read (one line: why)."""


class _Encoder:
    """A state as JSON plus a dict of tensors (see the module docstring)."""

    def __init__(self) -> None:
        self.tensors: dict[str, th.Tensor] = {}
        self._names: dict[int, str] = {}  # id(tensor or array) -> key in ``tensors``
        self._refs: dict[int, int] = {}  # id(object) -> its number, for objects met again
        self._alive: list[Any] = []  # whatever an id was taken of, so that no id is reused meanwhile

    def _tensor(self, value: Any, make) -> str:
        name = self._names.get(id(value))
        if name is None:
            name = self._names[id(value)] = f"t{len(self.tensors)}"
            self.tensors[name] = make(value)
            self._alive.append(value)
        return name

    def _shared(self, value: Any) -> dict[str, Any] | None:
        """``{"ref": n}`` for an object met before; else number it (the caller encodes it)."""
        if id(value) in self._refs:
            return {"ref": self._refs[id(value)]}
        self._refs[id(value)] = len(self._refs)
        self._alive.append(value)
        return None

    def encode(self, value: Any) -> Any:
        kind = type(value)
        if value is None or kind in (bool, int, str):
            return value
        if kind is float:
            return value if np.isfinite(value) else {"float": repr(value)}
        if isinstance(value, np.generic):
            if value.dtype.str not in _DTYPES:
                raise TypeError(f"a checkpoint holds no numpy {value.dtype} scalar")
            return {"scalar": value.dtype.str, "value": self.encode(value.item())}
        if isinstance(value, th.Tensor):
            return {"tensor": self._tensor(value, lambda t: t.detach()), "grad": value.requires_grad}
        if isinstance(value, np.ndarray):
            if value.dtype.str not in _DTYPES:
                raise TypeError(f"a checkpoint holds no numpy array of {value.dtype}")
            return {"array": self._tensor(value, _as_tensor), "dtype": value.dtype.str, "shape": list(value.shape)}
        if kind is tuple:
            return {"tuple": [self.encode(v) for v in value]}
        ref = self._shared(value)
        if ref is not None:
            return ref
        n = self._refs[id(value)]
        if kind in (list, dict) and _is_json(value):  # plain data (a day's metrics): as JSON, inner objects copied
            return {"json": value, "id": n}
        if kind is list and len(value) > 1 and _like_arrays(value):  # (the days drawn): one stacked array
            return {
                "stack": self._tensor(value, lambda v: th.from_numpy(np.stack(v))),
                "dtype": value[0].dtype.str,
                "shape": [len(value), *value[0].shape],
                "id": n,
            }
        if kind is list:
            return {"list": [self.encode(v) for v in value], "id": n}
        if kind is dict:
            return {"dict": [[self.encode(k), self.encode(v)] for k, v in value.items()], "id": n}
        if isinstance(value, np.random.Generator):
            return {"rng": self.encode(value.bit_generator.state), "id": n}
        if kind.__name__ in _OPTIMIZERS and _OPTIMIZERS[kind.__name__] is kind:
            return {
                "optimizer": kind.__name__,
                "params": self.encode([list(g["params"]) for g in value.param_groups]),
                "state_dict": self.encode(value.state_dict()),
                "id": n,
            }
        if kind.__name__ in _STATEFUL and hasattr(value, "checkpoint_state"):  # read back as the plain state it gives
            state = value.checkpoint_state()
            self._alive.append(state)
            return {"state_of": kind.__name__, "state": self.encode(state), "id": n}
        if _CLASSES.get(kind.__name__) is kind:
            return {"object": kind.__name__, "attrs": self.encode(dict(vars(value))), "id": n}
        raise TypeError(f"a checkpoint holds no {kind.__module__}.{kind.__qualname__}")


class _Decoder:
    """The inverse of :class:`_Encoder`: builds only plain data, tensors, arrays, numpy
    generators, the optimisers of :data:`_OPTIMIZERS` and the classes :func:`register` names."""

    def __init__(self, tensors: dict[str, th.Tensor], device: th.device) -> None:
        self.tensors = tensors
        self.device = device
        self._done: dict[tuple[str, str], Any] = {}  # tensors and arrays read so far (shared ones are one object)
        self._refs: dict[int, Any] = {}

    def _stored(self, name: Any) -> th.Tensor:
        if not isinstance(name, str) or name not in self.tensors:
            raise CheckpointRefused(f"its JSON names a tensor {str(name)[:40]!r} that its .pt does not hold")
        return self.tensors[name]

    def _register(self, node: dict[str, Any], value: Any) -> Any:
        n = node.get("id")
        if type(n) is not int or n in self._refs:
            raise CheckpointRefused("its JSON numbers its objects wrongly")
        self._refs[n] = value
        return value

    def decode(self, node: Any) -> Any:
        if node is None or type(node) in (bool, int, str, float):
            return node
        if type(node) is not dict:
            raise CheckpointRefused(f"its JSON holds a bare {type(node).__name__}")
        if "ref" in node:
            return _known(self._refs, node["ref"], "object")
        if "float" in node:
            return float(_known({"nan", "inf", "-inf"}, node["float"], "float"))
        if "scalar" in node:
            return _plain_dtype(node["scalar"]).type(self.decode(node["value"]))
        if "tensor" in node:
            key = ("tensor", node["tensor"])
            if key not in self._done:
                t = self._stored(node["tensor"])
                if t.device != self.device:
                    t = t.detach().to(self.device)
                self._done[key] = t.requires_grad_(bool(node.get("grad")) and t.is_floating_point())
            return self._done[key]
        if "array" in node:
            key = ("array", node["array"])
            if key not in self._done:
                dtype, shape = _plain_dtype(node["dtype"]), node["shape"]
                a = self._stored(node["array"]).detach().cpu().numpy()
                if a.dtype != dtype or not isinstance(shape, list) or list(a.shape) != shape:
                    raise CheckpointRefused(f"array {node['array']} is not the {dtype} {shape} its JSON says")
                self._done[key] = a
            return self._done[key]
        if "json" in node:  # JSON's own lists, dicts and scalars: nothing to build
            return self._register(node, node["json"])
        if "stack" in node:
            stacked = self.decode({"array": node["stack"], "dtype": node["dtype"], "shape": node["shape"]})
            return self._register(node, list(stacked))
        if "tuple" in node:
            return tuple(self.decode(v) for v in _list(node["tuple"]))
        if "list" in node:
            out: list[Any] = self._register(node, [])
            out.extend(self.decode(v) for v in _list(node["list"]))
            return out
        if "dict" in node:
            d: dict[Any, Any] = self._register(node, {})
            for pair in _list(node["dict"]):
                if not isinstance(pair, list) or len(pair) != 2:
                    raise CheckpointRefused("its JSON holds a bad dict")
                d[self.decode(pair[0])] = self.decode(pair[1])
            return d
        if "rng" in node:
            state = self.decode(node["rng"])
            bit_generator = _known(_BIT_GENERATORS, state["bit_generator"], "random generator")()
            bit_generator.state = state
            return self._register(node, np.random.Generator(bit_generator))
        if "optimizer" in node:
            cls = _known(_OPTIMIZERS, node["optimizer"], "optimiser")
            groups, state_dict = self.decode(node["params"]), self.decode(node["state_dict"])
            saved = state_dict["param_groups"][0]
            options = {k: v for k, v in saved.items() if k != "params" and k in inspect.signature(cls).parameters}
            optimizer = cls([{"params": params} for params in groups], **options)
            optimizer.load_state_dict(state_dict)
            return self._register(node, optimizer)
        if "state_of" in node:  # read back as the plain state; the live object restores itself from it
            _known(_STATEFUL, node["state_of"], "class")
            return self._register(node, self.decode(node["state"]))
        if "object" in node:
            cls = _known(_CLASSES, node["object"], "class")
            obj = self._register(node, cls.__new__(cls))
            attrs = self.decode(node["attrs"])
            if not isinstance(attrs, dict) or not all(isinstance(k, str) for k in attrs):
                raise CheckpointRefused(f"its JSON holds bad attributes of a {cls.__name__}")
            obj.__dict__.update(attrs)
            return obj
        raise CheckpointRefused(f"its JSON holds an unknown node {sorted(node)[:3]}")


def _known(table: Any, name: Any, what: str) -> Any:
    """``table[name]`` (a set: ``name``) for a name a checkpoint may use; else refused."""
    if not isinstance(name, (str, int)) or name not in table:
        raise CheckpointRefused(f"its JSON names an unknown {what} {str(name)[:40]!r}")
    return table[name] if isinstance(table, dict) else name


def _is_json(value: dict | list) -> bool:
    """Whether ``value`` is JSON's own data: str-keyed dicts, lists, None, bool, int, str,
    finite floats (each container scanned before its contents, so that most others fail fast)."""
    todo = [value]
    while todo:
        v = todo.pop()
        if type(v) is dict:
            if not all(type(k) is str for k in v):
                return False
            v = v.values()
        deeper = []
        for x in v:
            t = type(x)
            if t is dict or t is list:
                deeper.append(x)
            elif t not in _JSON_SCALARS and not (t is float and x - x == 0.0):  # not inf, not nan
                return False
        todo += deeper
    return True


def _like_arrays(values: list[Any]) -> bool:
    """Whether ``values`` are numpy arrays of one dtype (a checkpoint's) and one shape."""
    first = values[0]
    return (
        type(first) is np.ndarray
        and first.dtype.str in _DTYPES
        and all(type(v) is np.ndarray and v.dtype == first.dtype and v.shape == first.shape for v in values)
    )


def _plain_dtype(text: Any) -> np.dtype:
    """A numeric numpy dtype (bool, integers, floats) by its ``str``; else refused."""
    return _known(_DTYPES, text, "dtype")


def _list(value: Any) -> list[Any]:
    if isinstance(value, list):
        return value
    raise CheckpointRefused("its JSON holds a bad list")


def _sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _first_line(exc: BaseException) -> str:
    line = (str(exc).strip().splitlines() or [""])[0].strip()[:160]
    return line if isinstance(exc, CheckpointRefused) else f"{type(exc).__name__}: {line}".rstrip(": ")


class Checkpoint:
    """The checkpoint of one batch (``path``, its ``.state.json`` beside it): :attr:`state`
    holds what was saved, :meth:`save` writes when :meth:`due`, :meth:`remove` once the batch
    ends. The files are checked and read (``weights_only``) at once; their objects are
    rebuilt at the first read of :attr:`state`."""

    def __init__(self, path: str | Path, every_seconds: float = DEFAULT_EVERY_SECONDS, device: str | th.device = "cpu"):
        self.path = Path(path)
        self.every_seconds = every_seconds
        self.device = th.device(device)
        self.saved_at = time.monotonic()
        found = any(p.exists() for p in (self.path, self.sidecar, _tmp(self.path)))
        self._read: tuple[dict[str, Any], dict[str, th.Tensor]] | None = (
            self._refused_as_none(self._load) if found else None
        )
        self._state: dict[str, Any] | None = None
        self._onto: th.device | None = None  # the device ``_state`` was rebuilt onto
        self._started = time.monotonic()

    @property
    def state(self) -> dict[str, Any] | None:
        """What was saved, its tensors on :attr:`device`; None when there is no usable checkpoint."""
        if self._read is not None and self._onto != self.device:
            self._onto = self.device
            self._state = self._refused_as_none(lambda: self._rebuild(*self._read))
            if self._state is None:
                self._read = None
        return self._state if self._read is not None else None

    @property
    def seconds_before(self) -> float:
        """Training seconds spent before this process (in the runs that wrote the checkpoint)."""
        return float(self.state["seconds"]) if self.state else 0.0

    @property
    def sidecar(self) -> Path:
        """``<path>.state.json``: the JSON half."""
        return checkpoint_files(self.path)[1]

    def files(self) -> list[Path]:
        """Every file this checkpoint may have left (:func:`checkpoint_files`)."""
        return checkpoint_files(self.path)

    def _refused_as_none(self, read: Any) -> Any:
        try:
            return read()
        except Exception as exc:  # anything not written by this code, damaged, or of another version: start afresh
            print(
                f"nutribench: {self.path}: checkpoint refused ({_first_line(exc)}); the batch starts over",
                file=sys.stderr,
                flush=True,
            )
            return None

    def _load(self) -> tuple[dict[str, Any], dict[str, th.Tensor]]:
        if not self.sidecar.is_file():
            raise CheckpointRefused(f"no {self.sidecar.name} beside it: not a checkpoint of this nutribench")
        meta = json.loads(self.sidecar.read_text(encoding="utf-8"))
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise CheckpointRefused(f"{self.sidecar.name} is not of format {FORMAT}")
        digest = meta.get("tensors_sha256")
        if not self.path.is_file() or _sha256(self.path) != digest:
            tmp = _tmp(self.path)
            if not (tmp.is_file() and _sha256(tmp) == digest):
                raise CheckpointRefused(f"its tensors do not match {self.sidecar.name}")
            os.replace(tmp, self.path)  # a save stopped between its two renames: finish it
        if tuple(int(x) for x in th.__version__.split("+")[0].split(".")[:2]) < (2, 6):
            raise CheckpointRefused(
                "torch < 2.6 does not read tensors safely (CVE-2025-32434): upgrade torch to resume"
            )
        try:
            tensors = th.load(self.path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as exc:
            raise CheckpointRefused(
                "its .pt is not a plain dict of tensors (torch.load with weights_only refused it)"
            ) from exc
        if not isinstance(tensors, dict) or not all(
            isinstance(k, str) and isinstance(v, th.Tensor) for k, v in tensors.items()
        ):
            raise CheckpointRefused("its .pt is not a dict of tensors")
        return meta, tensors

    def _rebuild(self, meta: dict[str, Any], tensors: dict[str, th.Tensor]) -> dict[str, Any]:
        state = _Decoder(tensors, self.device).decode(meta.get("state"))
        if not isinstance(state, dict) or not isinstance(state.get("seconds"), float):
            raise CheckpointRefused("its JSON holds no state")
        return state

    def read_onto(self, device: str | th.device) -> dict[str, Any] | None:
        """:attr:`state` with its tensors on ``device`` (rebuilt again if it was on another)."""
        self.device = th.device(device)
        return self.state

    def due(self) -> bool:
        """Whether ``every_seconds`` have passed since the last save (or the start)."""
        return time.monotonic() - self.saved_at >= self.every_seconds

    def save(self, **state: Any) -> None:
        """Write ``state`` (plus the training seconds so far): both halves to temporary names,
        then renamed (the JSON first). A save that fails for want of disk says so in one line;
        the previous checkpoint stays, and training goes on."""
        encoder = _Encoder()
        node = encoder.encode({**state, "seconds": self.seconds_before + time.monotonic() - self._started})
        tmp, sidecar_tmp = _tmp(self.path), _tmp(self.sidecar)
        renamed = False
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            th.save(encoder.tensors, tmp)
            meta = {"format": FORMAT, "tensors_sha256": _sha256(tmp), "state": node}
            sidecar_tmp.write_text(json.dumps(meta, separators=(",", ":")), encoding="utf-8")
            os.replace(sidecar_tmp, self.sidecar)
            renamed = True  # from here the new JSON names the new tensors: a read finds them at ``tmp``
            os.replace(tmp, self.path)
        except OSError as exc:
            for p in (sidecar_tmp,) if renamed else (tmp, sidecar_tmp):
                p.unlink(missing_ok=True)
            print(
                f"nutribench: {self.path}: checkpoint not saved ({_first_line(exc)}); training goes on",
                file=sys.stderr,
                flush=True,
            )
        self.saved_at = time.monotonic()

    def remove(self) -> None:
        """Delete its files (the batch has ended and its results are handed over)."""
        for p in self.files():
            p.unlink(missing_ok=True)


def checkpoint_files(path: str | Path) -> list[Path]:
    """The files a checkpoint at ``path`` may have left: the two halves and their temporary names."""
    path = Path(path)
    return [path, path.with_name(path.name + ".state.json"), _tmp(path), path.with_name(path.name + ".state.json.tmp")]


def _tmp(path: Path) -> Path:
    return path.with_name(path.name + ".tmp")


def resumed(checkpoint: Checkpoint | None, key: str) -> Any:
    """``checkpoint.state[key]`` when resuming from ``checkpoint``, else None."""
    return None if checkpoint is None or checkpoint.state is None else checkpoint.state[key]
