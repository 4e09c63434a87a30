"""Reading SEM images (formats, palettes, bit depths) and finding the scale bar."""

from __future__ import annotations

import numpy as np
import pytest

from espin.core.errors import ConfigError, SEMError
from espin.imaging.image import parse_rows, read_image, row_slice
from espin.imaging.scale import detect_scale_bar


def _gradient(rows: int = 40, cols: int = 60) -> np.ndarray:
    """A grey ramp 0..1 over the columns, different in every column (uint8-exact)."""
    return np.tile(np.linspace(0.0, 1.0, cols), (rows, 1))


def test_png_jpeg_and_16bit_png_read_as_grey(tmp_path):
    from PIL import Image

    ramp = _gradient()
    Image.fromarray(np.round(ramp * 255).astype(np.uint8)).save(tmp_path / "a.png")
    Image.fromarray(np.round(ramp * 255).astype(np.uint8)).save(tmp_path / "a.jpg", quality=95)
    Image.fromarray(np.round(ramp * 65535).astype(np.uint16)).save(tmp_path / "b.png")
    rgb = np.stack([np.round(ramp * 255).astype(np.uint8)] * 3, axis=2)
    Image.fromarray(rgb).save(tmp_path / "c.png")
    # 8-bit exact to 1/255; JPEG is lossy (a few grey levels); 16-bit to 1/65535.
    np.testing.assert_allclose(read_image(tmp_path / "a.png"), ramp, atol=0.5 / 255)
    np.testing.assert_allclose(read_image(tmp_path / "a.jpg"), ramp, atol=4 / 255)
    np.testing.assert_allclose(read_image(tmp_path / "b.png"), ramp, atol=0.5 / 65535)
    np.testing.assert_allclose(read_image(tmp_path / "c.png"), ramp, atol=1 / 255)


def test_palette_tiff_is_mapped_through_its_colour_table(tmp_path):
    from PIL import Image

    # Palette index i shows grey 255 - i: reading the indices would invert the image.
    index = np.round(_gradient() * 255).astype(np.uint8)
    img = Image.frombytes("P", (index.shape[1], index.shape[0]), index.tobytes())
    img.putpalette([v for i in range(256) for v in (255 - i,) * 3])
    img.save(tmp_path / "p.tif")
    img.save(tmp_path / "p.png")
    expected = (255 - index) / 255
    np.testing.assert_allclose(read_image(tmp_path / "p.tif"), expected, atol=0.5 / 255)
    np.testing.assert_allclose(read_image(tmp_path / "p.png"), expected, atol=0.5 / 255)


def test_16bit_tiff(tmp_path):
    import tifffile

    ramp = _gradient()
    tifffile.imwrite(tmp_path / "d.tif", np.round(ramp * 65535).astype(np.uint16))
    np.testing.assert_allclose(read_image(tmp_path / "d.tif"), ramp, atol=0.5 / 65535)


def test_unreadable_and_missing_files_name_the_file(tmp_path):
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"not an image")
    with pytest.raises(SEMError, match="bad.tif.*not a readable"):
        read_image(bad)
    with pytest.raises(SEMError, match="no such file"):
        read_image(tmp_path / "missing.png")


def test_row_ranges():
    assert parse_rows("880:960", "crop_rows") == (880, 960)
    assert row_slice((-80, 960), 960, "x") == slice(880, 960)
    with pytest.raises(ConfigError, match="scale_bar_rows"):
        parse_rows("880", "scale_bar_rows")
    with pytest.raises(ConfigError, match="crop_rows.*within the image"):
        row_slice((900, 1000), 960, "crop_rows")


def _image_with_bar(kind: str, bright: bool) -> np.ndarray:
    rng = np.random.default_rng(1)
    image = 0.5 + 0.05 * rng.standard_normal((200, 400))
    mark = 1.0 if bright else 0.0
    if kind == "bar":
        image[170:176, 100:261] = mark  # 161 px long
    else:
        for col in range(50, 351, 30):  # 11 ticks, centres 50 + 1 ... 350 + 1: span 300 px
            image[165:180, col:col + 3] = mark
    return image


@pytest.mark.parametrize("bright", [True, False])
def test_solid_bar_length(bright):
    bar = detect_scale_bar(_image_with_bar("bar", bright), slice(150, 200))
    assert bar.kind == "bar" and bar.length_px == 161


def test_tick_series_span():
    bar = detect_scale_bar(_image_with_bar("ticks", True), slice(150, 200))
    assert bar.kind == "ticks" and bar.n_ticks == 11 and bar.length_px == pytest.approx(300.0)


def test_no_bar_in_rows_is_an_error():
    with pytest.raises(SEMError, match="scale_bar_rows 10:60: no scale bar found"):
        detect_scale_bar(_image_with_bar("bar", True), slice(10, 60))
    # A bar cut by the row range (like a fiber crossing it) is no bar.
    with pytest.raises(SEMError, match="no scale bar"):
        detect_scale_bar(_image_with_bar("bar", True), slice(172, 200))
