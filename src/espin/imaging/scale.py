"""The image scale: given in um per pixel, or measured on the microscope's scale bar.

A scale bar is found in the image rows the user names (where the data bar prints it). It is
either a solid bar (a component at least ``MIN_BAR_PX`` long and four times longer than high)
whose length is its extent in pixels, or a row of three or more identical, evenly spaced tick
marks (as Hitachi microscopes print) whose length is the distance between the centres of the
first and last tick. The bar must stand out from the rows around it, brighter or darker: a
pixel belongs to it if it lies beyond the midpoint between the median and the extreme grey
level of those rows. A mark must lie wholly inside the rows (a fiber cut by the row range is
no bar) and a solid bar must fill at least 80 % of its bounding box. The longest candidate wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from espin.core.errors import SEMError

__all__ = ["MIN_BAR_PX", "ScaleBar", "detect_scale_bar"]

MIN_BAR_PX = 20
"""Shortest scale bar (or tick span) accepted [px]: shorter marks are letters, not bars."""

_MIN_CONTRAST = 0.2  # extreme minus median grey level of the rows, in [0, 1] units
_TICK_GAP_TOLERANCE = 0.05  # relative spread of tick spacings


@dataclass(frozen=True)
class ScaleBar:
    """A scale bar found in an image.

    Attributes
    ----------
    length_px : float [px]
        Length of the bar (solid) or span between the first and last tick centres.
    row_range : tuple[int, int]
        First and one-past-last image row of the bar.
    column_range : tuple[float, float] [px]
        Columns of its two ends (bar edges, or first and last tick centres).
    kind : str
        ``"bar"`` or ``"ticks"``.
    n_ticks : int
        Number of tick marks (0 for a solid bar).
    """

    length_px: float
    row_range: tuple[int, int]
    column_range: tuple[float, float]
    kind: str
    n_ticks: int


def detect_scale_bar(grey: np.ndarray, rows: slice) -> ScaleBar:
    """Find the scale bar in the given rows of an image.

    Parameters
    ----------
    grey : (rows, cols) float64
        Grey levels in [0, 1] (the whole image).
    rows : slice
        The rows that hold the bar (checked against the image beforehand).

    Returns
    -------
    ScaleBar
        The longest solid bar or tick series found.

    Raises
    ------
    SEMError
        No bar or tick series stands out in these rows.
    """
    region = grey[rows]
    found: list[ScaleBar] = []
    for values in (region, 1.0 - region):  # a bright bar, then a dark one
        median, top = float(np.median(values)), float(values.max())
        if top - median < _MIN_CONTRAST:
            continue
        labels, _ = ndimage.label(values > (median + top) / 2.0, structure=np.ones((3, 3)))
        boxes = [
            box for box in ndimage.find_objects(labels) if box[0].start > 0 and box[0].stop < len(region)
        ]  # wholly inside the rows
        fill = ndimage.sum_labels(labels > 0, labels, np.arange(1, labels.max() + 1))
        found += _solid_bars(boxes, fill, labels, rows.start) + _tick_series(boxes, rows.start)
    if not found:
        raise SEMError(
            f"scale_bar_rows {rows.start}:{rows.stop}: no scale bar found (expected a solid "
            f"bar at least {MIN_BAR_PX} px long, or three or more evenly spaced tick marks, "
            "brighter or darker than the rows around them and wholly inside them); check the "
            "rows, or give "
            "um_per_px instead"
        )
    return max(found, key=lambda bar: bar.length_px)


def _extent(box: tuple[slice, slice]) -> tuple[int, int]:
    return box[0].stop - box[0].start, box[1].stop - box[1].start


def _solid_bars(boxes: list, area: np.ndarray, labels: np.ndarray, row0: int) -> list[ScaleBar]:
    """Long, thin, nearly rectangular marks."""
    bars = []
    for box in boxes:
        height, width = _extent(box)
        label = int(labels[box].max())
        if width >= MIN_BAR_PX and width >= 4 * height and area[label - 1] >= 0.8 * height * width:
            bars.append(
                ScaleBar(
                    float(width),
                    (row0 + box[0].start, row0 + box[0].stop),
                    (float(box[1].start), float(box[1].stop)),
                    "bar",
                    0,
                )
            )
    return bars


def _tick_series(boxes: list, row0: int) -> list[ScaleBar]:
    """Groups of >= 3 identical tall, thin marks (same rows, same width), evenly spaced."""
    ticks = np.array(
        [(b[0].start, b[0].stop, b[1].start, b[1].stop) for b in boxes if _extent(b)[0] >= 2 * _extent(b)[1]],
        dtype=float,
    ).reshape(-1, 4)
    series = []
    used = np.zeros(len(ticks), dtype=bool)
    for i in range(len(ticks)):
        if used[i]:
            continue
        width = ticks[:, 3] - ticks[:, 2]
        same = (np.abs(ticks[:, 0] - ticks[i, 0]) <= 1) & (np.abs(ticks[:, 1] - ticks[i, 1]) <= 1)
        same &= np.abs(width - width[i]) <= 1
        used |= same
        centre = np.sort((ticks[same, 2] + ticks[same, 3] - 1) / 2.0)
        if len(centre) < 3:
            continue
        gaps = np.diff(centre)
        span = centre[-1] - centre[0]
        if np.ptp(gaps) <= _TICK_GAP_TOLERANCE * gaps.mean() + 1.0 and span >= MIN_BAR_PX:
            rows = (row0 + int(ticks[i, 0]), row0 + int(ticks[i, 1]))
            ends = (float(centre[0]), float(centre[-1]))
            series.append(ScaleBar(float(span), rows, ends, "ticks", len(centre)))
    return series
