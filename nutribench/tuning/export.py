"""A study's best trial as a new agent file, beside (never over) the paper's.

The file is the search space's base agent with the best trial's values, a new name
(``<agent>_tuned`` unless told), version 1, and a description naming the study, the trial,
its objective value and the search space's name, version and hash; the same facts head the
file as comments. The description is part of the config's content, so every job trained
from the file records in the database which study chose it. An existing file is never
overwritten, and a paper agent's name is refused.

The search space is the study's own (:func:`~nutribench.tuning.study.study_space`): the file
whose path the study kept, else the text it kept (a plug-in's space given by path, moved
since), else the space of its name in ``regimes/search/``; its version and hash must be those
the study was created with.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any

from nutribench.agents.config import agent_config_to_toml, agents_dir
from nutribench.agents.registry import by_entry_point, paper_names
from nutribench.config.loading import ConfigError
from nutribench.safe_write import atomic_write, check_folder_target, check_regular_file
from nutribench.tuning.space import decoded, load_search_space, validated_space
from nutribench.tuning.study import SPACE_ATTR, TuneError, count_trials, stored_settings


def tuned_config(study: Any, name: str | None = None) -> tuple[Any, str]:
    """The best trial's agent config and the comment block that heads its file."""
    counts = count_trials(study)
    if counts.best_number is None:
        raise TuneError(f"study {study.study_name!r} has no complete trial yet: nothing to export")
    settings = stored_settings(study)
    space = study_space(study)
    best = study.best_trial
    name = name or f"{space.base().name}_tuned"
    if name in paper_names():
        raise TuneError(f"--name {name!r} is a paper agent's name; its file is never overwritten: give another name")
    provenance = (
        f"tuned by nutribench tune: study {study.study_name!r}, trial {best.number}, objective {best.value:.4f} "
        f"(IQM share of the never -> planner gap on validation days), search space {space.name} v{space.version} "
        f"(sha256 {space.sha256[:12]})"
    )
    cfg = space.config({k: decoded(v) for k, v in best.params.items()}, name=name, description=provenance)
    header = "\n".join(
        [
            f"# {name}: the best trial of tuning study {study.study_name!r} (docs/tuning.md).",
            f"# Base agent: {space.base().name}; searched: {', '.join(space.params)}.",
            f"# Study: regimes {','.join(settings.regimes)}, tuning seeds {','.join(map(str, settings.seeds))}, "
            f"{settings.days} days per trial, {_scored(cfg, settings)}.",
            f"# Trial {best.number}: objective {best.value:.4f} ({settings.objective}); {counts.complete} complete, "
            f"{counts.pruned} pruned trials.",
            "# Made by `nutribench tune best --write`; never edit it in place: a changed agent file is a new version.",
        ]
    )
    return cfg, header


def _scored(cfg: Any, settings: Any) -> str:
    """How the study scored a trial: periodic evaluations, or once at its end (a plug-in's own loop)."""
    days = f"{settings.val_episodes} validation day{'s' if settings.val_episodes != 1 else ''}"
    if by_entry_point(cfg.algo):
        return f"each agent scored once, after its last day, on {days} (a plug-in's own loop)"
    return f"evaluated every {settings.eval_every} days on {days}"


def space_file_attr(path: Any) -> dict[str, str]:
    """What a study keeps of its search space's file: its absolute path and its text."""
    path = Path(path)
    return {"path": str(path.resolve()), "toml": path.read_text(encoding="utf-8")}


def study_space(study: Any) -> Any:
    """The study's search space, as it was when the study was created (version and hash
    checked): from the file at its kept path, else from its kept text (the file moved or
    gone), else by its name in ``regimes/search/`` (a study made before the file was kept)."""
    settings = stored_settings(study)
    kept = study.user_attrs.get(SPACE_ATTR)
    kept = kept if isinstance(kept, dict) else {}
    path, text = kept.get("path"), kept.get("toml")
    source = f"study {study.study_name!r}'s kept search space {settings.space!r}"
    loaders = [
        *([lambda: load_search_space(path)] if isinstance(path, str) and os.path.isfile(path) else []),
        *([lambda: _kept_space(text, source)] if isinstance(text, str) else []),
        lambda: load_search_space(settings.space),
    ]
    wanted = (settings.space, settings.space_version, settings.space_sha256)
    found: list[Any] = []
    problems: list[str] = []
    for load in loaders:
        try:
            space = load()
        except ConfigError as e:
            problems.append(str(e))
            continue
        if (space.name, space.version, space.sha256) == wanted:
            return space
        found.append(space)
    if found:
        space = found[-1]
        raise TuneError(
            f"search space {settings.space!r} changed since study {study.study_name!r} was created "
            f"(version {settings.space_version}, sha256 {settings.space_sha256[:12]}; now version {space.version}, "
            f"{space.sha256[:12]}): restore that file to export this study"
        )
    raise TuneError(f"study {study.study_name!r}: its search space is not found: {'; '.join(problems)}")


def _kept_space(text: str, source: str) -> Any:
    """The search space of a study's kept text (``source`` names it in a one-line ConfigError)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{source}: {e}") from None
    return validated_space(data, source)


def write_tuned(study: Any, name: str | None = None, folder: Path | None = None) -> Path:
    """Write the best trial's agent file into ``folder`` (the agents folder by default) and
    return its path; refuse an existing file."""
    cfg, header = tuned_config(study, name)
    what = "--out" if folder is not None else "the agents folder"
    folder = folder or agents_dir()
    check_folder_target(folder, what, TuneError, "give a folder for the agent file (--out)")
    path = folder / f"{cfg.name}.toml"
    check_regular_file(path, what, TuneError)
    if path.exists() or path.is_symlink():
        raise TuneError(f"{path} exists: a tuned file is never overwritten; give another --name or remove it")
    with atomic_write(path, what, TuneError, "free space or give another --out") as tmp:
        tmp.write_text(header + "\n" + agent_config_to_toml(cfg))
    return path
