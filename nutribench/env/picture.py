"""The environment's ``render_mode="rgb_array"`` picture, drawn with numpy alone (the base
install, gymnasium, numpy and pydantic, has no plotting library; Gymnasium's ``check_env``
renders every mode the metadata lists).

:func:`nutrient_picture` draws three bars, carbohydrates, fats and proteins in the colours the
report gives them, each the amount absorbed so far (solid) with what is eaten and still on its
way by the end of the day stacked on it (striped), against the daily target (a dashed black
line at 1.0); under each bar its letter, and along the top a bar of the day's progress (steps
taken of the horizon). The vertical scale runs from 0 to 1.5 times the target, or further when
a bar reaches higher. Pixels only, no text rendering: a picture a video recorder can store.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: The picture's size, (height, width) in pixels.
SIZE: tuple[int, int] = (240, 320)
#: C, F, P: the colours of the three nutrients (RGB).
COLORS: tuple[tuple[int, int, int], ...] = ((76, 114, 176), (221, 132, 82), (85, 168, 104))
_WHITE, _BLACK, _GREY = (255, 255, 255), (0, 0, 0), (170, 170, 170)
#: 3 x 5 pixel letters under the bars (1 = ink), each scaled up when drawn.
_GLYPHS = {
    "C": ("111", "100", "100", "100", "111"),
    "F": ("111", "100", "110", "100", "100"),
    "P": ("111", "101", "111", "100", "100"),
}


def _glyph(img: np.ndarray, letter: str, top: int, left: int, scale: int) -> None:
    ink = np.kron([[c == "1" for c in row] for row in _GLYPHS[letter]], np.ones((scale, scale))) > 0
    img[top : top + 5 * scale, left : left + 3 * scale][ink] = _BLACK  # each pixel of the letter a scale x scale block


def nutrient_picture(absorbed: Sequence[float], pending: Sequence[float], step: int, horizon: int) -> np.ndarray:
    """An RGB picture (uint8, shape ``SIZE + (3,)``) of the nutrients ``absorbed`` (C, F, P,
    as multiples of the daily target) and those ``pending`` (eaten, arriving by the end of the
    day) against the target, after ``step`` of ``horizon`` steps."""
    h, w = SIZE
    img = np.full((h, w, 3), _WHITE, dtype=np.uint8)
    absorbed = np.clip(np.asarray(absorbed, dtype=float), 0.0, None)
    pending = np.clip(np.asarray(pending, dtype=float), 0.0, None)
    top_value = max(1.5, float(np.max(absorbed + pending)) * 1.1)
    plot_top, plot_bottom, left, right = 28, h - 30, 24, w - 16
    span = plot_bottom - plot_top

    def y_of(value: float) -> int:  # the pixel row of a value (0 at the bottom of the plot)
        return int(round(plot_bottom - span * min(value, top_value) / top_value))

    # the day's progress along the top
    img[8:16, left:right] = _GREY
    done = left + int(round((right - left) * min(max(step, 0), horizon) / max(horizon, 1)))
    img[8:16, left:done] = _BLACK
    # the bars
    slot = (right - left) // 3
    bar = int(slot * 0.6)
    rows = np.arange(h)[:, None]
    cols = np.arange(w)[None, :]
    for i, (a, p, color) in enumerate(zip(absorbed, pending, COLORS)):
        x0 = left + i * slot + (slot - bar) // 2
        x1 = x0 + bar
        y_abs, y_all = y_of(a), y_of(a + p)
        img[y_abs:plot_bottom, x0:x1] = color
        if y_all < y_abs:  # pending: diagonal stripes of the nutrient's colour over white, outlined
            stripes = ((rows[y_all:y_abs] + cols[:, x0:x1]) // 4) % 2 == 0
            region = img[y_all:y_abs, x0:x1]
            region[stripes] = color
            img[y_all:y_abs, [x0, x1 - 1]] = _GREY
            img[y_all, x0:x1] = _GREY
        _glyph(img, "CFP"[i], plot_bottom + 6, x0 + bar // 2 - 6, 4)
    # the axis and the target, dashed
    img[plot_bottom : plot_bottom + 2, left - 4 : right] = _BLACK
    img[plot_top:plot_bottom, left - 4 : left - 2] = _BLACK
    y_target = y_of(1.0)
    for x in range(left - 4, right, 12):
        img[y_target - 1 : y_target + 1, x : min(x + 7, right)] = _BLACK
    return img


__all__ = ["COLORS", "SIZE", "nutrient_picture"]
