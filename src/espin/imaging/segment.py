"""Segmentation of SEM images: which pixels are fibers.

Secondary-electron images show fibers bright on a darker background, with noise, brightness
that drifts across the field (detector position, charging) and dimmer, blurred fibers deeper
in the mat. The steps, all scaled by the typical fiber width w (estimated here, or given):

1. Contrast is stretched between the 0.5 and 99.5 percentiles (robust to a few hot pixels).
2. Noise: Gaussian smoothing, sigma = max(1, w / 8) px (keeps the edges of a w-wide fiber).
3. Uneven brightness: the background is a grey opening with a square of side 3 w (no fiber
   fits in it, so the opening is the level between and below the fibers), smoothed by a
   Gaussian of sigma w; it is subtracted (a white top-hat) and the result rescaled so its
   99.5th percentile is 1.
4. Threshold: Otsu's on the flattened image; holes smaller than w^2 / 2 px (noise inside a
   fiber) are filled, objects smaller than 2 w^2 px (specks) removed.

The width w is estimated by a first pass (Otsu on the image flattened at a large scale):
w = median of 2 d - 1 over its skeleton pixels, d the Euclidean distance to the background
(a w-px-wide strip has d = (w + 1) / 2 on its centre line).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from espin.core.errors import SEMError

__all__ = ["Segmentation", "segment_fibers", "MIN_WIDTH_PX"]

MIN_WIDTH_PX = 3.0
"""Narrowest fiber measurable [px]: below this the width is a pixel-rounding artefact."""

_MIN_CONTRAST = 1e-3  # 99.5 minus 0.5 percentile of a usable image, grey units in [0, 1]
_MIN_FIBER_FRACTION = 0.01  # fiber pixels needed after thresholding


@dataclass(frozen=True, eq=False)
class Segmentation:
    """Fiber pixels of an image and the images behind them.

    Attributes
    ----------
    flat : (rows, cols) float64
        Denoised, background-subtracted image, fibers bright, 99.5th percentile = 1.
    mask : (rows, cols) bool
        Fiber pixels.
    width_px : float [px]
        Typical fiber width w used to scale the filters.
    threshold : float
        Otsu threshold applied to ``flat``.
    """

    flat: np.ndarray
    mask: np.ndarray
    width_px: float
    threshold: float


def segment_fibers(grey: np.ndarray, width_px: float | None = None) -> Segmentation:
    """Fiber pixels of an SEM image (see the module notes for the steps).

    Parameters
    ----------
    grey : (rows, cols) float64
        Grey levels.
    width_px : float [px], optional
        Typical fiber width; estimated from the image when not given.

    Returns
    -------
    Segmentation

    Raises
    ------
    SEMError
        The image has no contrast or no fiber-like structure.
    """
    lo, hi = np.percentile(grey, [0.5, 99.5])
    if hi - lo < _MIN_CONTRAST:
        raise SEMError("image has no contrast (blank or constant): no fibers to measure")
    image = np.clip((grey - lo) / (hi - lo), 0.0, 1.0)
    if width_px is None:
        width_px = _estimate_width(image)
    w = float(width_px)
    smooth = ndimage.gaussian_filter(image, max(1.0, w / 8.0))
    flat = _flatten(smooth, w)
    threshold = _otsu(flat)
    mask = _clean(flat > threshold, w)
    if mask.mean() < _MIN_FIBER_FRACTION:
        raise SEMError("no fibers found: after thresholding, fewer than 1 % of the pixels are fiber-like structures")
    return Segmentation(flat=flat, mask=mask, width_px=w, threshold=threshold)


def _flatten(smooth: np.ndarray, w: float) -> np.ndarray:
    """White top-hat with a square of side 3 w, background smoothed; 99.5th percentile = 1."""
    side = 2 * int(round(1.5 * w)) + 1
    background = ndimage.grey_opening(smooth, size=(side, side), mode="reflect")
    background = ndimage.gaussian_filter(background, w)
    flat = np.clip(smooth - background, 0.0, None)
    top = np.percentile(flat, 99.5)
    if top <= 0:
        raise SEMError("no fibers found: nothing stands out of the background")
    return np.clip(flat / top, 0.0, 1.0)


def _otsu(values: np.ndarray) -> float:
    from skimage.filters import threshold_otsu

    return float(threshold_otsu(values))


def _clean(mask: np.ndarray, w: float) -> np.ndarray:
    from skimage.morphology import remove_small_holes, remove_small_objects

    mask = remove_small_holes(mask, max_size=max(int(w * w / 2), 1))
    return remove_small_objects(mask, max_size=max(int(2 * w * w), 1))


def _estimate_width(image: np.ndarray) -> float:
    """Typical fiber width [px]: median 2 d - 1 on the skeleton of a first segmentation."""
    from skimage.morphology import skeletonize

    scale = max(image.shape) / 8.0
    smooth = ndimage.gaussian_filter(image, 1.0)
    flat = smooth - ndimage.gaussian_filter(smooth, scale)
    mask = flat > _otsu(flat)
    mask = ndimage.binary_opening(mask, iterations=1)
    skeleton = skeletonize(mask)
    if skeleton.sum() == 0:
        raise SEMError("no fibers found: no elongated bright structures in the image")
    d = ndimage.distance_transform_edt(mask)[skeleton]
    width = float(np.median(2.0 * d - 1.0))
    if width <= MIN_WIDTH_PX:
        raise SEMError(
            f"no fibers found: the bright structures are {width:.1f} px wide, not "
            f"more than the {MIN_WIDTH_PX:g} px a width can be measured on "
            "(noise?); give width_px if the fibers really are this thin"
        )
    return width
