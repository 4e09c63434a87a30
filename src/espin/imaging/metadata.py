"""The pixel size an SEM image's TIFF tags record: FEI / Thermo Fisher, Zeiss, ImageJ.

Only tags that record the pixel size of the scan are read, in this order (the first that holds
one wins):

1. FEI / Thermo Fisher tag 34682 (FEI_HELIOS), then 34680 (FEI_SFEG): an INI-like text,
   ``PixelWidth`` and ``PixelHeight`` of its ``[Scan]`` section in metres;
2. Zeiss tag 34118 (CZ_SEM): ``ap_image_pixel_size``, a value with its unit (``nm``, ``um``
   ...);
3. an ImageJ description (tag 270 starting with ``ImageJ=``) whose ``unit=`` is a length
   (``micron``, ``um``, ``µm``, ImageJ's ``\\u00B5m``, ``nm``, ``mm``): ImageJ stores pixels per
   unit in XResolution (tag 282) and YResolution (283), so the pixel size is their inverse.

The generic TIFF resolution (XResolution with ResolutionUnit inch or centimetre, "dpi") is
never read: it is the printing resolution image software writes, not the microscope's pixel
size (PLGA-1500_1.tif says 256 per inch, which would read as 99 um/px).

The tag values are parsed by ``tifffile`` (its ``fei_metadata`` and ``sem_metadata`` readers).
Pixels whose width and height differ by more than :data:`SQUARE_TOLERANCE` are refused (a
:class:`~espin.core.errors.SEMError` naming both): one pixel size cannot measure such an image.
A pixel size that is not finite, <= 0 or above :data:`MAX_UM_PER_PX` is ignored with a
:class:`MetadataWarning` naming the tag, and the next source is tried: an unset or damaged
field (a microscope that was not calibrated writes 0) must not stop a measurement whose scale
is given otherwise, and with no other scale the measurement stops anyway ("no scale").
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from espin.core.errors import SEMError

__all__ = [
    "MAX_UM_PER_PX",
    "SQUARE_TOLERANCE",
    "MetadataScale",
    "MetadataWarning",
    "pixel_size_from_tags",
    "read_pixel_size",
]

MAX_UM_PER_PX = 1000.0
"""Largest pixel size read from a tag [um / px] (as ``um_per_px`` of ``espin measure``)."""
SQUARE_TOLERANCE = 0.01
"""Largest relative difference between pixel width and height accepted as square."""

_TIFF_SUFFIXES = (".tif", ".tiff")  # as espin.imaging.image reads them
_FEI_TAGS = {34682: "FEI_HELIOS", 34680: "FEI_SFEG"}
_ZEISS_TAG = 34118
_DESCRIPTION, _X_RESOLUTION, _Y_RESOLUTION = 270, 282, 283
_TAGS = (*_FEI_TAGS, _ZEISS_TAG, _DESCRIPTION, _X_RESOLUTION, _Y_RESOLUTION)
_UM_PER_UNIT = {
    "nm": 1e-3,
    "um": 1.0,
    "\u00b5m": 1.0,
    "\u03bcm": 1.0,
    "\\u00b5m": 1.0,
    "micron": 1.0,
    "microns": 1.0,
    "mm": 1e3,
}
"""Length units of the Zeiss and ImageJ tags (lower case) [um]; ImageJ escapes µ as
``\\u00B5``."""


class MetadataWarning(UserWarning):
    """A tag's pixel size is absurd (not finite, <= 0 or too large) and was ignored."""


@dataclass(frozen=True)
class MetadataScale:
    """The pixel size found in an image's tags.

    Attributes
    ----------
    um_per_px : float [um / px]
        Pixel size (the width; the height agrees within :data:`SQUARE_TOLERANCE`).
    source : str
        Where it came from, e.g. ``"FEI tag 34682 [Scan] PixelWidth"``.
    """

    um_per_px: float
    source: str


def read_pixel_size(path: str | Path) -> MetadataScale | None:
    """The pixel size recorded in a TIFF file's microscope or ImageJ tags.

    Parameters
    ----------
    path : str or Path
        An image file; a file without a ``.tif`` / ``.tiff`` suffix has no tags read.

    Returns
    -------
    MetadataScale or None
        The pixel size and its tag (module notes), or None when no tag records one.

    Raises
    ------
    SEMError
        The file is not a readable TIFF, or its pixels are not square.
    """
    import tifffile

    path = Path(path)
    if path.suffix.lower() not in _TIFF_SUFFIXES:
        return None
    try:
        with tifffile.TiffFile(path) as tif:
            tags = tif.pages.first.tags
            values = {code: tags.valueof(code) for code in _TAGS if code in tags}
    except Exception as err:  # any decoder failure: the user's file, not our bug
        raise SEMError(f"image {str(path)!r} is not a readable TIFF ({err})") from err
    return pixel_size_from_tags(values, source=str(path))


def pixel_size_from_tags(values: Mapping[int, Any], source: str = "image") -> MetadataScale | None:
    """The pixel size recorded in TIFF tag values (as ``tifffile`` parses them).

    Parameters
    ----------
    values : mapping of tag code to value
        Tags 34682, 34680 (dicts of sections), 34118 (dict), 270 (str), 282 and 283
        ((numerator, denominator)); others are not read.
    source : str
        The image, named in errors and warnings.

    Returns
    -------
    MetadataScale or None
        From the first tag of the module notes' order that holds a usable pixel size.

    Raises
    ------
    SEMError
        Its pixels are not square.
    """
    readers: list[tuple[int, Callable[[int, Mapping[int, Any]], _Found | None]]] = [
        (34682, _fei),
        (34680, _fei),
        (_ZEISS_TAG, _zeiss),
        (_DESCRIPTION, _imagej),
    ]
    for code, reader in readers:
        found = reader(code, values) if values.get(code) is not None else None
        if found is not None and _usable(found, source):
            return MetadataScale(found.width_um, found.name)
    return None


@dataclass(frozen=True)
class _Found:
    """A pixel width and height [um] (height None if not recorded) and the tag's name."""

    width_um: float
    height_um: float | None
    name: str


def _fei(code: int, values: Mapping[int, Any]) -> _Found | None:
    """``[Scan] PixelWidth`` / ``PixelHeight`` [m] of an FEI tag."""
    scan = values[code].get("Scan") if isinstance(values[code], dict) else None
    if not isinstance(scan, dict) or "PixelWidth" not in scan:
        return None
    height = _number(scan["PixelHeight"]) * 1e6 if "PixelHeight" in scan else None
    return _Found(_number(scan["PixelWidth"]) * 1e6, height, f"FEI tag {code} [Scan] PixelWidth")


def _zeiss(code: int, values: Mapping[int, Any]) -> _Found | None:
    """``ap_image_pixel_size`` (name, value, unit) of the Zeiss tag."""
    entry = values[code].get("ap_image_pixel_size") if isinstance(values[code], dict) else None
    if not isinstance(entry, tuple) or len(entry) < 2:
        return None
    unit = str(entry[2]).lower() if len(entry) > 2 else ""
    factor = _UM_PER_UNIT.get(unit, math.nan)  # no or an unknown unit: NaN, warned about
    return _Found(_number(entry[1]) * factor, None, f"Zeiss tag {code} ap_image_pixel_size")


def _imagej(code: int, values: Mapping[int, Any]) -> _Found | None:
    """1 / XResolution (and YResolution) in the length unit of an ImageJ description."""
    description = values[code]
    if not isinstance(description, str) or not description.startswith("ImageJ="):
        return None
    fields = dict(line.split("=", 1) for line in description.splitlines() if "=" in line)
    unit = fields.get("unit", "").strip()
    factor = _UM_PER_UNIT.get(unit.lower())
    if factor is None:  # no unit, "pixel", "inch": no pixel size
        return None
    width, height = (_inverse(values.get(tag)) * factor for tag in (_X_RESOLUTION, _Y_RESOLUTION))
    return _Found(width, height, f"ImageJ description unit={unit}, tag 282 XResolution")


def _usable(found: _Found, source: str) -> bool:
    """Whether a found pixel size is sane (else warned about); refuse non-square pixels."""
    for size in (found.width_um, found.height_um):
        if size is not None and not (math.isfinite(size) and 0 < size <= MAX_UM_PER_PX):
            warnings.warn(
                f"{source}: {found.name} gives a pixel size of {size!r} um, not in (0, {MAX_UM_PER_PX:g}] um; ignored",
                MetadataWarning,
                stacklevel=3,
            )
            return False
    if found.height_um is not None and abs(found.height_um - found.width_um) > SQUARE_TOLERANCE * found.width_um:
        raise SEMError(
            f"{source}: {found.name} records non-square pixels, {found.width_um:.6g} um wide and "
            f"{found.height_um:.6g} um high (more than {SQUARE_TOLERANCE:.0%} apart); espin "
            "measures images of square pixels: resample the image, or give um_per_px to "
            "measure it anyway"
        )
    return True


def _number(value: Any) -> float:
    """A tag value as a float; NaN if it is not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _inverse(rational: Any) -> float:
    """1 / a TIFF rational (numerator, denominator); NaN if missing, inf if zero."""
    try:
        numerator, denominator = rational
        return float(denominator) / float(numerator) if numerator else math.inf
    except (TypeError, ValueError):
        return math.nan
