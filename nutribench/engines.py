"""The engines a job can be trained by, named once: every other module spells them through
:class:`Engine` (a ``str`` enum: its members equal the strings stored in ``jobs.engine``, in
archives and on the command line, so reading old rows and parsing ``--engine`` are unchanged).

* :attr:`Engine.SB3`: one job per worker through Stable-Baselines3 (``nutribench run``'s default);
* :attr:`Engine.BATCHED`: the jobs of one agent config trained together (:mod:`nutribench.engine`);
* :attr:`Engine.EXTERNAL`: a plug-in's or a recorded loop's own training (:mod:`nutribench.recorder`).
"""

from __future__ import annotations

from enum import StrEnum


class Engine(StrEnum):
    """What trained a job (``jobs.engine``)."""

    SB3 = "sb3"
    BATCHED = "batched"
    EXTERNAL = "external"


#: The engines ``nutribench run --engine`` and the benchmarks train with (nutribench's own).
TRAINING_ENGINES: tuple[Engine, ...] = (Engine.SB3, Engine.BATCHED)
#: Every engine a stored job (or an archive's) may name.
ENGINES: tuple[Engine, ...] = tuple(Engine)
