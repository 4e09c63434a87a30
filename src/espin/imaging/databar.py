"""Finding the microscope's data bar (text, scale bar) at the bottom or top of an SEM image.

Two kinds are found, in this order, bottom before top:

1. **A separate band**: rows, starting at the image edge, in which at least
   :data:`UNIFORM_FRACTION` of the pixels hold one and the same grey level (8-bit quantized):
   the uniform black or grey background of the band, around its text. A fiber image never
   holds half a row at one exact level. The band is at least :data:`MIN_BAND_FRACTION` and at
   most :data:`MAX_BAR_FRACTION` of the rows; the analysed rows stop at its first row.
2. **Text overlaid on the image** (Hitachi): glyphs, the connected components (8-connected)
   of nearly saturated pixels (within :data:`SATURATION_MARGIN` of the image's maximum)
   that are 5 px to :func:`max_glyph_px` high, at most 1.5 times as wide as high plus 4 px,
   and stand out from the pixels around them (median at least :data:`GLYPH_CONTRAST` below),
   aligned on lines: at least :data:`MIN_GLYPHS` of them share their top and bottom
   rows (within 1 px), all inside the :data:`MAX_BAR_FRACTION` of the rows next to the edge.
   The bar starts a margin before the line nearest the image, the height of that line's
   glyphs (PLGA-1500_1.tif: tick marks in rows 897-914, 17 px high, so the bar starts at row
   880).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = [
    "DataBar",
    "detect_data_bar",
    "max_glyph_px",
    "UNIFORM_FRACTION",
    "MIN_BAND_FRACTION",
    "MAX_BAR_FRACTION",
    "SATURATION_MARGIN",
    "MIN_GLYPHS",
    "GLYPH_CONTRAST",
]

UNIFORM_FRACTION = 0.5
"""A row belongs to a separate band when at least this fraction of its pixels share one grey
level."""
MIN_BAND_FRACTION = 0.01
"""A separate band covers at least this fraction of the rows (and 3 rows): one or two uniform
rows at the edge are a scan artefact, not a data bar."""
MAX_BAR_FRACTION = 0.25
"""A data bar covers at most this fraction of the rows next to the edge."""
SATURATION_MARGIN = 0.02
"""Overlaid glyphs are pixels within this much of the image's largest grey level (grey levels
in [0, 1])."""
MIN_GLYPHS = 4
"""Glyphs sharing their top and bottom rows that make a line of text (or of tick marks)."""
MIN_GLYPH_PX = 5
"""Smallest glyph height [px] (smaller bright specks are noise)."""
GLYPH_CONTRAST = 0.3
"""A glyph stands out: the median grey level of the pixels around it is at least this much
below the saturated level (noise in a bright fiber saturates specks in bright
surroundings)."""


@dataclass(frozen=True)
class DataBar:
    """A data bar found in an image.

    Attributes
    ----------
    side : str
        ``"bottom"`` or ``"top"``.
    kind : str
        ``"separate band"`` or ``"overlaid text"``.
    rows : tuple[int, int]
        Image rows (start, stop) the bar covers, Python slice.
    """

    side: str
    kind: str
    rows: tuple[int, int]

    def describe(self) -> str:
        """E.g. ``"bottom rows 880-960 (overlaid text)"``."""
        return f"{self.side} rows {self.rows[0]}-{self.rows[1]} ({self.kind})"


def max_glyph_px(n_rows: int) -> int:
    """Largest glyph height [px] of overlaid text: 40 px, or 5 % of the rows on large images."""
    return max(40, int(0.05 * n_rows))


def detect_data_bar(grey: np.ndarray) -> tuple[tuple[int, int], DataBar | None]:
    """The rows to analyse, without the microscope's data bar, and the bar found.

    Parameters
    ----------
    grey : (rows, cols) float64
        Grey levels in [0, 1].

    Returns
    -------
    rows : tuple[int, int]
        Rows (start, stop) to analyse; all rows when no bar is found.
    DataBar or None
        The bar found, or None.
    """
    n_rows = grey.shape[0]
    for side in ("bottom", "top"):
        bar = _separate_band(grey, side)
        if bar is not None:
            return _rows_left(bar, n_rows), bar
    for side in ("bottom", "top"):
        bar = _overlaid_text(grey, side)
        if bar is not None:
            return _rows_left(bar, n_rows), bar
    return (0, n_rows), None


def _rows_left(bar: DataBar, n_rows: int) -> tuple[int, int]:
    """The rows on the image's side of a bar."""
    return (0, bar.rows[0]) if bar.side == "bottom" else (bar.rows[1], n_rows)


def _separate_band(grey: np.ndarray, side: str) -> DataBar | None:
    """The run of rows from the edge on ``side`` in which at least :data:`UNIFORM_FRACTION` of
    the pixels share one grey level, if it is a plausible band."""
    n_rows, n_cols = grey.shape
    levels = np.clip(np.round(grey * 255.0), 0, 255).astype(np.int64)
    counts = np.bincount((levels + 256 * np.arange(n_rows)[:, None]).ravel(), minlength=256 * n_rows).reshape(
        n_rows, 256
    )
    uniform = counts.max(axis=1) >= UNIFORM_FRACTION * n_cols
    from_edge = uniform[::-1] if side == "bottom" else uniform
    height = int(np.argmin(from_edge)) if not from_edge.all() else n_rows
    if height < max(3, MIN_BAND_FRACTION * n_rows) or height > MAX_BAR_FRACTION * n_rows:
        return None
    rows = (n_rows - height, n_rows) if side == "bottom" else (0, height)
    return DataBar(side=side, kind="separate band", rows=rows)


def _overlaid_text(grey: np.ndarray, side: str) -> DataBar | None:
    """Lines of nearly saturated glyphs in the rows next to the edge on ``side``, and the bar
    they make (a margin of one glyph height towards the image)."""
    n_rows = grey.shape[0]
    zone = int(MAX_BAR_FRACTION * n_rows)
    rows = slice(n_rows - zone, n_rows) if side == "bottom" else slice(0, zone)
    offset = rows.start
    top, bottom = _aligned_glyphs(grey[rows], n_rows)
    if len(top) == 0:
        return None
    top, bottom = top + offset, bottom + offset
    if side == "bottom":
        first = int(np.argmin(top))
        start = max(int(top[first] - (bottom[first] - top[first])), 0)
        return DataBar(side=side, kind="overlaid text", rows=(start, n_rows))
    last = int(np.argmax(bottom))
    stop = min(int(bottom[last] + (bottom[last] - top[last])), n_rows)
    return DataBar(side=side, kind="overlaid text", rows=(0, stop))


def _aligned_glyphs(grey: np.ndarray, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Top and bottom rows (stop, exclusive) of the glyphs in ``grey`` that lie on a line:
    at least :data:`MIN_GLYPHS` glyphs share both rows within 1 px.

    Parameters
    ----------
    grey : (rows, cols) float64
        The rows searched, grey levels in [0, 1].
    n_rows : int
        Rows of the whole image (sets the largest glyph height).
    """
    level = grey.max()
    bright = grey >= level - SATURATION_MARGIN
    labels, n = ndimage.label(bright, np.ones((3, 3), dtype=bool))
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    boxes = ndimage.find_objects(labels)
    top = np.array([box[0].start for box in boxes])
    bottom = np.array([box[0].stop for box in boxes])
    width = np.array([box[1].stop - box[1].start for box in boxes])
    height = bottom - top
    ring = np.where(bright, 0, ndimage.grey_dilation(labels, size=(3, 3)))
    surround = np.asarray(ndimage.median(grey, ring, np.arange(1, n + 1)))
    glyph = (
        (height >= MIN_GLYPH_PX)
        & (height <= max_glyph_px(n_rows))
        & (width <= 1.5 * height + 4)
        & (surround <= level - GLYPH_CONTRAST)
    )
    top, bottom = top[glyph], bottom[glyph]
    same = (np.abs(top[:, None] - top[None, :]) <= 1) & (np.abs(bottom[:, None] - bottom[None, :]) <= 1)
    aligned = same.sum(axis=1) >= MIN_GLYPHS
    return top[aligned], bottom[aligned]
