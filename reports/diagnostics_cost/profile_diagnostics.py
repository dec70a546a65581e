"""The share of SB3-engine training time spent in the training diagnostics' own code, by profile.

For each algorithm: ``nutribench.agents.train`` of the shipped config on run0 under cProfile,
and the time spent inside ``nutribench/agents/training_log.py`` as entered from outside it
(each of its functions' cumulative time over the calls from outside the module: the callback's
methods, the logger's ``record``, the gradient probe's hooks), less the work those hand on and
that runs with or without the diagnostics, as a share of the whole profiled run. Not counted:
the few ``.item()`` reads and the norm PPO's, A2C's, DDQN's, SAC's and GRU-PPO's own updates
keep for their ``train/*`` keys (``nutribench/agents/sb3_train.py``, ``algos.py``, ``sac/``,
``gru_ppo/``). The runs in this study's README were made when PPO's and A2C's norm was kept by
a wrapper of torch's ``clip_grad_norm_`` in ``training_log.py`` (then counted here, the SB3
update it called not); that wrapper is gone. A profile slows small Python calls more than torch's kernels, so the share is an
upper bound on the cost without the profiler. DDQN starts learning after 200 days, so it gets
300 (100 days with updates).

    python reports/diagnostics_cost/profile_diagnostics.py [--algos mc,ppo,...]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats

from nutribench.agents import train

DAYS = {"mc": 100, "ppo": 100, "gru_ppo": 60, "ddqn": 300, "sac": 40}
MODULE = "training_log.py"
#: (file path part, function or None for any) of the work a diagnostics function hands on (it
#: runs without them too): SB3's update, torch's clip_grad_norm_ (its _no_grad_wrapper)
HANDED_ON = (("stable_baselines3", "train"), ("torch/nn/utils/clip_grad", None))


def share(algo: str, days: int) -> tuple[float, float]:
    """(seconds in the diagnostics' code, seconds of the whole run), both under the profiler."""
    train("run0", algo, seed=0, episodes=2)  # imports and first-call costs out of the way
    prof = cProfile.Profile()
    prof.enable()
    train("run0", algo, seed=0, episodes=days)
    prof.disable()
    st = pstats.Stats(prof)
    ours = 0.0
    for (path, _, name), (_, _, _, _, callers) in st.stats.items():  # type: ignore[attr-defined]
        inside = {c: v for c, v in callers.items() if c[0].endswith(MODULE)}
        if path.endswith(MODULE):  # entered from outside: its cumulative time over those calls
            ours += sum(v[3] for c, v in callers.items() if c not in inside)
        elif any(part in path and fn in (None, name) for part, fn in HANDED_ON):
            ours -= sum(v[3] for v in inside.values())  # handed on by the module: not its cost
    return ours, st.total_tt  # type: ignore[attr-defined]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--algos", default=",".join(DAYS))
    args = ap.parse_args()
    print("| algo | days | profiled run (s) | in the diagnostics' code (s) | share |")
    print("|---|---|---|---|---|")
    for algo in args.algos.split(","):
        ours, total = share(algo, DAYS[algo])
        print(f"| {algo} | {DAYS[algo]} | {total:.1f} | {ours:.3f} | {100 * ours / total:.2f} % |", flush=True)


if __name__ == "__main__":
    main()
