"""Local fiber widths from grey-level profiles across the traced centre lines.

At sample points every ``max(1, w / 4)`` px along each traced fiber, the flattened image is
read (bilinear) along the normal, from -1.5 w to +1.5 w in quarter pixels. On each side the
edge is where the profile first falls below half-way between the fiber's peak (the maximum
within w / 2 of the centre line) and that side's background (the profile's minimum on that
side): the full width at half maximum, sub-pixel by linear interpolation. A blurred step
edge crosses half-way exactly at the edge, so the width depends neither on the threshold
nor on how dim a deeper fiber is, nor on blur as long as the blur leaves the fiber's peak
alone (sigma below about w / 4); blur that dims the peak widens it, which
:func:`fiber_diameters` undoes for each fiber. Samples closer than w to a junction (another
fiber changes the profile) or w / 2 to a fiber end, and profiles with no edge on a side or
less than 10 % contrast, are skipped.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize, special
from scipy.spatial import cKDTree

__all__ = ["WidthSamples", "fiber_diameters", "local_widths", "sample_counts"]

_MIN_CONTRAST = 0.1  # peak minus background, in units of the flattened image (0-1)
_PROFILE_STEP = 0.25  # px
_MIN_FIT_SAMPLES = 3  # a fiber's diameter is fitted to the median of at least this many profiles
_MAX_AMPLITUDE = 1.25  # the fitted blur may dim a fiber's peak by at most 20 %
_FIT_RANGE = (0.8, 1.05)  # a fitted width is kept within these times the FWHM (the docs)


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
    centre_px : (n,) float64 [px]
        Midpoint of the two half-maximum edges, along ``normal`` from ``point``.
    """

    fiber: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    width_px: np.ndarray
    centre_px: np.ndarray

    def subset(self, keep: np.ndarray, fiber: np.ndarray | None = None) -> WidthSamples:
        """The samples ``keep`` (mask or indices); their fiber numbers replaced by ``fiber``."""
        return WidthSamples(
            fiber=self.fiber[keep] if fiber is None else fiber,
            point=self.point[keep],
            normal=self.normal[keep],
            width_px=self.width_px[keep],
            centre_px=self.centre_px[keep],
        )


def local_widths(flat: np.ndarray, paths: list[np.ndarray], junctions: np.ndarray, width_px: float) -> WidthSamples:
    """Full widths at half maximum across the traced fibers (see the module notes).

    Parameters
    ----------
    flat : (rows, cols) float64
        Background-flattened image, fibers bright.
    paths : list of (n_i, 2) float64 [px]
        Fiber centre lines (row, col), one point per pixel of arc length.
    junctions : (n_junctions, 2) float64 [px]
        Junction centres, and any other points where fibers overlap (no sample within w).
    width_px : float [px]
        Typical fiber width w (sets the sampling, the profile length and the exclusions).

    Returns
    -------
    WidthSamples
        Only the valid samples.
    """
    w = float(width_px)
    fiber, point, normal = _sample_points(paths, junctions, w)
    t, profile = _profiles(flat, point, normal, 1.5 * w)
    half = len(t) // 2
    peak = profile[:, np.abs(t) <= w / 2.0].max(axis=1)
    right, ok_r = _edge(profile[:, half:], peak)
    left, ok_l = _edge(profile[:, half::-1], peak)
    width = (right + left) * _PROFILE_STEP
    ok = ok_r & ok_l & (width > 0)
    return WidthSamples(
        fiber=fiber[ok],
        point=point[ok],
        normal=normal[ok],
        width_px=width[ok],
        centre_px=0.5 * (right - left)[ok] * _PROFILE_STEP,
    )


def sample_counts(paths: list[np.ndarray], junctions: np.ndarray, width_px: float) -> np.ndarray:
    """Number of points of each fiber where :func:`local_widths` looks for a width (valid or
    not: every ``max(1, w / 4)`` px, away from junctions and ends).

    Parameters
    ----------
    paths : list of (n_i, 2) float64 [px]
        Fiber centre lines (row, col), one point per pixel of arc length.
    junctions : (n_junctions, 2) float64 [px]
        As given to :func:`local_widths`.
    width_px : float [px]
        Typical fiber width w.

    Returns
    -------
    (len(paths),) int64
    """
    fiber, _, _ = _sample_points(paths, junctions, float(width_px))
    return np.bincount(fiber, minlength=len(paths)).astype(np.int64)


def fiber_diameters(flat: np.ndarray, samples: WidthSamples, n_fibers: int, width_px: float) -> np.ndarray:
    """Diameter of each fiber: a blurred flat profile fitted to its median profile.

    The profiles of a fiber's samples, centred on their half-maximum midpoints and scaled on
    each side from that side's background (0) to the peak (1), are reduced to their median; a
    flat profile of width W and amplitude a, blurred by a Gaussian of sd sigma, plus an offset,
    is fitted to it (each profile only out to its minimum on either side: beyond lies the
    next fiber) by least squares (W, sigma, a, centre, offset free; a <= 1.25, i.e. blur
    dims the peak by 20 % at most). Its W is the fiber's diameter: the full width at half
    maximum of a fiber that blur dims (a deeper, out-of-focus fiber) overestimates it, by
    0.2 px for an 8 px fiber blurred by 2 px and 1.4 px for one blurred by 3 px. A fiber
    keeps the median of its local widths (its FWHM) when it has fewer than three samples, when
    the fit fails, or when W falls outside [0.8, 1.05] times that FWHM: blur that dims the
    peak by 20 % narrows the FWHM by the factor 0.838 at most, so such a fit read something
    else (a neighbouring fiber inside the profile, a shoulder).

    Parameters
    ----------
    flat : (rows, cols) float64
        Background-flattened image, fibers bright.
    samples : WidthSamples
        Valid local width samples (:func:`local_widths`).
    n_fibers : int
        Number of traced fibers (``samples.fiber`` indexes them).
    width_px : float [px]
        Typical fiber width w (the profiles reach 1.5 w to each side).

    Returns
    -------
    (n_fibers,) float64 [px]
        Diameter of each fiber; NaN for a fiber without samples.
    """
    w = float(width_px)
    out = np.full(n_fibers, np.nan)
    if len(samples.fiber) == 0:
        return out
    centre = samples.point + samples.centre_px[:, None] * samples.normal
    t, profile = _profiles(flat, centre, samples.normal, 1.5 * w)
    half = len(t) // 2
    rows, index = np.arange(len(profile)), np.arange(len(t))
    peak = profile[:, np.abs(t) <= w / 2.0].max(axis=1)
    # Each side's background is its minimum; beyond it lies the next fiber (or noise), which
    # is left out of the median.
    first = half - np.argmin(profile[:, half::-1], axis=1)
    last = half + np.argmin(profile[:, half:], axis=1)
    background = np.where(t < 0, profile[rows, first][:, None], profile[rows, last][:, None])
    unit = (profile - background) / np.maximum(peak[:, None] - background, 1e-12)
    unit = np.where((index >= first[:, None]) & (index <= last[:, None]), unit, np.nan)
    for f in np.unique(samples.fiber):
        mine = samples.fiber == f
        out[f] = np.median(samples.width_px[mine])
        if mine.sum() >= _MIN_FIT_SAMPLES:
            with warnings.catch_warnings():  # offsets no profile reaches are NaN: not fitted
                warnings.simplefilter("ignore", RuntimeWarning)
                median = np.nanmedian(unit[mine], axis=0)
            out[f] = _blurred_flat_width(t, median, out[f], w)
    return out


def _blurred_flat_width(t: np.ndarray, y: np.ndarray, fwhm: float, w: float) -> float:
    """Width W [px] of the blurred flat profile that fits y(t); ``fwhm`` if the fit fails."""
    root2 = np.sqrt(2.0)

    def model(p: np.ndarray) -> np.ndarray:
        width, sigma, amplitude, centre, offset = p
        s = t - centre
        return offset + 0.5 * amplitude * (
            special.erf((s + width / 2) / (root2 * sigma)) - special.erf((s - width / 2) / (root2 * sigma))
        )

    lower = [0.25, 0.05, 0.5, -w / 2, -0.1]
    upper = [3.0 * w, 2.0 * w, _MAX_AMPLITUDE, w / 2, 0.5]
    start = np.clip([fwhm, 1.0, 1.0, 0.0, 0.0], lower, upper)
    known = np.isfinite(y)
    fit = optimize.least_squares(lambda p: (model(p) - y)[known], start, bounds=(lower, upper))
    width = float(fit.x[0])
    plausible = _FIT_RANGE[0] * fwhm <= width <= _FIT_RANGE[1] * fwhm
    return width if fit.success and np.isfinite(width) and plausible else fwhm


def _profiles(flat: np.ndarray, point: np.ndarray, normal: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets t [px] (-reach..reach, quarter pixels) and the image read at point + t normal."""
    half = int(np.ceil(reach / _PROFILE_STEP))
    t = np.arange(-half, half + 1) * _PROFILE_STEP
    coords = point[:, None, :] + t[None, :, None] * normal[:, None, :]
    profile = ndimage.map_coordinates(flat, coords.reshape(-1, 2).T, order=1, mode="nearest").reshape(
        len(point), len(t)
    )
    return t, profile


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


def _sample_points(
    paths: list[np.ndarray], junctions: np.ndarray, w: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample points along all paths, their unit normals, away from junctions and ends."""
    if not paths:
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
    step = max(1, int(round(w / 4.0)))
    margin = int(np.ceil(w / 2.0))
    fiber = np.concatenate([np.full(len(p), i) for i, p in enumerate(paths)])
    point = np.concatenate(paths)
    tangent = np.concatenate([np.gradient(p, axis=0) if len(p) > 1 else np.zeros_like(p) for p in paths])
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
