"""The pixel size from the microscope's TIFF metadata (FEI, Zeiss, ImageJ), never from dpi,
and its place in espin measure's scale (given options win)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
import tifffile

import espin.geometry.rve
from conftest import SHARED, needs_shared
from espin.core.errors import ConfigError, SEMError
from espin.imaging.measurement import measure
from espin.imaging.metadata import MetadataWarning, pixel_size_from_tags, read_pixel_size
from espin.imaging.synthetic import render_sem

PLGA = SHARED / "data" / "sem" / "PLGA-1500_1.tif"
BLANK = np.zeros((32, 32), dtype=np.uint8)


def _fei_text(width_m: float, height_m: float | None = None) -> str:
    """An FEI / Thermo Fisher metadata text as the microscopes write it (INI, CRLF)."""
    height = width_m if height_m is None else height_m
    return ("[User]\r\nDate=12/01/2024\r\nTime=10:11:12 AM\r\n[Beam]\r\nHV=5000\r\n"
            f"[Scan]\r\nInternalScan=1\r\nPixelWidth={width_m!r}\r\nPixelHeight={height!r}\r\n"
            "HorFieldsize=2.56e-05\r\n[Stage]\r\nWorkingDistance=0.0101\r\n")


def _zeiss_bytes(value: str) -> bytes:
    """A Zeiss CZ_SEM text: upper-case parameter names, each followed by "Name = value unit"
    (cp1252, as the microscopes write µ)."""
    text = (f"\r\n0\r\nAP_WD\r\nWD = 8.5 mm\r\nAP_IMAGE_PIXEL_SIZE\r\nImage Pixel Size = {value}"
            "\r\nDP_DETECTOR_TYPE\r\nSignal A = InLens\r\n")
    return text.encode("cp1252")


def _fei_tiff(path: Path, text: str, code: int = 34682, data: np.ndarray = BLANK) -> Path:
    tifffile.imwrite(path, data, extratags=[(code, 2, None, text, True)])
    return path


def _imagej_tiff(path: Path, unit: str | None, pixels_per_unit: float = 20.0) -> Path:
    metadata = {} if unit is None else {"unit": unit}
    tifffile.imwrite(path, BLANK, imagej=True, resolution=(pixels_per_unit, pixels_per_unit),
                     metadata=metadata)
    return path


@pytest.mark.parametrize("code", [34682, 34680])
def test_fei_pixel_width_in_metres(tmp_path, code):
    found = read_pixel_size(_fei_tiff(tmp_path / "fei.tif", _fei_text(4.96e-9), code))
    assert found.um_per_px == pytest.approx(4.96e-3, rel=1e-12)
    assert found.source == f"FEI tag {code} [Scan] PixelWidth"


@pytest.mark.parametrize("value, um", [("12.5 nm", 0.0125), ("0.125 \u00b5m", 0.125)])
def test_zeiss_image_pixel_size_with_its_unit(tmp_path, value, um):
    data = _zeiss_bytes(value)
    path = tmp_path / "zeiss.tif"
    tifffile.imwrite(path, BLANK, extratags=[(34118, 1, len(data), data, True)])
    found = read_pixel_size(path)
    assert found.um_per_px == pytest.approx(um, rel=1e-12)
    assert found.source == "Zeiss tag 34118 ap_image_pixel_size"


@pytest.mark.parametrize("unit, um", [("micron", 0.05), ("um", 0.05), ("\\u00B5m", 0.05),
                                      ("nm", 5e-5), ("mm", 50.0)])
def test_imagej_unit_and_resolution(tmp_path, unit, um):
    found = read_pixel_size(_imagej_tiff(tmp_path / "ij.tif", unit))
    assert found.um_per_px == pytest.approx(um, rel=1e-9)
    assert found.source == f"ImageJ description unit={unit}, tag 282 XResolution"


@pytest.mark.parametrize("unit", [None, "inch", "pixel"])
def test_imagej_without_a_length_unit_has_no_pixel_size(tmp_path, unit):
    assert read_pixel_size(_imagej_tiff(tmp_path / "ij.tif", unit)) is None


def test_dpi_is_never_a_pixel_size(tmp_path):
    path = tmp_path / "dpi.tif"
    tifffile.imwrite(path, BLANK, resolution=(256, 256), resolutionunit="INCH")
    assert read_pixel_size(path) is None
    png = tmp_path / "image.png"
    png.write_bytes(b"not read")  # only TIFF files have their tags read
    assert read_pixel_size(png) is None


@needs_shared(PLGA)
def test_plga_image_has_only_dpi():
    assert read_pixel_size(PLGA) is None  # 256 per inch: not 99 um/px


def test_non_square_pixels_are_refused_naming_both(tmp_path):
    path = _fei_tiff(tmp_path / "fei.tif", _fei_text(5e-9, 5.2e-9))
    with pytest.raises(SEMError, match="non-square pixels, 0.005 um wide and 0.0052 um high"):
        read_pixel_size(path)
    assert read_pixel_size(_fei_tiff(tmp_path / "ok.tif", _fei_text(5e-9, 5.04e-9))) is not None


@pytest.mark.parametrize("width", ["0", "-5e-09", "nan", "0.002", "unknown"])
def test_absurd_values_are_ignored_with_a_warning(tmp_path, width):
    path = _fei_tiff(tmp_path / "fei.tif", _fei_text(5e-9).replace("PixelWidth=5e-09",
                                                                     f"PixelWidth={width}"))
    with pytest.warns(MetadataWarning, match="FEI tag 34682 \\[Scan\\] PixelWidth gives a pixel"):
        assert read_pixel_size(path) is None


def test_an_ignored_tag_leaves_the_next_source(tmp_path):
    path = tmp_path / "both.tif"
    tifffile.imwrite(path, BLANK, imagej=True, resolution=(20.0, 20.0),
                     metadata={"unit": "micron"},
                     extratags=[(34682, 2, None, _fei_text(0.0), True)])
    with pytest.warns(MetadataWarning, match="FEI tag 34682"):
        found = read_pixel_size(path)
    assert found.um_per_px == pytest.approx(0.05)
    assert found.source.startswith("ImageJ")


def test_unreadable_tiff_is_an_sem_error(tmp_path):
    path = tmp_path / "broken.tif"
    path.write_bytes(b"II*\x00 not a tiff")
    with pytest.raises(SEMError, match="not a readable TIFF"):
        read_pixel_size(path)


# --- espin measure: the scale from the metadata -------------------------------------------


@pytest.fixture(scope="module")
def synthetic():
    mat = espin.geometry.rve.generate("plla", rve__size_ratio=60, rve__layers=3, rve__seed=4,
                                      rve__max_deviation_deg=20.0).mat
    image = render_sem(mat, side_um=30 * 0.45, layers=2, seed=4)
    return np.round(image.image * 255).astype(np.uint8), image.um_per_px


@pytest.fixture(scope="module")
def fei_tiff(synthetic, tmp_path_factory):
    data, um_per_px = synthetic
    path = tmp_path_factory.mktemp("fei") / "mat.tif"
    return _fei_tiff(path, _fei_text(um_per_px * 1e-6), data=data)


@pytest.mark.slow
def test_measure_takes_the_scale_from_the_metadata(synthetic, fei_tiff, tmp_path):
    data, um_per_px = synthetic
    from_tags = measure(fei_tiff)
    given = measure(data, um_per_px=um_per_px)
    assert from_tags.um_per_px == pytest.approx(um_per_px, rel=1e-12)
    assert from_tags.scale_source == "metadata" and from_tags.scale_note == ""
    assert len(from_tags.fibers) == len(given.fibers) > 5
    np.testing.assert_allclose(from_tags.fibers.select_dtypes("number").to_numpy(),
                               given.fibers.select_dtypes("number").to_numpy(), rtol=1e-9)
    summary = tomllib.loads(from_tags.write(tmp_path / "out")["summary"].read_text())
    assert summary["scale"]["source"] == "metadata"
    assert summary["scale"]["metadata_tag"] == "FEI tag 34682 [Scan] PixelWidth"
    assert dict(from_tags.table_rows())["scale"].endswith("(FEI tag 34682 [Scan] PixelWidth)")


def test_given_scale_wins_and_a_difference_is_noted(synthetic, fei_tiff):
    _, um_per_px = synthetic
    close = measure(fei_tiff, um_per_px=um_per_px * 1.01)
    assert close.scale_source == "um_per_px" and close.scale_note == ""
    off = measure(fei_tiff, um_per_px=um_per_px * 1.1)
    assert off.um_per_px == pytest.approx(um_per_px * 1.1)
    assert off.scale_source == "um_per_px"
    assert "metadata (FEI tag 34682 [Scan] PixelWidth)" in off.scale_note
    assert "9.1% off" in off.scale_note
    assert off.summary()["scale"]["note"] == off.scale_note
    assert off.summary()["scale"]["metadata_um_per_px"] == pytest.approx(um_per_px)


def test_non_square_metadata_with_a_given_scale_is_noted(synthetic, tmp_path):
    data, um_per_px = synthetic
    path = _fei_tiff(tmp_path / "skew.tif", _fei_text(5e-8, 6e-8), data=data)
    with pytest.raises(SEMError, match="non-square"):
        measure(path)
    m = measure(path, um_per_px=um_per_px)
    assert m.metadata is None and "non-square" in m.scale_note


def test_no_scale_says_no_metadata_was_found(tmp_path):
    path = tmp_path / "dpi.tif"
    tifffile.imwrite(path, np.zeros((64, 64), np.uint8), resolution=(256, 256),
                     resolutionunit="INCH")
    with pytest.raises(ConfigError, match="no scale: give um_per_px.*no pixel size in the "
                                          "image's metadata"):
        measure(path)
    with pytest.raises(ConfigError, match="an image array has no metadata"):
        measure(np.zeros((64, 64)))


def test_imagej_micro_sign_from_parsed_tags():
    values = {270: "ImageJ=1.54p\nunit=\u00b5m\n", 282: (10, 1), 283: (10, 1)}
    assert pixel_size_from_tags(values).um_per_px == pytest.approx(0.1)


def test_cli_measure_with_the_metadata_scale(fei_tiff, tmp_path, measure_app):
    from typer.testing import CliRunner

    out = tmp_path / "res"
    run = CliRunner().invoke(measure_app, ["measure", str(fei_tiff), "-o", str(out), "--no-figures"])
    assert run.exit_code == 0, run.output
    assert "FEI tag 34682 [Scan] PixelWidth" in run.output
    scale = tomllib.loads((out / "measurement.toml").read_text())["scale"]
    assert scale["source"] == "metadata"
    dpi = tmp_path / "dpi.tif"
    tifffile.imwrite(dpi, np.zeros((64, 64), np.uint8), resolution=(256, 256),
                     resolutionunit="INCH")
    bad = CliRunner().invoke(measure_app, ["measure", str(dpi), "-o", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "no scale" in bad.output and "metadata" in bad.output
    assert "--um-per-px" in bad.output and "--scale-bar-rows" in bad.output  # the flags, by name
