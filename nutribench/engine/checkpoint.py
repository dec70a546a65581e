"""Checkpoints of a batch in training, so that a stopped batch resumes instead of starting over.

A batch of the paper grid trains for hours (ten SAC agents: about two). Its jobs are stored
only when the whole batch ends, so without checkpoints a stopped process loses all of it.
With a :class:`Checkpoint`, the training loops save their whole state at a day boundary
(the off-policy loop) or a rollout boundary (the on-policy loop) every ``every_seconds``:
the K agents' networks and optimisers, replay buffers, observation and return statistics,
the envs and every random stream, the days recorded so far. A batch started again on the
same file carries on from there and ends exactly where an uninterrupted batch would
(tested: same metrics, same weights). The file is written to a temporary name and renamed,
so a process killed while saving leaves the previous checkpoint whole.

A checkpoint moves between devices: it is read with ``map_location`` onto the device the
batch trains on (:meth:`Checkpoint.read_onto`), so a batch stopped on a GPU resumes on the
CPU and the other way round; every tensor of the state (parameters, optimiser moments and
steps, GRU states) goes to that device, while the random streams (numpy generators) and
the replay buffers and statistics (numpy arrays) are the CPU's on every device. The resumed
run then goes on as a run on that device would, not bit for bit as the first device's would.

The file is a pickle (``torch.save``): read only checkpoints this tool wrote.
"""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path
from typing import Any

import torch as th

#: how often a batch saves its state (seconds of wall time, checked at day boundaries)
DEFAULT_EVERY_SECONDS = 300.0


class Checkpoint:
    """The checkpoint file of one batch: ``state`` holds what was saved (None when there is
    no usable file; its tensors on ``device``), :meth:`save` writes when :meth:`due`,
    :meth:`remove` once the batch ends."""

    def __init__(self, path: str | Path, every_seconds: float = DEFAULT_EVERY_SECONDS, device: str | th.device = "cpu"):
        self.path = Path(path)
        self.every_seconds = every_seconds
        self.device = th.device(device)
        self.saved_at = time.monotonic()
        self.state: dict[str, Any] | None = self._read()
        #: training seconds spent before this process (in the runs that wrote the checkpoint)
        self.seconds_before = float(self.state["seconds"]) if self.state else 0.0
        self._started = time.monotonic()

    def _read(self) -> dict[str, Any] | None:
        if not self.path.is_file():
            return None
        try:
            return th.load(self.path, map_location=self.device, weights_only=False)
        except Exception as exc:  # a file from another code version, or damaged: start afresh
            warnings.warn(f"{self.path}: unreadable checkpoint ({type(exc).__name__}: {exc}); the batch starts over", stacklevel=2)
            return None

    def read_onto(self, device: str | th.device) -> dict[str, Any] | None:
        """:attr:`state` with its tensors on ``device``: read again from the file (with
        ``map_location``) if it was read onto another device."""
        if self.state is not None and th.device(device) != self.device:
            self.device = th.device(device)
            self.state = self._read()
        return self.state

    def due(self) -> bool:
        """Whether ``every_seconds`` have passed since the last save (or the start)."""
        return time.monotonic() - self.saved_at >= self.every_seconds

    def save(self, **state: Any) -> None:
        """Write ``state`` (plus the training seconds so far) atomically."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        th.save({**state, "seconds": self.seconds_before + time.monotonic() - self._started}, tmp)
        os.replace(tmp, self.path)
        self.saved_at = time.monotonic()

    def remove(self) -> None:
        """Delete the file (the batch has ended and its results are handed over)."""
        self.path.unlink(missing_ok=True)
        self.path.with_name(self.path.name + ".tmp").unlink(missing_ok=True)


def resumed(checkpoint: Checkpoint | None, key: str) -> Any:
    """``checkpoint.state[key]`` when resuming from ``checkpoint``, else None."""
    if checkpoint is None or checkpoint.state is None:
        return None
    return checkpoint.state[key]
