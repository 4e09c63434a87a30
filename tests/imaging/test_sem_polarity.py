"""Image polarity: a synthetic SEM image (bright fibers) is measured as before, its inversion is
refused with advice (--invert), measured inverted with --invert (the same fibers), and --invert
on an image of bright fibers is refused; measurement.toml says which."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from espin.cli import app
from espin.core.errors import SEMError
from espin.datasets import SEM_UM_PER_PX, sem_image
from espin.imaging.image import read_image
from espin.imaging.measurement import measure
from espin.imaging.polarity import DARK_FIBERS_BELOW, line_ratio


@pytest.fixture(scope="module")
def grey(tmp_path_factory):
    return read_image(sem_image(tmp_path_factory.mktemp("sem") / "mat.tif"))


@pytest.fixture(scope="module")
def normal(grey):
    return measure(grey, um_per_px=SEM_UM_PER_PX)


def test_the_synthetic_image_is_bright_fibers_and_its_inversion_dark(grey):
    assert line_ratio(grey) > 1.0 / DARK_FIBERS_BELOW
    assert line_ratio(grey.max() - grey) < DARK_FIBERS_BELOW


def test_an_inverted_image_is_refused_with_advice(grey):
    with pytest.raises(SEMError, match=r"look dark on a bright background .*Give --invert"):
        measure(grey.max() - grey, um_per_px=SEM_UM_PER_PX)


@pytest.mark.slow
def test_invert_measures_the_inverted_image_as_the_original(grey, normal):
    inverted = measure(grey.max() + grey.min() - grey, um_per_px=SEM_UM_PER_PX, invert=True)
    assert len(inverted.fibers) == len(normal.fibers)
    assert inverted.fits.diameter.mean_um == pytest.approx(normal.fits.diameter.mean_um, rel=1e-9)
    assert "inverted as asked" in inverted.summary()["image"]["polarity"]
    assert "checked" in normal.summary()["image"]["polarity"]


@pytest.mark.slow
def test_invert_on_bright_fibers_is_refused_and_no_invert_skips_the_check(grey, normal):
    with pytest.raises(SEMError, match="bright on a dark background already.*leave out --invert"):
        measure(grey, um_per_px=SEM_UM_PER_PX, invert=True)
    unchecked = measure(grey, um_per_px=SEM_UM_PER_PX, invert=False)
    assert "not checked" in unchecked.summary()["image"]["polarity"]
    assert unchecked.fits.diameter.mean_um == normal.fits.diameter.mean_um


@pytest.mark.slow
def test_the_command_line_refuses_an_inverted_image_and_records_the_polarity(grey, tmp_path):
    import tifffile

    inverted = np.round(255.0 * (1.0 - grey / grey.max())).astype(np.uint8)
    tifffile.imwrite(tmp_path / "dark.tif", inverted)
    refused = CliRunner().invoke(app, ["measure", str(tmp_path / "dark.tif"), "--um-per-px", "0.05",
                                       "-o", str(tmp_path / "refused")])
    assert refused.exit_code == 3 and "--invert" in refused.output and "dark.tif" in refused.output
    assert not (tmp_path / "refused").exists()
    done = CliRunner().invoke(app, ["measure", str(tmp_path / "dark.tif"), "--um-per-px", "0.05", "--invert",
                                    "--no-figures", "-o", str(tmp_path / "done")])
    assert done.exit_code == 0, done.output
    assert 'polarity = "dark fibers on a bright background, inverted as asked' in \
        (tmp_path / "done" / "measurement.toml").read_text()
