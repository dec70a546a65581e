"""Addendum 2's ``reports/ladder/rename_checkpoints.py``: a checkpoint brought back from a lent
machine is renamed only when its manifest reproduces its name for the machine's commit and version.
A check of this study's script (``python -m pytest reports/ladder``); the digest itself, the
package's, is tested in ``tests/test_batch_digest.py``."""

from __future__ import annotations

import json
from pathlib import Path

from report_scripts import load_script

from nutribench.scheduler.batched_job import batch_digest

JOBS = [
    {"job_id": i, "algo_sha256": "a" * 64, "regime_sha256": r * 64, "seed": s, "episodes": 5000}
    for i, (r, s) in enumerate([("b", 3800), ("b", 3801), ("c", 3800)], start=1)
]


def rename(*argv: str) -> int:
    return load_script("ladder", "rename_checkpoints").main(list(argv))


def checkpoint(folder: Path, digest: str) -> None:
    for suffix, text in ((".pt", "tensors"), (".pt.state.json", "{}"), (".pt.jobs.json", json.dumps({"jobs": JOBS}))):
        (folder / f"gru_ppo-v2-{digest}{suffix}").write_text(text)


def test_renamed_only_when_the_name_is_reproduced(tmp_path, capsys):
    machine = batch_digest("c1", JOBS, 100, 5, "0.0.0+unknown")
    checkpoint(tmp_path, machine)
    assert rename(str(tmp_path), "--from", "c1", "--to", "c2") == 1  # this install's version: not the machine's name
    assert "left as it is" in capsys.readouterr().err
    assert rename(str(tmp_path), "--from", "c1", "--from-version", "0.0.0+unknown", "--to", "c2") == 0
    here = batch_digest("c2", JOBS, 100, 5)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"gru_ppo-v2-{here}{s}" for s in (".pt", ".pt.state.json", ".pt.jobs.json")
    )
    assert (tmp_path / f"gru_ppo-v2-{here}.pt").read_text() == "tensors"
