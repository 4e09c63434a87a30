"""Local widths (FWHM) and per-fiber diameters (blurred flat profile fit) on exact profiles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage
from scipy.special import erf

from espin.imaging.segment import segment_fibers
from espin.imaging.widths import fiber_diameters, local_widths

WIDTH = 8.0  # px, true fiber width


def _band(sigma: float, width: float = WIDTH, noise: float = 0.0, angle_deg: float = 0.0):
    """A straight bright fiber of ``width`` px across a 96 x 96 image, blurred by ``sigma``."""
    n = 96
    rows, cols = np.mgrid[0:n, 0:n].astype(float)
    a = np.radians(angle_deg)
    # signed distance from the line through the centre at angle a (row, col frame)
    d = (rows - n / 2) * np.cos(a) - (cols - n / 2) * np.sin(a)
    image = 0.1 + 0.8 * np.clip(width / 2 + 0.5 - np.abs(d), 0.0, 1.0)  # anti-aliased edge
    image = ndimage.gaussian_filter(image, sigma) if sigma > 0 else image
    image += np.random.default_rng(0).normal(0.0, noise, image.shape)
    s = np.arange(8.0, n - 8.0)
    path = np.column_stack([n / 2 + (s - n / 2) * np.sin(a), n / 2 + (s - n / 2) * np.cos(a)])
    return image, [path]


def _fwhm_of_blurred_flat(width: float, sigma: float) -> float:
    x = np.linspace(0.0, width + 6 * sigma, 200001)
    scale = np.sqrt(2) * sigma
    profile = erf((x + width / 2) / scale) - erf((x - width / 2) / scale)
    return 2 * x[np.argmax(profile < profile[0] / 2)]


@pytest.mark.parametrize("sigma", [1.0, 2.0, 3.0])
def test_fiber_diameter_undoes_the_blur_that_widens_the_fwhm(sigma):
    image, paths = _band(sigma)
    samples = local_widths(image, paths, np.zeros((0, 2)), WIDTH)
    fwhm = np.median(samples.width_px)
    # The half-maximum width of a blurred flat profile is exact while the blur leaves the
    # peak alone, and too wide once it dims it (8 px, sigma 3: 9.35 px).
    assert fwhm == pytest.approx(_fwhm_of_blurred_flat(WIDTH, sigma), abs=0.1)
    diameter = fiber_diameters(image, samples, 1, WIDTH)
    assert diameter[0] == pytest.approx(WIDTH, abs=0.1)


def test_fiber_diameter_with_noise_and_at_an_angle():
    """Through the segmentation's denoised, flattened image, as espin measure does."""
    image, paths = _band(3.0, noise=0.05, angle_deg=30.0)
    flat = segment_fibers(image, WIDTH).flat
    samples = local_widths(flat, paths, np.zeros((0, 2)), WIDTH)
    assert np.median(samples.width_px) > WIDTH + 1.5
    assert abs(np.median(samples.centre_px)) < 0.2  # the path runs along the fiber's middle
    assert fiber_diameters(flat, samples, 1, WIDTH)[0] == pytest.approx(WIDTH, abs=0.3)


def test_fiber_without_enough_samples_keeps_its_median_width():
    image, paths = _band(3.0)
    samples = local_widths(image, paths, np.zeros((0, 2)), WIDTH)
    two = samples.subset(np.arange(2))
    out = fiber_diameters(image, two, 2, WIDTH)
    assert out[0] == pytest.approx(np.median(two.width_px))
    assert np.isnan(out[1])  # no samples at all


def test_centre_offset_follows_a_path_beside_the_middle():
    """A path 2 px off the fiber's middle: the half-maximum midpoint is 2 px along the normal
    back towards it, and the profiles re-centred there give the same diameter."""
    image, (path,) = _band(2.0)
    shifted = path + np.array([2.0, 0.0])  # 2 px down the rows, across the fiber at 0 deg
    samples = local_widths(image, [shifted], np.zeros((0, 2)), WIDTH)
    assert np.allclose(samples.point + samples.centre_px[:, None] * samples.normal,
                       samples.point - [2.0, 0.0], atol=0.05)
    assert fiber_diameters(image, samples, 1, WIDTH)[0] == pytest.approx(WIDTH, abs=0.1)


@pytest.mark.parametrize("spacing", [1.25, 1.5, 2.0])
def test_a_neighbouring_fiber_does_not_narrow_the_fit(spacing):
    """A parallel fiber ``spacing`` widths beside the first (blur 2 px, 9 px fibers): each
    profile is fitted only out to its minimum between the two, so the fit reads no narrower
    than the half-maximum width (fitted on the whole profile it read 6.6 px at 1.25 widths,
    where the half-maximum width is 8.05 px: the blurred gap no longer reaches the
    background), and within 0.5 px of the truth once the gap is half a fiber width."""
    width = 9.0
    image, paths = _band(2.0, width=width)
    neighbour, _ = _band(2.0, width=width)
    image = np.maximum(image, np.roll(neighbour, int(round(spacing * width)), axis=0))
    samples = local_widths(image, paths, np.zeros((0, 2)), width)
    diameter = fiber_diameters(image, samples, 1, width)[0]
    assert diameter > np.median(samples.width_px) - 0.2
    if spacing >= 1.5:
        assert diameter == pytest.approx(width, abs=0.5)
