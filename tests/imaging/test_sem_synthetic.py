"""Accuracy of espin measure on SEM-like images rendered from espin's own mats.

Tolerances (from the acceptance criteria): mean diameter within 10 % or 1 px, whichever is
larger; dominant direction within 5 deg on aligned mats; mean tortuosity within 0.02 on wavy
(max deviation 20 deg) and aligned mats. Tightened where the method does better: per-fiber
diameters within 7 % on wavy mats, tortuosity on wavy mats within 0.01 pooled and 0.015 image
by image, aligned mats within 0.015, and straight fibers read a median tortuosity below 1.0125
(the floor of the tracer). The measured errors are listed in docs/sem.md.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
import pytest

import espin.geometry.rve
from espin.core.errors import ConfigError
from espin.imaging.measurement import measure
from espin.imaging.synthetic import render_sem

D = 0.45  # um, plla diameter
SEEDS = (1, 2, 3)


def _mat(seed: int, **overrides):
    return espin.geometry.rve.generate("plla", rve__size_ratio=100, rve__layers=4, rve__seed=seed,
                              **overrides).mat


@pytest.fixture(scope="module")
def wavy():
    """Wavy uniform mats (max deviation 20 deg), 3 layers drawn, 60 D window, 8 px per D."""
    out = []
    for seed in SEEDS:
        image = render_sem(_mat(seed, rve__max_deviation_deg=20.0), side_um=60 * D, seed=seed)
        out.append((image, measure(image.image, um_per_px=image.um_per_px)))
    return out


def test_rendered_image_and_ground_truth():
    mat = _mat(1, rve__max_deviation_deg=20.0)
    image = render_sem(mat, side_um=60 * D, layers=2, seed=0)
    assert image.image.shape == (480, 480)
    assert image.image.min() >= 0 and image.image.max() <= 1
    assert image.um_per_px == pytest.approx(D / 8)
    top_two = {mat.n_layers - 1, mat.n_layers - 2}
    assert set(mat.fiber_layer[image.visible.fiber]) <= top_two
    assert np.all(image.visible.tortuosity >= 1.0)
    assert np.all(image.visible.chord_length >= 3 * D)
    np.testing.assert_array_equal(image.diameter_um, mat.fiber_diameter[image.fiber])
    # Depth dimming: with no noise, the brightest pixels belong to the top layer (~1.15 at its
    # edges) and a one-layer render has no grey level above the top fibers'.
    clean = render_sem(mat, side_um=60 * D, layers=1, noise_sd=0, illumination=0)
    assert 0.95 < clean.image.max() <= 1.0


def test_label_names_the_fiber_seen_at_each_pixel():
    """Without noise, blur or shading, a pixel is as bright as the depth of its labelled fiber
    says, and its centre lies within that fiber's radius of its centre line."""
    mat = _mat(2, rve__max_deviation_deg=20.0)
    image = render_sem(mat, side_um=30 * D, layers=2, noise_sd=0, blur_px=0, depth_blur_px=0,
                       illumination=0, background=0.0, depth_dimming=0.5)
    label = image.label
    depth = image.depth(label.ravel()).reshape(label.shape)
    assert set(np.unique(depth)) == {-1, 0, 1}
    assert np.all(image.image[ndimage.binary_erosion(depth == -1)] == 0.0)  # the background
    inner = ndimage.binary_erosion(depth == 0, iterations=2) & (image.image > 0)
    assert np.all(image.image[inner] >= 0.9)  # the top layer: 1 (edges 1.15, notches anti-aliased)
    lower = ndimage.binary_erosion(depth == 1, iterations=2)
    assert np.all(image.image[lower] <= 0.5 * 1.15 + 1e-9)  # one layer down: half as bright
    # the label's fiber covers the pixel centre
    rows, cols = np.nonzero(label >= 0)
    pick = np.random.default_rng(0).choice(len(rows), 300, replace=False)
    for r, c in zip(rows[pick], cols[pick]):
        f = label[r, c]
        xy = image.origin + np.array([(c + 0.5) * image.um_per_px, image.side - (r + 0.5) * image.um_per_px])
        v = mat.vertices[mat.fiber_offsets[f]:mat.fiber_offsets[f + 1]]
        a, b = v[:-1], v[1:]
        t = np.clip(np.einsum("ij,ij->i", xy - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
        distance = np.min(np.hypot(*(a + t[:, None] * (b - a) - xy).T))
        assert distance <= mat.fiber_diameter[f] / 2 + 0.5 * image.um_per_px


def test_render_options_are_checked():
    mat = _mat(1)
    with pytest.raises(ConfigError, match="layers"):
        render_sem(mat, layers=99)
    with pytest.raises(ConfigError, match="depth_dimming"):
        render_sem(mat, depth_dimming=1.0)


@pytest.mark.slow
def test_mean_diameter_within_10_percent_or_1_px(wavy):
    for image, m in wavy:
        true = float(np.mean(image.diameter_um))
        tolerance = max(0.10 * true, image.um_per_px)
        assert abs(np.median(m.widths_um) - true) <= tolerance
        # The primary diameter, the visible (top) fibers' mean: the criterion. Fewer fibers
        # than all (23-25 of 46-49), so two fused pairs of top fibers read as one fiber
        # (0.85 and 0.93 um on mat 1) raise it by 4 %: +10.6 % = 0.85 px on mat 1.
        assert abs(m.fits.diameter_mean_um - true) <= tolerance
        # Per-fiber diameters of all fibers undo the blur of deeper fibers: tighter than the
        # criterion.
        assert abs(m.diameter_all.mean_um - true) <= 0.07 * true


def test_mean_tortuosity_within_0_02_on_wavy_mats(wavy):
    measured = np.concatenate([m.fibers["tortuosity"].to_numpy() for _, m in wavy])
    true = np.concatenate([image.visible.tortuosity for image, _ in wavy])
    assert true.mean() > 1.02  # wavy enough for the test to mean something
    assert abs(measured.mean() - true.mean()) <= 0.01
    for image, m in wavy:  # and image by image
        assert abs(m.fibers["tortuosity"].mean() - image.visible.tortuosity.mean()) <= 0.015


@pytest.mark.slow
@pytest.mark.parametrize("kappa, mean_deg", [(10.0, 30.0), (20.0, 150.0)])
def test_direction_within_5_deg_and_tortuosity_within_0_02_on_aligned_mats(kappa, mean_deg):
    orientation = {"von_mises": {"mean_deg": mean_deg, "kappa": kappa}}
    for seed in SEEDS:
        mat = _mat(seed, rve__max_deviation_deg=10.0, rve__orientation=orientation)
        image = render_sem(mat, side_um=80 * D, um_per_px=D / 7, seed=seed)
        m = measure(image.image, um_per_px=image.um_per_px)
        v = image.visible
        true = np.degrees(np.angle(np.sum(v.contour_length * np.exp(2j * v.orientation))) / 2)
        error = (m.dominant_direction_deg - true + 90.0) % 180.0 - 90.0
        assert abs(error) <= 5.0
        assert m.coherency > 0.3  # aligned: clearly anisotropic
        assert m.fits.orientation_model == "von_mises"
        true_diameter = float(np.mean(image.diameter_um))
        tolerance = max(0.10 * true_diameter, image.um_per_px)  # 1 px = 14 % at 7 px per D
        assert abs(m.fits.diameter_mean_um - true_diameter) <= tolerance
        # Nearly straight fibers: crossing artefacts (U-turns at the border, jogs through
        # shallow crossings) are cut at sharp turns, so they do not inflate the tortuosity.
        assert abs(m.fibers["tortuosity"].mean() - v.tortuosity.mean()) <= 0.015


@pytest.mark.slow
def test_straight_fibers_read_a_small_tortuosity_floor():
    """Straight fibers (true tortuosity 1) crossing at all angles: the skeleton staircase,
    the end caps and the joins through crossings add little length."""
    orientation = {"von_mises": {"mean_deg": 45.0, "kappa": 3.0}}
    mat = _mat(1, rve__max_deviation_deg=0.0, rve__orientation=orientation)
    image = render_sem(mat, side_um=70 * D, seed=1)
    assert np.allclose(image.visible.tortuosity, 1.0)
    t = measure(image.image, um_per_px=image.um_per_px).fibers["tortuosity"]
    assert np.median(t) < 1.0125
    assert t.mean() < 1.02


def test_uniform_mat_is_nearly_isotropic(wavy):
    for _, m in wavy:
        assert m.coherency < 0.35
