"""Drawing a regime's per-food delays from its ranges and seed, and writing the file.

The draw is: ``rng = numpy.random.default_rng(seed)``; ``tau = rng.uniform(low, high,
size=(N, 3))`` with the Table 1 bounds per nutrient column (C, F, P), then ``sigma`` the
same way; foods in catalog order; values rounded to 2 decimals (the file is what fixes the
dynamics, the rounding only keeps it readable). ``nutribench regimes generate`` re-runs
this draw, so the written values are reproducible and reviewable.

:func:`derive_regime` makes a new regime from an existing one: other ranges (parsed from
the CLI's ``C=10-12,F=18-20,P=14-16`` by :func:`parse_ranges`), a seed (by default
:func:`default_seed` of the name), version 1, and a fresh draw.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from nutribench.config.loading import OBSERVATION_OPTIONS, ConfigError, validate
from nutribench.config.models import NUTRIENTS, DelayRanges, FoodCatalog, Regime
from nutribench.config.reading import check_strings
from nutribench.safe_write import atomic_write

DECIMALS = 2
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
_NUMBER = r"-?(?:\d+(?:\.\d*)?|\.\d+)"
_RANGE = re.compile(rf"^\s*(\w+)\s*=\s*({_NUMBER})\s*-\s*({_NUMBER})\s*$")


def draw_delays(ranges: DelayRanges, seed: int, catalog: FoodCatalog) -> dict[str, dict]:
    """The per-food ``{"tau": {...}, "sigma": {...}}`` drawn from ``ranges`` with ``seed``."""
    rng = np.random.default_rng(seed)
    n = len(catalog.food)
    drawn = {}
    for what in ("tau", "sigma"):
        lo, hi = getattr(ranges, what).bounds()
        values = np.round(rng.uniform(lo, hi, size=(n, 3)), DECIMALS)
        drawn[what] = np.clip(values, lo, hi)
    return {
        key: {what: {nut: float(drawn[what][i, j]) for j, nut in enumerate(NUTRIENTS)} for what in ("tau", "sigma")}
        for i, key in enumerate(catalog.keys)
    }


def regenerate(regime: Regime, catalog: FoodCatalog) -> Regime:
    """The same regime with its ``foods`` table redrawn from its own ranges and seed."""
    data = regime.model_dump(mode="json")
    data["foods"] = draw_delays(regime.ranges, regime.seed, catalog)
    return Regime.model_validate(data)


def default_seed(name: str) -> int:
    """The seed a new regime gets when none is given: the first 4 bytes of sha256(name)."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "big")


def check_regime_name(name: str) -> str:
    """``name`` if it can name a regime (and its file), else a one-line ConfigError."""
    if not _NAME.match(name):
        raise ConfigError(
            f"regime name '{name}' is not valid: use lowercase letters, digits and _, starting with a letter (e.g. run7)"
        )
    return name


def parse_ranges(text: str, option: str = "--tau") -> dict[str, dict[str, float]]:
    """``"C=10-12,F=18-20,P=14-16"`` -> ``{"C": {"low": 10.0, "high": 12.0}, ...}``.

    Any subset of C, F, P may be given; a bad item raises a one-line :class:`ConfigError`
    that names ``option``.
    """
    out: dict[str, dict[str, float]] = {}
    items = [i for i in text.split(",") if i.strip()]
    if not items:
        raise ConfigError(f"{option} '{text}': no ranges given: write e.g. {option} C=10-12,F=18-20,P=14-16")
    for item in items:
        m = _RANGE.match(item)
        if not m:
            raise ConfigError(
                f"{option} '{item}': malformed range: write NUTRIENT=LOW-HIGH, e.g. {option} C=10-12,F=18-20,P=14-16"
            )
        key, low, high = m.group(1).upper(), float(m.group(2)), float(m.group(3))
        if key not in NUTRIENTS:
            raise ConfigError(f"{option} '{item}': unknown nutrient '{m.group(1)}': use C, F or P")
        if low < 0 or high < 0:
            raise ConfigError(f"{option} '{item}': negative bound: delays are steps >= 0 (e.g. {key}=0-2)")
        if low > high:
            raise ConfigError(f"{option} '{item}': low {low:g} is above high {high:g}: write {key}={high:g}-{low:g}")
        if key in out:
            raise ConfigError(f"{option} '{text}': nutrient {key} given twice: give each of C, F, P at most once")
        out[key] = {"low": low, "high": high}
    return out


def derive_regime(
    source: Regime,
    catalog: FoodCatalog,
    name: str,
    *,
    tau: dict[str, dict[str, float]] | None = None,
    sigma: dict[str, dict[str, float]] | None = None,
    seed: int | None = None,
    description: str | None = None,
) -> Regime:
    """A new regime ``name`` (version 1) made from ``source``: its ranges with ``tau`` and
    ``sigma`` (per nutrient, from :func:`parse_ranges`) replacing theirs, its catalog and
    reward files, and per-food delays freshly drawn with ``seed`` (default
    :func:`default_seed` of ``name``). A ``description`` no config file may hold (a control
    character, a NUL among them, or more than :data:`~nutribench.config.reading.MAX_TEXT`
    characters: what reading the written file would refuse) is a :class:`ConfigError`."""
    if seed is not None and seed < 0:
        raise ConfigError(
            f"new regime {name}: seed {seed} is negative: give a seed >= 0 (or none, to derive it from the name)"
        )
    ranges = source.ranges.model_dump(mode="json")
    for what, new in (("tau", tau), ("sigma", sigma)):
        ranges[what].update(new or {})
    data = {
        "name": check_regime_name(name),
        "version": 1,
        "description": description if description is not None else _describe(source.name, ranges),
        "seed": default_seed(name) if seed is None else seed,
        "catalog": source.catalog,
        "reward": source.reward,
        "ranges": ranges,
        "foods": {},
    }
    where = f"new regime {name}"
    check_strings(where, {"description": data["description"]})  # before anything is written
    data["foods"] = draw_delays(validate(DelayRanges, ranges, where), data["seed"], catalog)
    return validate(Regime, data, where)


def _describe(source: str, ranges: dict) -> str:
    fmt = lambda r: ", ".join(f"{n} {r[n]['low']:g}-{r[n]['high']:g}" for n in NUTRIENTS)  # noqa: E731
    return f"tau {fmt(ranges['tau'])}; sigma {fmt(ranges['sigma'])} (from {source})"


def _toml_str(s: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(s, ensure_ascii=False)


def _num(x: float) -> str:
    return repr(float(x)) if x != int(x) else f"{int(x)}.0"


def _nutrients(d: dict[str, Any], value: Callable[[Any], str] = _num) -> str:
    """An inline table of one ``value`` per nutrient: ``{ C = 1.0, F = 2.5, P = 3.0 }``."""
    return "{ " + ", ".join(f"{n} = {value(d[n])}" for n in NUTRIENTS) + " }"


def _range_table(d: dict[str, dict[str, float]]) -> str:
    return _nutrients(d, lambda r: f"{{ low = {_num(r['low'])}, high = {_num(r['high'])} }}")


def regime_to_toml(regime: Regime) -> str:
    """TOML text of a regime, one line per food, in the layout of the shipped files."""
    d = regime.model_dump(mode="json")
    lines = [
        f"# Delay regime {d['name']}: {' '.join(d['description'].split())}.",
        "# The per-food values below were drawn by `nutribench regimes generate` from [ranges]",
        "# with `seed` (uniform, rounded to 2 decimals). They, not the ranges, fix the dynamics.",
        "# tau = mean absorption delay, sigma = spread, both in steps (1 step ~ 30 min).",
        f'name = "{d["name"]}"',
        f"version = {d['version']}",
        f"description = {_toml_str(d['description'])}",
        f"seed = {d['seed']}",
        f"catalog = {_toml_str(d['catalog'])}",
        f"reward = {_toml_str(d['reward'])}",
        *[f"{option} = true" for option in OBSERVATION_OPTIONS if d[option]],
        "",
        "[ranges]",
        *[f"{what} = {_range_table(d['ranges'][what])}" for what in ("tau", "sigma")],
        "",
        "[foods]",
    ]
    for key, delay in d["foods"].items():
        lines.append(f"{key} = {{ tau = {_nutrients(delay['tau'])}, sigma = {_nutrients(delay['sigma'])} }}")
    return "\n".join(lines) + "\n"


def write_regime(regime: Regime, path: Path) -> None:
    """Write ``regime`` to ``path`` in the layout of :func:`regime_to_toml`, atomically
    (:func:`nutribench.safe_write.atomic_write`: a unique temporary file beside it, then renamed
    over ``path``). A device node, a FIFO or a folder at ``path`` is refused, and a write that
    fails (a full disk, no permission) leaves ``path`` as it was (no empty file that would block
    and hide the name): each a one-line :class:`ConfigError`."""
    hint = "nothing was written (free space or fix the folder, then try again)"
    with atomic_write(path, error=ConfigError, hint=hint) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(regime_to_toml(regime))
        fh.flush()
        os.fsync(fh.fileno())
