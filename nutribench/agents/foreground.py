"""``nutribench train``'s one agent in the foreground (:class:`TrainRequest`): its options
checked before anything trains (the config files, a ``--save`` file that could not
be written, ``--tensorboard``), trained, evaluated greedily on the evaluation days of its seed,
the evaluation as table cells, and saved.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nutribench.errors import UserError

#: the columns of :meth:`TrainRequest.evaluation_cells`
EVALUATION_HEADERS = ("eval day", "return", "foods", "final distance", "overshoot ratio", "final C/F/P")


@dataclass(frozen=True)
class TrainRequest:
    """Train agent config ``algo`` on ``regime`` with ``seed`` for ``days`` days (``eval_every``:
    a greedy evaluation on ``val_episodes`` validation days every so many days), then play
    ``eval_episodes`` evaluation days; ``save``: a .zip the model goes to; ``tensorboard``: a
    folder whose run folder ``<algo>-<regime>-seed<seed>`` gets the training diagnostics. No
    field has a default: the command line's options hold them (``nutribench train --help``)."""

    algo: str
    regime: str
    seed: int
    days: int
    eval_episodes: int
    save: Path | None
    tensorboard: Path | None
    eval_every: int
    val_episodes: int

    def configs(self) -> tuple[Any, Any, Path | None]:
        """The regime's and the agent's configs and the TensorBoard run folder, the files
        checked first (one line each; the ranges of the numbers are the caller's)."""
        from nutribench.agents.api import vec_normalize_path
        from nutribench.agents.config import load_agent_config
        from nutribench.config import load_env_config
        from nutribench.safe_write import check_file_target, check_tensorboard

        env_cfg, cfg, save = load_env_config(self.regime), load_agent_config(self.algo), self.save
        if save is not None and save.suffix != ".zip":
            raise UserError(f"--save {save}: the model file must end in .zip")
        if save is not None and not save.parent.is_dir():
            raise UserError(f"--save {save}: folder {save.parent} does not exist")
        for written in (save, vec_normalize_path(save), save.with_suffix(".json")) if save is not None else ():
            check_file_target(written, "--save", UserError)
        if self.tensorboard is None:
            return env_cfg, cfg, None
        check_tensorboard(self.tensorboard)
        return env_cfg, cfg, self.tensorboard / f"{cfg.name}-{env_cfg.name}-seed{self.seed}"

    def evaluation_cells(self, agent: Any, env_cfg: Any) -> list[list[str]]:
        """The greedy evaluation on the seed's evaluation days: a row of cells per day, then the means."""
        from nutribench.agents.api import eval_food_streams, evaluate
        from nutribench.baselines import SUMMARY_KEYS

        streams = eval_food_streams(env_cfg, self.seed, self.eval_episodes)
        days = evaluate(agent, env_cfg, streams, record_steps=False).episodes
        cells = [
            [str(r["episode"]), f"{r['return']:.2f}", str(r["foods"]), f"{r['final_distance']:.3f}"]
            + [f"{r['overshoot_ratio']:.2f}", f"{r['final_C']:.2f} / {r['final_F']:.2f} / {r['final_P']:.2f}"]
            for r in days
        ]
        mean = {k: sum(r[k] for r in days) / len(days) for k in SUMMARY_KEYS}
        means = f"{mean['return']:.2f}", f"{mean['foods']:.2f}", f"{mean['final_distance']:.3f}"
        return [*cells, ["mean", *means, f"{mean['overshoot_ratio']:.2f}", ""]]

    def saved(self, agent: Any) -> str:
        """Save the model to ``save``; the line that says where (and the files beside it)."""
        from nutribench.agents.api import vec_normalize_path

        path = agent.save(self.save)
        extra = [p.name for p in (vec_normalize_path(path), path.with_suffix(".json")) if p.is_file()]
        return f'model saved to {path} (+ {", ".join(extra)}; README "Agents" shows how to load it with plain SB3)'


def validation_printer(say: Any, env_cfg: Any, seed: int, n: int) -> Any:
    """``train``'s ``on_validation``: one line per evaluation during training (mean return on the
    validation days, the share of the never -> planner gap it closes there), said to ``say``."""
    from nutribench.baselines import gap_closed, validation_yardsticks

    yard = validation_yardsticks(env_cfg, seed, n)

    def show(_: int, day: int, rows: list[dict]) -> None:
        ret = sum(r["return"] for r in rows) / len(rows)
        share = gap_closed(ret, yard["never"], yard["planner"])
        say(f"validation after day {day}: return {ret:.2f} on {len(rows)} days, gap closed {share:.0%}")

    return show
