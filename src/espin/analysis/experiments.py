"""Experimental stress-strain curves from CSV files, and the average of several specimens.

File format
-----------
A text table, one point per line: any number of columns, separated by commas, semicolons,
tabs or whitespace (detected from the first line unless ``delimiter`` is given). Blank lines
and lines starting with ``#`` are ignored, as are the first ``skip_rows`` lines (an instrument's
preamble). The first remaining line is a header when none of its fields is a number; columns
can then be chosen by name as well as by 0-based index. Strain is engineering strain
(0.01 = 1 %; ``percent_strain=True`` reads percent), stress is in MPa. The strain must
increase from line to line (a monotonic loading: cut unloading parts and repeated points).

Without explicit columns, default names are looked for in the header, case-insensitively:
``strain`` for the strain, and for the stress the first of ``stress_MPa`` (espin's own
``curve.csv``), ``stress [MPa]``, ``stress (MPa)``, ``stress`` and ``mean_MPa`` (an averaged
curve written by :meth:`AveragedCurve.to_csv`). A column not found by name is column 0
(strain) or 1 (stress) only when the file has no header or exactly two columns; a header with
more columns and no default name is an error listing its columns (choose them with
``strain_column`` / ``stress_column``, ``--strain-column`` / ``--stress-column`` on the command
line). Strain and stress resolving to the same column is an error.

A bad file raises :class:`CurveFileError` naming the file and the line.

Averaging
---------
Specimens are interpolated linearly onto a common strain grid; at each grid strain the mean,
the sample standard deviation (ddof = 1, as for the paper's N = 3 specimens) and the number of
specimens whose strain range covers it are reported. The default grid runs from 0 (or the
latest first strain of the specimens) to the smallest of their last strains, so every
specimen covers every point; a user grid may reach further, where fewer specimens count.
``grid="measured"`` keeps the measured strains instead of inventing new ones: the specimens'
common strains when they all share them (no interpolation at all), else the union of their
strains within the common range (each specimen interpolated at the others' strains); a fit
to the average then weighs the points that were measured, not an arbitrary grid.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from espin.core.atomic import atomic_write_bytes
from espin.core.errors import InputError

__all__ = ["CurveFileError", "Curve", "AveragedCurve", "read_curve", "average_curves"]

_STRAIN_NAMES = ("strain",)
_STRESS_NAMES = ("stress_MPa", "stress [MPa]", "stress (MPa)", "stress", "mean_MPa")
_DELIMITERS = ("\t", ";", ",")


class CurveFileError(InputError):
    """A curve file cannot be read (the message names the file and line), or curves cannot be
    averaged."""


@dataclass(frozen=True, eq=False)
class Curve:
    """One measured (or simulated) stress-strain curve.

    Attributes
    ----------
    strain : (n,) float64
        Engineering strain, increasing.
    stress_MPa : (n,) float64 [MPa]
        Stress at each strain.
    source : str
        Where the curve came from (the file path).
    """

    strain: np.ndarray
    stress_MPa: np.ndarray
    source: str


@dataclass(frozen=True, eq=False)
class AveragedCurve:
    """Mean and spread of several specimens on a common strain grid.

    Attributes
    ----------
    strain : (m,) float64
        The grid of engineering strains.
    mean_MPa : (m,) float64 [MPa]
        Mean stress over the specimens covering each strain.
    sd_MPa : (m,) float64 [MPa]
        Their sample standard deviation (ddof = 1); NaN where fewer than two cover it.
    n : (m,) int64
        Number of specimens covering each strain.
    sources : tuple of str
        The specimens' sources.
    """

    strain: np.ndarray
    mean_MPa: np.ndarray
    sd_MPa: np.ndarray
    n: np.ndarray
    sources: tuple[str, ...]

    def to_csv(self, path: str | Path) -> Path:
        """Write ``strain,mean_MPa,sd_MPa,n`` (header, then one row per grid strain) atomically.

        The file reads back with :func:`read_curve` (columns ``strain`` and ``mean_MPa``).
        """
        buffer = io.StringIO()
        buffer.write("strain,mean_MPa,sd_MPa,n\n")
        for row in zip(self.strain, self.mean_MPa, self.sd_MPa, self.n):
            buffer.write(f"{row[0]:.17g},{row[1]:.17g},{row[2]:.17g},{int(row[3])}\n")
        return atomic_write_bytes(path, buffer.getvalue().encode("utf-8"))


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------
def _data_lines(path: Path, skip_rows: int) -> list[tuple[int, str]]:
    """(1-based line number, text) of the lines that carry a header or data."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as err:
        raise CurveFileError(f"{path}: cannot read the file ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise CurveFileError(f"{path}: not a UTF-8 text file") from None
    lines = [(k + 1, line) for k, line in enumerate(text.splitlines()) if k >= skip_rows]
    kept = [(k, line) for k, line in lines if line.strip() and not line.lstrip().startswith("#")]
    if not kept:
        raise CurveFileError(f"{path}: no data (the file is empty after {skip_rows} skipped rows)")
    return kept


def _split(lines: list[tuple[int, str]], delimiter: str | None) -> list[tuple[int, list[str]]]:
    """Fields of each line; the delimiter is detected from the first line when None."""
    if delimiter is None:
        first = lines[0][1]
        delimiter = next((d for d in _DELIMITERS if d in first), " ")
    if delimiter.strip() == "":
        return [(k, line.split()) for k, line in lines]
    rows = csv.reader([line for _, line in lines], delimiter=delimiter)
    return [(k, [field.strip() for field in row]) for (k, _), row in zip(lines, rows)]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _column_index(path: Path, column: int | str | None, header: list[str] | None, line: int | None,
                  defaults: tuple[str, ...], fallback: int, what: str) -> int:
    """0-based index of a column given by index, by name, or by default (module docs)."""
    if column is None:
        if header is None:
            return fallback
        lowered = [name.lower() for name in header]
        found = [lowered.index(name.lower()) for name in defaults if name.lower() in lowered]
        if found:
            return found[0]
        if len(header) == 2:
            return fallback
        raise CurveFileError(
            f"{path}, line {line}: the header has no column with a default {what} name "
            f"({', '.join(defaults)}; any case), and with {len(header)} columns "
            f"({', '.join(repr(name) for name in header)}) there is no default by position: "
            f"choose it by name or 0-based index with --{what}-column ({what}_column= in Python)"
        )
    if isinstance(column, int):
        if column < 0:
            raise CurveFileError(f"{path}: {what} column index must be >= 0, got {column}")
        return column
    if header is None:
        raise CurveFileError(f"{path}: {what} column {column!r} is a name, but the file has no header line")
    lowered = [name.lower() for name in header]
    if column.lower() not in lowered:
        raise CurveFileError(
            f"{path}, line {line}: no {what} column named {column!r} in the header "
            f"(columns: {', '.join(header)})"
        )
    return lowered.index(column.lower())


def _label(header: list[str] | None, index: int, what: str) -> str:
    """How an error message names a column: by its header name, else by its index."""
    name = repr(header[index]) if header is not None and index < len(header) else str(index)
    return f"{what} column {name}"


def _value(path: Path, line: int, fields: list[str], index: int, label: str) -> float:
    if index >= len(fields):
        raise CurveFileError(
            f"{path}, line {line}: {len(fields)} field(s), but the {label} is field {index + 1}"
        )
    text = fields[index]
    try:
        value = float(text)
    except ValueError:
        raise CurveFileError(f"{path}, line {line}: {label}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise CurveFileError(f"{path}, line {line}: {label}: {text!r} is not a finite number")
    return value


def _check_increasing(path: Path, lines: list[int], strain: np.ndarray) -> None:
    step = np.diff(strain)
    if np.any(step <= 0.0):
        k = int(np.flatnonzero(step <= 0.0)[0])
        raise CurveFileError(
            f"{path}, line {lines[k + 1]}: strain {strain[k + 1]:.6g} does not increase from "
            f"{strain[k]:.6g} on line {lines[k]} (a curve must be a monotonic loading: cut "
            "unloading parts and repeated points)"
        )


def read_curve(
    path: str | Path,
    *,
    strain_column: int | str | None = None,
    stress_column: int | str | None = None,
    percent_strain: bool = False,
    delimiter: str | None = None,
    skip_rows: int = 0,
) -> Curve:
    """Read a stress-strain curve from a CSV (or other delimited text) file.

    Parameters
    ----------
    path
        The file (format in the module docs).
    strain_column, stress_column
        0-based index or header name (any case) of the strain and stress [MPa] columns.
        Default: the header's ``strain`` column and its first of ``stress_MPa``,
        ``stress [MPa]``, ``stress (MPa)``, ``stress``, ``mean_MPa`` (any case; espin's
        ``curve.csv``, an averaged curve); columns 0 and 1 for a file without a header or
        with exactly two columns; otherwise an error listing the header's columns.
    percent_strain
        The strain column is in percent.
    delimiter
        Field separator; default detected from the first line (tab, ``;``, ``,``, else
        whitespace). ``" "`` means any run of whitespace.
    skip_rows
        Lines to skip at the top of the file before the header or data (>= 0).

    Returns
    -------
    Curve
        Strain as a fraction (percent divided by 100), stress in MPa.

    Raises
    ------
    CurveFileError
        If the file cannot be read or is empty, a column is missing or cannot be chosen by
        default, strain and stress are the same column, a value is not a finite number, or
        the strain does not increase; the message names the file and the line.
    """
    path = Path(path)
    if skip_rows < 0:
        raise CurveFileError(f"{path}: skip_rows must be >= 0, got {skip_rows}")
    rows = _split(_data_lines(path, skip_rows), delimiter)
    header_line, first = rows[0]
    header = None
    if not any(_is_number(field) for field in first):
        header = first
        rows = rows[1:]
    x_col = _column_index(path, strain_column, header, header_line, _STRAIN_NAMES, 0, "strain")
    y_col = _column_index(path, stress_column, header, header_line, _STRESS_NAMES, 1, "stress")
    if x_col == y_col:
        where = f"{path}, line {header_line}" if header is not None else str(path)
        named = header is not None and x_col < len(header)
        column = f"{header[x_col]!r} (index {x_col})" if named else f"{x_col}"
        raise CurveFileError(
            f"{where}: strain and stress would both be read from column {column}; they must be "
            "different columns: give --strain-column and --stress-column (strain_column= and "
            "stress_column= in Python)"
        )
    if len(rows) < 2:
        raise CurveFileError(f"{path}: {len(rows)} data line(s); a curve needs at least 2")
    x_label, y_label = _label(header, x_col, "strain"), _label(header, y_col, "stress")
    lines = [line for line, _ in rows]
    points = [(_value(path, k, fields, x_col, x_label), _value(path, k, fields, y_col, y_label))
              for k, fields in rows]
    strain, stress = np.array(points).T
    _check_increasing(path, lines, strain)
    if percent_strain:
        strain = strain / 100.0
    return Curve(strain=strain, stress_MPa=stress, source=str(path))


# --------------------------------------------------------------------------------------------
# Averaging
# --------------------------------------------------------------------------------------------
def _default_grid(curves: Sequence[Curve], n_points: int) -> np.ndarray:
    start = max(0.0, max(float(c.strain[0]) for c in curves))
    end = min(float(c.strain[-1]) for c in curves)
    if end <= start:
        shortest = min(curves, key=lambda c: c.strain[-1])
        raise CurveFileError(
            f"the specimens share no strain range: {shortest.source} ends at strain {end:.6g}, "
            f"before {start:.6g} where the last of them starts"
        )
    return np.linspace(start, end, n_points)


_SAME_STRAIN = 1e-9
"""Relative tolerance (of the largest strain) under which two measured strains are one."""


def _shared_strains(curves: Sequence[Curve]) -> bool:
    """Whether every specimen was measured at the same strains (to ``_SAME_STRAIN``)."""
    first = np.asarray(curves[0].strain, dtype=float)
    scale = max(float(np.max(np.abs(c.strain))) for c in curves) or 1.0
    return all(len(c.strain) == len(first) and np.allclose(c.strain, first, rtol=0.0, atol=_SAME_STRAIN * scale)
               for c in curves[1:])


def _measured_grid(curves: Sequence[Curve]) -> np.ndarray:
    """The union of the specimens' strains within their common strain range (strains closer
    than ``_SAME_STRAIN`` merged)."""
    scale = max(float(np.max(np.abs(c.strain))) for c in curves) or 1.0
    span = _default_grid(curves, 2)  # the common range (and its error when there is none)
    union = np.unique(np.concatenate([np.asarray(c.strain, dtype=float) for c in curves]))
    union = union[(union >= span[0] - _SAME_STRAIN * scale) & (union <= span[-1] + _SAME_STRAIN * scale)]
    keep = np.concatenate([[True], np.diff(union) > _SAME_STRAIN * scale])
    return np.clip(union[keep], span[0], span[-1])


def average_curves(
    curves: Sequence[Curve], grid: ArrayLike | str | None = None, n_points: int = 101
) -> AveragedCurve:
    """Mean, sample sd and count of several specimens' stress on a common strain grid.

    Parameters
    ----------
    curves
        The specimens (at least one).
    grid : (m,) array_like or "measured", optional
        Increasing strains to average at; default ``n_points`` strains from 0 (or the latest
        first strain) to the smallest last strain of the specimens. ``"measured"``: the
        specimens' own strains, their common strains when they all share them (to a relative
        1e-9), else the union of their strains within the common range.
    n_points
        Size of the default grid (>= 2).

    Returns
    -------
    AveragedCurve

    Raises
    ------
    CurveFileError
        If there are no curves, the specimens share no strain range (default grid), or a grid
        strain lies outside every specimen.
    """
    if not curves:
        raise CurveFileError("no curves to average")
    if isinstance(grid, str):
        if grid != "measured":
            raise CurveFileError(f'grid must be strains or "measured", got {grid!r}')
        if _shared_strains(curves):  # no interpolation: the measured values themselves
            stress = np.array([c.stress_MPa for c in curves], dtype=float)
            return _averaged(np.array(curves[0].strain, dtype=float), stress, curves)
        strain = _measured_grid(curves)
    elif grid is None:
        if n_points < 2:
            raise CurveFileError(f"n_points must be >= 2, got {n_points}")
        strain = _default_grid(curves, n_points)
    else:
        strain = np.asarray(grid, dtype=float).ravel()
        if len(strain) < 1 or not np.all(np.isfinite(strain)) or np.any(np.diff(strain) <= 0):
            raise CurveFileError("the averaging grid must be finite, increasing strains")
    stress = np.full((len(curves), len(strain)), np.nan)
    for row, curve in zip(stress, curves):
        covered = (strain >= curve.strain[0]) & (strain <= curve.strain[-1])
        row[covered] = np.interp(strain[covered], curve.strain, curve.stress_MPa)
    return _averaged(strain, stress, curves)


def _averaged(strain: np.ndarray, stress: np.ndarray, curves: Sequence[Curve]) -> AveragedCurve:
    """Mean, sd and count of the (specimens, strains) stress table (NaN: not covered)."""
    covered = np.isfinite(stress)
    n = covered.sum(axis=0)
    if np.any(n == 0):
        outside = strain[n == 0][0]
        raise CurveFileError(f"grid strain {outside:.6g} lies outside every specimen's strain range")
    values = np.where(covered, stress, 0.0)
    mean = values.sum(axis=0) / n
    squares = np.where(covered, (stress - mean) ** 2, 0.0).sum(axis=0)
    sd = np.sqrt(squares / np.maximum(n - 1, 1))
    sd[n < 2] = np.nan
    return AveragedCurve(strain=strain, mean_MPa=mean, sd_MPa=sd, n=n.astype(np.int64),
                         sources=tuple(c.source for c in curves))
