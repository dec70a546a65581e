"""``nutribench regimes list|check|generate``: inspect, check and regenerate the regime files."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table

from nutribench.cli.common import console, err_console, user_errors

regimes_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Inspect, check and regenerate the regime files.")


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
def regimes_check(
    regimes: Annotated[str, typer.Option(help="'all' or comma-separated names or paths")] = "all",
) -> None:
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
            err_console.print(f"{cfg.path}: foods: values differ from a fresh draw with seed {cfg.regime.seed}")
        else:
            console.print(f"{cfg.path}: ok (sha256 {cfg.sha256[:12]})")
    if bad:
        raise typer.Exit(1)


@regimes_app.command("generate")
@user_errors
def regimes_generate(
    regime: Annotated[str, typer.Argument(help="regime name or path whose [foods] table is redrawn")],
    write: Annotated[bool, typer.Option(help="overwrite the file (else print it)")] = False,
) -> None:
    """Redraw a regime's per-food tau and sigma from its [ranges] and seed."""
    from nutribench.config import load_env_config
    from nutribench.config.generate import regenerate, regime_to_toml, write_regime

    cfg = load_env_config(regime)
    fresh = regenerate(cfg.regime, cfg.catalog)
    if write:
        write_regime(fresh, cfg.path)
        console.print(f"wrote {cfg.path}" + ("" if fresh == cfg.regime else " (values changed: bump its version)"))
    else:
        typer.echo(regime_to_toml(fresh), nl=False)
