"""Porosity, pore sizes and intersections of drawn fiber masks with known answers; the local
orientation field; the scale-bar length."""

from __future__ import annotations

import math

import numpy as np
import pytest

from espin.imaging.figures import scale_bar_um
from espin.imaging.orientation import local_orientation
from espin.imaging.pores import mat_structure, skeleton_length_px
from espin.imaging.trace import trace_fibers

UM = 0.1  # um per px


def _grid(rows: int, cols: int, centres_r, centres_c, width: int) -> np.ndarray:
    """A mask of horizontal bands at rows ``centres_r`` and vertical ones at ``centres_c``."""
    mask = np.zeros((rows, cols), bool)
    half = width // 2
    for r in centres_r:
        mask[r - half:r - half + width] = True
    for c in centres_c:
        mask[:, c - half:c - half + width] = True
    return mask


def test_grid_of_bands_gives_square_pores_of_known_side():
    # bands 11 px wide every 60 px: interior pores are 49 x 49 px squares
    mask = _grid(245, 305, [65, 125, 185], [65, 125, 185, 245], 11)
    s = mat_structure(mask, np.zeros((0, 2)), UM)
    assert s.porosity == pytest.approx(1.0 - mask.sum() / mask.size)
    assert len(s.pore_diameter_um) == 2 * 3  # between 3 x 4 bands
    np.testing.assert_allclose(s.pore_diameter_um, math.sqrt(4 * 49**2 / math.pi) * UM)
    np.testing.assert_allclose(s.pore_inscribed_um, 49 * UM)  # odd side: exact
    assert s.n_pores_on_border == 4 * 5 - 6
    assert s.area_um2 == pytest.approx(245 * 305 * UM**2)


def test_disc_hole_is_one_pore_of_its_diameter():
    rows, cols = np.mgrid[0:201, 0:201]
    radius = 40.0
    mask = np.hypot(rows - 100, cols - 100) > radius
    s = mat_structure(mask, np.zeros((0, 2)), UM)
    assert len(s.pore_diameter_um) == 1 and s.n_pores_on_border == 0
    assert s.pore_diameter_um[0] == pytest.approx(2 * radius * UM, rel=0.01)
    assert s.pore_inscribed_um[0] == pytest.approx(2 * radius * UM, abs=1.5 * UM)
    assert s.porosity == pytest.approx(math.pi * radius**2 / mask.size, rel=0.01)
    assert s.pore_diameter_median_um == pytest.approx(s.pore_diameter_um[0])


def test_diagonal_fiber_line_separates_two_pores():
    mask = np.eye(64, dtype=bool)  # an 8-connected one-pixel line
    s = mat_structure(mask, np.zeros((0, 2)), UM)
    assert s.n_pores_on_border == 2 and len(s.pore_diameter_um) == 0
    assert np.isnan(s.pore_diameter_median_um)


@pytest.mark.parametrize("n_rows, n_cols", [(1, 1), (2, 3), (3, 4)])
def test_crossings_of_straight_bands_are_counted(n_rows, n_cols):
    rows, cols, width = 260, 320, 10
    centres_r = np.linspace(0, rows, n_rows + 2)[1:-1].astype(int)
    centres_c = np.linspace(0, cols, n_cols + 2)[1:-1].astype(int)
    mask = _grid(rows, cols, centres_r, centres_c, width)
    traced = trace_fibers(mask, float(width))
    s = mat_structure(mask, traced.junctions, UM)
    assert s.n_junctions == n_rows * n_cols
    assert s.intersection_density_per_um2 == pytest.approx(n_rows * n_cols / (rows * cols * UM**2))
    length = n_rows * cols + n_cols * rows  # band centre lines
    assert s.fiber_length_um == pytest.approx(length * UM, rel=0.01)
    assert s.intersections_per_um == pytest.approx(n_rows * n_cols / (length * UM), rel=0.01)


def test_skeleton_length_of_a_diagonal_band():
    rows, cols = np.mgrid[0:200, 0:200]
    mask = np.abs(rows - cols) <= 4  # 9 px band along the diagonal, corner to corner
    assert skeleton_length_px(mask) == pytest.approx(199 * math.sqrt(2), rel=0.02)
    assert skeleton_length_px(np.zeros((10, 10), bool)) == 0.0


def test_summary_and_table_rows_carry_units():
    mask = _grid(245, 305, [65, 125, 185], [65, 125, 185, 245], 11)
    s = mat_structure(mask, np.zeros((3, 2)), UM)
    summary = s.summary()
    assert summary["n_pores"] == 6 and summary["n_junctions"] == 3
    assert summary["pore_diameter_median_um"] == pytest.approx(s.pore_diameter_median_um)
    assert summary["intersection_density_per_um2"] == pytest.approx(3 / s.area_um2)
    names = [name for name, _ in s.table_rows()]
    assert names == ["porosity", "pore size", "intersections"]


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, 90.0, 135.0])
def test_local_orientation_of_stripes(angle_deg):
    rows, cols = np.mgrid[0:96, 0:96]
    a = math.radians(angle_deg)
    # stripes along the direction (cos a, sin a) with y up: constant along it
    across = -math.sin(a) * cols + math.cos(a) * (-rows)
    direction, coherency = local_orientation(np.sin(across * 0.6), window_px=4.0)
    centre = direction[32:64, 32:64]
    off = (centre - angle_deg + 90.0) % 180.0 - 90.0
    assert np.abs(off).max() < 1.0
    assert coherency[32:64, 32:64].min() > 0.95
    assert ((direction >= 0) & (direction < 180)).all()


@pytest.mark.parametrize("width_um, expected", [(84.4, 10.0), (25.6, 5.0), (9.9, 1.0),
                                                 (0.5, 0.1), (1000.0, 200.0)])
def test_scale_bar_is_a_round_fifth_of_the_width(width_um, expected):
    assert scale_bar_um(width_um) == pytest.approx(expected)


def test_orientation_map_colours_horizontal_red_and_vertical_cyan(tmp_path):
    from types import SimpleNamespace

    from matplotlib.colors import rgb_to_hsv
    from PIL import Image

    from espin.imaging.figures import save_orientation_map

    image = np.full((200, 200), 0.1)
    image[40:52] = 0.9  # a horizontal band
    image[:, 140:152] = 0.9  # a vertical one
    m = SimpleNamespace(image=image, um_per_px=0.1, typical_width_px=12.0,
                        dominant_direction_deg=45.0, coherency=0.1)
    path = save_orientation_map(m, tmp_path / "map.png")
    rgb = np.asarray(Image.open(path).convert("RGB"), dtype=float)[:1000] / 255.0  # the image part
    hsv = rgb_to_hsv(rgb)
    scale = 1000 / 200  # drawn at 1000 px
    horizontal = hsv[int(46 * scale), int(60 * scale)]
    vertical = hsv[int(120 * scale), int(146 * scale)]
    assert min(horizontal[0], 1 - horizontal[0]) < 0.03 and horizontal[1] > 0.8  # red, saturated
    assert abs(vertical[0] - 0.5) < 0.03 and vertical[1] > 0.8  # cyan
    assert hsv[int(150 * scale), int(60 * scale), 2] < 0.2  # the dark background stays dark
