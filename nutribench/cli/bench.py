"""``nutribench bench env|train|tune``: env and training throughput; tuning trials per hour,
stacked in batched processes against one SB3 process per trial (:mod:`nutribench.bench.tune`).
The developer's benchmarks (learnability, the two engines compared, ``status`` speed) are
scripts beside the package, in ``benchmarks/``."""

from __future__ import annotations

from typing import Optional

from nutribench.cli.common import (
    DEVICE_HELP,
    EpisodesAlias,
    RepeatsOption,
    UserError,
    command_group,
    console,
    old_spelling,
    option,
    print_table,
    split_csv,
    user_errors,
)
from nutribench.engines import Engine

bench_app = command_group("Benchmarks: env and training throughput, tuning trials per hour.")
#: ``bench tune --space``
SPACE_HELP = (
    "search space whose trials are drawn (an algorithm with per-agent settings: ppo, mc, gru_ppo, sac) [default: ppo]"
)


@bench_app.command("env")
@user_errors
def bench_env_cmd(
    regimes: option(str, "comma-separated regimes") = "run0,run6",
    sizes: option(str, "comma-separated vector env sizes") = "1,64,1024,4096",
    repeats: RepeatsOption = 5,
) -> None:
    """Env-steps per second of the single env and the vector env (random actions)."""
    from nutribench.bench.throughput import bench_env
    from nutribench.config import list_regimes

    names = split_csv(regimes, list_regimes(), "regime")
    ns = parse_sizes(sizes)
    rows = bench_env(names, ns, repeats=repeats)
    cells = [[r["regime"], r["env"], str(r["num_envs"]), f"{r['steps_per_s']:,.0f}"] for r in rows]
    print_table(("regime", "env", "num_envs", "env-steps/s (median)"), cells)


#: the largest vector env ``bench env`` builds (its arrays grow with it: 2**20 envs take about a GB)
MAX_BENCH_SIZE = 2**20


def parse_sizes(text: str) -> list[int]:
    """``--sizes 1,64,1024``: vector env sizes from 1 to :data:`MAX_BENCH_SIZE`, else a one-line UserError."""
    items = [s.strip() for s in text.split(",")]
    if not all(s.isascii() and s.isdigit() for s in items):
        raise UserError(f"--sizes must be comma-separated positive integers, got '{text}': e.g. --sizes 1,64,1024")
    for item in items:
        if not 1 <= int(item) <= MAX_BENCH_SIZE:
            raise UserError(
                f"--sizes '{text}': size {item[:24]} is out of range: give sizes from 1 to {MAX_BENCH_SIZE}"
            )
    return [int(s) for s in items]


#: the finished studies' cost benches, once hidden options of ``bench train``: where they went
MOVED = {"--diagnostics-cost": "reports/diagnostics_cost/README.md", "--eval-every": "reports/eval_cost/README.md"}


@bench_app.command("train")
@user_errors
def bench_train_cmd(
    algos: option(str, "'all' or comma-separated algorithms") = "all",
    regime: option(str, "regime") = "run0",
    days: option(Optional[int], "training days per timed run [default: 100]", "--days", min=1) = None,
    episodes_alias: EpisodesAlias = None,
    repeats: RepeatsOption = 3,
    engine: option(str, "'sb3', or 'batched': the batched engine at K = 35 beside SB3's") = Engine.SB3.value,
    device: option(str, f"--engine batched: {DEVICE_HELP} (SB3's rows: the CPU)") = "auto",
    diagnostics_cost: option(bool, None, "--diagnostics-cost", hidden=True) = False,
    lockstep: option(bool, None, "--lockstep", hidden=True) = False,
    eval_every: option(int, None, "--eval-every", hidden=True) = 0,
    _block: option(Optional[int], None, "--block", hidden=True) = None,
    _val_episodes: option(Optional[int], None, "--val-episodes", hidden=True) = None,
) -> None:
    """Training env-steps per second of each algorithm, and of bare SB3 PPO / DQN on the same
    env (the overhead of nutribench's plumbing), with the paper grid's CPU-hours at that rate.
    With --engine batched, also the batched engine (7 regimes x 5 seeds at once): its rate,
    FLOPs per env step, this machine's matmul rate and the share of that floor reached."""
    given = {"--diagnostics-cost": diagnostics_cost or lockstep or _block is not None}
    given["--eval-every"] = bool(eval_every or _val_episodes is not None)
    for flag in (o for o, g in given.items() if g):
        raise UserError(
            f"bench train {flag}: that bench moved out of the package with the finished study that used it: "
            f"see {MOVED[flag]}"
        )
    episodes = old_spelling(days, episodes_alias, "--days", "--episodes", 100)
    from nutribench.agents.registry import paper_names
    from nutribench.bench.throughput import bench_train
    from nutribench.config import load_env_config
    from nutribench.scheduler.pools import check_engine

    check_engine(engine, 1, device)  # an unknown engine or device, or CUDA where there is none: before anything trains
    names = split_csv(algos, paper_names(), "algorithm")
    load_env_config(regime)
    rows = bench_train(names, regime=regime, episodes=episodes, repeats=repeats)
    columns = ["run", "env-steps/s (median)", "vs bare SB3 (paired median)", "paper grid CPU-hours"]
    ratio = lambda r: f"{r['vs_bare']:.3f}" if "vs_bare" in r else ""  # noqa: E731
    cells = [[r["what"], f"{r['steps_per_s']:,.0f}", ratio(r), f"{r['paper_grid_cpu_hours']:.1f}"] for r in rows]
    print_table(columns, cells, f"training throughput, {regime}, {episodes} days x {repeats}")
    total = sum(r["paper_grid_cpu_hours"] for r in rows if not r["bare"])
    console.print(
        f"paper grid (7 regimes x 5 seeds x 5000 days per algorithm, all 5 algorithms): ~{total:.0f} CPU-hours"
    )
    if engine != Engine.SB3:
        sb3_rate = {r["algo"]: r["steps_per_s"] for r in rows if not r["bare"]}
        _batched_rows(names, sb3_rate, episodes, repeats, device)


def _batched_rows(names: list[str], sb3_rate: dict[str, float], episodes: int, repeats: int, device: str) -> None:
    """``bench train --engine batched``'s second table: the batched engine's rate per algorithm."""
    from nutribench.agents.registry import batched_names
    from nutribench.bench.throughput import bench_train_batched

    columns = ["algo", "K", "env-steps/s (median)", "vs SB3 engine", "MFLOP / env step", "matmul GFLOP/s"]
    columns += ["share of floor", "paper grid wall h"]
    cells = []
    for algo in [a for a in names if a in batched_names()]:
        b = bench_train_batched(algo, episodes=episodes, repeats=repeats, device=device)
        row = [algo, str(b["k"]), f"{b['steps_per_s']:,.0f}", f"{b['steps_per_s'] / sb3_rate[algo]:.1f}x"]
        row += [
            f"{b['flops_per_step'] / 1e6:.2f}",
            f"{b['matmul_flops_per_s'] / 1e9:.0f}",
            f"{100 * b['floor_share']:.0f} %",
        ]
        cells.append(row + [f"{b['paper_grid_wall_hours']:.2f} (floor {b['paper_grid_floor_hours']:.2f})"])
    print_table(columns, cells, f"batched engine, {episodes} days x {repeats}, batches on all cores")
    skipped = [a for a in names if a not in batched_names()]
    if skipped:
        console.print(f"not in the batched engine yet: {', '.join(skipped)}", highlight=False)


def moved_command(name: str) -> None:
    """``bench NAME``, a developer's benchmark that moved to ``benchmarks/NAME.py``: one line saying so."""

    @bench_app.command(name, hidden=True, context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
    @user_errors
    def moved() -> None:
        raise UserError(
            f"bench {name} is a developer's benchmark and moved out of the installed package: from a checkout, "
            f"run python benchmarks/{name}.py (the same options)"
        )


for _moved in ("learn", "status", "engines"):
    moved_command(_moved)


@bench_app.command("tune")
@user_errors
def bench_tune_cmd(
    space: option(Optional[str], SPACE_HELP, "--space") = None,
    algo: option(Optional[str], None, "--algo", hidden=True) = None,
    trials: option(int, "trials, the same in both arms", min=1) = 8,
    days: option(int, "training days per agent", min=1) = 20,
    regimes: option(str, "tuning regimes, comma-separated") = "run0,run3",
    seeds: option(str, "tuning seeds, comma-separated") = "101,102",
    eval_every: option(int, "days between validation evaluations", min=1) = 10,
    val_episodes: option(int, "validation days per evaluation", min=1) = 5,
    workers: option(Optional[int], "processes per arm (default: the cores)", min=1) = None,
    repeats: option(int, "repeats of both arms, orders alternating", min=1) = 1,
) -> None:
    """Trials per hour: stacked trials in batched processes vs one SB3 process per trial (rl-zoo3's way)."""
    space = old_spelling(space, algo, "--space", "--algo")  # as tune's --space; None: bench_tune's default
    from nutribench.bench.tune import bench_tune
    from nutribench.config import list_regimes
    from nutribench.scheduler.grid import parse_seeds

    names = tuple(split_csv(regimes, list_regimes(), "regime"))
    with console.status(f"training {trials} trials in each arm"):
        rows = bench_tune(
            **({"space": space} if space is not None else {}),
            trials=trials,
            days=days,
            regimes=names,
            seeds=tuple(parse_seeds(seeds)),
            eval_every=eval_every,
            val_episodes=val_episodes,
            workers=workers,
            repeats=repeats,
        )
    r0 = rows[0]
    title = f"{r0['space']}: {trials} trials x {r0['agents_per_trial']} agents x {days} days, {r0['workers']} processes"
    cells = [
        [r["arm"], f"{r['wall_s']:.1f}", " ".join(f"{w:.1f}" for w in r["walls"]), f"{r['trials_per_hour']:.0f}"]
        + [f"{r.get('ratio', 1.0):.1f}x"]
        for r in rows
    ]
    print_table(("arm", "wall s (median)", "walls", "trials/hour", "vs sb3"), cells, title)
