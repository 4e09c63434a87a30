"""Macroscopic loading programs: tests, segments, steps (docs/model.md section 6).

A test is defined in the loading frame, whose axes are those of the RVE rotated by
``direction_deg``; the deformation gradient applied to the RVE is F = R F' R^T. A program is a
sequence of segments (load to a strain at a rate, or hold) cut into steps. Each step knows its
time, its load parameter ("strain") and the prescribed part of F. Mixed control (uniaxial
with a free lateral side) adds unknown components of F: F = F_prescribed + sum_k f_k G_k, with
the conjugate stress components P : G_k = 0 as extra equations; a lateral stress target
(``lateral = {stress_MPa = s}``) frees F'22 alone, with P'22 = s (nominal) or P'22 = s / F'22
(Kirchhoff, tau'22 = P'22 F'22 = s) as its equation (:class:`LateralStress`).

The load parameter s is the engineering strain F'11 - 1 for ``uniaxial``, lambda - 1 for
``equibiaxial`` (F = lambda I) and ``pure_shear`` (F' = diag(lambda, 1 / lambda)), the
shear gamma for ``simple_shear`` (F' = [[1, gamma], [0, 1]]), and the time for ``path``.

Tables
------
``loading.path_csv`` (columns ``time_s, F11, F12, F21, F22``; time in s) and
``loading.lateral.transverse_csv`` (columns ``axial_strain, transverse_strain``, engineering
strains) are CSV text: a header line naming the columns (in any order; other columns are
ignored), then one row of numbers per line, ``.`` as the decimal mark. Blank lines, empty rows
(``,,,``) and lines starting with ``#`` are ignored. Text may be UTF-8 (with or without a
byte-order mark), UTF-16 with a byte-order mark, or Latin-1. Every value must be finite and of
magnitude at most :data:`MAX_TABLE_MAGNITUDE`; the first column (time, axial strain) must
increase strictly from row to row; a table needs at least 2 rows and at most
:data:`MAX_TABLE_ROWS`, a file at most :data:`MAX_TABLE_BYTES`, a line at most
:data:`MAX_TABLE_LINE_CHARS`; directories, devices and pipes are refused. Every F of a path
must have det F > 0.

A file that does not exist is a bad config value (:class:`~espin.core.errors.ConfigError`,
as for every file a config references); a file that exists but cannot be used as a table is
bad input data (:class:`~espin.core.errors.InputError`), its message naming the config key,
the file, the line and column and the columns expected, and never echoing the file's contents
(at most a header name of 20 printable characters).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from espin.core.config import (
    HoldSegment,
    LoadingConfig,
    LoadSegment,
    PoissonLateral,
    StressLateral,
    TransverseCSVLateral,
)
from espin.core.errors import ConfigError
from espin.core.textfiles import TextFormat, missing, parse_number, read_text, shown_names, text_lines

__all__ = [
    "path_program",
    "LoadProgram",
    "LateralStress",
    "load_program",
    "read_table",
    "MAX_TABLE_BYTES",
    "MAX_TABLE_ROWS",
    "MAX_TABLE_LINE_CHARS",
    "MAX_TABLE_MAGNITUDE",
]

MAX_TABLE_BYTES = 16 * 2**20
"""Largest loading table read [bytes]: 16 MiB. 10^5 rows of five numbers take a few MB."""

MAX_TABLE_ROWS = 100_000
"""Most rows in a loading table: a path of 10^5 steps (one per row) would run for days."""

MAX_TABLE_LINE_CHARS = 4096
"""Longest line of a loading table [characters]; a row is a few numbers."""

MAX_TABLE_MAGNITUDE = 1e12
"""Largest magnitude of a value in a loading table (time [s], F, strain); beyond it a value is
no load."""

_PATH_COLUMNS = ("time_s", "F11", "F12", "F21", "F22")
_TRANSVERSE_COLUMNS = ("axial_strain", "transverse_strain")

_E12 = np.array([[0.0, 1.0], [0.0, 0.0]])
_E22 = np.array([[0.0, 0.0], [0.0, 1.0]])


def _rotation(direction_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))
    return np.array([[c, -s], [s, c]])


def _table_format(key: str, columns: Sequence[str]) -> TextFormat:
    """What a loading table named by config ``key`` with ``columns`` is, for its checks."""
    return TextFormat(
        what="loading table",
        max_bytes=MAX_TABLE_BYTES,
        max_line_chars=MAX_TABLE_LINE_CHARS,
        key=key,
        expected=(
            f"expected a CSV table: a header line naming the columns {', '.join(columns)}, then "
            "one row of numbers per line (UTF-8, UTF-16 with byte-order mark or Latin-1 text)"
        ),
        size_hint="10^5 rows of five numbers take a few MB; is this the table?",
        line_hint="a row is a few numbers; is this the table?",
    )


def _fields(path: Path, fmt: TextFormat, number: int, line: str) -> list[str]:
    """The comma-separated fields of one line, stripped (quotes allowed within the line)."""
    try:
        return [field.strip() for field in next(csv.reader([line], strict=True))]
    except csv.Error:
        raise fmt.fail(path, f"not a line of CSV (a misplaced '\"'); {fmt.expected}", number) from None


def _header(path: Path, fmt: TextFormat, lines: Iterator[tuple[int, str]], columns: Sequence[str]) -> list[int]:
    """0-based index of each of ``columns`` in the header, the first kept line."""
    number, line = next(lines, (None, ""))
    if number is None:
        raise fmt.fail(path, f"no header and no data (empty, or only blank and # lines); {fmt.expected}")
    names = _fields(path, fmt, number, line)
    missing = [name for name in columns if name not in names]
    if missing:
        found = (
            "it holds numbers, not column names"
            if all(parse_number(name) is not None for name in names)
            else f"its columns are {shown_names(names)}"
        )
        raise fmt.fail(path, f"the header lacks column(s) {', '.join(missing)} ({found}); {fmt.expected}", number)
    repeated = next((name for name in columns if names.count(name) > 1), None)
    if repeated is not None:
        raise fmt.fail(
            path,
            f"the header names column {repeated} {names.count(repeated)} times; which one to read is unclear",
            number,
        )
    return [names.index(name) for name in columns]


def _value(path: Path, fmt: TextFormat, number: int, fields: list[str], index: int, name: str) -> float:
    """The number in field ``index`` (0-based) of a data line, column ``name``."""
    if index >= len(fields):
        raise fmt.fail(
            path, f"{len(fields)} field(s), but the header puts {name} in column {index + 1}; {fmt.expected}", number
        )
    column = f"column {index + 1} ({name})"
    text = fields[index]
    if not text:
        raise fmt.fail(path, "empty; expected a number such as 0.05 or 5e-2", number, column)
    value = parse_number(text)
    if value is None:
        raise fmt.fail(
            path, "not a number; expected a number such as 0.05 or 5e-2 ('.' as the decimal mark)", number, column
        )
    if not abs(value) <= MAX_TABLE_MAGNITUDE:
        kind = "NaN" if math.isnan(value) else "infinite" if math.isinf(value) else f"{value:.3g}"
        raise fmt.fail(
            path, f"{kind}; expected a finite number of magnitude at most {MAX_TABLE_MAGNITUDE:g}", number, column
        )
    return value


def _rows(
    path: Path, fmt: TextFormat, lines: Iterator[tuple[int, str]], index: list[int], columns: Sequence[str]
) -> tuple[list[int], list[list[float]]]:
    """Line numbers and values of the data rows (empty rows such as ``,,,`` skipped)."""
    numbers: list[int] = []
    rows: list[list[float]] = []
    for number, line in lines:
        fields = _fields(path, fmt, number, line)
        if not any(fields):
            continue
        if len(rows) == MAX_TABLE_ROWS:
            raise fmt.fail(
                path,
                f"more than {MAX_TABLE_ROWS:,} data rows, the limit for a {fmt.what} "
                "(a path has one step per row): thin it out",
                number,
            )
        rows.append([_value(path, fmt, number, fields, i, name) for i, name in zip(index, columns)])
        numbers.append(number)
    return numbers, rows


def _check_increasing(
    path: Path, fmt: TextFormat, numbers: list[int], values: np.ndarray, index: int, name: str
) -> None:
    """The first column increases strictly from row to row."""
    falls = np.flatnonzero(np.diff(values) <= 0.0)
    if falls.size:
        k = int(falls[0])
        raise fmt.fail(
            path,
            f"{values[k + 1]:.6g} does not increase from {values[k]:.6g} on line "
            f"{numbers[k]}; {name} must increase strictly (cut repeated or "
            "decreasing rows)",
            numbers[k + 1],
            f"column {index + 1} ({name})",
        )


def read_table(path: Path, columns: Sequence[str], key: str) -> tuple[np.ndarray, np.ndarray]:
    """Read named numeric columns of a loading table (format in the module docs).

    Parameters
    ----------
    path
        The CSV file.
    columns
        Names of the columns to read, in the header; the first (time [s], axial strain) must
        increase strictly.
    key
        The config key naming the file, for messages (``loading.path_csv``).

    Returns
    -------
    values : (n, len(columns)) float64
        The columns' values, n >= 2 rows, in the units of the columns.
    lines : (n,) int64
        The 1-based line of the file each row comes from.

    Raises
    ------
    ConfigError
        If ``path`` does not exist (naming ``key`` and the path).
    InputError
        If the file is not a regular file, is over a limit, is not text, or its header lacks a
        column, a value is missing, not a number, not finite or out of range, the first column
        does not increase, or it has fewer than 2 rows: naming ``key``, the file, the line and
        column and the columns expected, never echoing its contents.
    """
    if missing(path):
        raise ConfigError(f"{key}: the file it references does not exist: {path}")
    fmt = _table_format(key, columns)
    lines = text_lines(path, read_text(path, fmt), fmt)
    index = _header(path, fmt, lines, columns)
    numbers, rows = _rows(path, fmt, lines, index, columns)
    if len(rows) < 2:
        raise fmt.fail(path, f"{len(rows)} data row(s); a table needs at least 2; {fmt.expected}")
    values = np.array(rows, dtype=float)
    _check_increasing(path, fmt, numbers, values[:, 0], index[0], columns[0])
    return values, np.array(numbers, dtype=np.int64)


def _check_path_determinants(path: Path, F: np.ndarray, lines: np.ndarray) -> None:
    """Every F of a path table has det F > 0 (the error names the first row that has not)."""
    det = np.linalg.det(F)
    bad = np.flatnonzero(~(det > 0.0))
    if bad.size:
        k = int(bad[0])
        fmt = _table_format("loading.path_csv", _PATH_COLUMNS)
        raise fmt.fail(
            path, f"det F = {det[k]:.3g}; every F must have det F > 0 (no material is turned inside out)", int(lines[k])
        )


_START_TOLERANCE = 1e-6
"""How far a table's first row may be from the undeformed state (F = I, transverse strain 0)."""


def _check_transverse_range(path: Path, table: np.ndarray, lines: np.ndarray, low: float, high: float) -> None:
    """The transverse-strain table covers the program's axial strains and gives 0 at 0."""
    fmt = _table_format("loading.lateral.transverse_csv", _TRANSVERSE_COLUMNS)
    first, last = table[0, 0], table[-1, 0]
    if first > min(low, 0.0) or last < high:
        raise fmt.fail(
            path,
            f"the table covers axial strains {first:.4g} to {last:.4g}, but the "
            f"loading program goes from {min(low, 0.0):.4g} to {high:.4g}: extend the table "
            "(it is not extrapolated)",
            int(lines[0] if first > min(low, 0.0) else lines[-1]),
        )
    at_zero = float(np.interp(0.0, table[:, 0], table[:, 1]))
    if abs(at_zero) > _START_TOLERANCE:
        raise fmt.fail(
            path,
            f"the transverse strain at zero axial strain is {at_zero:.4g}, not 0: the "
            "undeformed RVE would start stretched (give strains relative to the unloaded "
            "specimen)",
            int(lines[0]),
        )


@dataclass(frozen=True)
class LateralStress:
    """The lateral stress a uniaxial test holds (``loading.lateral = {stress_MPa = s}``).

    Its one free component, F'22, is held where the lateral stress is ``stress_MPa``: the
    nominal P'22 = s, or the Kirchhoff tau'22 = P'22 F'22 = s (F'21 = 0), i.e. P'22 = s / F'22.
    Both are the derivative of a potential in F'22 (s F'22 and s ln F'22 per reference
    volume), so the equilibrium stays a minimization.

    Attributes
    ----------
    stress_MPa : float [MPa]
        The target s.
    kirchhoff : bool
        Whether s is the Kirchhoff tau'22 (else the nominal P'22).
    """

    stress_MPa: float
    kirchhoff: bool

    def nominal(self, stretch: float) -> tuple[float, float]:
        """The nominal P'22 [MPa] the target asks for at lateral stretch ``stretch`` = F'22,
        and its derivative with F'22 [MPa]."""
        if self.kirchhoff:
            return self.stress_MPa / stretch, -self.stress_MPa / stretch**2
        return self.stress_MPa, 0.0


@dataclass(frozen=True, eq=False)
class LoadProgram:
    """A loading program cut into steps.

    Attributes
    ----------
    time : (n_steps + 1,) float64 [s]
        Time at the start of the program and at the end of every step.
    strain : (n_steps + 1,) float64
        Load parameter s at those times (see the module docs).
    segment : (n_steps,) int64
        Program segment of each step.
    rotation : (2, 2) float64
        R, from the loading frame to the RVE axes.
    free_directions : (n_free, 2, 2) float64
        G_k: directions of the unknown components of F (RVE axes); P : G_k = 0, or the
        lateral stress target.
    test : str
        Kind of test.
    lateral_stress_MPa : float or None
        The lateral stress target s of ``lateral = {stress_MPa = s}`` [MPa] (its measure is
        ``output.stress_measure``, :class:`LateralStress`); None for other conditions.
    """

    time: np.ndarray
    strain: np.ndarray
    segment: np.ndarray
    rotation: np.ndarray
    free_directions: np.ndarray
    test: str
    lateral_stress_MPa: float | None = None
    _table: np.ndarray | None = None
    _lateral: tuple[str, float | np.ndarray] = ("fixed", 0.0)

    @property
    def n_steps(self) -> int:
        """Number of steps."""
        return len(self.time) - 1

    def strain_at(self, t: float) -> float:
        """Load parameter at time ``t`` [s] (linear within a step)."""
        return float(np.interp(t, self.time, self.strain))

    def prescribed_F(self, t: float) -> np.ndarray:
        """(2, 2) prescribed part of F at time ``t`` [s] (free components at their base)."""
        if self.test == "path":
            table = cast(np.ndarray, self._table)  # set for every path program
            return np.array([np.interp(t, table[:, 0], table[:, k]) for k in (1, 2, 3, 4)]).reshape(2, 2)
        s = self.strain_at(t)
        if self.test == "uniaxial":
            kind, value = self._lateral
            if kind == "poisson":
                lateral = 1.0 - value * s
            elif kind == "csv":
                curve = cast(np.ndarray, value)  # the transverse table
                lateral = 1.0 + float(np.interp(s, curve[:, 0], curve[:, 1]))
            else:  # fixed, free or a stress target (the unknown f_k add to F'22 = 1)
                lateral = 1.0
            local = np.array([[1.0 + s, 0.0], [0.0, lateral]])
        elif self.test == "equibiaxial":
            local = np.diag([1.0 + s, 1.0 + s])
        elif self.test == "pure_shear":
            local = np.diag([1.0 + s, 1.0 / (1.0 + s)])
        else:  # simple_shear
            local = np.array([[1.0, s], [0.0, 1.0]])
        R = self.rotation
        return R @ local @ R.T


def _segment_steps(seg: LoadSegment | HoldSegment, start: float) -> tuple[float, float, int]:
    """(duration [s], end strain, steps) of one program segment."""
    if isinstance(seg, HoldSegment):
        return seg.hold_s, start, seg.steps
    change = abs(seg.to_strain - start)
    steps = seg.steps if seg.steps is not None else max(1, math.ceil(100 * change - 1e-9))
    return change / seg.rate_per_s, seg.to_strain, steps


def path_program(time: np.ndarray, F: np.ndarray, strain: np.ndarray | None = None) -> LoadProgram:
    """The program that drives the whole F through a table (test ``"path"``).

    Parameters
    ----------
    time : (n,) float64 [s]
        Increasing times of the recorded steps (the first is the start).
    F : (n, 2, 2) float64
        Deformation gradient at each time (linear in between); the first is usually I.
    strain : (n,) float64, optional
        The load parameter of each step (default: the time from the start, as for a path CSV).
    """
    time = np.asarray(time, dtype=float)
    n = len(time) - 1
    load = time - time[0] if strain is None else np.asarray(strain, dtype=float)
    return LoadProgram(
        time=time - time[0],
        strain=load,
        segment=np.zeros(n, np.int64),
        rotation=np.eye(2),
        free_directions=np.zeros((0, 2, 2)),
        test="path",
        _table=np.c_[time - time[0], np.reshape(F, (-1, 4))],
    )


def load_program(loading: LoadingConfig) -> LoadProgram:
    """Cut the configured loading into steps.

    Parameters
    ----------
    loading
        The ``[loading]`` section.

    Returns
    -------
    LoadProgram
    """
    R = _rotation(loading.direction_deg)
    if loading.test == "path":
        path_csv = cast(Path, loading.path_csv)  # required by a "path" test
        table, lines = read_table(path_csv, _PATH_COLUMNS, "loading.path_csv")
        _check_path_determinants(path_csv, table[:, 1:].reshape(-1, 2, 2), lines)
        if np.abs(table[0, 1:] - np.eye(2).ravel()).max() > _START_TOLERANCE:
            fmt = _table_format("loading.path_csv", _PATH_COLUMNS)
            raise fmt.fail(
                path_csv,
                "the first F is not the identity: a path starts from the undeformed RVE (F11 = F22 = 1, F12 = F21 = 0)",
                int(lines[0]),
            )
        return path_program(table[:, 0], table[:, 1:].reshape(-1, 2, 2))
    times, strains, segments = [0.0], [0.0], []
    for index, seg in enumerate(loading.segments):
        duration, end, steps = _segment_steps(seg, strains[-1])
        if duration <= 0.0:
            raise ConfigError(
                f"loading.program[{index}]: segment goes nowhere (to_strain equals the current strain {strains[-1]:g})"
            )
        t0, s0 = times[-1], strains[-1]
        for k in range(1, steps + 1):
            times.append(t0 + duration * k / steps)
            strains.append(s0 + (end - s0) * k / steps)
            segments.append(index)
    lateral: tuple[str, float | np.ndarray] = ("fixed", 0.0)
    free = np.zeros((0, 2, 2))
    lateral_stress = None
    if loading.test == "uniaxial":
        if loading.lateral == "free":
            lateral = ("free", 0.0)
            free = np.array([R @ _E12 @ R.T, R @ _E22 @ R.T])
        elif isinstance(loading.lateral, StressLateral):
            lateral = ("stress", loading.lateral.stress_MPa)
            free = np.array([R @ _E22 @ R.T])
            lateral_stress = loading.lateral.stress_MPa
        elif isinstance(loading.lateral, PoissonLateral):
            lateral = ("poisson", loading.lateral.poisson_ratio)
        elif isinstance(loading.lateral, TransverseCSVLateral):
            table, lines = read_table(
                loading.lateral.transverse_csv, _TRANSVERSE_COLUMNS, "loading.lateral.transverse_csv"
            )
            _check_transverse_range(loading.lateral.transverse_csv, table, lines, min(strains), max(strains))
            lateral = ("csv", table)
    strains_arr = np.array(strains)
    if loading.test in ("equibiaxial", "pure_shear", "uniaxial") and strains_arr.min() <= -1.0:
        raise ConfigError("loading: the strain must stay above -1 (positive stretch)")
    program = LoadProgram(
        time=np.array(times),
        strain=strains_arr,
        segment=np.array(segments, dtype=np.int64),
        rotation=R,
        free_directions=free,
        test=loading.test,
        lateral_stress_MPa=lateral_stress,
        _lateral=lateral,
    )
    det = np.array([np.linalg.det(program.prescribed_F(t)) for t in program.time])
    if np.any(det <= 0.0):
        k = int(np.argmax(det <= 0.0))
        raise ConfigError(
            f"loading.lateral: the prescribed lateral stretch is not positive at strain "
            f"{program.strain[k]:.4g} (det F = {det[k]:.3g}); lower the Poisson ratio or the "
            "strain, or extend the transverse-strain table"
        )
    return program
