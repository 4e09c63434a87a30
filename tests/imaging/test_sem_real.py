"""espin measure on the two real SEM images in ../shared/data/sem (skipped if absent).

Checks: no crash, the PLGA scale from its tick marks, plausible numbers, and stability under a
crop and a re-scaling of the image. Tolerances are a little wider than the spreads measured
(docs/sem.md): a crop or re-scale changes which fiber pieces are traced.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import SHARED, needs_shared
from espin.imaging.image import read_image
from espin.imaging.measurement import measure

SEM = SHARED / "data" / "sem"
PLGA = SEM / "PLGA-1500_1.tif"
NANO = SEM / "nanofiber_fiji_diameterj.tif"

pytestmark = needs_shared(PLGA, NANO)


@pytest.fixture(scope="module")
def plga():
    return measure(PLGA, scale_bar_um=30.0, scale_bar_rows="880:960")


@pytest.fixture(scope="module")
def nano():
    return measure(NANO, um_per_px=0.05)  # no scale bar: an assumed pixel size


def _rescaled(path: Path, rows: slice, factor: float) -> np.ndarray:
    from skimage.transform import rescale

    return rescale(read_image(path)[rows], factor, anti_aliasing=True)


@pytest.mark.slow
def test_plga_scale_from_its_tick_marks(plga):
    bar = plga.scale_bar
    assert bar.kind == "ticks" and bar.n_ticks == 11
    # 11 ticks 3.0 um apart, about 45.4 px apart in the image: about 0.0661 um/px.
    assert plga.um_per_px == pytest.approx(30.0 / (10 * 45.4), rel=0.01)
    assert plga.rows == (0, 880)  # the data bar is left out
    assert plga.field_of_view_um == pytest.approx((1280 * plga.um_per_px, 880 * plga.um_per_px))


def test_plga_plausible_numbers(plga):
    assert len(plga.fibers) >= 24
    assert 1.5 < np.median(plga.widths_um) < 4.5  # top fibers about 45 px = 3 um wide
    assert 1.0 <= plga.fibers["tortuosity"].mean() < 1.2
    assert 0.0 <= plga.coherency < 0.5
    # Several thick top fibers run from the top edge to the bottom one (6 traced so, none
    # back to the edge it came from; docs/sem.md).
    assert plga.n_crossing >= 4 and plga.u_turn_fraction == 0.0
    assert 0.9 < plga.straightness <= 1.0


def test_nano_plausible_numbers(nano):
    assert len(nano.fibers) >= 36
    assert 5 < np.median(nano.widths_um) / nano.um_per_px < 20  # fibers about 10 px wide
    assert 1.0 <= nano.fibers["tortuosity"].mean() < 1.2


@pytest.mark.slow
@pytest.mark.parametrize("which", ["plga", "nano"])
def test_stable_under_crop_and_rescale(which, plga, nano):
    base = plga if which == "plga" else nano
    path = PLGA if which == "plga" else NANO
    rows = slice(0, 880) if which == "plga" else slice(None)
    grey = read_image(path)[rows]
    cropped = measure(grey[16:-16, 32:-32], um_per_px=base.um_per_px)
    smaller = measure(_rescaled(path, rows, 0.8), um_per_px=base.um_per_px / 0.8)
    for other in (cropped, smaller):
        assert np.median(other.widths_um) == pytest.approx(np.median(base.widths_um), rel=0.2)
        assert other.fibers["tortuosity"].mean() == pytest.approx(
            base.fibers["tortuosity"].mean(), abs=0.015)
        turn = (other.dominant_direction_deg - base.dominant_direction_deg + 90) % 180 - 90
        assert abs(turn) < 5.0
        assert len(other.fibers) > 0.5 * len(base.fibers)


@pytest.mark.slow
def test_data_bar_found_without_crop_options(plga, nano):
    # PLGA-1500_1: Hitachi text and tick marks overlaid on the bottom rows (ticks in rows
    # 897-914, 17 px high): the bar starts at row 880, and the measurement is the one of the
    # rows the scale bar's rows leave (0:880).
    found = measure(PLGA, um_per_px=plga.um_per_px)
    assert found.data_bar is not None
    assert found.data_bar.describe() == "bottom rows 880-960 (overlaid text)"
    assert found.rows == plga.rows == (0, 880)
    pd.testing.assert_frame_equal(found.fibers, plga.fibers)
    assert (found.dominant_direction_deg, found.coherency) == (plga.dominant_direction_deg,
                                                               plga.coherency)
    assert (found.n_crossing, found.straightness) == (plga.n_crossing, plga.straightness)
    assert nano.data_bar is None and nano.rows == (0, 512)  # no data bar: nothing cropped


@pytest.mark.parametrize("path", [PLGA, NANO], ids=["plga", "nano"])
def test_real_images_are_bright_fibers_and_their_inversions_are_not(path):
    from espin.imaging.polarity import DARK_FIBERS_BELOW, line_ratio

    grey = read_image(path)[:-80]
    assert line_ratio(grey) > 1.0 / DARK_FIBERS_BELOW
    assert line_ratio(grey.max() - grey) < DARK_FIBERS_BELOW


def test_inverted_real_image_is_refused_then_measured_as_before_with_invert(nano):
    from espin.core.errors import SEMError

    grey = read_image(NANO)
    with pytest.raises(SEMError, match="dark on a bright background.*--invert"):
        measure(grey.max() - grey, um_per_px=0.05)
    again = measure(grey.max() + grey.min() - grey, um_per_px=0.05, invert=True)
    assert again.fits.diameter.mean_um == pytest.approx(nano.fits.diameter.mean_um, rel=1e-9)
    assert "inverted as asked" in again.summary()["image"]["polarity"]
    assert "checked" in nano.summary()["image"]["polarity"]
