"""Measured (or typed-in) distributions that a virtual mat's geometry is calibrated to.

The targets come from SEM images, one row per traced fiber, as written by ``espin measure``:

* ``fibers.csv`` with any of the columns ``diameter_um``, ``orientation_deg`` (axis in
  [0, 180) deg), ``tortuosity`` (contour / end-to-end length, >= 1), and optionally
  ``contour_length_um`` and ``end_to_end_um`` (tortuosity is their ratio when the
  ``tortuosity`` column is absent). Other columns are ignored; empty cells are fibers where
  that quantity was not measured.
* a folder holding ``fibers.csv`` and ``measurement.toml`` with at least ``um_per_px`` and
  ``field_of_view_um = [width, height]`` (and optionally ``min_chord_um``, the shortest
  end-to-end length the tracer kept).

Or they are typed in: a normal diameter distribution (mean, sd), a half-normal tortuosity
``halfnorm(loc=1, scale)`` as the paper fitted (SPEC 7), and a uniform or axial von Mises
orientation distribution.

Units: um, degrees (at this user-facing edge).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from espin.errors import EspinError

__all__ = ["MeasurementError", "GeometryTargets", "MIN_SAMPLE_SIZE", "equivalent_square_side"]

MIN_SAMPLE_SIZE = 10
"""Fewest measured values of a quantity that a distribution is calibrated to."""

SAMPLE_COLUMNS = ("diameter_um", "orientation_deg", "tortuosity")
LENGTH_COLUMNS = ("contour_length_um", "end_to_end_um")


class MeasurementError(EspinError, ValueError):
    """Measured or typed-in targets are missing, unreadable or out of range."""


def equivalent_square_side(width_um: float, height_um: float) -> float:
    """Side [um] of the square window with the same mean chord as a width x height field.

    By Cauchy-Crofton the mean chord of isotropic random lines through a convex window is
    pi A / P; for a rectangle that is pi w h / (2 (w + h)) and for a square of side s it is
    pi s / 4, so s = 2 w h / (w + h) (the harmonic mean of the sides). Fiber portions seen in
    both windows then have the same mean chord, the length over which tortuosity is measured.
    """
    return 2.0 * width_um * height_um / (width_um + height_um)


def _sample(values: ArrayLike | None, name: str, low: float, high: float,
            closed_high: bool = False) -> np.ndarray | None:
    """A validated 1-D float sample, or None. NaN entries are left out."""
    if values is None:
        return None
    x = np.asarray(values, dtype=float).ravel()
    x = x[~np.isnan(x)]
    bad = ~np.isfinite(x) | (x < low) | ((x > high) if closed_high else (x >= high))
    if bad.any():
        upper = "]" if closed_high else ")"
        raise MeasurementError(
            f"{name}: values must lie in [{low:g}, {high:g}{upper}; got {x[bad][0]!r} "
            f"({int(bad.sum())} of {len(x)} values out of range)"
        )
    if len(x) < MIN_SAMPLE_SIZE:
        raise MeasurementError(
            f"{name}: {len(x)} measured values; at least {MIN_SAMPLE_SIZE} are needed to "
            "calibrate a distribution"
        )
    return x


def _positive(value: float | None, name: str, allow_zero: bool = False) -> None:
    if value is None:
        return
    ok = math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)
    if not ok:
        raise MeasurementError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")


@dataclass(frozen=True, eq=False)
class GeometryTargets:
    """What the calibrated mat must reproduce; any quantity may be left out (None).

    Each of diameter, orientation and tortuosity is given either as a measured sample or as
    typed-in distribution parameters, not both.

    Attributes
    ----------
    diameter_um : (n,) float64 [um], optional
        Measured fiber diameters (> 0).
    orientation_deg : (n,) float64 [deg], optional
        Measured fiber axes in [0, 180).
    tortuosity : (n,) float64, optional
        Measured contour / end-to-end length of each traced fiber portion (>= 1).
    diameter_mean_um, diameter_sd_um : float [um], optional
        Typed-in normal diameter distribution (sd defaults to 0: a fixed diameter).
    orientation_uniform : bool
        Typed-in uniform orientation.
    orientation_mean_deg, orientation_kappa : float, optional
        Typed-in axial von Mises orientation, p ~ exp(kappa cos 2(theta - mean)),
        mean in [0, 180) deg, kappa in [0, 700].
    tortuosity_scale : float, optional
        Typed-in half-normal tortuosity ``halfnorm(loc=1, scale)``, scale in (0, 10].
    field_of_view_um : (width, height) [um], optional
        Size of the SEM images the sample was measured on.
    min_chord_um : float [um], optional
        Shortest end-to-end length the tracer kept (the virtual measurement does the same).
    source : str
        Where the targets came from, for reports.
    """

    diameter_um: np.ndarray | None = None
    orientation_deg: np.ndarray | None = None
    tortuosity: np.ndarray | None = None
    diameter_mean_um: float | None = None
    diameter_sd_um: float | None = None
    orientation_uniform: bool = False
    orientation_mean_deg: float | None = None
    orientation_kappa: float | None = None
    tortuosity_scale: float | None = None
    field_of_view_um: tuple[float, float] | None = None
    min_chord_um: float | None = None
    source: str = "typed-in"

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "diameter_um", _sample(self.diameter_um, "diameter_um", 0.0, math.inf))
        if self.diameter_um is not None and (self.diameter_um <= 0.0).any():
            raise MeasurementError("diameter_um: values must be > 0")
        orientation = _sample(self.orientation_deg, "orientation_deg", 0.0, 180.0, closed_high=True)
        set_(self, "orientation_deg", None if orientation is None else np.mod(orientation, 180.0))
        tortuosity = _sample(self.tortuosity, "tortuosity", 1.0 - 1e-9, math.inf)
        set_(self, "tortuosity", None if tortuosity is None else np.maximum(tortuosity, 1.0))
        self._check_typed()
        if self.field_of_view_um is not None:
            fov = tuple(float(v) for v in np.ravel(self.field_of_view_um))
            if len(fov) != 2 or not all(math.isfinite(v) and v > 0 for v in fov):
                raise MeasurementError(
                    f"field_of_view_um must be [width, height] with both > 0, got {self.field_of_view_um!r}"
                )
            set_(self, "field_of_view_um", fov)
        _positive(self.min_chord_um, "min_chord_um", allow_zero=True)

    def _check_typed(self) -> None:
        both = [
            ("diameter", self.diameter_um, self.diameter_mean_um is not None or self.diameter_sd_um is not None),
            ("orientation", self.orientation_deg, self.orientation_uniform
             or self.orientation_mean_deg is not None or self.orientation_kappa is not None),
            ("tortuosity", self.tortuosity, self.tortuosity_scale is not None),
        ]
        for name, sample, typed in both:
            if sample is not None and typed:
                raise MeasurementError(
                    f"the {name} is both measured (a column of the sample) and typed in: give one"
                )
        if self.diameter_sd_um is not None and self.diameter_mean_um is None:
            raise MeasurementError("diameter_sd_um needs diameter_mean_um (the mean diameter)")
        _positive(self.diameter_mean_um, "diameter_mean_um")
        _positive(self.diameter_sd_um, "diameter_sd_um", allow_zero=True)
        if self.orientation_uniform and (
            self.orientation_mean_deg is not None or self.orientation_kappa is not None
        ):
            raise MeasurementError(
                "orientation: give uniform, or orientation_mean_deg with orientation_kappa, not both"
            )
        if (self.orientation_mean_deg is None) != (self.orientation_kappa is None):
            raise MeasurementError(
                "a von Mises orientation needs both orientation_mean_deg and orientation_kappa"
            )
        if self.orientation_mean_deg is not None and not 0.0 <= self.orientation_mean_deg < 180.0:
            raise MeasurementError(
                f"orientation_mean_deg must be in [0, 180), got {self.orientation_mean_deg!r}"
            )
        if self.orientation_kappa is not None and not 0.0 <= self.orientation_kappa <= 700.0:
            raise MeasurementError(
                f"orientation_kappa must be in [0, 700], got {self.orientation_kappa!r}"
            )
        if self.tortuosity_scale is not None and not 0.0 < self.tortuosity_scale <= 10.0:
            raise MeasurementError(
                f"tortuosity_scale (half-normal, loc 1) must be in (0, 10], got {self.tortuosity_scale!r}"
            )

    # ----------------------------------------------------------------------------------------
    # reading
    # ----------------------------------------------------------------------------------------
    @classmethod
    def from_csv(cls, path: str | Path, **extra: Any) -> GeometryTargets:
        """Targets from a ``fibers.csv`` (one row per measured fiber; see the module doc).

        Rows whose ``end_to_end_um`` is below ``min_chord_um`` (if both are known) are left out
        of the tortuosity sample, as the virtual measurement drops such stubs.

        Parameters
        ----------
        path
            The CSV file.
        **extra
            Further fields (``field_of_view_um``, ``min_chord_um``, typed-in values).
        """
        import pandas as pd

        path = Path(path)
        if not path.is_file():
            raise MeasurementError(f"measured fibers file not found: {path}")
        try:
            table = pd.read_csv(path)
        except (ValueError, OSError) as err:  # pandas' parser errors are ValueErrors
            raise MeasurementError(f"cannot read {path} as CSV: {err}") from None
        columns = {c.strip(): c for c in table.columns}
        known = [c for c in SAMPLE_COLUMNS + LENGTH_COLUMNS if c in columns]
        has_lengths = all(c in columns for c in LENGTH_COLUMNS)
        if not any(c in columns for c in SAMPLE_COLUMNS) and not has_lengths:
            raise MeasurementError(
                f"{path} has none of the columns {', '.join(SAMPLE_COLUMNS)} (or both "
                f"{' and '.join(LENGTH_COLUMNS)}); found: {', '.join(map(str, table.columns))}"
            )

        def column(name: str) -> np.ndarray:
            try:
                return pd.to_numeric(table[columns[name]], errors="raise").to_numpy(dtype=float)
            except (ValueError, TypeError):
                raise MeasurementError(f"{path}: column {name} holds non-numeric values") from None

        values = {name: column(name) for name in known}
        if "tortuosity" not in values and has_lengths:
            with np.errstate(divide="ignore", invalid="ignore"):
                values["tortuosity"] = values["contour_length_um"] / values["end_to_end_um"]
        min_chord = extra.get("min_chord_um")
        if "tortuosity" in values and "end_to_end_um" in values and min_chord:
            values["tortuosity"] = np.where(
                values["end_to_end_um"] >= min_chord, values["tortuosity"], np.nan
            )
        samples = {k: values.get(k) for k in SAMPLE_COLUMNS}
        return cls(**samples, source=str(path), **extra)

    @classmethod
    def from_folder(cls, folder: str | Path, **extra: Any) -> GeometryTargets:
        """Targets from a folder of ``espin measure``: ``fibers.csv`` + ``measurement.toml``."""
        folder = Path(folder)
        toml_path = folder / "measurement.toml"
        if not (folder / "fibers.csv").is_file() or not toml_path.is_file():
            raise MeasurementError(
                f"{folder} must hold fibers.csv and measurement.toml (as written by espin measure)"
            )
        try:
            meta = tomllib.loads(toml_path.read_text("utf-8"))
        except tomllib.TOMLDecodeError as err:
            raise MeasurementError(f"{toml_path} is not valid TOML: {err}") from None
        for key in ("um_per_px", "field_of_view_um"):
            if key not in meta:
                raise MeasurementError(f"{toml_path}: missing key {key}")
        um_per_px = meta["um_per_px"]
        if not isinstance(um_per_px, (int, float)) or not um_per_px > 0:
            raise MeasurementError(f"{toml_path}: um_per_px must be a number > 0, got {um_per_px!r}")
        found = {"field_of_view_um": meta["field_of_view_um"]}
        if "min_chord_um" in meta:
            found["min_chord_um"] = meta["min_chord_um"]
        return cls.from_csv(folder / "fibers.csv", **(found | extra))

    @classmethod
    def from_path(cls, path: str | Path, **extra: Any) -> GeometryTargets:
        """Targets from a measure folder or a ``fibers.csv``."""
        path = Path(path)
        if path.is_dir():
            return cls.from_folder(path, **extra)
        return cls.from_csv(path, **extra)

    def with_typed(self, **values: Any) -> GeometryTargets:
        """These targets plus typed-in values (None entries are ignored).

        Raises
        ------
        MeasurementError
            If a typed-in value concerns a quantity that is already measured.
        """
        allowed = {f.name for f in fields(self)} - set(SAMPLE_COLUMNS)
        unknown = set(values) - allowed
        if unknown:
            raise MeasurementError(f"unknown target(s): {', '.join(sorted(unknown))}")
        given = {k: v for k, v in values.items() if v is not None and v is not False}
        return replace(self, **given) if given else self

    # ----------------------------------------------------------------------------------------
    # what is targeted
    # ----------------------------------------------------------------------------------------
    @property
    def has_diameter(self) -> bool:
        """A diameter distribution is targeted."""
        return self.diameter_um is not None or self.diameter_mean_um is not None

    @property
    def has_orientation(self) -> bool:
        """An orientation distribution is targeted."""
        return (self.orientation_deg is not None or self.orientation_uniform
                or self.orientation_mean_deg is not None)

    @property
    def has_tortuosity(self) -> bool:
        """A tortuosity distribution is targeted."""
        return self.tortuosity is not None or self.tortuosity_scale is not None

    @property
    def is_empty(self) -> bool:
        """Nothing is targeted."""
        return not (self.has_diameter or self.has_orientation or self.has_tortuosity)

    @property
    def window_um(self) -> float | None:
        """Side [um] of the square observation window equivalent to the field of view."""
        if self.field_of_view_um is None:
            return None
        return equivalent_square_side(*self.field_of_view_um)

    def tortuosity_distribution(self) -> Any:
        """``scipy.stats.halfnorm(loc=1, scale)`` (frozen) of a typed-in tortuosity, or None."""
        from scipy import stats

        if self.tortuosity_scale is None:
            return None
        return stats.halfnorm(loc=1.0, scale=self.tortuosity_scale)
