"""Tensile properties as testing standards report them (ISO 527-1, ASTM D882), for measured curves.

Beside espin's bilinear fit (:mod:`espin.analysis.properties`), a tensile report of a mat
states (docs/properties.md):

* **chord modulus** E_c [MPa]: the slope of the least-squares line through the curve's points
  with eps_1 <= strain <= eps_2 (ISO 527-1 allows the regression in place of the two-point
  secant); default eps_1 = 0.05 %, eps_2 = 0.25 % (ISO 527-1). The range must hold at least
  two points of the curve.
* **offset yield** (proof stress R_p, e.g. 0.2 %): where the curve first falls below the
  chord line shifted by the offset strain (the chord line crossing zero stress at eps_0, the
  toe compensation of ASTM D638 and D882), interpolated linearly between points.
* **tensile strength** sigma_m [MPa] and the strain at it: the largest stress, reported only
  when the stress falls after it (a curve that rises to its last point has not shown its
  strength: a simulated mat, or a test stopped early).
* **strain at break** eps_b (and the stress there): the last point before the stress, after
  its maximum, first falls below (1 - ``break_drop``) sigma_m (a break detected as that load
  drop, 50 % by default); none when it does not fall that far.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from espin.analysis.properties import CurveError, check_curve

__all__ = ["ISO_CHORD_RANGE", "StandardProperties", "standard_properties"]

ISO_CHORD_RANGE = (0.0005, 0.0025)
"""The chord modulus's strain range of ISO 527-1 (0.05 % to 0.25 %)."""


@dataclass(frozen=True)
class StandardProperties:
    """Tensile properties of one curve by the testing standards' definitions (module docs).

    Attributes
    ----------
    chord_modulus_MPa : float [MPa]
        E_c over ``chord_range``; NaN when the range holds fewer than two points.
    chord_range : tuple of float
        (eps_1, eps_2), strains.
    offset_yield_stress_MPa, offset_yield_strain : float [MPa], strain
        The offset yield point; NaN without a chord modulus or a crossing.
    offset : float
        The offset strain (0.002 for R_p0.2).
    tensile_strength_MPa, strain_at_strength : float [MPa], strain
        The maximum; NaN when the stress does not fall after it.
    strain_at_break, stress_at_break_MPa : float, float [MPa]
        The break point; NaN when no break is detected.
    note : str
        What could not be determined and why; empty when everything was.
    """

    chord_modulus_MPa: float
    chord_range: tuple[float, float]
    offset_yield_stress_MPa: float
    offset_yield_strain: float
    offset: float
    tensile_strength_MPa: float
    strain_at_strength: float
    strain_at_break: float
    stress_at_break_MPa: float
    note: str

    def as_dict(self) -> dict[str, float | str]:
        """Flat fields (the chord range as ``chord_from``, ``chord_to``)."""
        values = asdict(self)
        lo, hi = values.pop("chord_range")
        return {"chord_from": lo, "chord_to": hi, **values}


def _check_options(chord_range: tuple[float, float], offset: float, break_drop: float) -> None:
    lo, hi = chord_range
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi):
        raise CurveError(f"chord_range: strains 0 <= eps_1 < eps_2 (got {chord_range})")
    if not (math.isfinite(offset) and offset > 0.0):
        raise CurveError(f"offset: a strain > 0, e.g. 0.002 for 0.2 % (got {offset})")
    if not 0.0 < break_drop < 1.0:
        raise CurveError(f"break_drop: a fraction of the tensile strength in (0, 1) (got {break_drop})")


def chord_modulus(
    strain: np.ndarray, stress: np.ndarray, chord_range: tuple[float, float]
) -> tuple[float, float] | None:
    """Slope [MPa] and zero-stress strain eps_0 of the least-squares line through the points
    in ``chord_range``; None when it holds fewer than two distinct strains."""
    inside = (strain >= chord_range[0]) & (strain <= chord_range[1])
    x, y = strain[inside], stress[inside]
    if np.unique(x).size < 2:
        return None
    slope, intercept = np.polyfit(x, y, 1)
    if slope <= 0.0:
        return float(slope), math.nan
    return float(slope), float(-intercept / slope)


def _offset_yield(
    strain: np.ndarray, stress: np.ndarray, modulus: float, zero: float, offset: float, start: float
) -> tuple[float, float]:
    """First point from strain ``start`` on where the curve falls below the offset line."""
    above = stress - modulus * (strain - zero - offset)
    after = strain > start
    if after.any() and above[np.argmax(after)] < 0.0:
        return math.nan, -math.inf  # below the offset line from the chord range on
    candidates = np.flatnonzero((above[:-1] >= 0.0) & (above[1:] < 0.0) & (strain[1:] > start))
    if candidates.size == 0:
        return math.nan, math.nan
    i = candidates[0]
    t = above[i] / (above[i] - above[i + 1])
    return (float(stress[i] + t * (stress[i + 1] - stress[i])), float(strain[i] + t * (strain[i + 1] - strain[i])))


def standard_properties(
    strain: ArrayLike,
    stress: ArrayLike,
    *,
    chord_range: tuple[float, float] = ISO_CHORD_RANGE,
    offset: float = 0.002,
    break_drop: float = 0.5,
    require_chord: bool = False,
) -> StandardProperties:
    """Chord modulus, offset yield, tensile strength and strain at break of a curve.

    Parameters
    ----------
    strain, stress
        Engineering strain (increasing) and stress [MPa].
    chord_range
        (eps_1, eps_2) of the chord modulus, strains (default ISO 527-1: 0.0005, 0.0025).
    offset
        Offset strain of the offset yield (default 0.002: R_p0.2).
    break_drop
        Load drop after the maximum that marks the break, a fraction of the tensile strength
        in (0, 1) (default 0.5).
    require_chord
        Raise instead of reporting NaN when ``chord_range`` holds fewer than two points
        (a range the user stated).

    Raises
    ------
    CurveError
        If the curve cannot be read as one (see :func:`espin.analysis.properties.check_curve`),
        an option is out of range, or ``require_chord`` and the range is empty.
    """
    _check_options(chord_range, offset, break_drop)
    x, y = check_curve(strain, stress)
    notes = []
    chord = chord_modulus(x, y, chord_range)
    modulus = zero = math.nan
    span = f"{100 * chord_range[0]:g} % to {100 * chord_range[1]:g} % strain"
    if chord is None:
        inside = int(np.count_nonzero((x >= chord_range[0]) & (x <= chord_range[1])))
        message = (
            f"the chord range {span} holds {inside} "
            f"point(s) of the curve (its strains: {100 * x[0]:.3g} % to {100 * x[-1]:.3g} %, "
            f"{x.size} points); give a chord range (chord_range, --chord-range LO:HI) over the curve's "
            "linear part that holds two points or more, e.g. 0:0.02 on a curve in 1 % steps such as "
            "espin's own (not the ISO range, so not an ISO 527 value)"
        )
        if require_chord:
            raise CurveError(message)
        notes.append(f"no chord modulus: {message}")
    else:
        modulus, zero = chord
        if not modulus > 0.0:
            notes.append(f"no offset yield: the stress does not rise over {span}")
    yield_stress = yield_strain = math.nan
    if modulus > 0.0:
        yield_stress, yield_strain = _offset_yield(x, y, modulus, zero, offset, chord_range[0])
        if yield_strain == -math.inf:
            yield_strain = math.nan
            notes.append(
                f"no offset yield: the curve lies below the chord line shifted by {100 * offset:g} % "
                "from the chord range on (is the curve linear there?)"
            )
        elif math.isnan(yield_stress):
            notes.append(f"no offset yield: the curve stays above the chord line shifted by {100 * offset:g} %")
    peak = int(np.argmax(y))
    strength = strength_strain = break_strain = break_stress = math.nan
    if y[peak] <= 0.0:
        notes.append("no tensile strength or break: the stress is never positive")
    elif peak == y.size - 1:
        notes.append(
            "no tensile strength or break: the stress rises to the curve's last point (a simulated "
            "mat, or a test stopped before the maximum; a curve cut at a brittle break has its "
            "strength at the last point)"
        )
    else:
        strength, strength_strain = float(y[peak]), float(x[peak])
        dropped = np.flatnonzero(y[peak:] < (1.0 - break_drop) * strength)
        if dropped.size:
            last = peak + dropped[0] - 1
            break_strain, break_stress = float(x[last]), float(y[last])
        else:
            notes.append(f"no break: the stress does not fall by {100 * break_drop:g} % after its maximum")
    return StandardProperties(
        modulus,
        (float(chord_range[0]), float(chord_range[1])),
        yield_stress,
        yield_strain,
        float(offset),
        strength,
        strength_strain,
        break_strain,
        break_stress,
        "; ".join(notes),
    )
