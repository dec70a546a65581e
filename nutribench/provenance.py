"""Reproducibility facts about the running process (host, versions, git commit), recorded with
every job and every saved model. At the bottom of the house: agents and jobs both use it."""

from __future__ import annotations

import functools
import hashlib
import platform
import socket
import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any


def dist_version(dist: str) -> str | None:
    """The installed version of the distribution ``dist``; None when it is not installed."""
    try:
        return version(dist)
    except PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def git_state(folder: str | None = None) -> tuple[str | None, bool | None]:
    """(commit, dirty) of the checkout holding the nutribench package; (None, None) if it is
    not a git checkout. Dirty means tracked files differ from the commit (untracked files,
    such as a results database in the tree, do not count)."""
    where = folder or str(Path(__file__).resolve().parents[1])  # <checkout>/nutribench/provenance.py

    def git(*args: str, timeout: int) -> str:
        run = subprocess.run(["git", "-C", where, *args], capture_output=True, text=True, timeout=timeout, check=True)
        return run.stdout.strip()

    try:
        commit = git("rev-parse", "HEAD", timeout=10)
        dirty = git("status", "--porcelain", "--untracked-files=no", timeout=30) != ""
    except (OSError, subprocess.SubprocessError):
        return None, None
    return (commit or None), dirty


def file_sha256(path: str | Path | None) -> str | None:
    """sha256 of a file's bytes (None when ``path`` is not a file): what an external job's
    source, a recorded script or an evaluated model file, is recorded with."""
    if not path or not Path(path).is_file():
        return None
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def collect_metadata() -> dict[str, Any]:
    """Host, platform, Python and package versions, git commit and whether the tree is dirty."""
    import nutribench

    commit, dirty = git_state()
    return {
        "host": socket.gethostname(),
        "platform": platform.platform(terse=True)[:255],
        "python_version": platform.python_version(),
        "numpy_version": dist_version("numpy"),
        "torch_version": dist_version("torch"),
        "sb3_version": dist_version("stable-baselines3") or dist_version("stable_baselines3"),
        "nutribench_version": nutribench.__version__,
        "git_commit": commit,
        "git_dirty": dirty,
    }
