"""An archive's configs held against the installed ones: a regime, a reward, a food catalog
or a built-in agent config that an archive names with the **name and version of a file
this installation ships** must have that file's content. The report and the leaderboard
score a regime's days on the installed file's never/planner yardsticks (looked up by name
and version), so a ``run0`` v2 with other reward weights, its sha256 recomputed, would be
scored on the real ``run0``'s yardsticks, and in a folder of archives it would make the
genuine ``run0`` v2 clash. Same name and version with other content is the error that says
"bump the version": refused here, in one line, before anything is written.

A built-in agent config is held to the installed file's settings (its description may
differ: prose). A config whose name the installation does not ship, or whose version differs from the
installed file's (an older ``run0`` v1, a regime of the observation ladder), is not compared:
nothing of the installation describes it, and the yardsticks leave it out (by version).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

from nutribench.store.archive.format import InvalidArchive, open_archive, short_repr
from nutribench.store.engine import StoreError

#: (kind, name, version) -> (sha256 of the installed content, the file it comes from)
Installed = dict[tuple[str, str, int], tuple[str, str]]


def _signature(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """The installed files' names, sizes and times: a changed file is read again."""
    out = []
    for p in sorted([*folder.glob("*.toml"), *(folder / "agents").glob("*.toml")]):
        try:
            st = p.stat()
        except OSError:
            continue
        out.append((str(p), st.st_size, st.st_mtime_ns))
    return tuple(out)


def installed_configs() -> Installed:
    """Every config this installation ships: its regimes (and the reward and food catalog
    each names) and its built-in agent configs (``regimes/agents/``); a file that does not
    load is left out (nothing to compare with). Empty without a regimes folder."""
    from nutribench.config.loading import ConfigError, regimes_dir

    try:
        folder = regimes_dir()
    except ConfigError:
        return {}
    return _installed(str(folder), _signature(folder))


@lru_cache(maxsize=4)
def _installed(folder_name: str, signature: tuple[tuple[str, int, int], ...]) -> Installed:
    from nutribench.agents.config import agent_config_sha256, parse_agent_config, settings_sha256
    from nutribench.config.loading import ConfigError, content_sha256, list_regimes, load_env_config, read_toml

    folder = Path(folder_name)
    out: Installed = {}
    try:
        names = list_regimes(folder)
    except ConfigError:
        names = []
    for name in names:
        try:
            cfg = load_env_config(folder / f"{name}.toml")
        except (ConfigError, OSError, ValueError):
            continue
        where = f"{folder.name}/{name}.toml"
        out[("regime", cfg.name, int(cfg.version))] = (cfg.sha256, where)
        for kind, part in (("reward", cfg.reward), ("food catalog", cfg.catalog)):
            out.setdefault((kind, part.name, int(part.version)), (content_sha256(part.model_dump(mode="json")), where))
    for path in sorted((folder / "agents").glob("*.toml")):
        try:
            cfg = parse_agent_config(read_toml(path), path)
        except (ConfigError, OSError, ValueError):
            continue
        ident = (str(cfg.name), int(cfg.version))
        out[("agent config", *ident)] = (agent_config_sha256(cfg), f"{folder.name}/agents/{path.name}")
        out[("agent settings", *ident)] = (settings_sha256(cfg), "")
    return out


def _part_sha256(kind: str, body: Any) -> str | None:
    """The content hash of a regime body's reward or catalog, read through its model (as the
    installed one is); None for one that does not validate (the replay refuses it)."""
    from nutribench.config.loading import content_sha256
    from nutribench.config.models import FoodCatalog, RewardConfig

    model = RewardConfig if kind == "reward" else FoodCatalog
    try:
        return content_sha256(model.model_validate(body).model_dump(mode="json"))
    except (TypeError, ValueError):
        return None


def check_installed(meta: dict[str, Any]) -> None:
    """Every config of the (checked) ``meta`` that bears an installed config's name and
    version has its content; :class:`InvalidArchive` naming the first that has not."""
    from nutribench.agents.config import body_settings_sha256

    installed = installed_configs()
    if not installed:
        return

    def clash(kind: str, name: Any, version: Any, sha: str | None, what: str) -> None:
        have = installed.get((kind, name, version)) if isinstance(name, str) and isinstance(version, int) else None
        if have is not None and sha is not None and sha != have[0]:
            raise InvalidArchive(
                f"{what} has other content than the installed {kind} {name} v{version} ({have[1]}): a config "
                "with a shipped name and version must be the shipped one (a changed config bumps its version)"
            )

    for row in meta["regimes"]:
        what = f"regime {short_repr(row['name'])} v{row['version']}"
        clash("regime", row["name"], row["version"], row["sha256"], what)
        body = row["body"]
        for kind, key in (("reward", "reward"), ("food catalog", "catalog")):
            part = body.get(key)
            name, version = (part.get("name"), part.get("version")) if isinstance(part, dict) else (None, None)
            if isinstance(name, str) and isinstance(version, int) and (kind, name, version) in installed:
                clash(kind, name, version, _part_sha256(kind, part), f"{what}'s {kind} {short_repr(name)} v{version}")
    for row in meta["agent_configs"]:
        # a built-in agent's config: its settings must be the shipped file's (the prose may differ)
        ident = ("agent config", row["name"], row["version"])
        if ident in installed and row["sha256"] != installed[ident][0]:
            settings = installed[("agent settings", row["name"], row["version"])][0]
            if body_settings_sha256(row["body"]) != settings:
                raise InvalidArchive(
                    f"agent config {short_repr(row['name'])} v{row['version']} has other settings than the installed "
                    f"{installed[ident][1]} of that name and version: a config with a shipped name and version must "
                    "be the shipped one (a changed config bumps its version)"
                )


def forged_regimes(engine) -> set[tuple[str, int]]:
    """(name, version) of the regimes of a database that bear an installed regime's name and
    version but other content (:func:`check_installed`'s rule)."""
    from sqlalchemy import select
    from sqlalchemy.orm import Session

    from nutribench.store import RegimeConfig

    installed = installed_configs()
    with Session(bind=engine) as s:
        rows = s.execute(select(RegimeConfig.name, RegimeConfig.version, RegimeConfig.sha256)).all()
    # a regime the installation does not ship has nothing to differ from (its own sha256)
    return {(name, int(v)) for name, v, sha in rows if installed.get(("regime", name, int(v)), (sha,))[0] != sha}


def _peek_configs(path: Path) -> set[tuple[str, str, int, str]] | None:
    """(kind, name, version, sha256) of the configs an archive's meta lists, read without the
    full check (its meta alone); None for a file whose meta cannot be read (its import says why)."""
    try:
        meta, _ = open_archive(path, arrays=False)
        lists = (("regimes", "regime"), ("agent_configs", "agent config"))
        idents = [(kind, row["name"], row["version"], row["sha256"]) for key, kind in lists for row in meta[key]]
    except (StoreError, KeyError, TypeError):  # the import refuses it with the reason
        return None
    return {i for i in idents if isinstance(i[1], str) and isinstance(i[3], str) and type(i[2]) is int}


def disagreeing_archives(archives: list[Path]) -> list[tuple[Path, str]]:
    """The archives that list a config (name and version not shipped with this installation)
    whose content another archive of the folder lists otherwise, each with the reason."""

    installed = installed_configs()
    holders: dict[tuple[str, str, int], dict[str, list[Path]]] = {}
    for path in archives:
        for kind, name, version, sha in _peek_configs(path) or ():
            if kind != "regime" or (kind, name, version) not in installed:  # an installed regime: held to its file
                holders.setdefault((kind, name, version), {}).setdefault(sha, []).append(path)
    out: dict[Path, str] = {}
    for (kind, name, version), by_sha in sorted(holders.items()):
        if len(by_sha) < 2:
            continue
        every = sorted({p for paths in by_sha.values() for p in paths})
        shipped = installed.get((kind, name, version), ("", ""))[0]
        for path in every:
            if path in by_sha.get(shipped, ()):
                continue  # the installed config's content: the others are refused
            others = ", ".join(p.name for p in every if p != path)
            out.setdefault(
                path,
                f"{path.name}: its {kind} {name} v{version} has other content in {others}: the archives disagree on what that "
                "version is, and which is right cannot be told (a changed config bumps its version)",
            )
    return sorted(out.items())
