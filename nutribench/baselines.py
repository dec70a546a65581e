"""The reference policies' table: every policy on every regime, on the same food streams; and
the yardsticks of the share of the never -> planner gap (:func:`gap_closed`) on given days:
:func:`day_yardsticks` (the test days of a report, the validation days of a tuner) and
:func:`validation_yardsticks` (a job's validation days).

Beside the simple policies (random, never, always, the greedy planner), two stronger ones say
how far above the planner's 100 % the optimum lies (:mod:`nutribench.env.policies`):
``lookahead`` (the planner's information, sampled futures) and ``clairvoyant`` (the day's
foods known; exact where its branch and bound proves the day's best return, a beam
otherwise): :func:`play_strong_policy`, and :func:`test_day_references` on the paper's test
days (``regimes/references.csv`` holds them, remade by ``nutribench baselines --test-days
--out regimes/references.csv``)."""

from __future__ import annotations

import numpy as np

from nutribench.config import EnvConfig, load_env_config
from nutribench.env import NutriRLVectorEnv
from nutribench.env.metrics import play
from nutribench.env.policies import DayModel, clairvoyant_actions, lookahead_actions, make_policy

POLICY_ORDER = ("random", "never", "always", "planner")
#: The two references above the planner, slower to play (:mod:`nutribench.env.policies`).
STRONG_POLICIES = ("lookahead", "clairvoyant")
SUMMARY_KEYS = ("return", "foods", "final_distance", "overshoot_ratio")
#: Sampled futures a lookahead step weighs each action on (``nutribench baselines``' default:
#: 0.8 s a day on this project's 2-core machine; :data:`TEST_DAY_SAMPLES` for the test days).
LOOKAHEAD_SAMPLES = 64
#: The lookahead's samples on the paper's test days (``regimes/references.csv``).
TEST_DAY_SAMPLES = 256
#: The clairvoyant beam's width and the most nodes its proof may hold at one step.
BEAM_WIDTH = 64
MAX_NODES = 20_000


def gap_closed(value: float, never: float, planner: float) -> float:
    """Share of the never -> planner gap that ``value`` closes (0 = never eat, 1 = the
    planner; the planner is greedy, not optimal, so more than 1 is possible); NaN where the
    two coincide (no gap to close)."""
    return float((value - never) / (planner - never)) if planner != never else float("nan")


def play_simple_policy(policy: str, regime: str | EnvConfig, foods: np.ndarray, seed: int = 0) -> list[dict]:
    """Per-episode metrics of ``policy`` on the given days ``(n, horizon)`` of food indices."""
    env = NutriRLVectorEnv(len(foods), regime=regime)
    return play(env, make_policy(policy, seed), episodes=len(foods), foods=foods)


def play_strong_policy(
    policy: str,
    regime: str | EnvConfig,
    foods: np.ndarray,
    samples: int = LOOKAHEAD_SAMPLES,
    seed: int = 0,
    width: int = BEAM_WIDTH,
    max_nodes: int = MAX_NODES,
) -> list[dict]:
    """Per-episode metrics of ``lookahead`` (``samples`` futures a step, ``seed``) or
    ``clairvoyant`` (beam ``width``, proof of at most ``max_nodes`` nodes a step) on the days
    ``foods`` ``(n, horizon)``: the actions planned on :class:`~nutribench.env.policies.DayModel`,
    played in the env. Each dict also has ``search``: ``"exact"`` or ``"beam"`` (clairvoyant),
    ``"sampled"`` (lookahead)."""
    model = DayModel(regime)
    foods = np.asarray(foods, dtype=np.int64)
    if policy == "lookahead":
        actions, how = lookahead_actions(model, foods, samples, seed), ["sampled"] * len(foods)
    elif policy == "clairvoyant":
        actions, how = clairvoyant_actions(model, foods, width, max_nodes)
    else:
        raise ValueError(f"unknown strong policy '{policy}': known ones are {', '.join(STRONG_POLICIES)}")
    env = NutriRLVectorEnv(len(foods), regime=model.dyn.config)
    played = play(env, lambda e: actions[:, e.steps_taken], episodes=len(foods), foods=foods)  # column t at step t
    return [{**p, "search": h} for p, h in zip(played, how)]


#: the two policies the share of the gap is measured between
YARDSTICKS = ("never", "planner")


def day_yardsticks(regime: str | EnvConfig, foods: np.ndarray) -> list[dict]:
    """The ``never`` and ``planner`` returns on each of the days ``(n, horizon)``: one dict per
    day (``episode``, ``never``, ``planner``)."""
    played = {name: [float(r["return"]) for r in play_simple_policy(name, regime, foods)] for name in YARDSTICKS}
    return [{"episode": e, **{name: played[name][e] for name in YARDSTICKS}} for e in range(len(foods))]


def validation_yardsticks(regime: str | EnvConfig, seed: int, n: int = 5) -> dict[str, float]:
    """The mean returns of ``never`` and ``planner`` over the ``n`` validation days of
    ``(regime, seed)`` (:func:`~nutribench.agents.days.validation_food_streams`), the
    yardsticks of an evaluation during training: its share of the gap is
    ``gap_closed(mean return, never, planner)``."""
    from nutribench.agents.days import validation_food_streams

    days = day_yardsticks(regime, validation_food_streams(regime, seed, n))
    return {name: float(np.mean([d[name] for d in days])) for name in YARDSTICKS}


def _drawn_days(cfg: EnvConfig, episodes: int, seed: int) -> np.ndarray:
    """``episodes`` days ``(episodes, horizon)`` of food indices drawn with ``seed``."""
    return np.random.default_rng(seed).integers(0, len(cfg.catalog.food), size=(episodes, cfg.reward.horizon))


def evaluate_simple_policy(policy: str, regime: str, episodes: int = 200, seed: int = 0) -> list[dict]:
    """Per-episode metrics of ``policy`` on ``episodes`` days drawn with ``seed``."""
    cfg = load_env_config(regime)
    return play_simple_policy(policy, cfg, _drawn_days(cfg, episodes, seed), seed)


def _row(regime: str, policy: str, eps: list[dict], never: float, planner: float, **extra: str) -> dict:
    """One row of :func:`baseline_table`: the means of ``eps``' metrics, their days and share of the gap."""
    s = {k: float(np.mean([e[k] for e in eps])) for k in SUMMARY_KEYS}
    return {
        "regime": regime,
        "policy": policy,
        **s,
        "days": len(eps),
        "gap": gap_closed(s["return"], never, planner),
    } | extra


def baseline_table(
    regimes: list[str], episodes: int = 200, seed: int = 0, strong_days: int = 0, samples: int = LOOKAHEAD_SAMPLES
) -> list[dict]:
    """One row per (regime, policy): the mean of each per-day metric
    (:data:`~nutribench.env.metrics.METRIC_KEYS`) over ``episodes`` days, with ``days`` and
    ``gap`` (the share of the never -> planner gap the mean return closes on those days).
    ``strong_days`` > 0 adds ``lookahead`` (``samples`` futures a step) and ``clairvoyant``
    on the first ``strong_days`` of the same days, their ``gap`` against never and the
    planner on those days, and ``search`` (clairvoyant: ``exact k/n`` days proven)."""
    rows = []
    for regime in regimes:
        played = {policy: evaluate_simple_policy(policy, regime, episodes, seed) for policy in POLICY_ORDER}
        never, planner = (float(np.mean([e["return"] for e in played[p]])) for p in YARDSTICKS)
        rows += [_row(regime, policy, played[policy], never, planner) for policy in POLICY_ORDER]
        if strong_days <= 0:
            continue
        n = min(strong_days, episodes)
        cfg = load_env_config(regime)
        foods = _drawn_days(cfg, episodes, seed)[:n]
        never_n, planner_n = (float(np.mean([e["return"] for e in played[p][:n]])) for p in YARDSTICKS)
        for policy in STRONG_POLICIES:
            eps = play_strong_policy(policy, cfg, foods, samples=samples, seed=seed)
            exact = sum(e["search"] == "exact" for e in eps)
            search = f"exact {exact}/{n}" if policy == "clairvoyant" else f"{samples} futures"
            rows.append(_row(regime, policy, eps, never_n, planner_n, search=search))
    return rows


#: Columns of ``regimes/references.csv`` (:func:`test_day_references`).
REFERENCE_COLUMNS = (
    "regime",
    "version",
    "sha256",
    "seed",
    "episode",
    "never",
    "planner",
    "lookahead",
    "clairvoyant",
    "search",
)


def test_day_references(
    regime: str | EnvConfig, seeds: tuple[int, ...], days: int = 5, samples: int = TEST_DAY_SAMPLES
) -> list[dict]:
    """The four yardsticks' returns on each test day of ``regime`` (the first ``days`` of
    :func:`~nutribench.agents.days.eval_food_streams` of each seed, the days every job of
    that seed is scored on): one dict per day with :data:`REFERENCE_COLUMNS` (``sha256``: the
    regime's content, so a changed regime file is seen; ``search``: the clairvoyant's)."""
    from nutribench.agents.days import eval_food_streams

    cfg = load_env_config(regime)
    rows = []
    for seed in seeds:
        foods = eval_food_streams(cfg, seed, days)
        simple = day_yardsticks(cfg, foods)
        look = play_strong_policy("lookahead", cfg, foods, samples=samples, seed=0)
        clair = play_strong_policy("clairvoyant", cfg, foods)
        for e in range(days):
            returns = (simple[e]["never"], simple[e]["planner"], float(look[e]["return"]), float(clair[e]["return"]))
            values = (cfg.name, int(cfg.version), cfg.sha256, int(seed), e, *returns, clair[e]["search"])
            rows.append(dict(zip(REFERENCE_COLUMNS, values)))
    return rows


#: the columns of :func:`baseline_cells`
BASELINE_HEADERS = ("regime", "policy", "days", "return", "foods", "final distance", "overshoot ratio", "gap closed")
BASELINE_HEADERS += ("search",)


def baseline_cells(rows: list[dict]) -> list[list[str]]:
    """:func:`baseline_table`'s rows as table cells (:data:`BASELINE_HEADERS`)."""
    return [
        [r["regime"], r["policy"], str(r["days"]), f"{r['return']:.2f}", f"{r['foods']:.2f}"]
        + [f"{r['final_distance']:.3f}", f"{r['overshoot_ratio']:.3f}", f"{100 * r['gap']:.1f} %", r.get("search", "")]
        for r in rows
    ]


#: the columns of :func:`test_day_cells`
TEST_DAY_HEADERS = ("regime", "days", "never", "planner", "lookahead", "clairvoyant", "lookahead %", "clairvoyant %")
TEST_DAY_HEADERS += ("clairvoyant search", "time")


def test_day_cells(names: list[str], seeds: tuple[int, ...]) -> tuple[list[dict], list[list[str]]]:
    """``baselines --test-days``: the four yardsticks on the test days of ``seeds``, per regime
    of ``names``: every day's row (:data:`REFERENCE_COLUMNS`) and a row of cells a regime
    (:data:`TEST_DAY_HEADERS`: the mean returns, the shares of the gap, the days searched
    exactly, the time it took)."""
    import time

    rows, cells = [], []
    for regime in names:
        start = time.perf_counter()
        days = test_day_references(regime, seeds)
        wall = time.perf_counter() - start
        rows += days
        mean = {k: sum(d[k] for d in days) / len(days) for k in ("never", "planner", "lookahead", "clairvoyant")}
        exact = sum(d["search"] == "exact" for d in days)
        shares = [gap_closed(mean[k], mean["never"], mean["planner"]) for k in ("lookahead", "clairvoyant")]
        cells.append(
            [regime, str(len(days))]
            + [f"{mean[k]:.3f}" for k in ("never", "planner", "lookahead", "clairvoyant")]
            + [f"{100 * share:.1f} %" for share in shares]
            + [f"exact {exact}/{len(days)}", f"{wall:.0f} s"]
        )
    return rows, cells
