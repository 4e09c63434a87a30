"""Bad SEM images: too large (or a decompression bomb), no pixels, not an image, truncated, or
float intensities that are negative or not finite. Each is a SEMError naming the file (exit
code 3 on the command line); none is decoded in full or measured as if it were fine."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
import tifffile
from PIL import Image
from typer.testing import CliRunner

import espin.imaging.image as image_module
from espin.cli import app
from espin.core.errors import SEMError
from espin.imaging.image import MAX_PIXELS, as_grey, read_image

HUGE = 20000  # px a side: 400 megapixels, 4.5 times MAX_PIXELS


def _ramp(rows: int = 32, cols: int = 32) -> np.ndarray:
    return np.tile(np.linspace(0, 255, cols).astype(np.uint8), (rows, 1))


def tiff_declaring_huge_size(path):
    """A 32 x 32 px TIFF whose header is then edited to declare HUGE x HUGE px (1 KB file)."""
    tifffile.imwrite(path, _ramp())
    with tifffile.TiffFile(path, mode="r+b") as tif:
        tif.pages[0].tags["ImageWidth"].overwrite(HUGE)
        tif.pages[0].tags["ImageLength"].overwrite(HUGE)


def tiff_bomb(path):
    """A real 20480 x 20480 px zlib TIFF of black tiles: 0.4 MB on disk, 419 MB decoded.

    One 1024 x 1024 tile is compressed once and written 400 times (tifffile writes byte
    strings as already-encoded tiles), so making it is cheap.
    """
    tile = zlib.compress(bytes(1024 * 1024), 9)
    tifffile.imwrite(
        path,
        iter([tile] * 400),
        shape=(20480, 20480),
        dtype=np.uint8,
        tile=(1024, 1024),
        compression="zlib",
    )


def png_declaring(path, side: int):
    """A 20 x 20 px PNG whose IHDR chunk then declares side x side px (CRC recomputed)."""
    Image.fromarray(_ramp(20, 20)).save(path)
    data = bytearray(path.read_bytes())
    data[16:24] = struct.pack(">II", side, side)
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    path.write_bytes(bytes(data))


def float_tiff(value):
    def make(path):
        a = np.linspace(0.0, 1.0, 32 * 32).reshape(32, 32)
        a[5, 7] = value
        tifffile.imwrite(path, a.astype(np.float32))

    return make


def zero_size_tiff(path):
    with pytest.warns(UserWarning, match="zero-size"):
        tifffile.imwrite(path, np.zeros((0, 0), np.uint8))


def text_file(path):
    path.write_text("fiber,diameter_um\n1,0.45\n")


def empty_file(path):
    path.write_bytes(b"")


def truncated(write):
    def make(path):
        write(path)
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])

    return make


def save(path, values: np.ndarray) -> None:
    """Write a grey image as TIFF (tifffile) or by its suffix (Pillow)."""
    if path.suffix == ".tif":
        tifffile.imwrite(path, values)
    else:
        Image.fromarray(values).save(path)


def one_pixel(path):
    save(path, np.ones((1, 1), np.uint8))


def noise(path):
    save(path, np.random.default_rng(0).integers(0, 256, (64, 64), dtype=np.uint8))


def complex_tiff(path):
    tifffile.imwrite(path, np.ones((32, 32), np.complex64))


CASES = {
    "tiff_declaring_huge_size": (
        "huge.tif",
        tiff_declaring_huge_size,
        [f"{HUGE} x {HUGE} px", str(MAX_PIXELS)],
    ),
    "tiff_bomb": ("bomb.tif", tiff_bomb, ["20480 x 20480 px", str(MAX_PIXELS)]),
    "png_above_limit": (
        "huge.png",
        lambda p: png_declaring(p, 10000),
        ["100000000 pixels", str(MAX_PIXELS)],
    ),
    "png_bomb": (
        "bomb.png",
        lambda p: png_declaring(p, HUGE),
        ["400000000 pixels", str(MAX_PIXELS)],
    ),
    "float_negative": (
        "neg.tif",
        float_tiff(-0.25),
        ["-0.25", "(5, 7)", "is negative", "intensities >= 0"],
    ),
    "float_nan": ("nan.tif", float_tiff(np.nan), ["nan", "(5, 7)", "not finite"]),
    "float_inf": ("inf.tif", float_tiff(np.inf), ["inf", "(5, 7)", "not finite"]),
    "complex": ("complex.tif", complex_tiff, ["complex64", "integer or float grey levels"]),
    "zero_size_tiff": ("zero.tif", zero_size_tiff, ["no pixels", "0 x 0 px"]),
    "one_pixel_tiff": ("one.tif", one_pixel, ["1 x 1 px", "too small"]),
    "one_pixel_png": ("one.png", one_pixel, ["1 x 1 px", "too small"]),
    "text_as_tiff": ("fibers.tif", text_file, ["not a readable"]),
    "text_as_png": ("fibers.png", text_file, ["not a readable"]),
    "empty_tiff": ("empty.tif", empty_file, ["not a readable"]),
    "truncated_tiff": ("cut.tif", truncated(noise), ["not a readable"]),
    "truncated_png": ("cut.png", truncated(noise), ["not a readable"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_image_is_a_clear_error(tmp_path, case):
    name, make, fragments = CASES[case]
    path = tmp_path / name
    make(path)
    with pytest.raises(SEMError) as caught:
        read_image(path)
    message = str(caught.value)
    assert str(path) in message, message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_tiff_bomb_is_small_on_disk(tmp_path):
    tiff_bomb(tmp_path / "bomb.tif")
    assert (tmp_path / "bomb.tif").stat().st_size < 1_000_000 < 20480**2 / 400


@pytest.mark.parametrize("suffix", [".tif", ".png"])
def test_limit_applies_before_decoding_at_exactly_max_pixels(tmp_path, monkeypatch, suffix):
    """The limit is inclusive: an image of MAX_PIXELS px is read, one more row is not."""
    monkeypatch.setattr(image_module, "MAX_PIXELS", 32 * 32)
    fits, too_big = tmp_path / f"fits{suffix}", tmp_path / f"big{suffix}"
    for path, rows in ((fits, 32), (too_big, 33)):
        save(path, _ramp(rows, 32))
    assert read_image(fits).shape == (32, 32)
    with pytest.raises(SEMError, match=r"32 x 33 px .* at most 1024 px"):
        read_image(too_big)


def test_pillow_bomb_check_is_an_error_even_when_pillow_only_warns(tmp_path, monkeypatch):
    # Pillow warns (and still decodes) between MAX_IMAGE_PIXELS and twice that: refused too.
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)
    path = tmp_path / "ramp.png"
    Image.fromarray(_ramp(12, 12)).save(path)
    with pytest.raises(SEMError, match="ramp.png.*144 pixels.*decompression bomb"):
        read_image(path)


def test_valid_float_image_is_scaled_by_its_maximum(tmp_path):
    a = np.linspace(0.0, 2.0, 32 * 32).reshape(32, 32).astype(np.float32)
    tifffile.imwrite(tmp_path / "float.tif", a)
    np.testing.assert_allclose(read_image(tmp_path / "float.tif"), a / 2.0, rtol=1e-6)


def test_multipage_tiff_reads_the_first_page(tmp_path):
    path = tmp_path / "stack.tif"
    first, second = _ramp(), 255 - _ramp()
    tifffile.imwrite(path, np.stack([first, second]), photometric="minisblack")
    with tifffile.TiffFile(path) as tif:
        assert len(tif.pages) == 2
    np.testing.assert_allclose(read_image(path), first / 255)


def test_directory_is_a_clear_error(tmp_path):
    (tmp_path / "folder.tif").mkdir()
    with pytest.raises(SEMError, match="folder.tif.*is a directory"):
        read_image(tmp_path / "folder.tif")


def test_arrays_are_checked_like_files():
    a = np.full((32, 32), 0.5)
    a[1, 2] = -1.0
    with pytest.raises(SEMError, match=r"image array: grey level -1.0 at \(row, column\) \(1, 2\)"):
        as_grey(a, source="image array")


@pytest.mark.parametrize("case", ["tiff_bomb", "float_negative", "text_as_tiff"])
def test_measure_on_a_bad_image_exits_3_without_traceback(tmp_path, case):
    name, make, fragments = CASES[case]
    path = tmp_path / name
    make(path)
    result = CliRunner().invoke(
        app, ["measure", str(path), "--um-per-px", "0.05", "-o", str(tmp_path / "out"), "-q"]
    )
    assert result.exit_code == 3, result.output
    assert "Traceback" not in result.output and name in result.output
    assert fragments[0] in result.output
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("dtype", ["int32", "uint32", "int64"])
def test_wide_integer_image_of_8_bit_values_is_scaled_by_its_maximum(tmp_path, dtype):
    """Image software widens 8-bit data to 32 bits; divided by 2^32 it looked blank."""
    values = np.arange(256, dtype=np.uint8).reshape(16, 16)
    path = tmp_path / "wide.tif"
    tifffile.imwrite(path, values.astype(dtype))
    assert np.allclose(read_image(path), values / 255.0)


@pytest.mark.parametrize("special", ["fifo", "/dev/zero"])
def test_pipes_and_devices_are_refused_without_reading(tmp_path, special):
    import os

    if special == "fifo":
        if not hasattr(os, "mkfifo"):
            pytest.skip("no named pipes on this platform")
        path = tmp_path / "image.tif"
        os.mkfifo(path)
    else:
        path = special
        if not os.path.exists(path):
            pytest.skip(f"no {path} on this platform")
    with pytest.raises(SEMError, match="not a regular file"):
        read_image(path)
    result = CliRunner().invoke(app, ["measure", str(path), "--um-per-px", "0.05", "-o", str(tmp_path / "m")])
    assert result.exit_code == 3 and "not a regular file" in result.output


def test_a_fiber_width_wider_than_the_image_is_refused_before_segmenting():
    from espin.core.errors import ConfigError
    from espin.imaging.measurement import measure

    with pytest.raises(ConfigError, match="width_px = 1e"):
        measure(np.random.default_rng(0).random((64, 64)), um_per_px=0.05, width_px=1e9)
