"""Checkpoints of a batch in training, so that a stopped batch resumes instead of starting over.

A paper-grid batch trains for hours and its jobs are stored only when it ends. With a
:class:`Checkpoint`, the training loops save the algorithm's
:meth:`~nutribench.engine.algorithm.BatchedAlgorithm.state_dict` at a day (off-policy) or rollout
(on-policy) boundary every ``every_seconds``: networks, optimisers, replay buffers,
statistics, the envs and every random stream, the days and diagnostics so far. A batch
started again on the same file makes its algorithm afresh and loads that state into it
(``load_state_dict``); it ends exactly where an uninterrupted batch would (tested: same
metrics, same weights).

A state is plain data: tensors, numpy arrays of numbers, JSON's own values, and tuples and
dicts with non-string keys (an optimiser's ``state_dict``), marked. No pickle and no class
names, so a file planted in a shared models folder cannot run code: ``<name>.pt`` is a flat
dict of the state's tensors and arrays (``torch.save``, read with ``weights_only=True``),
``<name>.pt.state.json`` the rest, naming each tensor by its key and the sha256 of the
``.pt``. A save writes both to temporary names, then renames the JSON, then the tensors; a
process killed between the two renames leaves the new tensors at the temporary name, and
the next read puts them in place. A checkpoint that does not read this way (a pickle, a
damaged file, tensors that do not match their JSON, an older format) is refused in one line
(a warning of the ``nutribench.engine.checkpoint`` logger: on stderr where logging is not
configured, as in a worker process) and the batch starts over. A save that fails (a full
disk) says so in one line the same way, the previous checkpoint stays whole, and training
goes on.

A checkpoint is read onto the device the batch trains on (:meth:`Checkpoint.read_onto`): a
batch stopped on a GPU resumes on the CPU and the other way round, its tensors moved, its
numpy arrays (replays, statistics, envs) the CPU's on every device; it then goes on as a run
on that device would, not bit for bit as the first device's would.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pickle
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from nutribench.engine import DEFAULT_EVERY_SECONDS, EVERY_SECONDS_ENV, every_seconds_from_env  # noqa: F401 (here too)

log = logging.getLogger(__name__)

#: the JSON half's ``format``: a checkpoint of another (an older nutribench's) is refused
CHECKPOINT_FORMAT = "nutribench-checkpoint/3"

_SCALARS = (type(None), bool, int, str, float)


class CheckpointRefused(Exception):
    """A checkpoint that is not read (one line: why)."""


def encode(value: Any, tensors: dict[str, th.Tensor]) -> Any:
    """``value`` (plain data) as JSON, its tensors and arrays put into ``tensors`` by key."""
    if type(value) in _SCALARS:
        return value
    if isinstance(value, np.generic) and value.dtype.kind in "biuf":
        return value.item()
    key = f"t{len(tensors)}"  # the next tensor's
    if isinstance(value, th.Tensor):
        tensors[key] = value.detach()
        return {"$tensor": key}
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise TypeError(f"a checkpoint holds arrays of numbers only, not of {value.dtype}")
        writable = value.flags.c_contiguous and value.flags.writeable
        tensors[key] = th.from_numpy(value if writable else np.array(value, order="C"))
        return {"$array": key}
    if isinstance(value, tuple):
        return {"$tuple": [encode(v, tensors) for v in value]}
    if isinstance(value, list):
        return [encode(v, tensors) for v in value]
    if isinstance(value, dict):
        if all(type(k) is str and not k.startswith("$") for k in value):
            return {k: encode(v, tensors) for k, v in value.items()}
        return {"$items": [[encode(k, tensors), encode(v, tensors)] for k, v in value.items()]}
    raise TypeError(f"a checkpoint holds plain data only, not a {type(value).__module__}.{type(value).__qualname__}")


def decode(node: Any, tensors: dict[str, th.Tensor], device: th.device) -> Any:
    """The inverse of :func:`encode`: tensors onto ``device``, arrays on the CPU."""
    if type(node) in _SCALARS:
        return node
    if type(node) is list:
        return [decode(v, tensors, device) for v in node]
    if type(node) is not dict:
        raise CheckpointRefused(f"its JSON holds a {type(node).__name__}")
    if "$tensor" in node or "$array" in node:
        key = node.get("$tensor", node.get("$array"))
        if not isinstance(key, str) or key not in tensors:
            raise CheckpointRefused(f"its JSON names a tensor {str(key)[:40]!r} that its .pt does not hold")
        return tensors[key].to(device) if "$tensor" in node else tensors[key].numpy()
    if "$tuple" in node and type(node["$tuple"]) is list:
        return tuple(decode(v, tensors, device) for v in node["$tuple"])
    if "$items" in node and type(node["$items"]) is list:
        pairs = [decode(pair, tensors, device) for pair in node["$items"]]
        if not all(type(pair) is list and len(pair) == 2 and type(pair[0]) in _SCALARS for pair in pairs):
            raise CheckpointRefused("its JSON holds a bad dict")
        return dict(pairs)
    unknown = [k for k in node if k.startswith("$")]
    if unknown:
        raise CheckpointRefused(f"its JSON holds an unknown node {unknown[0][:40]!r}")
    return {k: decode(v, tensors, device) for k, v in node.items()}


def _sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _first_line(exc: BaseException) -> str:
    line = (str(exc).strip().splitlines() or [""])[0].strip()[:160]
    return line if isinstance(exc, CheckpointRefused) else f"{type(exc).__name__}: {line}".rstrip(": ")


class Checkpoint:
    """The checkpoint of one batch (``path``, its ``.state.json`` beside it): :attr:`state` holds
    what was saved (checked and read at once, decoded when first asked for), :meth:`save` writes
    when :meth:`due`, :meth:`remove` once the batch ends."""

    def __init__(self, path: str | Path, every_seconds: float | None = None, device: str | th.device = "cpu"):
        self.path = Path(path)
        #: seconds between saves (None: :func:`every_seconds_from_env`)
        self.every_seconds = every_seconds_from_env() if every_seconds is None else every_seconds
        self.device = th.device(device)
        self.saved_at = time.monotonic()
        found = any(p.exists() for p in (self.path, self.sidecar, _tmp(self.path)))
        self._read: tuple[Any, dict[str, th.Tensor]] | None = self._refused_as_none(self._load) if found else None
        self._state: dict[str, Any] | None = None
        self._onto: th.device | None = None  # the device ``_state`` was decoded onto
        self._started = time.monotonic()

    @property
    def state(self) -> dict[str, Any] | None:
        """What was saved, its tensors on :attr:`device`; None when there is no usable checkpoint."""
        if self._read is not None and self._onto != self.device:
            self._onto = self.device
            self._state = self._refused_as_none(lambda: self._decode(*self._read))  # refused: no _read
        return self._state if self._read is not None else None

    @property
    def seconds_before(self) -> float:
        """Training seconds spent before this process (in the runs that wrote the checkpoint)."""
        return float(self.state["seconds"]) if self.state else 0.0

    @property
    def sidecar(self) -> Path:
        """``<path>.state.json``: the JSON half."""
        return checkpoint_files(self.path)[1]

    def _refused_as_none(self, read: Any) -> Any:
        try:
            return read()
        except Exception as exc:  # anything not written by this code, damaged, or of another version: start afresh
            return self.refuse(exc)

    def refuse(self, exc: BaseException) -> None:
        """Say in one line why this checkpoint is not used, and hold no state from now on."""
        log.warning("nutribench: %s: checkpoint refused (%s); the batch starts over", self.path, _first_line(exc))
        self._read = self._state = None

    def _load(self) -> tuple[Any, dict[str, th.Tensor]]:
        if not self.sidecar.is_file():
            raise CheckpointRefused(f"no {self.sidecar.name} beside it: not a checkpoint of this nutribench")
        meta = json.loads(self.sidecar.read_text(encoding="utf-8"))
        if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
            raise CheckpointRefused(f"{self.sidecar.name} is not of format {CHECKPOINT_FORMAT}")
        digest = meta.get("tensors_sha256")
        if not self.path.is_file() or _sha256(self.path) != digest:
            tmp = _tmp(self.path)
            if not (tmp.is_file() and _sha256(tmp) == digest):
                raise CheckpointRefused(f"its tensors do not match {self.sidecar.name}")
            os.replace(tmp, self.path)  # a save stopped between its two renames: finish it
        if tuple(int(x) for x in th.__version__.split("+")[0].split(".")[:2]) < (2, 6):
            raise CheckpointRefused("torch < 2.6 reads tensors unsafely (CVE-2025-32434): upgrade torch to resume")
        try:
            tensors = th.load(self.path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as exc:
            raise CheckpointRefused("its .pt is not a plain dict of tensors (weights_only refused it)") from exc
        if not isinstance(tensors, dict) or not all(
            isinstance(k, str) and isinstance(v, th.Tensor) for k, v in tensors.items()
        ):
            raise CheckpointRefused("its .pt is not a dict of tensors")
        return meta.get("state"), tensors

    def _decode(self, node: Any, tensors: dict[str, th.Tensor]) -> dict[str, Any]:
        state = decode(node, tensors, self.device)
        if not isinstance(state, dict) or not isinstance(state.get("seconds"), float):
            raise CheckpointRefused("its JSON holds no state")
        return state

    def read_onto(self, device: str | th.device) -> dict[str, Any] | None:
        """:attr:`state` with its tensors on ``device`` (decoded again if it was on another)."""
        self.device = th.device(device)
        return self.state

    def due(self) -> bool:
        """Whether ``every_seconds`` have passed since the last save (or the start)."""
        return time.monotonic() - self.saved_at >= self.every_seconds

    def save(self, **state: Any) -> None:
        """Write ``state`` (plain data, plus the training seconds so far): both halves to
        temporary names, then renamed (the JSON first). A save that fails for want of disk
        says so in one line; the previous checkpoint stays, and training goes on."""
        tensors: dict[str, th.Tensor] = {}
        node = encode({**state, "seconds": self.seconds_before + time.monotonic() - self._started}, tensors)
        tmp, sidecar_tmp = _tmp(self.path), _tmp(self.sidecar)
        renamed = False
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            th.save(tensors, tmp)
            meta = {"format": CHECKPOINT_FORMAT, "tensors_sha256": _sha256(tmp), "state": node}
            sidecar_tmp.write_text(json.dumps(meta, separators=(",", ":")), encoding="utf-8")
            os.replace(sidecar_tmp, self.sidecar)
            renamed = True  # from here the new JSON names the new tensors: a read finds them at ``tmp``
            os.replace(tmp, self.path)
        except OSError as exc:
            for p in (sidecar_tmp,) if renamed else (tmp, sidecar_tmp):
                p.unlink(missing_ok=True)
            log.warning("nutribench: %s: checkpoint not saved (%s); training goes on", self.path, _first_line(exc))
        self.saved_at = time.monotonic()

    def remove(self) -> None:
        """Delete its files (the batch has ended and its results are handed over)."""
        for p in checkpoint_files(self.path):
            p.unlink(missing_ok=True)


def checkpoint_files(path: str | Path) -> list[Path]:
    """The files a checkpoint at ``path`` may have left: the two halves and their temporary names."""
    path = Path(path)
    return [path, path.with_name(path.name + ".state.json"), _tmp(path), path.with_name(path.name + ".state.json.tmp")]


def _tmp(path: Path) -> Path:
    return path.with_name(path.name + ".tmp")
