"""A fingerprint of short batched runs of all five algorithms, for checking that a change to
the batched engine changes no result, bit for bit (on the CPU, with one torch version).

Run it before the change and after, and compare the two files::

    python tests/engine_fingerprint.py /tmp/before.json
    # ... change the engine ...
    python tests/engine_fingerprint.py /tmp/after.json
    cmp /tmp/before.json /tmp/after.json

or, where a change means to change the diagnostics only (what each logged value means), let
it say what differs, the training numbers apart from the diagnostics::

    python tests/engine_fingerprint.py --compare /tmp/before.json /tmp/after.json

Each run trains three agents (run0 seeds 0 and 21, run6 seed 3) for a few days (short
rollouts and warm-ups, so that every algorithm updates several times; PPO also with its
shipped config) and writes, per agent: every training day's metrics, the returns of two
greedy evaluation days, a hash of every weight tensor of its SB3 model, of its observation
statistics, its return statistics, and its diagnostics. Not a test: the hashes hold for one
torch build only.

``--first-of K`` trains each of the three agents first in a batch of K instead (the other K - 1
places hold filler jobs, run3 seeds 500 on) and writes the same file: on a batch-invariant
engine it equals the plain fingerprint; on an engine whose rounding depended on the batch it
shows what each agent's numbers were in that other batch::

    python tests/engine_fingerprint.py --first-of 8 /tmp/first8.json
"""

from __future__ import annotations

import hashlib
import json
import sys
import time

import torch as th

from nutribench.agents.api import eval_food_streams, evaluate
from nutribench.agents.config import load_agent_config
from nutribench.engine.train import train_batched

JOBS = [("run0", 0), ("run0", 21), ("run6", 3)]
#: name -> (algorithm, config changes, days)
SETUPS = {
    "ppo": ("ppo", dict(n_steps=100, batch_size=50, n_epochs=3), 6),
    "ppo_default": ("ppo", {}, 11),
    "mc": ("mc", {}, 4),
    "gru_ppo": ("gru_ppo", dict(n_steps=100, batch_size=50, n_epochs=2), 4),
    "ddqn": ("ddqn", dict(learning_starts=60, target_update_interval=40, buffer_size=300), 5),
    "sac": ("sac", dict(buffer_size=200), 5),
}


def digest(t) -> str:
    return hashlib.sha256(th.as_tensor(t).detach().cpu().contiguous().numpy().tobytes()).hexdigest()[:16]


def train(cfg, days: int, first_of: int | None) -> list:
    """The three agents trained together, or each first in a batch of ``first_of``."""
    if first_of is None:
        return train_batched(JOBS, cfg, days, device="cpu")
    fillers = [("run3", 500 + i) for i in range(first_of - 1)]
    return [train_batched([job, *fillers], cfg, days, device="cpu")[0] for job in JOBS]


def fingerprint(first_of: int | None = None) -> dict:
    out = {}
    for name, (algo, update, days) in SETUPS.items():
        t0 = time.perf_counter()
        agents = train(load_agent_config(algo).model_copy(update=update), days, first_of)
        rows = []
        for (regime, seed), agent in zip(JOBS, agents):
            days_evaluated = evaluate(agent, regime, eval_food_streams(regime, seed, 2), record_steps=False).episodes
            vn = agent.vec_normalize
            rows.append(
                {
                    "episodes": agent.train_episodes,
                    "eval": [d["return"] for d in days_evaluated],
                    "weights": {k: digest(v) for k, v in agent.model.policy.state_dict().items()},
                    "obs_rms": None if vn is None else [digest(vn.obs_rms.mean), digest(vn.obs_rms.var)],
                    "ret_rms": None if vn is None else [float(vn.ret_rms.mean), float(vn.ret_rms.var)],
                    "diagnostics": getattr(agent, "diagnostics", None),
                }
            )
        out[name] = rows
        print(f"{name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return out


def compare(before: dict, after: dict) -> bool:
    """Print what differs between two fingerprints; whether all but the diagnostics are equal."""
    same = before.keys() == after.keys()
    for name in sorted(before.keys() & after.keys()):
        for i, (x, y) in enumerate(zip(before[name], after[name], strict=True)):
            for key in sorted(x.keys() | y.keys()):
                if x.get(key) == y.get(key):
                    continue
                if key == "diagnostics":
                    rows = zip(x[key] or [], y[key] or [])
                    print(
                        f"{name} agent {i}: diagnostics differ in",
                        sorted({k for a, b in rows for k in a if a.get(k) != b.get(k)}),
                    )
                else:
                    same = False
                    print(f"{name} agent {i}: {key} differs")
    print("training numbers identical" if same else "TRAINING NUMBERS DIFFER")
    return same


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        sys.exit(0 if compare(*(json.load(open(p)) for p in sys.argv[2:4])) else 1)
    args = sys.argv[1:]
    first_of = None
    if args[0] == "--first-of":
        first_of, args = int(args[1]), args[2:]
    with open(args[0], "w") as f:
        json.dump(fingerprint(first_of), f, indent=0, sort_keys=True)
