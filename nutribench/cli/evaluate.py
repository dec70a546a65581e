"""``nutribench evaluate``: a model saved by any framework, played on the fixed evaluation days
of (regime, seed) and stored as a job beside the built-in agents."""

from __future__ import annotations

from nutribench.cli.common import DbOption, console, option, path_option, user_errors
from nutribench.errors import UserError


@user_errors
def evaluate_cmd(
    model_given: option(str, "the saved model (a file or folder your loader reads)", "--model", metavar="PATH"),
    entry_point: option(str, "package.module:load, called as load(MODEL) -> a policy with predict() or a callable"),
    name: option(str, "the agent's name in the database ([a-z][a-z0-9_]*)"),
    regime: option(str, "regime name or regime file") = "run0",
    seed: option(int, "picks the evaluation days (the same for every agent of this seed)", min=0) = 0,
    version: option(int, "the agent's version", min=1) = 1,
    eval_episodes: option(int, "evaluation days (5: the paper's)", min=1) = 5,
    db: DbOption = "nutribench.db",
) -> None:
    """Evaluate a saved model greedily and store it as a job (engine 'external', no training rows;
    its budget the training days of the model's .json sidecar, where nutribench wrote one)."""
    from nutribench.agents.model_files import sidecar_training_days
    from nutribench.agents.registry import import_entry_point
    from nutribench.provenance import file_sha256
    from nutribench.recorder import Recorder
    from nutribench.store.engine import database_url, display_url

    model = path_option(model_given, "--model", "the saved model's file or folder")
    if not model.exists():
        raise UserError(f"--model {model}: no such file or folder")
    trained_days = sidecar_training_days(model)
    load = import_entry_point(entry_point)
    try:
        policy = load(str(model))
    except Exception as e:  # the user's loader: its failure is theirs to read, in one line
        raise UserError(f"--entry-point {entry_point} could not load {model}: {type(e).__name__}: {e}") from None
    source = (f"{entry_point} {model.resolve()}", file_sha256(model))
    how = dict(regime=regime, seed=seed, version=version, eval_episodes=eval_episodes, trained_days=trained_days)
    with Recorder(db, name=name, source=source, **how) as rec:
        rows = rec.evaluate(policy)
    mean = sum(r["return"] for r in rows) / len(rows)
    foods = sum(r["foods"] for r in rows) / len(rows)
    trained = (
        f"trained {trained_days} days (its sidecar)"
        if trained_days
        else "training not recorded (no sidecar records it)"
    )
    console.print(
        f"{name} on {rec.regime_config.name} seed {seed}: {len(rows)} evaluation days, mean return {mean:.2f}, "
        f"{foods:.1f} foods a day, {trained}; stored in {display_url(database_url(db))}"
    )
