"""The microscope's data bar: found on synthetic SEM images (a separate band or text overlaid on
the image, at the bottom or the top, 4-10 % of the rows), never on images without one, and
left out by ``measure`` / ``espin measure`` unless rows are given or detection is off."""

from __future__ import annotations

import tomllib

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import espin.geometry.rve
from espin.core.errors import ConfigError
from espin.imaging.databar import DataBar, detect_data_bar
from espin.imaging.measurement import measure
from espin.imaging.synthetic import render_sem

D = 0.45


@pytest.fixture(scope="module")
def mat():
    return espin.geometry.rve.generate("plla", rve__size_ratio=70, rve__layers=3, rve__seed=4,
                                       rve__max_deviation_deg=20.0).mat


@pytest.mark.parametrize("kind", ["band", "overlaid"])
@pytest.mark.parametrize("side", ["bottom", "top"])
@pytest.mark.parametrize("fraction", [0.04, 0.07, 0.10])
def test_synthetic_data_bar_found_within_two_rows(mat, kind, side, fraction):
    image = render_sem(mat, side_um=64 * D, layers=2, seed=1, data_bar=kind, data_bar_side=side,
                       data_bar_fraction=fraction)
    rows, bar = detect_data_bar(image.image)
    assert bar is not None
    assert (bar.side, bar.kind) == (side, "separate band" if kind == "band" else "overlaid text")
    assert np.abs(np.subtract(bar.rows, image.data_bar_rows)).max() <= 2
    n_rows = image.image.shape[0]
    assert rows == ((0, bar.rows[0]) if side == "bottom" else (bar.rows[1], n_rows))


@pytest.mark.parametrize("seed", [1, 2, 3, 5])
@pytest.mark.parametrize("px_per_diameter", [5, 8, 12])
def test_no_data_bar_found_without_one(mat, seed, px_per_diameter):
    image = render_sem(mat, side_um=48 * D, um_per_px=D / px_per_diameter, layers=2, seed=seed)
    assert detect_data_bar(image.image) == ((0, image.image.shape[0]), None)


def test_data_bar_description():
    bar = DataBar(side="bottom", kind="overlaid text", rows=(880, 960))
    assert bar.describe() == "bottom rows 880-960 (overlaid text)"


def test_render_sem_data_bar_options(mat):
    with pytest.raises(ConfigError, match="data_bar must be"):
        render_sem(mat, side_um=20 * D, data_bar="stripe")
    with pytest.raises(ConfigError, match="data_bar_side"):
        render_sem(mat, side_um=20 * D, data_bar="band", data_bar_side="left")
    with pytest.raises(ConfigError, match="data_bar_fraction"):
        render_sem(mat, side_um=20 * D, data_bar="band", data_bar_fraction=0.5)
    assert render_sem(mat, side_um=20 * D).data_bar_rows is None


@pytest.fixture(scope="module")
def with_bar(mat):
    return render_sem(mat, side_um=40 * D, layers=2, seed=4, data_bar="overlaid",
                      data_bar_fraction=0.07)


@pytest.mark.slow
def test_measure_leaves_out_the_data_bar_found(with_bar):
    start = with_bar.data_bar_rows[0]
    found = measure(with_bar.image, um_per_px=with_bar.um_per_px)
    assert found.data_bar is not None and abs(found.rows[1] - start) <= 2
    assert found.rows == (0, found.data_bar.rows[0])
    assert found.summary()["image"]["data_bar"] == found.data_bar.describe()
    assert ("data bar", f"{found.data_bar.describe()}, left out (found)") in found.table_rows()
    given = measure(with_bar.image, um_per_px=with_bar.um_per_px, crop_rows=(0, start - 10))
    assert given.data_bar is None and given.rows == (0, start - 10)
    off = measure(with_bar.image, um_per_px=with_bar.um_per_px, detect_data_bar=False)
    assert off.data_bar is None and off.rows == (0, with_bar.image.shape[0])
    assert off.summary()["image"]["data_bar"] is None
    with pytest.raises(ConfigError, match="detect_data_bar"):
        measure(with_bar.image, um_per_px=with_bar.um_per_px, detect_data_bar="no")


@pytest.mark.slow
def test_cli_and_python_agree_on_the_data_bar(with_bar, tmp_path, measure_app):
    from PIL import Image

    path = tmp_path / "bar.png"
    Image.fromarray(np.round(with_bar.image * 255).astype(np.uint8)).save(path)
    run = CliRunner().invoke(measure_app, ["measure", str(path), "--um-per-px", str(with_bar.um_per_px),
                                   "-o", str(tmp_path / "res"), "--no-figures"])
    assert run.exit_code == 0, run.output
    python = measure(path, um_per_px=with_bar.um_per_px)
    assert "data bar" in run.output and python.data_bar is not None
    summary = tomllib.loads((tmp_path / "res" / "measurement.toml").read_text())
    assert summary["image"]["data_bar"] == python.data_bar.describe()
    assert summary["image"]["rows_analysed"] == list(python.rows)
    cli_fibers = pd.read_csv(tmp_path / "res" / "fibers.csv")
    np.testing.assert_allclose(cli_fibers["diameter_um"], python.fibers["diameter_um"], rtol=1e-5)
    off = CliRunner().invoke(measure_app, ["measure", str(path), "--um-per-px", str(with_bar.um_per_px),
                                   "-o", str(tmp_path / "off"), "--no-figures",
                                   "--no-detect-data-bar", "-q"])
    assert off.exit_code == 0, off.output
    summary = tomllib.loads((tmp_path / "off" / "measurement.toml").read_text())
    assert "data_bar" not in summary["image"]
    assert summary["image"]["rows_analysed"] == [0, with_bar.image.shape[0]]
