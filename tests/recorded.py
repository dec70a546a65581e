"""A small archive of real results, for the archive tests that replay evaluation days: two
jobs recorded by :class:`nutribench.Recorder` (a hand-written policy, no torch), each with
two training days and two evaluation days on run0, exported with ``db export``."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

import nutribench
from nutribench.cli import app


def recorded_archive(folder: Path) -> tuple[Path, Path]:
    """``(database, archive)`` of the two recorded jobs (seeds 0 and 1)."""
    db = folder / "real.db"
    for seed in (0, 1):
        with nutribench.Recorder(db=str(db), name="eat_early", regime="run0", seed=seed, eval_episodes=2) as rec:
            for _ in range(2):
                rec.env.reset()
                for t in range(50):
                    rec.env.step(int(t < 4))
            rec.evaluate(lambda obs: int(obs[:3].sum() < 1.5))
    archive = folder / "real.npz"
    res = CliRunner().invoke(app, ["db", "export", str(archive), "--db", str(db)])
    assert res.exit_code == 0, res.output
    return db, archive
