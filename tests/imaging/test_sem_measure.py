"""espin measure: outputs, the fibers.csv contract, option and input errors, the CLI."""

from __future__ import annotations

import tomllib

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import espin.geometry.rve
from espin.core.errors import ConfigError, SEMError
from espin.geometry.fibers_csv import FIBER_COLUMNS, read_fibers_csv
from espin.imaging.distributions import fit_distributions
from espin.imaging.measurement import measure
from espin.imaging.synthetic import render_sem

D = 0.45


@pytest.fixture(scope="module")
def synthetic():
    mat = espin.geometry.rve.generate("plla", rve__size_ratio=60, rve__layers=3, rve__seed=4,
                             rve__max_deviation_deg=20.0).mat
    return render_sem(mat, side_um=40 * D, layers=2, seed=4)


@pytest.fixture(scope="module")
def result(synthetic):
    return measure(synthetic.image, um_per_px=synthetic.um_per_px)


def test_measurement_columns_and_ranges(result, synthetic):
    f = result.fibers
    assert list(f.columns) == list(FIBER_COLUMNS)
    assert len(f) >= 10
    assert f["fiber"].dtype == np.int64
    assert (f["tortuosity"] >= 1).all()
    assert ((f["orientation_deg"] >= 0) & (f["orientation_deg"] < 180)).all()
    np.testing.assert_allclose(f["tortuosity"], f["contour_length_um"] / f["end_to_end_um"])
    assert (f["end_to_end_um"] >= result.min_chord_um).all()
    side = synthetic.image.shape[0] * synthetic.um_per_px
    assert result.field_of_view_um == pytest.approx((side, side))
    assert len(result.paths_px) == len(f)
    assert result.width_samples.fiber.max() < len(f)


def test_write_outputs_and_read_back(result, tmp_path):
    files = result.write(tmp_path / "out")
    assert {p.name for p in files.values()} == {"fibers.csv", "measurement.toml", "histograms.png",
                                                "overlay.png", "orientation_map.png"}
    table = read_fibers_csv(files["fibers"])
    assert list(table.columns) == list(FIBER_COLUMNS)
    np.testing.assert_allclose(table["tortuosity"], result.fibers["tortuosity"], rtol=1e-5)
    meta = tomllib.loads(files["summary"].read_text())
    assert meta["um_per_px"] == pytest.approx(result.um_per_px)
    assert meta["field_of_view_um"] == pytest.approx(list(result.field_of_view_um))
    assert meta["counts"]["fibers"] == len(result.fibers)
    assert meta["diameter"]["mean_um"] == pytest.approx(result.fits.diameter_mean_um)
    assert meta["pores"]["porosity"] == pytest.approx(1.0 - result.mask.mean())
    assert meta["tortuosity"]["loc"] == 1.0
    assert meta["orientation"]["selection"] == "AIC"
    assert files["overlay"].stat().st_size > 10_000


def test_read_hand_made_csv(tmp_path):
    path = tmp_path / "hand.csv"
    path.write_text("diameter_um, tortuosity, note\n0.4, 1.1, a\n0.5, , b\n")
    table = read_fibers_csv(path)
    assert list(table.columns) == ["fiber", "diameter_um", "tortuosity"]
    assert table["diameter_um"].tolist() == [0.4, 0.5]
    assert np.isnan(table["tortuosity"][1])


@pytest.mark.parametrize("text, match", [
    ("length\n1\n", "at least one of the columns"),
    ("tortuosity\n1.2\n0.9\n", "column tortuosity, data row 2: 0.9 is not >= 1"),
    ("orientation_deg\n180\n", "orientation_deg.*in \\[0, 180\\)"),
    ("diameter_um\nthick\n", "diameter_um, data row 1: 'thick' is not a number"),
])
def test_bad_csv_names_column_and_row(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(SEMError, match=match):
        read_fibers_csv(path)


@pytest.mark.parametrize("kwargs, match", [
    ({}, "no scale: give um_per_px"),
    ({"um_per_px": -1.0}, "um_per_px must be a number in \\[1e-6, 1000\\]"),
    ({"um_per_px": 1e300}, "um_per_px must be a number in"),
    ({"scale_bar_um": 1e300, "scale_bar_rows": "0:10"}, "scale_bar_um must be a number in"),
    ({"scale_bar_um": 30.0}, "scale_bar_um needs scale_bar_rows"),
    ({"scale_bar_rows": "0:10"}, "scale_bar_rows needs scale_bar_um"),
    ({"um_per_px": 0.1, "scale_bar_um": 3.0, "scale_bar_rows": "0:10"}, "not both"),
    ({"um_per_px": 0.1, "max_bend_deg": 120.0}, "max_bend_deg must be in \\(0, 90\\]"),
    ({"um_per_px": 0.1, "min_length_diameters": 0.5}, "min_length_diameters"),
    ({"um_per_px": 0.1, "width_px": 1.0}, "width_px must be a number >= 3"),
    ({"um_per_px": 0.1, "crop_rows": "0:10", "crop_bottom_px": 5}, "crop_rows or crop_bottom_px"),
    ({"um_per_px": 0.1, "crop_rows": "50:20"}, "crop_rows = 50:20"),
])
def test_bad_options_name_the_parameter(synthetic, kwargs, match):
    with pytest.raises(ConfigError, match=match):
        measure(synthetic.image, **kwargs)


def test_options_are_checked_before_reading_the_file(tmp_path):
    with pytest.raises(ConfigError, match="no scale"):
        measure(tmp_path / "missing.tif")


def test_blank_and_noise_images_have_no_fibers():
    with pytest.raises(SEMError, match="no contrast"):
        measure(np.full((64, 64), 0.3), um_per_px=0.1)
    noise = np.random.default_rng(0).uniform(size=(128, 128))
    with pytest.raises(SEMError, match="no fibers"):
        measure(noise, um_per_px=0.1)


def test_scale_bar_sets_the_scale_and_crops_the_data_bar(synthetic):
    image = np.vstack([synthetic.image, np.zeros((40, synthetic.image.shape[1]))])
    image[-20:-14, 100:300] = 1.0  # a 200 px bar in a black data bar
    m = measure(image, scale_bar_um=10.0, scale_bar_rows=(-40, image.shape[0]))
    assert m.um_per_px == pytest.approx(10.0 / 200)
    assert m.rows == (0, synthetic.image.shape[0])  # the data bar is not analysed
    with pytest.raises(SEMError, match="no scale bar found"):
        measure(image, scale_bar_um=10.0, scale_bar_rows=(0, 40))


def test_orientation_model_selection_by_aic():
    rng = np.random.default_rng(3)
    evenly = (np.arange(200) + 0.5) * 0.9  # evenly spread axes: no preferred direction
    uniform = fit_distributions(np.ones(200), evenly, np.ones(200))
    assert uniform.orientation_model == "uniform"
    aligned_deg = np.degrees(rng.vonmises(2 * np.radians(40.0), 8.0, 200) / 2) % 180
    aligned = fit_distributions(np.ones(200), aligned_deg, np.ones(200))
    assert aligned.orientation_model == "von_mises"
    assert aligned.orientation_mean_deg == pytest.approx(40.0, abs=3.0)
    assert aligned.orientation_kappa == pytest.approx(8.0, rel=0.25)
    grid = np.linspace(0, 180, 2001)
    assert np.trapezoid(aligned.orientation_pdf(grid), grid) == pytest.approx(1.0, rel=1e-3)


@pytest.mark.slow
def test_cli_measure(synthetic, tmp_path, measure_app):
    from PIL import Image

    path = tmp_path / "mat.png"
    Image.fromarray(np.round(synthetic.image * 255).astype(np.uint8)).save(path)
    out = tmp_path / "res"
    run = CliRunner().invoke(measure_app, ["measure", str(path), "--um-per-px",
                                   str(synthetic.um_per_px), "-o", str(out)])
    assert run.exit_code == 0, run.output
    assert "diameter" in run.output and "tortuosity" in run.output
    assert len(pd.read_csv(out / "fibers.csv")) > 5
    bad = CliRunner().invoke(measure_app, ["measure", str(path)])
    assert bad.exit_code == 2 and "no scale" in bad.output
