"""Measured (or typed-in) distributions that a virtual mat's geometry is calibrated to.

The targets come from SEM images, one row per traced fiber, as written by ``espin measure``:

* ``fibers.csv`` (read by :func:`espin.geometry.fibers_csv.read_fibers_csv`) with any of the columns
  ``diameter_um``, ``orientation_deg`` (axis in [0, 180) deg), ``tortuosity`` (contour /
  end-to-end length, >= 1), and optionally ``contour_length_um`` and ``end_to_end_um``
  (tortuosity is their ratio when the ``tortuosity`` column is absent), and ``visible``
  (``espin measure``: the diameter target is then the fully visible fibers' diameters; the
  orientation and tortuosity stay those of all fibers). Other columns are
  ignored; empty cells are fibers where that quantity was not measured, and a column with no
  value at all is skipped (with a note). The contour lengths of the measured pieces are kept:
  the virtual mat is then measured on pieces of the same lengths (length-matched sampling,
  :mod:`espin.imaging.geometry_calibration.virtual`).
* a folder holding ``fibers.csv`` and ``measurement.toml`` with at least ``um_per_px`` and
  ``field_of_view_um = [width, height]`` (and optionally ``min_chord_um``, the shortest
  end-to-end length the tracer kept, and a ``[crossing]`` table with ``n_crossing``,
  ``u_turn_fraction`` and ``straightness`` of the fibers traced from edge to edge of the
  image).
* an :class:`espin.imaging.measurement.SEMMeasurement` (:meth:`GeometryTargets.from_measurement`).

Or they are typed in: a normal diameter distribution (mean, sd), a half-normal tortuosity
``halfnorm(loc=1, scale)`` as the paper fitted (docs/model.md section 7), and a uniform or axial von Mises
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

from espin.core.errors import InputError
from espin.geometry.fibers_csv import VISIBLE_COLUMN, parse_flags

__all__ = ["MeasurementError", "GeometryTargets", "MIN_SAMPLE_SIZE", "equivalent_square_side"]

MIN_SAMPLE_SIZE = 10
"""Fewest measured values of a quantity that a distribution is calibrated to."""

SAMPLE_COLUMNS = ("diameter_um", "orientation_deg", "tortuosity")
LENGTH_COLUMNS = ("contour_length_um", "end_to_end_um")


class MeasurementError(InputError):
    """Measured or typed-in targets are missing, unreadable or out of range."""


def equivalent_square_side(width_um: float, height_um: float) -> float:
    """Side [um] of the square window with the same mean chord as a width x height field.

    By Cauchy-Crofton the mean chord of isotropic random lines through a convex window is
    pi A / P; for a rectangle that is pi w h / (2 (w + h)) and for a square of side s it is
    pi s / 4, so s = 2 w h / (w + h) (the harmonic mean of the sides). Fiber portions seen in
    both windows then have the same mean chord, the length over which tortuosity is measured.
    """
    return 2.0 * width_um * height_um / (width_um + height_um)


def _sample(
    values: ArrayLike | None, name: str, low: float, high: float, closed_high: bool = False
) -> np.ndarray | None:
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
            f"{name}: {len(x)} measured values; at least {MIN_SAMPLE_SIZE} are needed to calibrate a distribution"
        )
    return x


def _number(value: Any, name: str) -> float:
    """``value`` as a float, or a MeasurementError naming ``name`` (strings, lists... refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise MeasurementError(f"{name} must be a number, got {value!r}")
    return float(value)


def _visible_diameters(diameter: np.ndarray, visible: Any) -> tuple[np.ndarray, str]:
    """The diameters of the fully visible fibers (the others NaN: a partly hidden fiber reads
    narrower, docs/sem.md), and a note; all of them when no fiber is visible."""
    flags, bad = parse_flags(visible)
    if bad is not None:
        raise MeasurementError(
            f"column {VISIBLE_COLUMN} must hold True or False, got "
            f"{np.asarray(visible, dtype=object).ravel()[bad]!r} (fiber {bad})"
        )
    measured = np.isfinite(diameter)
    if not (flags & measured).any():
        return diameter, (
            f"diameter: no fiber is marked {VISIBLE_COLUMN}; the diameters of all "
            f"{int(measured.sum())} fibers are the target"
        )
    return np.where(flags, diameter, np.nan), (
        f"diameter: the {int((flags & measured).sum())} fully visible fibers of "
        f"{int(measured.sum())} measured (column {VISIBLE_COLUMN})"
    )


def _field_of_view(value: Any) -> tuple[float, float]:
    """A validated ``(width, height)`` [um]: two finite numbers > 0."""
    message = f"field_of_view_um must be [width, height] in um, both numbers > 0; got {value!r}"
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise MeasurementError(message)
    try:
        fov = tuple(_number(v, "field_of_view_um") for v in value)
    except MeasurementError:
        raise MeasurementError(message) from None
    if not all(math.isfinite(v) and v > 0 for v in fov):
        raise MeasurementError(message)
    return fov[0], fov[1]


_CROSSING_KEYS = ("n_crossing", "u_turn_fraction", "straightness")


def _crossing(n_crossing: Any = None, u_turn_fraction: Any = None, straightness: Any = None) -> dict[str, Any]:
    """Checked edge-to-edge statistics: a count >= 0, a fraction in [0, 1], a straightness in
    (0, 1]. A fraction or straightness of NaN (no fiber crossed) becomes None."""
    out: dict[str, Any] = {"n_crossing": None, "u_turn_fraction": None, "straightness": None}
    if n_crossing is not None:
        count = _number(n_crossing, "n_crossing")
        if not (count >= 0 and count == int(count)):
            raise MeasurementError(f"n_crossing must be an integer >= 0, got {n_crossing!r}")
        out["n_crossing"] = int(count)
    for name, value, low in (("u_turn_fraction", u_turn_fraction, "["), ("straightness", straightness, "(")):
        number = None if value is None else _number(value, name)
        if number is None or math.isnan(number):
            continue
        if not ((number > 0.0 if low == "(" else number >= 0.0) and number <= 1.0):
            raise MeasurementError(f"{name} must be in {low}0, 1], got {value!r}")
        out[name] = number
    return out


def _crossing_table(table: Any) -> dict[str, Any]:
    """The checked ``[crossing]`` table of a ``measurement.toml`` ({} when absent: files
    written before espin measure reported it)."""
    if not isinstance(table, dict):
        raise MeasurementError(f"[crossing] must be a table, got {table!r}")
    return _crossing(**{key: table[key] for key in _CROSSING_KEYS if key in table})


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
    contour_length_um : (m,) float64 [um], optional
        Contour lengths of the measured pieces (the lengths over which tortuosity and
        orientation were observed). When given, the virtual mat is measured on pieces of
        these lengths (length-matched sampling); otherwise on whole window portions.
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
    n_crossing : int, optional
        Measured fibers traced from edge to edge of the image (``espin measure``).
    u_turn_fraction : float, optional
        Of those, the fraction that leave through the edge they entered, in [0, 1]; None when
        not measured or when no fiber crossed (compare
        :func:`espin.geometry.pieces.window_crossings`).
    straightness : float, optional
        Their mean end-to-end distance over contour length, in (0, 1]; None as
        ``u_turn_fraction``.
    source : str
        Where the targets came from, for reports.
    notes : tuple of str
        What the reader noticed (columns skipped, rows left out), for reports.
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
    contour_length_um: np.ndarray | None = None
    notes: tuple[str, ...] = ()
    n_crossing: int | None = None
    u_turn_fraction: float | None = None
    straightness: float | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "diameter_um", _sample(self.diameter_um, "diameter_um", 0.0, math.inf))
        if self.diameter_um is not None and (self.diameter_um <= 0.0).any():
            raise MeasurementError("diameter_um: values must be > 0")
        orientation = _sample(self.orientation_deg, "orientation_deg", 0.0, 180.0, closed_high=True)
        set_(self, "orientation_deg", None if orientation is None else np.mod(orientation, 180.0))
        tortuosity = _sample(self.tortuosity, "tortuosity", 1.0 - 1e-9, math.inf)
        set_(self, "tortuosity", None if tortuosity is None else np.maximum(tortuosity, 1.0))
        lengths = _sample(self.contour_length_um, "contour_length_um", 0.0, math.inf)
        if lengths is not None and (lengths <= 0.0).any():
            raise MeasurementError("contour_length_um: values must be > 0")
        set_(self, "contour_length_um", lengths)
        set_(self, "notes", tuple(self.notes))
        self._check_typed()
        if self.field_of_view_um is not None:
            set_(self, "field_of_view_um", _field_of_view(self.field_of_view_um))
        if self.min_chord_um is not None:
            set_(self, "min_chord_um", _number(self.min_chord_um, "min_chord_um"))
        _positive(self.min_chord_um, "min_chord_um", allow_zero=True)
        for key, value in _crossing(**{k: getattr(self, k) for k in _CROSSING_KEYS}).items():
            set_(self, key, value)

    def _check_typed(self) -> None:
        both = [
            ("diameter", self.diameter_um, self.diameter_mean_um is not None or self.diameter_sd_um is not None),
            (
                "orientation",
                self.orientation_deg,
                self.orientation_uniform or self.orientation_mean_deg is not None or self.orientation_kappa is not None,
            ),
            ("tortuosity", self.tortuosity, self.tortuosity_scale is not None),
        ]
        for name, sample, typed in both:
            if sample is not None and typed:
                raise MeasurementError(f"the {name} is both measured (a column of the sample) and typed in: give one")
        if self.diameter_sd_um is not None and self.diameter_mean_um is None:
            raise MeasurementError("diameter_sd_um needs diameter_mean_um (the mean diameter)")
        _positive(self.diameter_mean_um, "diameter_mean_um")
        _positive(self.diameter_sd_um, "diameter_sd_um", allow_zero=True)
        if self.orientation_uniform and (self.orientation_mean_deg is not None or self.orientation_kappa is not None):
            raise MeasurementError(
                "orientation: give uniform, or orientation_mean_deg with orientation_kappa, not both"
            )
        if (self.orientation_mean_deg is None) != (self.orientation_kappa is None):
            raise MeasurementError("a von Mises orientation needs both orientation_mean_deg and orientation_kappa")
        if self.orientation_mean_deg is not None and not 0.0 <= self.orientation_mean_deg < 180.0:
            raise MeasurementError(f"orientation_mean_deg must be in [0, 180), got {self.orientation_mean_deg!r}")
        if self.orientation_kappa is not None and not 0.0 <= self.orientation_kappa <= 700.0:
            raise MeasurementError(f"orientation_kappa must be in [0, 700], got {self.orientation_kappa!r}")
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

        The table is read and validated by :func:`espin.geometry.fibers_csv.read_fibers_csv`. Rows whose
        ``end_to_end_um`` is below ``min_chord_um`` (if both are known) are left out of every
        sample, as the virtual measurement drops such stubs. A column without any value is
        skipped (with a note).

        Parameters
        ----------
        path
            The CSV file.
        **extra
            Further fields (``field_of_view_um``, ``min_chord_um``, typed-in values).
        """
        from espin.core.errors import SEMError
        from espin.geometry.fibers_csv import read_fibers_csv

        path = Path(path)
        if not path.is_file():
            raise MeasurementError(f"measured fibers file not found: {path}")
        try:
            table = read_fibers_csv(path)
        except SEMError as err:
            raise MeasurementError(str(err)) from None
        return cls.from_table(table, **({"source": str(path)} | extra))

    @classmethod
    def from_table(cls, table: Any, **extra: Any) -> GeometryTargets:
        """Targets from a per-fiber table (a DataFrame with the columns of ``fibers.csv``).

        Parameters
        ----------
        table : pandas.DataFrame
            Columns as :data:`espin.geometry.fibers_csv.FIBER_COLUMNS` (missing ones allowed; NaN = not
            measured), e.g. :attr:`espin.imaging.measurement.SEMMeasurement.fibers`.
        **extra
            Further fields (``field_of_view_um``, ``min_chord_um``, ``source``, typed-in
            values).
        """
        notes: list[str] = list(extra.pop("notes", ()))
        values: dict[str, np.ndarray] = {}
        for name in SAMPLE_COLUMNS + LENGTH_COLUMNS:
            if name not in table.columns:
                continue
            try:
                column = np.asarray(table[name], dtype=float)
            except (TypeError, ValueError):
                raise MeasurementError(f"column {name} holds non-numeric values") from None
            if len(column) and np.isnan(column).all():
                notes.append(f"column {name} has no values: skipped")
                continue
            values[name] = column
        if "diameter_um" in values and VISIBLE_COLUMN in table.columns:
            values["diameter_um"], note = _visible_diameters(values["diameter_um"], table[VISIBLE_COLUMN])
            notes.append(note)
        if "tortuosity" not in values and all(c in values for c in LENGTH_COLUMNS):
            with np.errstate(divide="ignore", invalid="ignore"):
                values["tortuosity"] = values["contour_length_um"] / values["end_to_end_um"]
            notes.append("tortuosity = contour_length_um / end_to_end_um")
        if "contour_length_um" not in values and "end_to_end_um" in values and "tortuosity" in values:
            values["contour_length_um"] = values["tortuosity"] * values["end_to_end_um"]
        min_chord = extra.get("min_chord_um")
        if min_chord is not None:
            min_chord = _number(min_chord, "min_chord_um")
        if "end_to_end_um" in values and min_chord:
            short = values["end_to_end_um"] < min_chord
            if short.any():
                notes.append(
                    f"{int(short.sum())} rows with end_to_end_um < min_chord_um = "
                    f"{min_chord:g} um left out (as the virtual measurement does)"
                )
                values = {k: np.where(short, np.nan, v) for k, v in values.items()}
        if not any(k in values for k in SAMPLE_COLUMNS):
            raise MeasurementError(
                f"{extra.get('source', 'the table')}: none of the columns {', '.join(SAMPLE_COLUMNS)} holds a value"
            )
        lengths = None
        if "contour_length_um" in values and ("tortuosity" in values or "orientation_deg" in values):
            # The observation lengths of the pieces whose tortuosity / orientation was measured.
            measured = values["tortuosity"] if "tortuosity" in values else values["orientation_deg"]
            lengths = values["contour_length_um"][np.isfinite(measured)]
            lengths = lengths[np.isfinite(lengths)]
            if len(lengths) < MIN_SAMPLE_SIZE:
                notes.append(f"only {len(lengths)} contour lengths: whole window portions measured")
                lengths = None
        samples: dict[str, Any] = {k: values.get(k) for k in SAMPLE_COLUMNS}
        return cls(**samples, contour_length_um=lengths, notes=tuple(notes), **extra)

    @classmethod
    def from_measurement(cls, measurement: Any, **extra: Any) -> GeometryTargets:
        """Targets from an :class:`espin.imaging.measurement.SEMMeasurement`
        (``espin.imaging.measurement.measure(...)``): its fibers table, field of view, shortest
        chord and edge-to-edge statistics."""
        found = {
            "field_of_view_um": tuple(measurement.field_of_view_um),
            "min_chord_um": float(measurement.min_chord_um),
            "source": f"espin measure of {getattr(measurement, 'source', 'an image')}",
        }
        found |= {key: getattr(measurement, key, None) for key in _CROSSING_KEYS}
        return cls.from_table(measurement.fibers, **(found | extra))

    @classmethod
    def from_folder(cls, folder: str | Path, **extra: Any) -> GeometryTargets:
        """Targets from a folder of ``espin measure``: ``fibers.csv`` + ``measurement.toml``
        (its ``[crossing]`` table, when present, gives the edge-to-edge statistics)."""
        folder = Path(folder)
        toml_path = folder / "measurement.toml"
        if not (folder / "fibers.csv").is_file() or not toml_path.is_file():
            raise MeasurementError(f"{folder} must hold fibers.csv and measurement.toml (as written by espin measure)")
        try:
            meta = tomllib.loads(toml_path.read_text("utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
            raise MeasurementError(f"{toml_path} is not valid TOML: {err}") from None
        for key in ("um_per_px", "field_of_view_um"):
            if key not in meta:
                raise MeasurementError(f"{toml_path}: missing key {key}")
        um_per_px = meta["um_per_px"]
        if isinstance(um_per_px, bool) or not isinstance(um_per_px, (int, float)) or not um_per_px > 0:
            raise MeasurementError(f"{toml_path}: um_per_px must be a number > 0, got {um_per_px!r}")
        try:
            found: dict[str, Any] = {"field_of_view_um": _field_of_view(meta["field_of_view_um"])}
            if "min_chord_um" in meta:
                found["min_chord_um"] = _number(meta["min_chord_um"], "min_chord_um")
            found |= _crossing_table(meta.get("crossing", {}))
        except MeasurementError as err:
            raise MeasurementError(f"{toml_path}: {err}") from None
        return cls.from_csv(folder / "fibers.csv", **(found | extra))

    @classmethod
    def from_path(cls, path: str | Path, **extra: Any) -> GeometryTargets:
        """Targets from a measure folder or a ``fibers.csv``."""
        path = Path(path)
        try:
            if path.is_dir():
                return cls.from_folder(path, **extra)
            return cls.from_csv(path, **extra)
        except MeasurementError as err:
            if str(path) in str(err):
                raise
            where = path / "fibers.csv" if path.is_dir() else path
            raise MeasurementError(f"{where}: {err}") from None

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
        return self.orientation_deg is not None or self.orientation_uniform or self.orientation_mean_deg is not None

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
