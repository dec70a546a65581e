"""Which agent configs a figure draws, in what order, in what colour and under what label.

A config named like a registered algorithm (:mod:`nutribench.agents.registry`) takes that
algorithm's place, label and colour: the five built-in configs keep the paper's order, labels
and colours (published figures use them). Any other config (a variant, a plug-in agent) comes after them, sorted by name, and is
labelled with its name. Its colour comes first from :data:`USER_COLORS`, four colours chosen
by measured distance (a search over the sRGB cube) to stay apart from the five built-in colours,
from black (the planner's reference line) and from each other, for normal vision and under
simulated deuteranopia and protanopia, and dark enough to read on white: a hash of the name picks where in that list
it starts, and it takes the first one no config sorted before it took. When all are taken, a
hash of the name picks a sequence of candidate colours (never pale: CIELAB lightness at most
:data:`MAX_LIGHTNESS`), and the config takes the first candidate clearly apart from every
colour placed before it. So a name's colour is a function of the name alone unless a config
that sorts before it holds that colour, and the same set of names always gets the same
colours. Build one :class:`Palette` per report (over every
config the database holds) and every figure of it uses the same colour for a name.

Colour is not the only cue: each config also has a marker (:meth:`Palette.marker`), the five
their own (:data:`BUILTIN_MARKERS`), the others one of :data:`USER_MARKERS` picked as their
colour is, so two agents whose colours a reader cannot tell apart still differ by marker.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from matplotlib.colors import hsv_to_rgb, to_hex, to_rgb

import nutribench.agents.registry as registry

#: The paper's five algorithms' configs, in the paper's order, and their colours (the
#: registry's: :mod:`nutribench.agents.registry`)
BUILTIN_ORDER: tuple[str, ...] = tuple(registry.paper_names())
BUILTIN_COLORS: dict[str, str] = {a: registry.get(a).color for a in BUILTIN_ORDER}
#: Smallest CIELAB (CIE76) distance between a derived colour and any colour placed before it.
MIN_DISTANCE = 32.0
#: The colours configs other than the five take first: pink, plum, deep blue and cyan, chosen over
#: the sRGB cube (CIELAB lightness 25-72, chroma at least 30) to maximise the smallest CIEDE2000
#: distance to the five, to black and to each other, for normal vision and (weighted 1.5) under
#: simulated deuteranopia and protanopia, keeping CIE76 distances of at least
#: :data:`USER_MIN_DISTANCE`. The palettes of Okabe & Ito and of Paul Tol (the teal, orange,
#: indigo and wine used before) each hold a colour near one of the five: Tol's teal is 22
#: CIEDE2000 from PPO's green, the wine 20 from MC's brown. tests/test_figures_legible.py checks.
USER_COLORS: tuple[str, ...] = ("#ff8899", "#770055", "#0011cc", "#44bbcc")
#: Smallest CIE76 distance of a user colour to each of the five built-in colours and to each other.
USER_MIN_DISTANCE = 38.0
#: Smallest CIEDE2000 distance of a user colour to each of the five and to each other: for normal
#: vision, and under simulated deuteranopia or protanopia (Machado et al. 2009, severity 1).
USER_MIN_DE2000 = 24.0
USER_MIN_DE2000_CVD = 15.0
#: Markers of the five (paper order) and those the other configs take, as colours are taken;
#: none is a reference line's (``x``, ``.``, ``+``, ``*``: :data:`nutribench.report.figures.POLICY_STYLES`).
BUILTIN_MARKERS: dict[str, str] = dict(zip(BUILTIN_ORDER, ("o", "s", "^", "D", "v")))
USER_MARKERS: tuple[str, ...] = ("P", "X", "h", "<", ">", "p", "d", "8")
#: Lightest a derived colour may be (CIELAB L*): a paler line is hard to read on white.
MAX_LIGHTNESS = 75.0
#: Candidate colours tried per name before the most distant one is taken.
CANDIDATES = 96
_GOLDEN = 0.6180339887498949


def _registered() -> dict[str, Any]:
    """The registered algorithms that may name a config (all but ``external``), in registry order."""
    table = registry.algorithms()
    return {a: table[a] for a in registry.names()}


def order(names: Iterable[str]) -> list[str]:
    """``names`` once each: those of registered algorithms in the registry's order (the paper's
    five first, in its order), then the others by name."""
    rank = {n: i for i, n in enumerate(_registered())}
    return sorted(set(map(str, names)), key=lambda n: (rank.get(n, len(rank)), n))


def label(name: str) -> str:
    """The legend and table label: a registered algorithm's label (MC, DDQN, PPO, SAC, GRU-PPO
    for the five), else the name."""
    entry = _registered().get(name)
    return name if entry is None else entry.display


def lab(color: str) -> np.ndarray:
    """sRGB colour -> CIELAB (D65 white)."""
    rgb = np.asarray(to_rgb(color))
    lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = m @ lin / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def distance(a: str, b: str) -> float:
    """Perceptual distance of two colours (CIE76: Euclidean in CIELAB)."""
    return float(np.linalg.norm(lab(a) - lab(b)))


def candidates(name: str) -> Iterator[str]:
    """The colours ``name`` may take, in order: hue from a hash of the name, then steps of the
    golden angle; saturation and brightness vary, never grey and never pale."""
    h = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "big")
    hue0 = (h % 10_000) / 10_000
    for k in range(CANDIDATES):
        hue = (hue0 + k * _GOLDEN) % 1.0
        sat = (0.85, 0.6, 0.95)[(h // 10_000 + k) % 3]
        val = (0.75, 0.9, 0.55)[(h // 30_000 + k // 3) % 3]
        yield to_hex(hsv_to_rgb((hue, sat, val)))


def _pick(name: str, taken: list[str]) -> str:
    """The first candidate of ``name`` far enough from every colour in ``taken``; if none is,
    the candidate farthest from them."""
    best, best_d = "", -1.0
    for c in candidates(name):
        if lab(c)[0] > MAX_LIGHTNESS:
            continue
        d = min((distance(c, t) for t in taken), default=np.inf)
        if d >= MIN_DISTANCE:
            return c
        if d > best_d:
            best, best_d = c, d
    return best


def colors(names: Iterable[str]) -> dict[str, str]:
    """A colour per name, in :func:`order`: the built-in colours for the five, for the others
    one of :data:`USER_COLORS` while one is free, then derived colours (distinct from every
    colour before)."""
    fixed = {a: e.color for a, e in _registered().items() if e.color}  # the registered algorithms' (the five's)
    taken = list(fixed.values())
    out: dict[str, str] = {}
    for n in order(names):
        # one of USER_COLORS not yet taken, from a place the name's hash picks; else a derived one
        out[n] = fixed.get(n) or next((c for c in _ring(n, USER_COLORS) if c not in taken), None) or _pick(n, taken)
        if n not in fixed:
            taken.append(out[n])
    return out


def markers(names: Iterable[str]) -> dict[str, str]:
    """A marker per name, in :func:`order`: the five's own, for the others one of
    :data:`USER_MARKERS` from a place the name's hash picks, the first free one (as colours);
    when all are taken, the one the hash picks (the colour still differs)."""
    out: dict[str, str] = {}
    for n in order(names):
        ring = _ring(n, USER_MARKERS)
        out[n] = BUILTIN_MARKERS.get(n) or next((m for m in ring if m not in out.values()), ring[0])
    return out


def _ring(name: str, options: tuple[str, ...]) -> list[str]:
    """``options`` from a place a hash of ``name`` picks, round to the one before it."""
    start = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "big") % len(options)
    return [options[(start + k) % len(options)] for k in range(len(options))]


@dataclass(frozen=True)
class Palette:
    """The colours and markers of one report's configs; a name it does not know is added to it."""

    colors: Mapping[str, str]
    markers: Mapping[str, str] = field(default_factory=dict)

    def marker(self, name: str) -> str:
        """``name``'s marker (as in :func:`markers` over the palette's names and ``name``)."""
        return self.markers.get(name) or markers([*self.colors, *self.markers, name])[name]

    def color(self, name: str) -> str:
        """``name``'s colour (as in :func:`colors` over the palette's names and ``name``)."""
        return self.colors.get(name) or colors([*self.colors, name])[name]


def palette(names: Iterable[str] = ()) -> Palette:
    """The :class:`Palette` of ``names`` (give every config of the report, so that each
    figure colours a name the same way)."""
    names = list(names)
    return Palette(colors(names), markers(names))
