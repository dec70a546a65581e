"""The share of SB3-engine training time spent in the training diagnostics' own code, by profile.

For each algorithm: ``nutribench.agents.train`` of the shipped config on run0 under cProfile,
and the cumulative time of the entry points of ``nutribench/agents/training_log.py`` (its
functions that no other function of that module called: the callback's methods, the gradient
probe's hooks, the logger's ``record``), so that nothing is counted twice, as a share of the
whole profiled run. Not counted: the few ``.item()`` reads DDQN's, SAC's and GRU-PPO's own
updates make for their ``train/*`` keys (``nutribench/agents/algos.py``, ``sac/``,
``gru_ppo/``). A profile slows small Python calls more than torch's kernels, so the share is an
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


def share(algo: str, days: int) -> tuple[float, float]:
    """(seconds in the diagnostics' code, seconds of the whole run), both under the profiler."""
    train("run0", algo, seed=0, episodes=2)  # imports and first-call costs out of the way
    prof = cProfile.Profile()
    prof.enable()
    train("run0", algo, seed=0, episodes=days)
    prof.disable()
    st = pstats.Stats(prof)
    ours = {k: v for k, v in st.stats.items() if k[0].endswith(MODULE)}  # type: ignore[attr-defined]
    entry = [v for v in ours.values() if not any(c[0].endswith(MODULE) for c in v[4])]
    return sum(v[3] for v in entry), st.total_tt  # type: ignore[attr-defined]


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
