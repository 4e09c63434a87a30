"""Experimental stress-strain curves from text tables (CSV) or .xlsx workbooks, and the average
of several specimens.

File format
-----------
A text table, one point per line: any number of columns, separated by commas, semicolons,
tabs or whitespace (detected from the first line unless ``delimiter`` is given: a tab or ``;``
in it, else whitespace when its fields are all decimal-comma numbers such as ``0,01 1,5``, else
``,`` when it has one, else whitespace). Text may be UTF-8 (with or without a byte-order mark),
UTF-16 with a byte-order mark, or Latin-1 (read when the bytes are not UTF-8: instrument
exports). A file named ``.xlsx`` / ``.xlsm`` is read from its first sheet, one point per row
(needs the optional ``openpyxl``: ``pip install "espin[xlsx]"``); errors then name the row.
Blank lines and lines starting with ``#`` are ignored, as are the first ``skip_rows`` lines
(an instrument's preamble). The first remaining line is a header when none of its fields is
a number; columns can then be chosen by name as well as by 0-based index. Strain is
engineering strain (0.01 = 1 %; ``percent_strain=True`` reads percent), stress is in MPa. The
strain must increase from line to line (a monotonic loading: cut unloading parts and repeated
points), reach above 0, and the stress must be positive somewhere (a tensile curve).

Decimal mark: ``.`` unless ``decimal=","`` is given or detected; a decimal comma is detected
when the separator is not ``,`` and the strain and stress fields hold commas but no point
(``0,01;1,5``). A thousands separator is not supported (stresses in MPa and strains need none).

Without explicit columns, default names are looked for in the header, case-insensitively:
``strain`` for the strain, and for the stress the first of ``stress_MPa`` (espin's own
``curve.csv``), ``stress [MPa]``, ``stress (MPa)``, ``stress`` and ``mean_MPa`` (an averaged
curve written by :meth:`AveragedCurve.to_csv`). A column not found by name is column 0
(strain) or 1 (stress) only when the file has no header or exactly two columns; a header with
more columns and no default name is an error listing its columns (choose them with
``strain_column`` / ``stress_column``, ``--strain-column`` / ``--stress-column`` on the command
line). Strain and stress resolving to the same column is an error.

Limits, checked before the data are parsed: a file (or a workbook's unpacked contents) of at
most :data:`MAX_FILE_BYTES` (64 MiB), at most :data:`MAX_DATA_ROWS` (250,000) points, lines of
at most :data:`MAX_LINE_CHARS` (4096) characters, values of magnitude at most
:data:`MAX_MAGNITUDE` (1e12); directories, devices and pipes are refused.

A bad file raises :class:`CurveFileError` naming the file, the line and the column, and the
format expected. Messages show a field of the file only when it is short (at most 20
printable characters): they never echo a file's contents.

Units that look wrong give a :class:`CurveWarning` naming the file: a strain column read as
fractions whose largest strain exceeds 1 (100 %, what a percent column read as fractions looks
like; few mats stretch that far in a tensile test) or whose header says percent; a strain
column read as percent (``percent_strain``) that ends at 1 % or less; a strain header with a
length unit; a stress header with a unit other than MPa; a stress above 10^4 MPa (10 GPa,
stronger than any fiber mat: probably Pa or kPa).

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
to the average then weighs the points that were measured, not an arbitrary grid. Specimens
whose largest strains differ by a factor of :data:`UNIT_MISMATCH_RATIO` (20) or more are
refused: a factor of 100 is the mark of percent mixed with fractions, and specimens of one
mat differ by a few.
"""

from __future__ import annotations

import csv
import io
import math
import re
import warnings
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from espin.core.atomic import atomic_write_bytes
from espin.core.errors import ConfigError, InputError
from espin.core.textfiles import (
    TextFormat,
    check_file,
    decode,
    read_bytes,
    showable,
    shown,
    shown_names,
    text_lines,
    too_large,
)

__all__ = [
    "CurveFileError",
    "CurveWarning",
    "Curve",
    "AveragedCurve",
    "read_curve",
    "average_curves",
    "MAX_FILE_BYTES",
    "MAX_DATA_ROWS",
    "MAX_LINE_CHARS",
    "MAX_MAGNITUDE",
    "UNIT_MISMATCH_RATIO",
]

MAX_FILE_BYTES = 64 * 2**20
"""Largest curve file read [bytes], and largest unpacked size of an .xlsx workbook: 64 MiB. A
tensile test of 10^5 points takes a few MB; a larger file is refused before it is read."""

MAX_DATA_ROWS = 250_000
"""Most points in one curve: 2.5 times the ~10^5 of a long, finely sampled tensile test. The
bilinear fit of ``espin properties`` takes ~3 s per 10^5 points, so a larger curve is refused
rather than fitted for minutes (thin it out: keep every k-th line)."""

MAX_LINE_CHARS = 4096
"""Longest line of a text table [characters]; a point is a few numbers."""

MAX_MAGNITUDE = 1e12
"""Largest magnitude of a strain or a stress [MPa] read; beyond it a value is no measurement."""

UNIT_MISMATCH_RATIO = 20.0
"""Averaging refuses specimens whose largest strains differ by this factor or more."""

_LARGE_STRESS_MPA = 1e4
"""A stress above this [MPa] (10 GPa) is warned about as probably in Pa or kPa."""

_STRAIN_NAMES = ("strain",)
_STRESS_NAMES = ("stress_MPa", "stress [MPa]", "stress (MPa)", "stress", "mean_MPa")
_WORKBOOK_SUFFIXES = (".xlsx", ".xlsm")
_EXPECTED = (
    "expected a text table (CSV: one point per line, strain and stress [MPa] as numbers; "
    "UTF-8, UTF-16 with byte-order mark or Latin-1) or an .xlsx workbook"
)
_DECIMAL_COMMA = re.compile(r"[+-]?(\d+,\d*|,\d+)([eE][+-]?\d+)?")
_UNIT = re.compile(r"[\[(]\s*([^\])]*?)\s*[\])]|_([^_\s]+)$")
_LENGTH_UNITS = ("mm", "m", "cm", "um", "µm", "μm", "in")
_OTHER_STRESS_UNITS = {
    "pa": "Pa",
    "kpa": "kPa",
    "gpa": "GPa",
    "psi": "psi",
    "ksi": "ksi",
    "n": "N, a force",
    "kn": "kN, a force",
    "lbf": "lbf, a force",
}


class CurveFileError(InputError):
    """A curve file cannot be read (the message names the file, line and column), or curves
    cannot be averaged."""


class CurveWarning(UserWarning):
    """A curve was read, but its units look wrong, or it is the partial curve of a run that has
    not completed (the message names the file and the fix)."""


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
# Reading: the file, its lines (or a workbook's rows) and their fields
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Table:
    """The kept lines (or workbook rows) of a curve file, split into fields."""

    path: Path
    numbers: list[int]  # 1-based line (row) number of each kept line
    rows: list[list[str]]
    separator: str | None  # the text's field separator; None for a workbook

    def at(self, k: int) -> str:
        """``file, line N`` of kept line ``k`` (``row N`` in a workbook)."""
        return f"{self.path}, {'row' if self.separator is None else 'line'} {self.numbers[k]}"

    def cell(self, k: int, column: int) -> str:
        """``file, line N, field M`` (``row N, column X`` in a workbook) of a field."""
        if self.separator is None:
            return f"{self.at(k)}, column {_column_letters(column)}"
        return f"{self.at(k)}, field {column + 1}"


def _column_letters(index: int) -> str:
    """A spreadsheet's name of the 0-based column ``index`` (0 -> A, 26 -> AA)."""
    letters = ""
    index += 1
    while index:
        index, rest = divmod(index - 1, 26)
        letters = chr(ord("A") + rest) + letters
    return letters


def _format() -> TextFormat:
    """What a curve file is, with the module's limits as they are now."""
    return TextFormat(
        what="curve file",
        expected=_EXPECTED,
        max_bytes=MAX_FILE_BYTES,
        max_line_chars=MAX_LINE_CHARS,
        error=CurveFileError,
        size_hint=(
            "a tensile test of 10^5 points takes a few MB; is this the curve? thin it out "
            "(keep every k-th line) or cut it"
        ),
        line_hint="one point, a few numbers, per line; is this the curve file?",
    )


def _too_many_points(path: Path) -> CurveFileError:
    return CurveFileError(
        f"{path}: more than {MAX_DATA_ROWS:,} data lines, the limit for one curve (a tensile "
        "test has up to ~10^5 points): thin it out (keep every k-th line)"
    )


def _no_data(path: Path, skip_rows: int) -> CurveFileError:
    return CurveFileError(
        f"{path}: no data (the file is empty after {skip_rows} skipped rows "
        f"and its blank and # comment lines); {_EXPECTED}"
    )


def _check_options(delimiter: str | None, decimal: str | None, skip_rows: int) -> None:
    """Refuse option values that cannot describe a curve table (ConfigError: usage)."""
    if isinstance(skip_rows, bool) or not isinstance(skip_rows, int) or skip_rows < 0:
        raise ConfigError(f"skip_rows (--skip-rows): an integer >= 0 (got {skip_rows!r})")
    odd = delimiter is not None and (len(delimiter) != 1 or delimiter.isalnum() or delimiter in '.+-"#\r\n')
    if odd:
        raise ConfigError(
            "delimiter (--delimiter): one character such as ',', ';', tab or ' ' (any run of "
            f"whitespace), not a letter, digit, sign, '.', '\"' or '#' (got {delimiter!r})"
        )
    if decimal not in (None, ".", ","):
        raise ConfigError(f"decimal (--decimal): '.' or ',' (got {decimal!r})")
    if decimal is not None and decimal == delimiter:
        raise ConfigError(f"decimal and delimiter are both {decimal!r}; they must differ")


def _refuse_workbooks(path: Path, data: bytes) -> None:
    """Refuse a workbook's bytes in a file not named .xlsx (the fix: rename it, or save as CSV)."""
    if data.startswith(b"PK\x03\x04"):
        raise CurveFileError(
            f"{path}: a zip archive (an Excel workbook?): name it .xlsx to read "
            "its first sheet, or save the sheet as CSV"
        )
    if data.startswith(b"\xd0\xcf\x11\xe0"):
        raise CurveFileError(
            f"{path}: an old-format Excel (.xls) or other OLE2 file, which espin "
            "does not read: save the sheet as .xlsx or CSV"
        )


def _text_lines(path: Path, fmt: TextFormat, skip_rows: int) -> tuple[list[int], list[str]]:
    """Numbers (1-based) and text of the lines after ``skip_rows`` that are not blank or comments."""
    data = read_bytes(path, fmt)
    _refuse_workbooks(path, data)
    numbers: list[int] = []
    lines: list[str] = []
    for number, line in text_lines(path, decode(path, data, fmt), fmt, skip_rows=skip_rows):
        if len(lines) > MAX_DATA_ROWS:  # a header and MAX_DATA_ROWS points already
            raise _too_many_points(path)
        numbers.append(number)
        lines.append(line)
    if not lines:
        raise _no_data(path, skip_rows)
    return numbers, lines


def _separator(first: str, decimal: str | None) -> str:
    """The field separator, from the first line (rule in the module docs)."""
    for candidate in ("\t", ";"):
        if candidate in first:
            return candidate
    fields = first.split()
    if decimal == "," or (len(fields) > 1 and all(_DECIMAL_COMMA.fullmatch(f) for f in fields)):
        return " "
    return "," if "," in first else " "


def _separator_name(separator: str) -> str:
    return {"\t": "tabs", " ": "whitespace"}.get(separator, repr(separator))


def _fields(path: Path, numbers: list[int], lines: list[str], separator: str) -> list[list[str]]:
    """Each line's fields (whitespace: any run of it; else CSV, quotes allowed within a line)."""
    if separator == " ":
        return [line.split() for line in lines]
    rows: list[list[str]] = []
    reader = csv.reader(lines, delimiter=separator, skipinitialspace=True)
    try:
        for fields in reader:
            if reader.line_num != len(rows) + 1:  # the row took in the next line(s)
                break
            rows.append([field.strip() for field in fields])
    except csv.Error:
        pass  # reported below, at the line where it happened
    if len(rows) < len(lines):
        raise CurveFileError(
            f"{path}, line {numbers[len(rows)]}: a quoted field does not end on its "
            "line (an unbalanced '\"'); expected one point per line"
        )
    return rows


def _read_text(path: Path, fmt: TextFormat, skip_rows: int, delimiter: str | None, decimal: str | None) -> _Table:
    numbers, lines = _text_lines(path, fmt, skip_rows)
    separator = delimiter or _separator(lines[0], decimal)
    return _Table(path, numbers, _fields(path, numbers, lines, separator), separator)


def _check_unpacked_size(path: Path, fmt: TextFormat) -> None:
    """Refuse a workbook whose contents unpack to more than MAX_FILE_BYTES (a zip bomb)."""
    try:
        with zipfile.ZipFile(path) as archive:
            unpacked = sum(item.file_size for item in archive.infolist())
    except (zipfile.BadZipFile, OSError, EOFError, ValueError):
        raise CurveFileError(
            f"{path}: not a readable .xlsx workbook (not a zip archive); expected an "
            "Excel workbook with the curve on its first sheet"
        ) from None
    if unpacked > MAX_FILE_BYTES:
        raise too_large(path, fmt, f"{unpacked:,} bytes unpacked")


def _excel_frame(path: Path) -> pd.DataFrame:
    """The first sheet, every cell as read, empty ones as "" and no text taken for NaN (row index
    0 is the sheet's row 1)."""
    try:
        return pd.read_excel(path, sheet_name=0, header=None, dtype=object, na_filter=False, engine="openpyxl")
    except ImportError:
        raise CurveFileError(
            f"{path}: reading an .xlsx workbook needs the optional package openpyxl: "
            'pip install "espin[xlsx]" (or save the sheet as CSV)'
        ) from None
    except Exception as err:  # noqa: BLE001 - any failure of the workbook parser is a bad file
        raise CurveFileError(
            f"{path}: not a readable .xlsx workbook ({type(err).__name__}); expected "
            "an Excel workbook with the curve on its first sheet"
        ) from None


def _cell(value: object) -> str:
    """A workbook cell as a field: empty, or its value as text (a number exactly: repr)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return str(value).strip()


def _read_workbook(path: Path, fmt: TextFormat, skip_rows: int) -> _Table:
    _check_unpacked_size(path, fmt)
    numbers: list[int] = []
    rows: list[list[str]] = []
    for number, values in enumerate(_excel_frame(path).itertuples(index=False, name=None), start=1):
        fields = [_cell(value) for value in values]
        while fields and not fields[-1]:
            fields.pop()
        if number <= skip_rows or not fields or next(f for f in fields if f).startswith("#"):
            continue
        if len(rows) > MAX_DATA_ROWS:
            raise _too_many_points(path)
        numbers.append(number)
        rows.append(fields)
    if not rows:
        raise _no_data(path, skip_rows)
    return _Table(path, numbers, rows, None)


def _read_table(path: Path, delimiter: str | None, decimal: str | None, skip_rows: int) -> _Table:
    """The kept lines of a text table or the kept rows of a workbook's first sheet."""
    fmt = _format()
    check_file(path, fmt)
    if path.suffix.lower() in _WORKBOOK_SUFFIXES:
        return _read_workbook(path, fmt, skip_rows)
    return _read_text(path, fmt, skip_rows, delimiter, decimal)


# --------------------------------------------------------------------------------------------
# Reading: the header, the columns and their values
# --------------------------------------------------------------------------------------------
def _is_number(text: str, comma: bool) -> bool:
    try:
        float(text.replace(",", ".") if comma else text)
    except ValueError:
        return False
    return True


def _split_header(table: _Table) -> tuple[list[str] | None, list[int]]:
    """The header (the first line when none of its fields is a number) and the data lines."""
    comma = table.separator != ","
    if any(_is_number(field, comma) for field in table.rows[0]):
        return None, list(range(len(table.rows)))
    return table.rows[0], list(range(1, len(table.rows)))


def _column_index(
    table: _Table,
    column: int | str | None,
    header: list[str] | None,
    defaults: tuple[str, ...],
    fallback: int,
    what: str,
) -> int:
    """0-based index of a column given by index, by name, or by default (module docs)."""
    if column is None:
        if header is None:
            return fallback
        lowered = [name.lower() for name in header]
        found = [name.lower() for name in defaults if name.lower() in lowered]
        if found:
            return _only(table, lowered, found[0], what)
        if len(header) == 2:
            return fallback
        raise CurveFileError(
            f"{table.at(0)}: the header has no column with a default {what} name "
            f"({', '.join(defaults)}; any case), and with {len(header)} column{'s' * (len(header) != 1)} "
            f"({shown_names(header)}) there is no default by position: "
            f"choose it by name or 0-based index with --{what}-column ({what}_column= in Python)"
        )
    if isinstance(column, int):
        if column < 0:
            raise ConfigError(f"{what}_column (--{what}-column): an index must be >= 0, got {column}")
        return column
    if header is None:
        raise CurveFileError(
            f"{table.path}: {what} column {column!r} is a name, but the file has no "
            "header line (a first line without numbers)"
        )
    lowered = [name.lower() for name in header]
    if column.lower() not in lowered:
        raise CurveFileError(
            f"{table.at(0)}: no {what} column named {column!r} in the header (columns: {shown_names(header)})"
        )
    return _only(table, lowered, column.lower(), what)


def _only(table: _Table, lowered: list[str], name: str, what: str) -> int:
    """The index of the one column called ``name``; a name given to several columns is an error."""
    indices = [k for k, found in enumerate(lowered) if found == name]
    if len(indices) > 1:
        raise CurveFileError(
            f"{table.at(0)}: the header names columns {', '.join(str(k) for k in indices)} "
            f"alike ({shown(name, 'name')}, any case): choose the {what} column by 0-based "
            f"index with --{what}-column ({what}_column= in Python)"
        )
    return indices[0]


def _label(header: list[str] | None, index: int, what: str) -> str:
    """How a message names a column: by its header name when short, else by its index."""
    if header is not None and index < len(header) and header[index] and showable(header[index]):
        return f"{what} column {header[index]!r}"
    return f"{what} column {index}"


def _columns(
    table: _Table, header: list[str] | None, strain_column: int | str | None, stress_column: int | str | None
) -> list[tuple[int, str]]:
    """(index, label) of the strain and the stress column."""
    x_col = _column_index(table, strain_column, header, _STRAIN_NAMES, 0, "strain")
    y_col = _column_index(table, stress_column, header, _STRESS_NAMES, 1, "stress")
    if x_col == y_col:
        where = table.at(0) if header is not None else str(table.path)
        named = header is not None and x_col < len(header)
        column = f"{shown(header[x_col], 'name')} (index {x_col})" if named and header is not None else f"{x_col}"
        raise CurveFileError(
            f"{where}: strain and stress would both be read from column {column}; they must be "
            "different columns: give --strain-column and --stress-column (strain_column= and "
            "stress_column= in Python)"
        )
    return [(x_col, _label(header, x_col, "strain")), (y_col, _label(header, y_col, "stress"))]


def _check_fields(table: _Table, data: list[int], columns: list[tuple[int, str]]) -> None:
    """Every data line has the strain and the stress field."""
    need = max(col for col, _ in columns)
    short = next((k for k in data if len(table.rows[k]) <= need), None)
    if short is None:
        return
    fields = table.rows[short]
    col, label = next((col, label) for col, label in columns if col >= len(fields))
    if table.separator is None:
        raise CurveFileError(f"{table.cell(short, col)} ({label}): empty; expected a number")
    raise CurveFileError(
        f"{table.at(short)}: {len(fields)} field(s) separated by "
        f"{_separator_name(table.separator)}, but the {label} is field {col + 1}"
    )


def _decimal(table: _Table, data: list[int], columns: list[tuple[int, str]], given: str | None) -> str:
    """The decimal mark: given, else ',' when the fields have commas and no point (not in CSV)."""
    if given is not None:
        return given
    if table.separator == ",":
        return "."
    texts = [table.rows[k][col] for k in data for col, _ in columns]
    return "," if any("," in t for t in texts) and not any("." in t for t in texts) else "."


def _why_not_a_value(text: str, value: float, decimal: str) -> str:
    """Why a field is not a usable strain or stress (NaN ``value``: not a number)."""
    quoted = shown(text)
    word = text.lstrip("+-").lower()
    if not text:
        return "empty; expected a number such as 0.012 or 1.2e-2"
    if math.isnan(value):
        if word == "nan":
            return f"{quoted} is not a finite number (NaN)"
        hint = (
            ("; a decimal comma? every value must use the same decimal mark (decimal=',', --decimal ,)")
            if decimal == "." and "," in text
            else ""
        )
        return f"{quoted} is not a number (expected e.g. 0.012 or 1.2e-2{hint})"
    if math.isinf(value) and word in ("inf", "infinity"):
        return f"{quoted} is not a finite number"
    return f"{quoted} is out of range: a strain or a stress [MPa] has a magnitude of at most {MAX_MAGNITUDE:g}"


def _numbers(table: _Table, data: list[int], columns: list[tuple[int, str]], decimal: str) -> list[np.ndarray]:
    """The columns' values on the data lines; the earliest bad field is an error."""
    parsed, bad_fields = [], []
    for col, label in columns:
        texts = [table.rows[k][col] for k in data]
        numbers = [t.replace(",", ".") for t in texts] if decimal == "," else texts
        values = pd.to_numeric(pd.Series(numbers, dtype=object), errors="coerce").to_numpy(dtype=float)
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~(np.abs(values) <= MAX_MAGNITUDE))
        if bad.size:
            i = int(bad[0])
            bad_fields.append((i, col, label, texts[i], float(values[i])))
        parsed.append(values)
    if bad_fields:
        i, col, label, text, value = min(bad_fields, key=lambda bad_field: bad_field[0])
        why = _why_not_a_value(text, value, decimal)
        raise CurveFileError(f"{table.cell(data[i], col)} ({label}): {why}")
    return parsed


def _check_increasing(table: _Table, data: list[int], strain: np.ndarray) -> None:
    step = np.diff(strain)
    if np.any(step <= 0.0):
        k = int(np.flatnonzero(step <= 0.0)[0])
        raise CurveFileError(
            f"{table.at(data[k + 1])}: strain {strain[k + 1]:.6g} does not increase from "
            f"{strain[k]:.6g} on {'row' if table.separator is None else 'line'} "
            f"{table.numbers[data[k]]} (a curve must be a monotonic loading: cut unloading parts "
            "and repeated points)"
        )


def _check_tensile(path: Path, strain: np.ndarray, stress: np.ndarray, columns: list[tuple[int, str]]) -> None:
    """A tensile curve: the strain rises above 0 and the stress is positive somewhere."""
    (_, x_label), (_, y_label) = columns
    if strain[-1] <= 0.0:
        raise CurveFileError(
            f"{path}: the {x_label} never rises above 0 (it ends at {strain[-1]:.6g}); expected a "
            "tensile curve, strain increasing from about 0 (the wrong column, or a compression test?)"
        )
    if not np.any(stress > 0.0):
        raise CurveFileError(
            f"{path}: no positive stress in the {y_label} (all {stress.size} values are <= 0); "
            "expected a tensile curve, stress [MPa] positive in tension (the wrong column, or "
            "compression counted positive?)"
        )


def _unit(name: str) -> str:
    """The unit a header name gives (``Stress [MPa]``, ``stress (kPa)``, ``load_N``), lower case."""
    match = _UNIT.search(name)
    if match is None:
        return ""
    return (match.group(1) or match.group(2) or "").lower().replace(" ", "")


def _unit_warnings(
    path: Path,
    header: list[str] | None,
    columns: list[tuple[int, str]],
    strain: np.ndarray,
    stress: np.ndarray,
    percent: bool,
) -> list[str]:
    """Why the units of a curve as read (``strain`` in the file's units) look wrong."""
    (x_col, x_label), (y_col, y_label) = columns
    x_name = header[x_col] if header is not None and x_col < len(header) else ""
    y_name = header[y_col] if header is not None and y_col < len(header) else ""
    says_percent = "%" in x_name or "percent" in x_name.lower()
    largest = float(strain[-1])
    found = []
    if not percent and (largest > 1.0 or says_percent):
        why = (
            f"its largest strain is {largest:.4g}, i.e. {100 * largest:.4g} % (few mats stretch "
            "beyond 100 % in a tensile test)"
            if largest > 1.0
            else "the header names it in percent"
        )
        found.append(
            f"{path}: the {x_label} is read as a fraction (0.01 = 1 %), but {why}: if it "
            "is in percent, pass --percent-strain (percent_strain=True)"
        )
    if percent and largest <= 1.0 and not says_percent:
        found.append(
            f"{path}: the {x_label} is read as percent (--percent-strain), so the curve ends "
            f"at {largest:.4g} % strain: if it holds fractions (0.01 = 1 %), leave "
            "--percent-strain out"
        )
    if _unit(x_name) in _LENGTH_UNITS:
        found.append(
            f"{path}: the {x_label} is labelled in {_unit(x_name)}, a length: espin reads "
            "engineering strain (extension / gauge length)"
        )
    if _unit(y_name) in _OTHER_STRESS_UNITS:
        found.append(
            f"{path}: the {y_label} is labelled in {_OTHER_STRESS_UNITS[_unit(y_name)]}, "
            "but espin reads stress in MPa: convert the column"
        )
    peak = float(np.max(np.abs(stress)))
    if peak > _LARGE_STRESS_MPA:
        found.append(
            f"{path}: stresses up to {peak:.4g} MPa in the {y_label}, over 10 GPa (no fiber "
            "mat is that strong): is it in Pa or kPa? espin reads MPa"
        )
    return found


def _partial(path: Path) -> list[str]:
    """A warning for the ``curve.csv`` of an espin run whose ``run.json`` is not ``complete``."""
    from espin.core.errors import ConfigError
    from espin.core.output_folder import read_manifest

    try:
        manifest = read_manifest(path.parent)
    except ConfigError:
        return []
    if manifest is None or not manifest.partial:
        return []
    return [
        f"{path}: a partial result: its folder's run.json says the run is {manifest.status} "
        "(killed, failed or still going)"
    ]


def read_curve(
    path: str | Path,
    *,
    strain_column: int | str | None = None,
    stress_column: int | str | None = None,
    percent_strain: bool = False,
    delimiter: str | None = None,
    skip_rows: int = 0,
    decimal: str | None = None,
) -> Curve:
    """Read a stress-strain curve from a CSV (or other delimited text) file or an .xlsx workbook.

    Parameters
    ----------
    path
        The file (format, encodings and limits in the module docs); ``.xlsx`` / ``.xlsm``: the
        first sheet of a workbook (needs ``pip install "espin[xlsx]"``).
    strain_column, stress_column
        0-based index or header name (any case) of the strain and stress [MPa] columns.
        Default: the header's ``strain`` column and its first of ``stress_MPa``,
        ``stress [MPa]``, ``stress (MPa)``, ``stress``, ``mean_MPa`` (any case; espin's
        ``curve.csv``, an averaged curve); columns 0 and 1 for a file without a header or
        with exactly two columns; otherwise an error listing the header's columns.
    percent_strain
        The strain column is in percent.
    delimiter
        Field separator of a text table, one character; default detected from the first line
        (tab, ``;``, ``,``, else whitespace). ``" "`` means any run of whitespace.
    skip_rows
        Lines (rows) to skip at the top of the file before the header or data (>= 0).
    decimal
        Decimal mark, ``"."`` or ``","``; default ``","`` when the separator is not ``,`` and
        the strain and stress fields hold commas but no point, else ``"."``.

    Returns
    -------
    Curve
        Strain as a fraction (percent divided by 100), stress in MPa.

    Raises
    ------
    CurveFileError
        If the file is not a regular file, is over a limit, is binary or cannot be read, is
        empty, a column is missing or cannot be chosen by default, strain and stress are the
        same column, a value is not a number, not finite or out of range, the strain does not
        increase or never exceeds 0, or no stress is positive; the message names the file and
        the line (and field) and never shows more than 20 characters of the file.
    ConfigError
        If ``delimiter``, ``decimal``, ``skip_rows`` or a column index is not a valid value.

    Warns
    -----
    CurveWarning
        If the units look wrong (module docs): probably percent read as fractions or the
        reverse, a length for the strain, a stress unit other than MPa, a stress above 10 GPa;
        or if the file lies in an espin results folder whose ``run.json`` is not complete.
    """
    path = Path(path)
    _check_options(delimiter, decimal, skip_rows)
    table = _read_table(path, delimiter, decimal, skip_rows)
    header, data = _split_header(table)
    columns = _columns(table, header, strain_column, stress_column)
    if len(data) < 2:
        raise CurveFileError(f"{path}: {len(data)} data line(s); a curve needs at least 2")
    if len(data) > MAX_DATA_ROWS:
        raise _too_many_points(path)
    _check_fields(table, data, columns)
    strain, stress = _numbers(table, data, columns, _decimal(table, data, columns, decimal))
    _check_increasing(table, data, strain)
    _check_tensile(path, strain, stress, columns)
    for message in [*_unit_warnings(path, header, columns, strain, stress, percent_strain), *_partial(path)]:
        warnings.warn(message, CurveWarning, stacklevel=2)
    if percent_strain:
        strain = strain / 100.0
    return Curve(strain=strain, stress_MPa=stress, source=str(path))


# --------------------------------------------------------------------------------------------
# Averaging
# --------------------------------------------------------------------------------------------
def _check_same_units(curves: Sequence[Curve]) -> None:
    """Refuse specimens whose largest strains differ by UNIT_MISMATCH_RATIO or more."""
    short = [c.source for c in curves if np.size(c.strain) < 2]
    if short:
        raise CurveFileError(f"{short[0]}: a curve needs at least 2 points to be averaged")
    ends = [(float(np.max(c.strain)), c.source) for c in curves]
    positive = [end for end in ends if end[0] > 0.0]
    if len(positive) < 2:
        return
    (low, low_source), (high, high_source) = min(positive), max(positive)
    if high >= UNIT_MISMATCH_RATIO * low:
        raise CurveFileError(
            f"the specimens' strain ranges differ by a factor of {high / low:.3g}: {high_source} "
            f"ends at strain {high:.4g}, {low_source} at {low:.4g}. A factor near 100 means some "
            "curves are in percent and others in fractions: read them all in the same units "
            "(--percent-strain applies to every file); specimens of one mat differ by a few, so "
            f"a factor of {UNIT_MISMATCH_RATIO:g} or more is refused (leave the short one out)"
        )


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
    return all(
        len(c.strain) == len(first) and np.allclose(c.strain, first, rtol=0.0, atol=_SAME_STRAIN * scale)
        for c in curves[1:]
    )


def _measured_grid(curves: Sequence[Curve]) -> np.ndarray:
    """The union of the specimens' strains within their common strain range (strains closer
    than ``_SAME_STRAIN`` merged)."""
    scale = max(float(np.max(np.abs(c.strain))) for c in curves) or 1.0
    span = _default_grid(curves, 2)  # the common range (and its error when there is none)
    union = np.unique(np.concatenate([np.asarray(c.strain, dtype=float) for c in curves]))
    union = union[(union >= span[0] - _SAME_STRAIN * scale) & (union <= span[-1] + _SAME_STRAIN * scale)]
    keep = np.concatenate([[True], np.diff(union) > _SAME_STRAIN * scale])
    return np.clip(union[keep], span[0], span[-1])


def average_curves(curves: Sequence[Curve], grid: ArrayLike | str | None = None, n_points: int = 101) -> AveragedCurve:
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
        If there are no curves, a curve has fewer than 2 points, the specimens' largest strains
        differ by a factor of ``UNIT_MISMATCH_RATIO`` (20) or more (percent mixed with
        fractions?), the specimens share no strain range (default grid), or a grid strain lies
        outside every specimen.
    """
    if not curves:
        raise CurveFileError("no curves to average")
    _check_same_units(curves)
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
    return AveragedCurve(
        strain=strain, mean_MPa=mean, sd_MPa=sd, n=n.astype(np.int64), sources=tuple(c.source for c in curves)
    )
