"""Which way round an SEM image is: bright fibers on a dark background (the secondary-electron
image of a mat) or dark fibers on a bright one (an inverted or a back-lit image).

Fibers are long thin ridges; the pores between them are irregular. At a few scales (Gaussian
sigma :data:`SCALES_PX`) the Hessian of the normalised image marks the strongest tenth of the
pixels; of those, the line-like ones (``1 - |small| / |large| > LINE_ANISOTROPY`` of the two
curvatures) are bright lines (the large curvature negative) or dark lines (positive).
:func:`line_ratio` is the geometric mean over the scales of bright-line over dark-line pixels:
1.4 to 4.6 on espin's synthetic image and the two real images of ``../shared/data/sem``, 0.2 to
0.7 on the same images inverted. Below
:data:`DARK_FIBERS_BELOW` an image is taken for dark fibers on a bright background.
"""

from __future__ import annotations

import numpy as np

from espin.core.errors import SEMError

__all__ = ["SCALES_PX", "LINE_ANISOTROPY", "DARK_FIBERS_BELOW", "line_ratio", "bright_fibers"]

SCALES_PX = (3.0, 5.0, 8.0)
"""Gaussian scales of the Hessian [px]."""
LINE_ANISOTROPY = 0.7
"""A pixel is line-like when 1 - |smaller curvature| / |larger curvature| exceeds this."""
DARK_FIBERS_BELOW = 0.8
"""A :func:`line_ratio` below this means dark fibers on a bright background."""


def line_ratio(grey: np.ndarray) -> float:
    """Bright-line over dark-line pixels among the strongest curvatures (module docstring):
    above 1 for bright fibers, below 1 for dark ones."""
    from skimage.feature import hessian_matrix, hessian_matrix_eigvals

    g = np.asarray(grey, dtype=float)
    g = (g - g.mean()) / (g.std() + 1e-12)
    ratios = []
    for sigma in SCALES_PX:
        large, small = hessian_matrix_eigvals(
            hessian_matrix(g, sigma=sigma, order="rc", use_gaussian_derivatives=False)
        )
        strength = np.maximum(np.abs(large), np.abs(small))
        line = (strength > np.percentile(strength, 90)) & (
            1.0 - np.minimum(np.abs(large), np.abs(small)) / (strength + 1e-12) > LINE_ANISOTROPY
        )
        bright = int(np.count_nonzero(line & (np.abs(small) > np.abs(large)) & (small < 0.0)))
        dark = int(np.count_nonzero(line & (np.abs(large) > np.abs(small)) & (large > 0.0)))
        ratios.append(max(bright, 1) / max(dark, 1))
    return float(np.exp(np.mean(np.log(ratios))))


def bright_fibers(grey: np.ndarray, invert: bool | None, source: str) -> tuple[np.ndarray, str]:
    """The image with bright fibers, and what was found and done, for ``measurement.toml``.

    Parameters
    ----------
    grey
        The analysed grey levels.
    invert
        None: check, and refuse dark fibers; True: invert (and refuse an image whose fibers are
        bright already); False: use as it is, unchecked.
    source
        The image, for messages.

    Raises
    ------
    SEMError
        When the fibers look dark on a bright background and ``invert`` is None, or bright and
        ``invert`` is True.
    """
    if invert is False:
        return grey, "bright fibers on a dark background (as given, --no-invert: not checked)"
    ratio = line_ratio(grey)
    if invert:
        if ratio > 1.0 / DARK_FIBERS_BELOW:
            raise SEMError(
                f"{source}: --invert was given, but the fibers look bright on a dark background "
                f"already (bright-to-dark line ratio {ratio:.2f}; dark fibers give below "
                f"{DARK_FIBERS_BELOW:g}); leave out --invert"
            )
        return (
            grey.max() + grey.min() - grey,
            f"dark fibers on a bright background, inverted as asked (--invert; line ratio {ratio:.2f})",
        )
    if ratio < DARK_FIBERS_BELOW:
        raise SEMError(
            f"{source}: the fibers look dark on a bright background (bright-to-dark line ratio "
            f"{ratio:.2f}, below {DARK_FIBERS_BELOW:g}; an SEM image of fibers gives 1.4 or more): measured "
            "as it is, the gaps would be taken for fibers. Give --invert to measure it inverted, or "
            "--no-invert if the fibers are bright"
        )
    return grey, f"bright fibers on a dark background (checked: line ratio {ratio:.2f})"
