"""``nutribench regimes list|check|generate``: inspect, check, regenerate and create the regime files."""

from __future__ import annotations

from typing import Optional

import typer
from rich.table import Table

from nutribench.cli.common import UserError, argument, command_group, console, option, say, say_err, user_errors

regimes_app = command_group("Inspect, check and regenerate the regime files.")


@regimes_app.command("list")
@user_errors
def regimes_list() -> None:
    """List the regimes with their delay ranges and content hash."""
    from nutribench.config import list_regimes, load_env_config

    table = Table("regime", "version", "description", "tau C/F/P", "sigma C/F/P", "sha256")
    for name in list_regimes():
        cfg = load_env_config(name)
        r = cfg.regime.ranges
        fmt = lambda nr: " / ".join(f"{x.low:g}-{x.high:g}" for x in (nr.C, nr.F, nr.P))  # noqa: E731
        table.add_row(name, str(cfg.version), cfg.regime.description, fmt(r.tau), fmt(r.sigma), cfg.sha256[:12])
    console.print(table)


@regimes_app.command("check")
@user_errors
def regimes_check(regimes: option(str, "'all' or comma-separated names or paths") = "all") -> None:
    """Validate regime files and check that their drawn values equal a fresh draw from ranges + seed."""
    from nutribench.config import list_regimes, load_env_config
    from nutribench.config.generate import regenerate

    names = list_regimes() if regimes == "all" else [r.strip() for r in regimes.split(",")]
    bad = 0
    for name in names:
        cfg = load_env_config(name)
        fresh = regenerate(cfg.regime, cfg.catalog)
        if fresh.foods != cfg.regime.foods:
            bad += 1
            say_err(f"{cfg.path}: foods: values differ from a fresh draw with seed {cfg.regime.seed}")
        else:
            say(f"{cfg.path}: ok (sha256 {cfg.sha256[:12]})")
    if bad:
        raise typer.Exit(1)


RANGES_HELP = "with --from: {what} ranges in steps per nutrient, NUTRIENT=LOW-HIGH, e.g. {example}; nutrients left out keep the --from regime's ranges"


@regimes_app.command("generate")
@user_errors
def regimes_generate(
    name: argument(
        str, "an existing regime (name or path) whose [foods] table is redrawn; with --from, the name of the new regime"
    ),
    source: option(
        Optional[str],
        "create regime NAME from this regime (name or path): its ranges (but --tau/--sigma), catalog and reward, and a fresh draw",
        "--from",
    ) = None,
    tau: option(Optional[str], RANGES_HELP.format(what="tau", example="C=10-12,F=18-20,P=14-16")) = None,
    sigma: option(Optional[str], RANGES_HELP.format(what="sigma", example="C=5-8.4,F=9-14,P=7-11.2")) = None,
    seed: option(
        Optional[int],
        "with --from: seed of the draw (default: derived from NAME, the first 4 bytes of sha256(NAME), so the same command gives the same file)",
    ) = None,
    description: option(
        Optional[str], "with --from: the description (default: the ranges and the --from regime)"
    ) = None,
    write: option(
        bool, "write the file (else print it); with --from it goes to the regimes folder as NAME.toml"
    ) = False,
    force: option(bool, "with --from: overwrite an existing NAME.toml") = False,
) -> None:
    """Redraw a regime's per-food tau and sigma from its [ranges] and seed, or, with --from,
    create regime NAME (version 1) from another's ranges with new --tau/--sigma ranges.

    Example: nutribench regimes generate run7 --from run6 --tau C=10-12,F=18-20,P=14-16 --write
    """
    if source is None:
        extra = (("--tau", tau), ("--sigma", sigma), ("--seed", seed), ("--description", description))
        given = [opt for opt, value in extra if value is not None]
        if given:
            raise UserError(
                f"regimes generate {name}: {given[0]} needs --from REGIME (it creates a new regime), e.g. --from run6"
            )
        _redraw(name, write)
    else:
        _create(name, source, tau=tau, sigma=sigma, seed=seed, description=description, write=write, force=force)


def _redraw(regime: str, write: bool) -> None:
    """An existing regime with its [foods] redrawn from its own ranges and seed: printed, or written back."""
    from nutribench.config import ConfigError, load_env_config
    from nutribench.config.generate import regenerate, regime_to_toml, write_regime

    try:
        cfg = load_env_config(regime)
    except ConfigError as e:
        if str(e).startswith("unknown regime"):
            raise ConfigError(f"{e}; to create it, add --from REGIME (e.g. --from run6)") from None
        raise
    fresh = regenerate(cfg.regime, cfg.catalog)
    if write:
        write_regime(fresh, cfg.path)
        note = "" if fresh == cfg.regime else " (values changed: bump its version)"
        say(f"wrote {cfg.path}{note}")
    else:
        typer.echo(regime_to_toml(fresh), nl=False)


def _create(
    name: str,
    source: str,
    *,
    tau: str | None,
    sigma: str | None,
    seed: int | None,
    description: str | None,
    write: bool,
    force: bool,
) -> None:
    """Regime ``name`` from ``source`` with new ranges: printed, or written to the regimes folder."""
    from nutribench.config import EnvConfig, FoodCatalog, RewardConfig, load_env_config, load_model, regimes_dir
    from nutribench.config.generate import check_regime_name, derive_regime, parse_ranges, regime_to_toml, write_regime
    from nutribench.safe_write import check_regular_file

    check_regime_name(name)
    new_tau = parse_ranges(tau, "--tau") if tau is not None else None
    new_sigma = parse_ranges(sigma, "--sigma") if sigma is not None else None
    src = load_env_config(source)
    folder = regimes_dir()
    path = folder / f"{name}.toml"
    for needed in (src.regime.catalog, src.regime.reward):
        if not (folder / needed).is_file():
            raise UserError(f"{folder}: no {needed} for the new regime {name}: copy {src.path.parent / needed} there")
    catalog = load_model(FoodCatalog, folder / src.regime.catalog)
    new = derive_regime(src.regime, catalog, name, tau=new_tau, sigma=new_sigma, seed=seed, description=description)
    EnvConfig(regime=new, catalog=catalog, reward=load_model(RewardConfig, folder / new.reward), path=path)  # validates
    if not write:
        typer.echo(regime_to_toml(new), nl=False)
        return
    check_regular_file(path, error=UserError)
    replaced = path.exists()
    if replaced and not force:
        raise UserError(f"{path} already exists: pass --force to overwrite it, or choose another NAME")
    write_regime(new, path)
    note = " (replaced the old file: if results were stored under it, bump its version)" if replaced else ""
    say(f"wrote {path} (seed {new.seed}); use it as regime={name} or --regimes {name}{note}")
