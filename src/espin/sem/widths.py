"""Local fiber widths from grey-level profiles across the traced centre lines.

At sample points every ``max(1, w / 4)`` px along each traced fiber, the flattened image is
read (bilinear) along the normal, from -1.5 w to +1.5 w in quarter pixels. On each side the
edge is where the profile first falls below half-way between the fiber's peak (the maximum
within w / 4 of the centre line) and that side's background (the profile's minimum on that
side): the full width at half maximum, sub-pixel by linear interpolation. A blurred step
edge crosses half-way exactly at the edge, so the width does not depend on the blur, the
threshold, or how dim a deeper fiber is. Samples closer than w to a junction (another fiber
changes the profile) or w / 2 to a fiber end, and profiles with no edge on a side or less
than 10 % contrast, are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

__all__ = ["WidthSamples", "local_widths"]

_MIN_CONTRAST = 0.1  # peak minus background, in units of the flattened image (0-1)
_PROFILE_STEP = 0.25  # px


@dataclass(frozen=True, eq=False)
class WidthSamples:
    """Local widths measured across traced fibers.

    Attributes
    ----------
    fiber : (n,) int64
        Index of the traced fiber (into the list of paths) of each sample.
    point : (n, 2) float64 [px]
        Sample position (row, col) on the centre line.
    normal : (n, 2) float64
        Unit normal (row, col) along which the width was measured.
    width_px : (n,) float64 [px]
        Full width at half maximum.
    """

    fiber: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    width_px: np.ndarray


def local_widths(flat: np.ndarray, paths: list[np.ndarray], junctions: np.ndarray,
                 width_px: float) -> WidthSamples:
    """Full widths at half maximum across the traced fibers (see the module notes).

    Parameters
    ----------
    flat : (rows, cols) float64
        Background-flattened image, fibers bright.
    paths : list of (n_i, 2) float64 [px]
        Fiber centre lines (row, col), one point per pixel of arc length.
    junctions : (n_junctions, 2) float64 [px]
        Junction centres.
    width_px : float [px]
        Typical fiber width w (sets the sampling, the profile length and the exclusions).

    Returns
    -------
    WidthSamples
        Only the valid samples.
    """
    w = float(width_px)
    fiber, point, normal = _sample_points(paths, junctions, w)
    half = int(np.ceil(1.5 * w / _PROFILE_STEP))
    t = np.arange(-half, half + 1) * _PROFILE_STEP
    coords = point[:, None, :] + t[None, :, None] * normal[:, None, :]
    profile = ndimage.map_coordinates(flat, coords.reshape(-1, 2).T, order=1,
                                      mode="nearest").reshape(len(point), len(t))
    core = np.abs(t) <= w / 2.0
    peak = profile[:, core].max(axis=1)
    right, ok_r = _edge(profile[:, half:], peak)
    left, ok_l = _edge(profile[:, half::-1], peak)
    width = (right + left) * _PROFILE_STEP
    ok = ok_r & ok_l & (width > 0)
    return WidthSamples(fiber=fiber[ok], point=point[ok], normal=normal[ok], width_px=width[ok])


def _edge(side: np.ndarray, peak: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel index (in profile steps) where each row first falls below its half level."""
    background = side.min(axis=1)
    level = (peak + background) / 2.0
    below = side < level[:, None]
    first = np.argmax(below, axis=1)
    ok = below.any(axis=1) & (first > 0) & (peak - background >= _MIN_CONTRAST)
    rows = np.arange(len(side))
    i = np.maximum(first, 1)
    hi, lo = side[rows, i - 1], side[rows, i]
    frac = np.where(hi > lo, (hi - level) / np.where(hi > lo, hi - lo, 1.0), 0.0)
    return (i - 1) + frac, ok


def _sample_points(paths: list[np.ndarray], junctions: np.ndarray,
                   w: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample points along all paths, their unit normals, away from junctions and ends."""
    if not paths:
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
    step = max(1, int(round(w / 4.0)))
    margin = int(np.ceil(w / 2.0))
    fiber = np.concatenate([np.full(len(p), i) for i, p in enumerate(paths)])
    point = np.concatenate(paths)
    tangent = np.concatenate([np.gradient(p, axis=0) if len(p) > 1 else np.zeros_like(p)
                              for p in paths])
    index = np.concatenate([np.arange(len(p)) for p in paths])
    length = np.concatenate([np.full(len(p), len(p)) for p in paths])
    keep = (index % step == 0) & (index >= margin) & (index < length - margin)
    if len(junctions):
        distance, _ = cKDTree(junctions).query(point)
        keep &= distance >= w
    norm = np.hypot(*tangent.T)
    keep &= norm > 0
    tangent = tangent[keep] / norm[keep, None]
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    return fiber[keep].astype(np.int64), point[keep], normal
