"""What ``nutribench report`` is asked to build (:class:`ReportRequest`): the ``--fig``,
``--table``, ``--algos`` and ``--pair`` values parsed, the combinations of options checked
(one line each, before the database is read), and the files built.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path

from nutribench.errors import UserError, check_range


def _split(values: list[str] | None) -> list[str]:
    """Repeated options and comma lists, flattened: ``--fig 1 --fig 3,4`` -> 1, 3, 4."""
    return [v.strip() for value in values or [] for v in value.split(",") if v.strip()]


def parse_figs(values: list[str] | None) -> list[int]:
    """``--fig`` values as figure numbers (``all`` = every figure; ``aggregate`` = 5, ``learning``
    = 6); bad values raise UserError."""
    from nutribench.report.build import FIGURE_NAMES, FIGURES

    items = [str(FIGURE_NAMES.get(v, v)) for v in _split(values)]
    if "all" in items:
        return list(FIGURES)
    bad = [v for v in items if not (v.isdigit() and int(v) in FIGURES)]
    if bad:
        raise UserError(
            f"--fig {', '.join(bad)}: the figures are {', '.join(map(str, FIGURES))} "
            f"({', '.join(f'{n} = {k}' for n, k in FIGURE_NAMES.items())}; repeat --fig or give a comma list)"
        )
    return list(dict.fromkeys(int(v) for v in items))


def parse_algos(value: str | None) -> list[str] | None:
    """``--algos a,b,c`` as names (None: every config of the database)."""
    if value is None:
        return None
    names = list(dict.fromkeys(_split([value])))
    if not names:
        raise UserError("--algos: give a comma list of agent config names, e.g. --algos ppo,sac")
    return names


def parse_pair(value: str | None) -> list[str] | None:
    """``--pair a,b``: Figure 4's two agent configs (None: ppo,gru_ppo)."""
    if value is None:
        return None
    names = _split([value])
    if len(names) != 2 or names[0] == names[1]:
        raise UserError(f"--pair {value}: give two different agent configs, e.g. --pair ppo,gru_ppo")
    return names


@dataclass(frozen=True)
class ReportRequest:
    """The figures (numbers) and tables (names) to build, or every one the database supports
    (``all``), drawing ``algos`` (None: every config) with Figure 4's ``pair``; or one
    ``trajectory`` (``algo`` on ``regime``, ``seed``'s job, evaluation ``episode``), or one
    agent config's training ``diagnostics`` (``seed``: only that one)."""

    figs: list[int]
    tables: list[str]
    all: bool = False
    algos: list[str] | None = None
    pair: list[str] | None = None
    trajectory: bool = False
    diagnostics: bool = False
    algo: str | None = None
    regime: str | None = None
    seed: int | None = None
    episode: int = 0
    reference_episodes: int = 200

    @classmethod
    def parse(
        cls, fig: list[str] | None, table: list[str] | None, all: bool, algos: str | None, pair: str | None, *rest
    ) -> ReportRequest:
        """The request of the command line's values (in the order of the fields), checked (:meth:`check`)."""
        # --table: 1-6, results, training, all, or a number from 7 / a config name for the database's
        # other agent configs (those are checked against the database when it is read)
        tables = list(dict.fromkeys(_split(table)))
        request = cls(parse_figs(fig), tables, all, parse_algos(algos), parse_pair(pair), *rest)
        request.check()
        return request

    @property
    def figures_or_tables(self) -> bool:
        return bool(self.figs or self.tables or self.all)

    def check(self) -> None:
        """Refuse an empty request or options that do not go together, one line each."""
        from nutribench.scheduler.grid import MAX_EPISODES, MAX_SEED

        if not (self.figures_or_tables or self.trajectory or self.diagnostics):
            raise UserError(
                "nothing to build: pass --fig, --table, --all, --trajectory or --diagnostics (see nutribench report --help)"
            )
        if self.trajectory and self.diagnostics:
            raise UserError("--trajectory and --diagnostics each take --algo --regime: build one at a time")
        if (self.algos or self.pair) and not self.figures_or_tables:
            raise UserError("--algos and --pair select what figures and tables draw: add --fig, --table or --all")
        needs = {"--algo": self.algo, "--regime": self.regime}
        if self.trajectory or self.diagnostics:
            needs |= {"--seed": self.seed} if self.trajectory else {}
            missing = [o for o, v in needs.items() if v is None]
            if missing:
                raise UserError(f"--{'trajectory' if self.trajectory else 'diagnostics'} needs {', '.join(missing)}")
        elif self.algo is not None or self.regime is not None or self.seed is not None:
            raise UserError(
                "--algo, --regime and --seed pick a trajectory or diagnostics: add --trajectory or --diagnostics"
            )
        if self.seed is not None:  # past the database's integer: an OverflowError traceback where it was compared
            check_range("--seed", self.seed, 0, MAX_SEED)
        why = "an evaluation episode's number as the database holds it"
        check_range("--episode", self.episode, 0, MAX_EPISODES - 1, why)

    def build(
        self,
        db: str,
        out: Path,
        log: Callable[[str], None] = print,
        progress: Callable[[str, str], AbstractContextManager] | None = None,
    ) -> list[Path]:
        """Build what is asked from the database ``db`` into ``out``; the files written. ``log``
        hears what is left out and why; ``progress(description, text)`` (None: none), a context
        manager that yields ``advance(text, done, total)``, shows the item being built."""
        from nutribench.report.build import build_report, build_trajectory

        paths: list[Path] = []
        if self.figures_or_tables:
            with progress("report", "reading the database") if progress else nullcontext(None) as advance:
                step = None if advance is None else lambda msg: advance(msg, *counted(msg))
                what = (self.figs, self.tables, self.all, self.reference_episodes, log, self.algos, self.pair, step)
                paths += build_report(db, out, *what)
        if self.trajectory:
            paths += build_trajectory(db, self.algo, self.regime, self.seed, episode=self.episode, out=out)
        if self.diagnostics:
            from nutribench.report.diagnostics import build_diagnostics

            seeds = None if self.seed is None else [self.seed]
            paths += build_diagnostics(db, self.algo, self.regime, seeds=seeds, out=out)
        return paths


def counted(msg: str) -> tuple[int | None, int | None]:
    """Items done and items in all of ``build_report``'s ``[3/14] figure 3``: (2, 14)."""
    m = re.match(r"\[(\d+)/(\d+)\]", msg)
    return (int(m[1]) - 1, int(m[2])) if m else (None, None)
