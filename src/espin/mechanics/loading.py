"""Macroscopic loading programs: tests, segments, steps (docs/model.md section 6).

A test is defined in the loading frame, whose axes are those of the RVE rotated by
``direction_deg``; the deformation gradient applied to the RVE is F = R F' R^T. A program is a
sequence of segments (load to a strain at a rate, or hold) cut into steps. Each step knows its
time, its load parameter ("strain") and the prescribed part of F. Mixed control (uniaxial
with a free lateral side) adds unknown components of F: F = F_prescribed + sum_k f_k G_k, with
the conjugate stress components P : G_k = 0 as extra equations.

The load parameter s is the engineering strain F'11 - 1 for ``uniaxial``, lambda - 1 for
``equibiaxial`` (F = lambda I) and ``pure_shear`` (F' = diag(lambda, 1 / lambda)), the
shear gamma for ``simple_shear`` (F' = [[1, gamma], [0, 1]]), and the time for ``path``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from espin.core.config import (
    HoldSegment,
    LoadingConfig,
    LoadSegment,
    PoissonLateral,
    TransverseCSVLateral,
)
from espin.core.errors import ConfigError

__all__ = ["LoadProgram", "load_program", "read_table"]

_E12 = np.array([[0.0, 1.0], [0.0, 0.0]])
_E22 = np.array([[0.0, 0.0], [0.0, 1.0]])


def _rotation(direction_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))
    return np.array([[c, -s], [s, c]])


def read_table(path: Path, columns: list[str], key: str) -> np.ndarray:
    """Read named numeric columns of a CSV file (header line required).

    Raises
    ------
    ConfigError
        Naming the config ``key``, the file, and the offending line.
    """
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as err:
        raise ConfigError(f"{key}: cannot read {path}: {err}") from None
    if not rows:
        raise ConfigError(f"{key}: {path} is empty")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in columns if c not in header]
    if missing:
        raise ConfigError(f"{key}: {path} lacks column(s) {missing}; it has {header}")
    index = [header.index(c) for c in columns]
    out = []
    for number, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        try:
            values = [float(row[i]) for i in index]
        except (ValueError, IndexError):
            raise ConfigError(f"{key}: {path} line {number}: not numeric: {row}") from None
        if not all(math.isfinite(v) for v in values):
            raise ConfigError(f"{key}: {path} line {number}: NaN or infinite value")
        out.append(values)
    if len(out) < 2:
        raise ConfigError(f"{key}: {path} needs at least two data rows")
    return np.array(out)


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
        G_k: directions of the unknown components of F (RVE axes); P : G_k = 0.
    test : str
        Kind of test.
    """

    time: np.ndarray
    strain: np.ndarray
    segment: np.ndarray
    rotation: np.ndarray
    free_directions: np.ndarray
    test: str
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
            table = self._table
            return np.array([np.interp(t, table[:, 0], table[:, k]) for k in (1, 2, 3, 4)]).reshape(2, 2)
        s = self.strain_at(t)
        if self.test == "uniaxial":
            kind, value = self._lateral
            if kind == "poisson":
                lateral = 1.0 - value * s
            elif kind == "csv":
                lateral = 1.0 + float(np.interp(s, value[:, 0], value[:, 1]))
            else:  # fixed, or free (the unknown f_k add to F'22 = 1)
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
        table = read_table(loading.path_csv, ["time_s", "F11", "F12", "F21", "F22"], "loading.path_csv")
        if np.any(np.diff(table[:, 0]) <= 0):
            raise ConfigError("loading.path_csv: time_s must increase strictly")
        F = table[:, 1:].reshape(-1, 2, 2)
        if np.any(np.linalg.det(F) <= 0):
            raise ConfigError("loading.path_csv: every F must have det F > 0")
        n = len(table) - 1
        return LoadProgram(
            time=table[:, 0] - table[0, 0], strain=table[:, 0] - table[0, 0],
            segment=np.zeros(n, np.int64), rotation=np.eye(2), free_directions=np.zeros((0, 2, 2)),
            test="path", _table=np.c_[table[:, 0] - table[0, 0], table[:, 1:]],
        )
    times, strains, segments = [0.0], [0.0], []
    for index, seg in enumerate(loading.segments):
        duration, end, steps = _segment_steps(seg, strains[-1])
        if duration <= 0.0:
            raise ConfigError(
                f"loading.program[{index}]: segment goes nowhere (to_strain equals the current "
                f"strain {strains[-1]:g})"
            )
        t0, s0 = times[-1], strains[-1]
        for k in range(1, steps + 1):
            times.append(t0 + duration * k / steps)
            strains.append(s0 + (end - s0) * k / steps)
            segments.append(index)
    lateral: tuple[str, float | np.ndarray] = ("fixed", 0.0)
    free = np.zeros((0, 2, 2))
    if loading.test == "uniaxial":
        if loading.lateral == "free":
            lateral = ("free", 0.0)
            free = np.array([R @ _E12 @ R.T, R @ _E22 @ R.T])
        elif isinstance(loading.lateral, PoissonLateral):
            lateral = ("poisson", loading.lateral.poisson_ratio)
        elif isinstance(loading.lateral, TransverseCSVLateral):
            table = read_table(loading.lateral.transverse_csv, ["axial_strain", "transverse_strain"],
                               "loading.lateral.transverse_csv")
            if np.any(np.diff(table[:, 0]) <= 0):
                raise ConfigError("loading.lateral.transverse_csv: axial_strain must increase strictly")
            lateral = ("csv", table)
    strains_arr = np.array(strains)
    if loading.test in ("equibiaxial", "pure_shear", "uniaxial") and strains_arr.min() <= -1.0:
        raise ConfigError("loading: the strain must stay above -1 (positive stretch)")
    program = LoadProgram(
        time=np.array(times), strain=strains_arr, segment=np.array(segments, dtype=np.int64),
        rotation=R, free_directions=free, test=loading.test, _lateral=lateral,
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
