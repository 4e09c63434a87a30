"""Reading SEM images as grey levels, and cropping the microscope's data bar.

TIFF files are read with ``tifffile`` (8/16/32-bit, float, palette, RGB; the first page of a
stack), other formats (PNG, JPEG, BMP ...) with Pillow; both come with scikit-image. Palette
images are mapped through their colour table, colour images to luminance
(0.2125 R + 0.7154 G + 0.0721 B, as ``skimage.color.rgb2gray``), and an alpha channel is
dropped. Grey levels are returned as float64 scaled by the range of the storage type (an 8-bit
image is divided by 255, a 16-bit one by 65535), so a 16-bit image that uses only 12 bits
stays dark: segmentation normalizes contrast itself. A float image, and an integer image of
32 or 64 bits (no detector records that many: such files come from image software that
widened 8- or 16-bit data), are divided by their own maximum.

Checks, each an :class:`~espin.core.errors.SEMError` naming the file: an image of more than
:data:`MAX_PIXELS` pixels is refused from its header, before any pixel is decoded (so a huge
image or a small compressed "decompression bomb" cannot exhaust memory; Pillow's own
decompression-bomb warning and error become this error too); so is an image without pixels
or of a type that holds no grey levels (complex numbers). A float image must hold finite
intensities >= 0 (NaN, infinity and negative values are refused: an SEM image records
intensities, and a float image is scaled by its largest value). An image must be at least
16 x 16 px. Of a multi-page TIFF only the first page is read.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import cast

import numpy as np

from espin.core.errors import ConfigError, SEMError

__all__ = ["MAX_PIXELS", "as_grey", "parse_rows", "read_image", "row_slice"]

MAX_PIXELS = 89_478_485
"""Largest image read [pixels]: Pillow's default ``Image.MAX_IMAGE_PIXELS`` (about
9459 x 9459 px), the same limit for TIFF and every other format. Its float64 grey levels take
0.7 GB, and segmentation works on a few arrays of that size."""

_LUMINANCE = np.array([0.2125, 0.7154, 0.0721])
_TIFF_SUFFIXES = (".tif", ".tiff")
_PALETTE = 3  # TIFF photometric interpretation "palette"


def read_image(path: str | Path) -> np.ndarray:
    """Grey levels of an image file.

    Parameters
    ----------
    path : str or Path
        A TIFF (incl. palette and 16-bit), PNG or JPEG file.

    Returns
    -------
    (rows, cols) float64
        Grey levels, 0 black; 1 is the brightest value of the storage type.

    Raises
    ------
    SEMError
        The file does not exist or is not a readable image, or breaks a rule of the module
        notes (size limit, finite intensities >= 0).
    """
    path = Path(path)
    if path.is_dir():
        raise SEMError(f"image {str(path)!r} is a directory; expected an image file")
    if path.exists() and not path.is_file():
        raise SEMError(f"image {str(path)!r} is not a regular file (a pipe or a device); expected an image file")
    if not path.is_file():
        raise SEMError(f"image {str(path)!r}: no such file")
    try:
        with warnings.catch_warnings():  # a damaged file's decoder chatter: the error says it
            warnings.simplefilter("ignore")
            if path.suffix.lower() in _TIFF_SUFFIXES:
                data = _read_tiff(path)
            else:
                data = _read_pillow(path)
    except SEMError:
        raise
    except Exception as err:  # any decoder failure: the user's file, not our bug
        raise SEMError(f"image {str(path)!r} is not a readable TIFF, PNG or JPEG image ({err})") from err
    return as_grey(data, source=str(path))


def as_grey(data: np.ndarray, source: str = "image") -> np.ndarray:
    """Grey levels (float64, see the module notes) of a 2-D grey or 3-D colour array."""
    a = np.asarray(data)
    _check_values(a, source)
    if a.ndim == 3 and a.shape[2] in (2, 4):  # grey + alpha, RGB + alpha
        a = a[..., :-1]
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim == 3 and a.shape[2] == 3:
        grey = _scaled(a) @ _LUMINANCE
    elif a.ndim == 2:
        grey = _scaled(a)
    else:
        raise SEMError(f"{source}: expected a grey or colour image, got an array of shape {a.shape}")
    if min(grey.shape) < 16:
        raise SEMError(f"{source}: image of {grey.shape[1]} x {grey.shape[0]} px is too small (at least 16 x 16 px)")
    return grey


def _check_values(a: np.ndarray, source: str) -> None:
    """Refuse arrays that hold no grey levels, and floats that are not finite or are < 0."""
    if a.dtype.kind not in "biuf":
        raise SEMError(f"{source}: image holds values of type {a.dtype}; expected integer or float grey levels")
    if a.dtype.kind != "f":
        return
    for bad, problem in ((~np.isfinite(a), "is not finite"), (a < 0, "is negative")):
        if np.any(bad):
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            raise SEMError(
                f"{source}: grey level {a[index].item()!r} at (row, column) {index[:2]} "
                f"{problem}; expected finite intensities >= 0 (rescale the image to [0, 1] "
                "or save it as an 8- or 16-bit image)"
            )


def _check_size(path: Path, width: int, height: int) -> None:
    """Refuse an image without pixels or above :data:`MAX_PIXELS`, before decoding it."""
    pixels = width * height
    if pixels == 0:
        raise SEMError(
            f"image {str(path)!r} has no pixels ({width} x {height} px); expected an image of at least 16 x 16 px"
        )
    if pixels > MAX_PIXELS:
        raise SEMError(
            f"image {str(path)!r} of {width} x {height} px ({pixels / 1e6:.1f} megapixels) is "
            f"larger than espin reads: at most {MAX_PIXELS} px ({MAX_PIXELS / 1e6:.1f} "
            "megapixels); crop or downscale it"
        )


def _scaled(a: np.ndarray) -> np.ndarray:
    if a.dtype == bool:
        return a.astype(float)
    if np.issubdtype(a.dtype, np.integer) and a.dtype.itemsize <= 2:
        info = np.iinfo(a.dtype)
        return (a.astype(float) - min(info.min, 0)) / (info.max - min(info.min, 0))
    if np.issubdtype(a.dtype, np.integer):
        a = a.astype(float) - min(float(a.min()), 0.0) if a.size else a.astype(float)
    a = a.astype(float)
    top = float(a.max()) if a.size else 0.0  # finite and >= 0: checked by as_grey
    return a / top if top > 0 else a


def _read_tiff(path: Path) -> np.ndarray:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        page = cast(tifffile.TiffPage, tif.pages[0])  # the first page is a page, never a frame
        _check_size(path, page.imagewidth, page.imagelength * page.imagedepth)
        if page.dtype is None or page.dtype.kind not in "biuf":
            raise SEMError(
                f"image {str(path)!r}: TIFF of sample type {page.dtype}; expected integer or float grey levels"
            )
        data = page.asarray()
        if int(page.photometric) == _PALETTE and page.colormap is not None:
            colormap = np.asarray(page.colormap).astype(np.uint16)  # (3, 2**bits), 16-bit
            rgb = colormap[:, data].transpose(1, 2, 0)
            # Many writers store an 8-bit palette as value << 8: read it back as 8 bits.
            data = (rgb >> 8).astype(np.uint8) if np.all(colormap % 256 == 0) else rgb
    return data


def _read_pillow(path: Path) -> np.ndarray:
    """Decode with Pillow, its decompression-bomb warning and error turned into a SEMError."""
    from PIL import Image

    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            return _decode_pillow(path)
        except (Image.DecompressionBombWarning, Image.DecompressionBombError) as err:
            reason = str(err).rstrip(".")
            raise SEMError(
                f"image {str(path)!r} is larger than espin reads: {reason}; expected "
                f"at most {MAX_PIXELS} px: crop or downscale it"
            ) from None


def _decode_pillow(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as opened:
        img: Image.Image = opened
        _check_size(path, *img.size)
        img.seek(0)
        if img.mode in ("P", "PA"):
            img = img.convert("RGBA")
        elif img.mode == "CMYK":
            img = img.convert("RGB")
        data = np.array(img)
        if img.mode == "I" and data.size and data.max() <= np.iinfo(np.uint16).max:
            data = data.astype(np.uint16)  # 16-bit PNG decoded to 32-bit integers
    return data


def parse_rows(value: str | tuple[int, int] | list[int], name: str) -> tuple[int, int]:
    """A row range ``(start, stop)`` from ``"START:STOP"`` or a pair (Python slice rules).

    Negative values count from the bottom, as in Python. Raises :class:`ConfigError` naming
    ``name`` on anything else.
    """
    if isinstance(value, str):
        start, sep, stop = value.partition(":")
        try:
            if not sep:
                raise ValueError
            pair = (int(start), int(stop))
        except ValueError:
            raise ConfigError(f"{name} must be START:STOP (two integers), got {value!r}") from None
    else:
        try:
            first, last = value
            pair = (int(first), int(last))
        except (TypeError, ValueError):
            raise ConfigError(f"{name} must be a pair (start, stop) of rows, got {value!r}") from None
    return pair


def row_slice(rows: tuple[int, int], n_rows: int, name: str) -> slice:
    """The slice of image rows ``rows`` resolves to, checked against ``n_rows``.

    Raises :class:`ConfigError` naming ``name`` if the range is empty or outside the image.
    """
    start, stop = rows
    start_abs = start + n_rows if start < 0 else start
    stop_abs = stop + n_rows if stop < 0 else stop
    if not (0 <= start_abs < stop_abs <= n_rows):
        raise ConfigError(
            f"{name} = {start}:{stop} must select rows within the image's 0:{n_rows} "
            "(START < STOP; negative values count from the bottom)"
        )
    return slice(start_abs, stop_abs)
