"""The per-fiber table ``fibers.csv``: written by ``espin measure``, read back validated.

Columns (units in the names): ``fiber`` (int), ``diameter_um`` (width of a blurred flat
profile fitted to the fiber's median profile), ``orientation_deg`` (axis of the end-to-end
line, [0, 180)), ``tortuosity`` (contour / end-to-end, >= 1), ``contour_length_um``,
``end_to_end_um``, ``start_edge`` and ``end_edge`` (the edge of the analysed image that the
fiber's first / last end lies on: ``bottom``, ``right``, ``top`` or ``left``; empty for an end
inside the image), ``visible`` (``True`` for a fully visible top fiber, ``False`` for a partly
hidden deeper one: :mod:`espin.imaging.visibility`; the diameter sample of a table with this
column is its visible fibers'). An empty number cell is a value that was not measured (e.g. a
fiber whose every width sample was next to a crossing). Tables written before the
``visible`` column existed are read without it (every fiber's diameter counts).
A table made by hand needs only one of ``diameter_um``, ``orientation_deg``, ``tortuosity``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from espin.core.atomic import atomic_write
from espin.core.errors import SEMError

__all__ = [
    "FIBER_COLUMNS",
    "EDGE_COLUMNS",
    "EDGE_NAMES",
    "VISIBLE_COLUMN",
    "parse_flags",
    "read_fibers_csv",
    "write_fibers_csv",
]

EDGE_COLUMNS = ("start_edge", "end_edge")
"""Text columns: the image edge each end of a fiber lies on (empty: inside the image)."""
EDGE_NAMES = ("bottom", "right", "top", "left")
"""Edge names, in the order of :func:`espin.geometry.pieces.border_edges` (0 = bottom)."""
_NUMBER_COLUMNS = ("diameter_um", "orientation_deg", "tortuosity", "contour_length_um", "end_to_end_um")
VISIBLE_COLUMN = "visible"
"""Boolean column: a fully visible top fiber (True) or a partly hidden deeper one (False)."""
FIBER_COLUMNS = ("fiber", *_NUMBER_COLUMNS, *EDGE_COLUMNS, VISIBLE_COLUMN)
"""Columns of ``fibers.csv``, in order."""

_MEASURED = ("diameter_um", "orientation_deg", "tortuosity")
# column -> (test, allowed range as text)
_RANGES = {
    "diameter_um": (lambda x: x > 0, "> 0"),
    "orientation_deg": (lambda x: (x >= 0) & (x < 180), "in [0, 180)"),
    "tortuosity": (lambda x: x >= 1, ">= 1"),
    "contour_length_um": (lambda x: x > 0, "> 0"),
    "end_to_end_um": (lambda x: x > 0, "> 0"),
}


def write_fibers_csv(table: pd.DataFrame, path: str | Path) -> Path:
    """Write the per-fiber table (exactly :data:`FIBER_COLUMNS`) atomically."""
    frame = table.loc[:, list(FIBER_COLUMNS)]
    return atomic_write(path, lambda tmp: frame.to_csv(tmp, index=False, float_format="%.6g"))


def read_fibers_csv(path: str | Path) -> pd.DataFrame:
    """Read and validate a per-fiber table.

    Parameters
    ----------
    path : str or Path
        A ``fibers.csv`` written by ``espin measure``, or made by hand with at least one of
        the columns ``diameter_um``, ``orientation_deg``, ``tortuosity``.

    Returns
    -------
    pandas.DataFrame
        The known columns present (others are dropped), as float (``fiber`` as int, the edge
        columns as text, ``visible`` as bool); empty number cells are NaN, empty edge cells "".
        A missing ``fiber`` column is numbered 0, 1, ...

    Raises
    ------
    SEMError
        Unreadable file, none of the measured columns, a non-numeric cell, a value outside
        its range, an unknown edge name or a ``visible`` cell that is not true or false (the
        message names the column, the first bad row and the range).
    """
    path = Path(path)
    if not path.is_file():
        raise SEMError(f"fibers table {str(path)!r}: no such file")
    try:
        raw = pd.read_csv(path, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise SEMError(f"fibers table {str(path)!r} is not a readable CSV file ({err})") from err
    raw.columns = [str(c).strip() for c in raw.columns]
    if not any(c in raw.columns for c in _MEASURED):
        raise SEMError(
            f"fibers table {str(path)!r} needs at least one of the columns "
            f"{', '.join(_MEASURED)}; found {', '.join(raw.columns) or 'none'}"
        )
    out = pd.DataFrame(index=raw.index)
    for column in _NUMBER_COLUMNS:
        if column in raw.columns:
            out[column] = _checked(raw[column], column, path)
    for column in EDGE_COLUMNS:
        if column in raw.columns:
            out[column] = _checked_edges(raw[column], column, path)
    if VISIBLE_COLUMN in raw.columns:
        out[VISIBLE_COLUMN] = _checked_flags(raw[VISIBLE_COLUMN], path)
    if "fiber" in raw.columns:
        out.insert(0, "fiber", _checked_ids(raw["fiber"], path))
    else:
        out.insert(0, "fiber", np.arange(len(raw), dtype=np.int64))
    return out.reset_index(drop=True)


def _checked(values: pd.Series, column: str, path: Path) -> pd.Series:
    numbers = pd.to_numeric(values, errors="coerce").astype(float)
    bad = numbers.isna() & values.notna() & (values.astype(str).str.strip() != "")
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise SEMError(
            f"fibers table {str(path)!r}: column {column}, data row {row + 1}: {values.iloc[row]!r} is not a number"
        )
    test, allowed = _RANGES[column]
    present = numbers.notna().to_numpy()
    x = numbers.to_numpy()
    wrong = present & ~np.asarray(test(np.where(present, x, np.nan)), dtype=bool)
    wrong |= present & ~np.isfinite(np.where(present, x, 0.0))
    if wrong.any():
        row = int(np.flatnonzero(wrong)[0])
        raise SEMError(f"fibers table {str(path)!r}: column {column}, data row {row + 1}: {x[row]:g} is not {allowed}")
    return numbers


def _checked_edges(values: pd.Series, column: str, path: Path) -> pd.Series:
    names = values.fillna("").astype(str).str.strip()
    bad = ~names.isin(("", *EDGE_NAMES))
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise SEMError(
            f"fibers table {str(path)!r}: column {column}, data row {row + 1}: "
            f"{values.iloc[row]!r} is not an edge ({', '.join(EDGE_NAMES)} or empty)"
        )
    return names


def parse_flags(values: Any) -> tuple[np.ndarray, int | None]:
    """True/False values (bools, 1/0, or the words true/false in any case) as a bool array, and
    the index of the first value that is none of these (NaN and blanks included), else None."""
    words = pd.Series(np.asarray(values, dtype=object).ravel()).astype(str).str.strip().str.lower()
    truth = {"true": True, "1": True, "1.0": True, "false": False, "0": False, "0.0": False}
    bad = np.flatnonzero(~words.isin(tuple(truth)).to_numpy())
    flags = np.array([truth.get(word, False) for word in words], dtype=bool)
    return flags, (int(bad[0]) if len(bad) else None)


def _checked_flags(values: pd.Series, path: Path) -> pd.Series:
    flags, bad = parse_flags(values)
    if bad is not None:
        raise SEMError(
            f"fibers table {str(path)!r}: column {VISIBLE_COLUMN}, data row {bad + 1}: "
            f"{values.iloc[bad]!r} is not True or False"
        )
    return pd.Series(flags, index=values.index)


def _checked_ids(values: pd.Series, path: Path) -> pd.Series:
    numbers = pd.to_numeric(values, errors="coerce")
    if numbers.isna().any() or not np.all(np.mod(numbers, 1) == 0):
        raise SEMError(f"fibers table {str(path)!r}: column fiber must hold integers")
    return numbers.astype(np.int64)
