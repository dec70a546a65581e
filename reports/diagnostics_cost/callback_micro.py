"""Where a PPO job's diagnostics could spend time, piece by piece, in one process:

1. per env step: what the diagnostics callback adds to SB3's callback dispatch
   (``CallbackList([recorder, diagnostics])`` against ``CallbackList([recorder])``, the
   recorder a do-nothing stand-in; ``update_locals`` and ``on_step`` with the locals of a
   real rollout step), 200,000 calls each, alternating in 20 rounds;
2. per update: SB3 PPO's ``model.train()`` (10 epochs x 8 minibatches on one 500-step rollout)
   with the diagnostics' logger (``DiagnosticsLogger``) and with SB3's own (``Logger``, no
   output, as a job without diagnostics gets), 40 times each, alternating, plus the row the
   callback closes at the next rollout's start;

each in proportion to one env step of training (a 500-step rollout and its update, timed).

    python reports/diagnostics_cost/callback_micro.py
"""

from __future__ import annotations

import time

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger

from nutribench.agents import training_log as tl
from nutribench.agents.api import make_train_env
from nutribench.agents.config import load_agent_config
from nutribench.agents.registry import make_model
from nutribench.config import load_env_config


class _Stand(BaseCallback):
    """The recorder's place in the list: a callback that does nothing."""

    def _on_step(self) -> bool:
        return True


class _Grab(BaseCallback):
    """Keeps the locals of the last step it saw."""

    def _on_step(self) -> bool:
        self.seen = dict(self.locals)
        return True


def per_step(model, loc: dict, n: int = 200_000, rounds: int = 20) -> tuple[float, float]:
    """Median seconds per step of the dispatch with and without the diagnostics callback."""
    diag = tl.TrainingDiagnostics(model)
    lists = {"with": CallbackList([_Stand(), diag]), "without": CallbackList([_Stand()])}
    for cb in lists.values():
        cb.init_callback(model)
    per: dict[str, list[float]] = {"with": [], "without": []}
    for r in range(rounds):
        for k in ("with", "without") if r % 2 else ("without", "with"):
            cb = lists[k]
            t = time.perf_counter()
            for _ in range(n // rounds):
                cb.update_locals(loc)
                cb.on_step()
            per[k].append((time.perf_counter() - t) / (n // rounds))
    return float(np.median(per["with"])), float(np.median(per["without"]))


def per_update(model, rounds: int = 40) -> tuple[float, float, float]:
    """Median seconds of ``model.train()`` with the diagnostics' logger and with SB3's, and of
    the row the callback closes after it."""
    loggers = {"with": tl.DiagnosticsLogger(tl.SB3_KEYS, []), "without": Logger(folder=None, output_formats=[])}
    diag = tl.TrainingDiagnostics(model)
    per: dict[str, list[float]] = {"with": [], "without": [], "row": []}
    for r in range(rounds):
        for k in ("with", "without") if r % 2 else ("without", "with"):
            model.set_logger(diag.diag_logger if k == "with" else loggers["without"])
            t = time.perf_counter()
            model.train()
            per[k].append(time.perf_counter() - t)
            if k == "with":
                t = time.perf_counter()
                diag.model = model
                diag._close_row()
                per["row"].append(time.perf_counter() - t)
    return tuple(float(np.median(per[k])) for k in ("with", "without", "row"))  # type: ignore[return-value]


def main() -> None:
    th.set_num_threads(1)
    env_cfg, cfg = load_env_config("run0"), load_agent_config("ppo")
    _, env = make_train_env(env_cfg, cfg)
    model = make_model(cfg, env, seed=0, horizon=50)
    grab = _Grab()
    t = time.perf_counter()
    model.learn(total_timesteps=2000, callback=grab)  # 4 rollouts of 500 steps and their updates
    step = (time.perf_counter() - t) / 2000
    with_s, without_s = per_step(model, grab.seen)
    upd_with, upd_without, row = per_update(model)
    extra_update = (upd_with - upd_without + row) / 500  # per env step (one update per 500 steps)
    print(f"one env step of PPO training (rollout and update), this run: {1e6 * step:.0f} us")
    print(
        f"callback dispatch per env step: {1e6 * with_s:.2f} us with the diagnostics callback, "
        f"{1e6 * without_s:.2f} us without: {1e6 * (with_s - without_s):+.2f} us "
        f"({100 * (with_s - without_s) / step:+.2f} % of a step)"
    )
    print(
        f"model.train(): {upd_with:.4f} s with the diagnostics' logger, {upd_without:.4f} s with SB3's; "
        f"the row closed after it {1e6 * row:.0f} us: {1e6 * extra_update:+.2f} us per env step "
        f"({100 * extra_update / step:+.2f} % of a step)"
    )


if __name__ == "__main__":
    main()
