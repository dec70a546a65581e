"""What the per-parameter gradient probe cost SB3 PPO's update: ``model.train()`` (one update
of 10 epochs x 8 minibatches on one 500-step rollout of run0) timed 40 times with the probe
(:class:`nutribench.agents.training_log.GradNormProbe`) installed and 40 times without,
alternating, in one process; paired median ratio of wall and CPU time. Then the time of 2000
env steps of training, to put the update's cost in proportion.

    python reports/diagnostics_cost/probe_update_micro.py
"""

from __future__ import annotations

import time

import numpy as np
import torch as th

from nutribench.agents import training_log as tl
from nutribench.agents.api import make_train_env
from nutribench.agents.config import load_agent_config
from nutribench.agents.registry import make_model
from nutribench.config import load_env_config


def main() -> None:
    th.set_num_threads(1)
    env_cfg, cfg = load_env_config("run0"), load_agent_config("ppo")
    _, env = make_train_env(env_cfg, cfg)
    model = make_model(cfg, env, seed=0, horizon=50)
    model.learn(total_timesteps=500)  # one rollout in the buffer
    logger = tl.DiagnosticsLogger(tl.SB3_KEYS, [])
    model.set_logger(logger)
    res: dict[str, list[tuple[float, float]]] = {"bare": [], "probe": []}
    for r in range(40):
        for v in ("bare", "probe") if r % 2 else ("probe", "bare"):
            params = list(model.policy.parameters())
            probe = tl.GradNormProbe(params, model.policy.optimizer, logger) if v == "probe" else None
            t, c = time.perf_counter(), time.process_time()
            model.train()
            res[v].append((time.perf_counter() - t, time.process_time() - c))
            if probe is not None:
                probe.remove()
    b, p = np.array(res["bare"]), np.array(res["probe"])
    print(f"update (s, median): without the probe {np.median(b[:, 0]):.4f}, with it {np.median(p[:, 0]):.4f}")
    print(
        f"paired median ratio with/without: wall {np.median(p[:, 0] / b[:, 0]):.4f}, CPU {np.median(p[:, 1] / b[:, 1]):.4f}"
    )
    t = time.perf_counter()
    model.learn(total_timesteps=2000, reset_num_timesteps=False)
    print(f"2000 env steps of training (4 rollouts and their updates): {time.perf_counter() - t:.2f} s")


if __name__ == "__main__":
    main()
