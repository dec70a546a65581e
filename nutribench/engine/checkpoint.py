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
    no usable file), :meth:`save` writes when :meth:`due`, :meth:`remove` once the batch ends."""

    def __init__(self, path: str | Path, every_seconds: float = DEFAULT_EVERY_SECONDS):
        self.path = Path(path)
        self.every_seconds = every_seconds
        self.saved_at = time.monotonic()
        self.state: dict[str, Any] | None = self._read()
        #: training seconds spent before this process (in the runs that wrote the checkpoint)
        self.seconds_before = float(self.state["seconds"]) if self.state else 0.0
        self._started = time.monotonic()

    def _read(self) -> dict[str, Any] | None:
        if not self.path.is_file():
            return None
        try:
            return th.load(self.path, weights_only=False)
        except Exception as exc:  # a file from another code version, or damaged: start afresh
            warnings.warn(f"{self.path}: unreadable checkpoint ({type(exc).__name__}: {exc}); the batch starts over", stacklevel=2)
            return None

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
