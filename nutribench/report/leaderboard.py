"""The leaderboard (``nutribench leaderboard``): every agent of a results database (or of a
folder of archives) in one ranked table, budgets and seeds honest.

One row per entry: an agent config's name, version and training budget
(:func:`nutribench.report.data.prepare_entries`; one job per entry, regime and seed), none
hidden by another: the paper archives' ``ppo`` v1 at 5000 days and a user's run of the shipped
``ppo`` v2 at 150 days are two rows, the second flagged by its budget. Per entry:

* the **aggregate score**: the IQM of its run scores (a run = one seed on one regime, scored
  as the share of the regime's never -> planner gap it closes on its own evaluation days,
  :func:`nutribench.report.scores.run_scores`) over **the regimes it covers**, with the 95 %
  interval over runs (:func:`nutribench.stats.iqm_runs_ci` through
  :func:`nutribench.report.aggregate.interval_estimates`);
* its share of the gap per regime (mean over seeds of each run's score);
* its training budget (days), seeds, engine, protocol and code version;
* flags where it departs from the reference grid (the paper's: :data:`REFERENCE_BUDGET` days,
  seeds :data:`REFERENCE_SEEDS`, every regime of the board): another budget, other seeds,
  regimes it lacks. Rows are ranked by the aggregate IQM; a row covering fewer regimes than
  the board is ranked on the regimes it has, and its flags say so.

The protocol of a row: ``paper config`` (one of the five built-in configs with the settings
shipped in ``regimes/agents/``: the shipped version, or an older one that differs from it
only in its description, e.g. the archives of ``reports/paper/`` after a version that rewrote
only the prose), ``tuned`` (a config written by ``nutribench tune best --write``: its
description names the study), ``variant`` (a built-in algorithm with other settings), ``plug-in`` (an
``algo = "external"`` config with an entry point, trained by ``nutribench run``),
``recorded`` (an agent trained elsewhere: :class:`nutribench.Recorder`, ``nutribench evaluate``).

Each row says how its evaluation days were checked (``checked``): ``replayed, not re-run``: an
archive's days are replayed from their stored foods and actions on import (the foods the
seed's test days, the regime the installed one where it bears a shipped name and version),
which proves the actions fit the regime, not that an agent chose them; no model is re-run.
With trained models supplied (``--verify MODELS``, :mod:`nutribench.report.leaderboard_verify`)
each job whose model is there is played again from it and compared action for action:
``verified (re-run)``, ``re-run: differs (...)`` or ``re-run: failed (...)``. A row whose
models differ or fail is not ranked among the others: it is listed after them, without a rank,
its flags and the caption saying why (its numbers are not its models').

DataFrame in, :class:`~nutribench.report.tables.TableResult` out (:func:`leaderboard_table`);
:func:`leaderboard_from_db` reads a database, :func:`leaderboard_from_archives` a folder of
archives, each checked on import as ``nutribench db import`` checks it: an archive refused is
listed (its one-line reason) and the others are ranked. A regime of a database that bears a
shipped regime's name and version but other content is never scored on the shipped
yardsticks (its days are left out of the ranking, and the caption says so).
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from nutribench.report.aggregate import interval_estimates, regime_span, run_scores, score_set
from nutribench.report.data import Log, ReportError, entries, entry_rows, quiet
from nutribench.report.figure_parts import UNRECORDED, budget_cell, seed_list, sort_regimes
from nutribench.report.leaderboard_verify import REPLAYED, not_reproduced, verify_entries
from nutribench.report.palette import BUILTIN_ORDER
from nutribench.report.palette import label as algo_label
from nutribench.report.scores import DEFAULT_REPS
from nutribench.report.tables import TableResult, interval_cell
from nutribench.scheduler.grid import PRESETS
from nutribench.stats import caption as interval_caption
from nutribench.store.archive.installed import disagreeing_archives, forged_regimes

#: The reference grid a row is checked against: the paper's budget and seeds.
REFERENCE_BUDGET: int = PRESETS["paper"].episodes
REFERENCE_SEEDS: tuple[int, ...] = PRESETS["paper"].seeds
#: how the description of a file written by ``nutribench tune best --write`` begins
TUNED_PREFIX = "tuned by nutribench tune"

#: The most bootstrap resamples a leaderboard draws (``--reps``): each agent's interval holds
#: resamples x runs numbers, and 100,000 already pins a 95 % interval far below its rounding.
MAX_REPS = 100_000
MIN_REPS = 100


def check_reps(reps: object) -> int:
    """``reps`` as a number of bootstrap resamples (:data:`MIN_REPS` .. :data:`MAX_REPS`);
    :class:`ReportError` in one line otherwise (a trillion would be a MemoryError)."""
    if not isinstance(reps, int) or isinstance(reps, bool) or not MIN_REPS <= reps <= MAX_REPS:
        shown = f"{reps:,}" if isinstance(reps, int) else repr(reps)
        raise ReportError(f"--reps {shown}: give {MIN_REPS:,} to {MAX_REPS:,} bootstrap resamples")
    return reps


def protocols(configs: pd.DataFrame) -> dict[str, str]:
    """The protocol of each agent config (columns name, version, sha256, body: the
    ``agent_configs`` rows of the versions drawn)."""
    from nutribench.agents.config import agent_config_sha256, body_settings_sha256, parse_agent_config, settings_sha256
    from nutribench.agents.registry import by_entry_point
    from nutribench.config.loading import read_toml, regimes_dir

    out = {}
    for r in configs.itertuples(index=False):
        body = r.body if isinstance(r.body, dict) else {}
        tuned = str(body.get("description", "")).startswith(TUNED_PREFIX)
        if by_entry_point(body.get("algo")):
            out[r.name] = ("tuned" if tuned else "plug-in") if body.get("entry_point") else "recorded"
            continue
        shipped = regimes_dir() / "agents" / f"{r.name}.toml"
        same = False
        if r.name in BUILTIN_ORDER and shipped.is_file():
            cfg = parse_agent_config(read_toml(shipped), shipped)
            exact = int(cfg.version) == int(r.version) and agent_config_sha256(cfg) == r.sha256
            # or the settings of the shipped file: equal but for nutribench.agents.config.NOT_SETTINGS,
            # read through the config model (a body that does not validate, None, has not)
            same = exact or body_settings_sha256(body) == settings_sha256(cfg)
        out[r.name] = "paper config" if same else "tuned" if tuned else "variant"
    return out


def _code_version(jobs: pd.DataFrame) -> str:
    """``0.4.0 (abc1234)`` of the jobs' package version and git commit, several joined by /."""
    parts = []
    for version, commit, dirty in (
        jobs[["nutribench_version", "git_commit", "git_dirty"]].drop_duplicates().itertuples(index=False)
    ):
        text = str(version) if isinstance(version, str) and version else "?"
        if isinstance(commit, str) and commit:
            text += f" ({commit[:7]}{', dirty' if dirty is True or dirty == 1 else ''})"
        parts.append(text)
    return " / ".join(sorted(set(parts))) or "?"


def _flags(budget: str, seeds: list[int], covered: list[str], board: list[str]) -> list[str]:
    flags = []
    if budget == "0":  # no training day recorded (an evaluated model without a sidecar that says)
        flags.append(f"{UNRECORDED} (reference {REFERENCE_BUDGET} days)")
    elif budget != str(REFERENCE_BUDGET):
        flags.append(f"budget {budget} day{'' if budget == '1' else 's'} (reference {REFERENCE_BUDGET})")
    if sorted(seeds) != sorted(REFERENCE_SEEDS):
        flags.append(f"seeds {seed_list(seeds)} (reference {', '.join(map(str, REFERENCE_SEEDS))})")
    missing = [r for r in board if r not in covered]
    if missing:
        flags.append(f"ranked on {regime_span(covered)} only: no {', '.join(missing)}")
    return flags


def _lookup(by: dict, entry: tuple[str, int, int], default: str) -> str:
    """``by``'s value for an entry (name, version, budget), else for (name, version), else for
    the name alone (a map of one row per name, as :func:`protocols` gives), else ``default``."""
    return next((by[key] for key in (entry, entry[:2], entry[0]) if key in by), default)


def leaderboard_rows(
    ev: pd.DataFrame,
    references: pd.DataFrame,
    jobs: pd.DataFrame,
    protocol: dict,
    reps: int = DEFAULT_REPS,
    checked: dict | None = None,
) -> pd.DataFrame:
    """One row per entry (agent config name, version, training budget:
    :data:`nutribench.report.data.ENTRY`) of the evaluation episodes ``ev`` (one job per entry
    and run), ranked by the IQM of its run scores over the regimes it covers; no entry hides
    another (a short run of a shipped agent is a row of its own, flagged by its budget, beside
    the published one). ``references``: the never/planner yardsticks of every evaluation day;
    ``jobs``: the jobs table (id, engine, versions); ``protocol``: entry, (name, version) or
    name -> protocol; ``checked``: the same keys -> the ``checked`` cell where models were
    re-run (:func:`nutribench.report.leaderboard_verify.verify_entries`). A row whose models
    did not reproduce its stored actions is set apart: listed after the ranked rows, with no rank
    and the reason in its flags (:func:`_set_apart`)."""
    board = sort_regimes(ev["regime"].unique())
    job_info = jobs.set_index("id")
    rows = []
    for entry in entries(ev):
        algo, version, _ = entry
        cell = entry_rows(ev, entry)
        mine = run_scores(cell, references)
        seeds = sorted({int(s) for s in cell["seed"]})
        budget = budget_cell(cell)
        mine_jobs = job_info.loc[sorted(set(cell["job_id"]))]
        engine = "/".join(sorted({str(e) for e in mine_jobs["engine"].dropna()})) or "?"
        cells = dict(version=version, budget=budget, seeds=" ".join(map(str, seeds)), engine=engine)
        cells.update(code=_code_version(mine_jobs), checked=_lookup(checked or {}, entry, REPLAYED))
        row = _row(algo, _lookup(protocol, entry, "?"), mine, board, reps, **cells)
        covered = row["covered"].split(",") if row["covered"] else []
        row["flags"] = "; ".join(_flags(budget, seeds, covered, board))
        rows.append(row)
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    out = out.sort_values("iqm", ascending=False, na_position="last", kind="stable").reset_index(drop=True)
    apart = _set_apart(out)
    out = pd.concat([out[~apart], out[apart]], ignore_index=True)  # set-apart rows last, unranked
    ranked = len(out) - int(apart.sum())
    out.insert(0, "rank", [i + 1 if i < ranked and np.isfinite(v) else None for i, v in enumerate(out["iqm"])])
    strong = _reference_rows(ev, references, board, reps)
    return pd.concat([out, strong], ignore_index=True) if not strong.empty else out


def _row(algo: str, protocol: str, mine: pd.DataFrame, board: list[str], reps: int, **cells) -> dict:
    """A row of the board from its run scores ``mine``: the IQM over the regimes it covers with
    its interval (NaN without one), then ``cells``, then its mean share of the gap per regime of
    the ``board``."""
    finite = np.isfinite(mine["score"].to_numpy(dtype=float))
    covered = sort_regimes(mine.loc[finite, "regime"].unique())
    row = {"algo": algo, "protocol": protocol, "iqm": np.nan, "iqm_lo": np.nan, "iqm_hi": np.nan}
    row.update(regimes=len(covered), covered=",".join(covered), runs=int(finite.sum()), **cells)
    if covered:
        iv = interval_estimates(score_set(mine, covered, [algo]), reps=reps)
        iqm = iv[iv["aggregate"] == "iqm"].iloc[0]
        row.update(iqm=float(iqm["point"]), iqm_lo=float(iqm["lo"]), iqm_hi=float(iqm["hi"]))
    for regime in board:
        s = mine.loc[mine["regime"] == regime, "score"].to_numpy(dtype=float)
        row[f"share_{regime}"] = float(np.mean(s)) if s.size and np.isfinite(s).all() else np.nan
    return row


#: The protocol cell of the references above the planner (unranked rows under the agents).
REFERENCE_PROTOCOL = "reference (planned, not learned)"


#: The references above the planner, each with why it is not ranked.
_UNRANKED = {"lookahead": "sampled futures finished by the planner", "clairvoyant": "the day's foods known"}


def _reference_rows(ev: pd.DataFrame, references: pd.DataFrame, board: list[str], reps: int) -> pd.DataFrame:
    """Unranked rows for lookahead and clairvoyant (:mod:`nutribench.report.references`): the
    same scores on the same days, over the board's regimes they cover; none where
    ``references`` lacks them."""
    from nutribench.report.references import SOURCE, reference_runs

    runs = reference_runs(ev, references).rename(columns={"policy": "algo"})
    rows = []
    for algo, why in _UNRANKED.items():
        mine = runs[runs["algo"] == algo]
        if mine.empty:
            continue
        # budget none: planned, not trained (empty in CSV, "-" in the table), as engine and code
        seeds = " ".join(map(str, sorted({int(s) for s in mine["seed"]})))
        cells = dict(budget=None, seeds=seeds, engine=None, code=None, checked=f"from {SOURCE}")
        row = {"rank": None, **_row(algo, REFERENCE_PROTOCOL, mine, board, reps, **cells)}
        row["flags"] = f"unranked: {why}"
        rows.append(row)
    return pd.DataFrame(rows)


#: the flag of a row set apart (:func:`_set_apart`)
SET_APART = "not ranked: its models, re-run, do not reproduce its stored actions (checked)"


def _set_apart(rows: pd.DataFrame) -> pd.Series:
    """Which rows are set apart from the ranking: those whose supplied models did not reproduce
    their stored actions under ``--verify`` (:func:`nutribench.report.leaderboard_verify.not_reproduced`);
    their flags say so. The others keep their order."""
    apart = rows["checked"].map(not_reproduced).astype(bool)
    rows.loc[apart, "flags"] = ["; ".join(f for f in (SET_APART, flags) if f) for flags in rows.loc[apart, "flags"]]
    return apart


def _set_apart_notes(checked: dict) -> list[str]:
    """A caption note for each entry set apart (:func:`_set_apart`), with its reason; ``checked``:
    entry (name, version, budget) -> its ``checked`` cell."""
    return [
        f"{algo_label(name)} v{version} ({budget} day{'' if budget == 1 else 's'}) is set apart, not ranked: {cell}"
        for (name, version, budget), cell in sorted(checked.items())
        if not_reproduced(cell)
    ]


def _pct(v: float) -> str:
    return str(round(100 * v)) if np.isfinite(v) else "n/a"  # an int: -0.4 % reads 0, not -0


def _cell(v) -> object:
    """A cell a reference row has none of (budget, engine, code): "-" in the table."""
    return "-" if v is None or (isinstance(v, float) and np.isnan(v)) else v


def _iqm_cell(point: float, lo: float, hi: float) -> str:
    """A row's IQM and interval as printed: ``68 [59, 77]``; ``0 [no spread]`` where the interval
    has zero width (every regime's seeds scored alike: several seeds, nothing between them);
    ``[single seed]`` where there is none (one seed per regime: :func:`interval_cell`)."""
    if np.isfinite(point) and np.isfinite(lo) and hi - lo == 0:
        return f"{_pct(point)} [no spread]"
    return interval_cell(point, lo, hi, _pct)


def leaderboard_table(rows: pd.DataFrame) -> TableResult:
    """The leaderboard as a table (Markdown, LaTeX, CSV); ``rows``: :func:`leaderboard_rows`."""
    board = [c.removeprefix("share_") for c in rows.columns if c.startswith("share_")]
    fmt = [
        {
            "rank": "" if r["rank"] is None or pd.isna(r["rank"]) else int(r["rank"]),
            "agent": algo_label(r["algo"]),
            "IQM share of gap (%) [95% CI]": _iqm_cell(r["iqm"], r["iqm_lo"], r["iqm_hi"]),
            "regimes": f"{r['regimes']}/{len(board)}",
            **{f"{g} (%)": _pct(r[f"share_{g}"]) for g in board},
            "version": "-" if r["protocol"] == REFERENCE_PROTOCOL else f"v{r['version']}" if "version" in r else "?",
            "budget (days)": _cell(r["budget"]),
            "seeds": r["seeds"].replace(" ", ", "),
            "engine": _cell(r["engine"]),
            "protocol": r["protocol"],
            "code": _cell(r["code"]),
            "checked": r.get("checked", REPLAYED),
            "flags": r["flags"] or "-",
        }
        for r in rows.to_dict("records")
    ]
    title = (
        "Leaderboard: every agent ranked by the IQM of its run scores (one seed on one regime = one run, scored as the "
        "share of the regime's never -> planner gap it closes on its own evaluation days; 0 % = never eat, 100 % = the "
        "greedy full-information planner) over the regimes it covers, with a 95 % interval over runs "
        f"({interval_caption('iqm')}, its standard error stratified by regime; [no spread]: every regime's seeds "
        "scored alike, a zero-width interval; [single seed]: one seed per regime, none); per regime, the mean share over "
        f"seeds. Reference grid: {REFERENCE_BUDGET} training days, seeds "
        f"{', '.join(map(str, REFERENCE_SEEDS))}, every regime of the board ({regime_span(board)}); a row that departs "
        "from it is flagged, and a row lacking regimes is ranked on those it has. Checked: every row's evaluation days "
        "are stored foods and actions, replayed on the regime (an archive's, on import); 'verified (re-run)': every "
        "job's trained model, supplied, played those actions again on this machine. Unranked under the agents: "
        "lookahead and clairvoyant, the references above the planner on the same days (headroom: 100 % is not the optimum)"
    )
    return TableResult("leaderboard", title, rows, pd.DataFrame(fmt))


def leaderboard_from_db(
    db,
    reps: int = DEFAULT_REPS,
    log: Log | None = None,
    verify: str | Path | None = None,
    algos: Sequence[str] | None = None,
) -> TableResult:
    """The leaderboard of the results database ``db`` (:class:`ReportError` when it holds no
    evaluation days): every entry (name, version, budget) of ``algos`` (default every agent
    config), none hidden by another (:func:`nutribench.report.data.prepare_entries`), each
    row's engine, code version and protocol from the database's jobs and agent configs; what
    the choice left out goes into its caption. ``verify``: a folder of the jobs' trained
    models, re-run to fill the ``checked`` column (:mod:`nutribench.report.leaderboard_verify`)."""
    from sqlalchemy import select

    from nutribench.report.data import check_known, prepare_entries, read_episodes
    from nutribench.report.references import eval_day_references
    from nutribench.store import AgentConfig, open_store, read_jobs, session_scope

    reps = check_reps(reps)
    ev = read_episodes(db, "eval")
    with open_store(db) as store:
        forged = forged_regimes(store.engine)
        with session_scope(store.engine) as s:
            configs = pd.DataFrame(
                s.execute(select(AgentConfig.name, AgentConfig.version, AgentConfig.sha256, AgentConfig.body)).all(),
                columns=["name", "version", "sha256", "body"],
            )
        jobs = read_jobs(store.engine)
    data = prepare_entries(ev, algos)
    if data.eval.empty:
        check_known(list(algos or ()), ev["algo"].unique(), "--algos")
    notes, ev = list(data.notes), data.eval
    scored = ev
    if forged:
        scored = ev[[(r, int(v)) not in forged for r, v in zip(ev["regime"], ev["regime_version"])]]
        notes.append(
            ", ".join(f"{r} v{v}" for r, v in sorted(forged))
            + " of this database has other content than the installed regime file of that name and version: "
            "its days are not scored on the installed yardsticks"
        )
    references = eval_day_references(scored, log=log)
    checked = None
    if verify is not None:
        checked = verify_entries(db, ev, verify, log)
        notes += _set_apart_notes(checked)
    rows = leaderboard_rows(ev, references, jobs, _drawn_protocols(configs, ev), reps, checked)
    return leaderboard_table(rows).add_notes(notes)


def _drawn_protocols(configs: pd.DataFrame, ev: pd.DataFrame) -> dict[tuple[str, int], str]:
    """(name, version) -> protocol (:func:`protocols`) of each agent config version ``ev`` draws;
    ``configs``: the database's ``agent_configs`` rows (name, version, sha256, body)."""
    drawn = set(map(tuple, ev[["algo", "algo_version"]].drop_duplicates().to_numpy()))
    configs = configs[[(n, v) in drawn for n, v in zip(configs["name"], configs["version"])]]
    return {
        (name, int(version)): protocols(rows)[name] for (name, version), rows in configs.groupby(["name", "version"])
    }


def leaderboard_from_archives(
    folder: str | Path, reps: int = DEFAULT_REPS, log: Log | None = None, verify: str | Path | None = None
) -> TableResult:
    """The leaderboard of every archive (``*.npz``, written by ``nutribench db export``) in
    ``folder``, each checked whole on import into a temporary database. An archive that fails
    a check is refused (logged, and listed in the caption with its one-line reason) and the
    others are ranked; so are all the archives that disagree on the content of a config of
    one name and version that this installation does not ship (which of them is right
    cannot be told; a shipped one is held against the installed file on import).
    :class:`ReportError` when no archive is left."""
    from nutribench.store.archive import import_results
    from nutribench.store.engine import StoreError

    reps, log = check_reps(reps), log or quiet
    folder = Path(folder)
    archives = sorted(folder.glob("*.npz")) if folder.is_dir() else []
    if not archives:
        raise ReportError(f"{folder}: no archives (*.npz) there: `nutribench db export FILE.npz` writes one")
    refused = dict(disagreeing_archives(archives))  # path -> one line, naming the archive
    with tempfile.TemporaryDirectory(prefix="nutribench-leaderboard-") as tmp:
        db = str(Path(tmp) / "leaderboard.db")
        for path in [p for p in archives if p not in refused]:
            try:
                import_results(path, db)
            except StoreError as e:
                reason = str(e).removeprefix("db import: ").removesuffix("; nothing imported")
                refused[path] = reason.replace(str(path), path.name, 1)
                continue
            log(f"imported {path.name}")
        listed = [refused[p] for p in archives if p in refused]
        if len(refused) == len(archives):
            raise ReportError(f"{folder}: every archive was refused ({'; '.join(listed)})")
        for reason in listed:
            log(f"refused: {reason}")
        table = leaderboard_from_db(db, reps=reps, log=log, verify=verify)
    if refused:
        table.title += f" (refused, not ranked: {'; '.join(listed)})"
    return table
