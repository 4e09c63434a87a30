"""Searches of the deposition walk (tortuosity, with its valley) and of the orientation kappa."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from espin.core.errors import ConfigError
from espin.imaging.geometry_calibration.fits import KAPPA_MAX, _mean_resultant, persistence_ratio
from espin.imaging.geometry_calibration.matching import _Target
from espin.imaging.geometry_calibration.virtual import VirtualMeasurement

__all__ = [
    "DEVIATION_RANGE_DEG",
    "DEVIATION_GRID_STEP_DEG",
    "SEGMENT_RATIO_MIN",
    "SEGMENT_RATIO_MAX_FRACTION",
    "VALLEY_SEGMENT_RATIOS",
    "ValleyPoint",
]

DEVIATION_RANGE_DEG = (0.0, 85.0)
"""Search range of ``rve.max_deviation_deg`` [deg]."""
DEVIATION_GRID_STEP_DEG = 5.0
SEGMENT_RATIO_MIN = 0.5
"""Shortest segment searched [D]: shorter ones multiply the deposition cost."""
SEGMENT_RATIO_MAX_FRACTION = 1.0 / 3.0
"""Longest segment searched, as a fraction of the window side: longer segments make every
visible portion a few straight pieces."""
VALLEY_SEGMENT_RATIOS = (1.0, 2.0, 3.0, 5.0, 8.0, 12.0)
"""Segment lengths [D] at which ``fit="both"`` searches the deviation."""


@dataclass(frozen=True)
class ValleyPoint:
    """Best deviation found at one segment length (``fit="both"``): the identifiability curve.

    Attributes
    ----------
    segment_ratio : float
        Segment length over D.
    max_deviation_deg : float [deg]
        Deviation of least tortuosity KS at this segment length.
    persistence_ratio : float
        Persistence length of the walk over D.
    ks : float
        Tortuosity KS distance reached.
    """

    segment_ratio: float
    max_deviation_deg: float
    persistence_ratio: float
    ks: float


class _Objective:
    """Visible-tortuosity KS of a walk (segment_ratio, max_deviation_deg), cached."""

    def __init__(self, measurement: VirtualMeasurement, rve: dict[str, Any], side_um: float,
                 target: _Target, progress: Callable[[str], None] | None) -> None:
        self.measurement, self.rve, self.side_um = measurement, rve, side_um
        self.target, self.progress = target, progress
        self.cache: dict[tuple[float, float], float] = {}
        self.n_virtual = 0

    def __call__(self, segment_ratio: float, max_deviation_deg: float) -> float:
        key = (round(segment_ratio, 6), round(max_deviation_deg, 6))
        if key not in self.cache:
            walk = {"segment_ratio": key[0], "max_deviation_deg": key[1]}
            seen = self.measurement.measure(self.rve | walk, self.side_um)
            self.cache[key] = self.target.ks(seen["tortuosity"])
            self.n_virtual = len(seen["tortuosity"])
            if self.progress is not None:
                self.progress(f"segment_ratio {key[0]:.3g}, max_deviation_deg {key[1]:.2f}: "
                              f"KS {self.cache[key]:.4f}")
        return self.cache[key]


def _grid_then_refine(f: Callable[[float], float], grid: np.ndarray, xatol: float) -> tuple[float, float]:
    """Minimize ``f`` over a grid, then refine in the bracket around the best grid point."""
    from scipy import optimize

    values = [f(x) for x in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    best_x, best_f = float(grid[i]), float(values[i])
    if hi > lo:
        res = optimize.minimize_scalar(f, bounds=(lo, hi), method="bounded",
                                       options={"xatol": xatol})
        if res.fun < best_f:
            best_x, best_f = float(res.x), float(res.fun)
    return best_x, best_f


def _search_deviation(objective: _Objective, segment_ratio: float) -> tuple[float, float]:
    lo, hi = DEVIATION_RANGE_DEG
    grid = np.arange(lo, hi + 1e-9, DEVIATION_GRID_STEP_DEG)
    x, ks = _grid_then_refine(lambda d: objective(segment_ratio, d), grid, xatol=0.05)
    return round(x, 1), ks


def _search_segment(objective: _Objective, max_deviation_deg: float, largest: float) -> tuple[float, float]:
    grid = np.linspace(math.log(SEGMENT_RATIO_MIN), math.log(largest), 13)
    x, ks = _grid_then_refine(lambda u: objective(math.exp(u), max_deviation_deg), grid, xatol=0.005)
    return float(f"{math.exp(x):.3g}"), ks


def _at_bound(value: float, low: float, high: float, tol: float) -> bool:
    return value <= low + tol or value >= high - tol


def _correct_kappa(measurement: VirtualMeasurement, rve: dict[str, Any], side_um: float,
                   mean_deg: float, kappa: float, order: float,
                   progress: Callable[[str], None] | None) -> tuple[float, str | None, int]:
    """Deposition kappa whose visible order matches ``order`` (the target's).

    Returns the kappa, a warning if the order is out of reach, and the evaluations made.
    """
    from scipy import optimize

    def visible_order(k: float) -> float:
        spec = {"von_mises": {"mean_deg": mean_deg, "kappa": k}}
        seen = measurement.measure(rve | {"orientation": spec}, side_um)
        value = _mean_resultant(np.radians(seen["orientation_deg"]))[0]
        if progress is not None:
            progress(f"orientation kappa {k:.4g}: visible order {value:.3f} (target {order:.3f})")
        return value

    calls = [0]

    def counted(k: float) -> float:
        calls[0] += 1
        return visible_order(k)

    if counted(kappa) >= order:
        return kappa, None, calls[0]
    highest = counted(KAPPA_MAX)
    if highest < order:
        return KAPPA_MAX, (
            f"the visible orientation order {order:.3f} is out of reach: even kappa = {KAPPA_MAX:g} "
            f"at deposition gives {highest:.3f}, because the deposition walk forgets its direction "
            "over about a quarter of its persistence length; kappa set to its maximum"
        ), calls[0]
    root = optimize.brentq(lambda u: counted(math.exp(u)) - order,
                           math.log(max(kappa, 1e-3)), math.log(KAPPA_MAX), xtol=0.01)
    return float(f"{math.exp(root):.4g}"), None, calls[0]


def _fit_walk(objective: _Objective, fit: str, segment_ratio: float, max_deviation_deg: float,
              largest_segment: float, segment_ratios: tuple[float, ...]
              ) -> tuple[float, float, list[ValleyPoint], str | None]:
    """Search the walk parameter(s) named by ``fit``; the other keeps its given value.

    Returns the segment ratio, the deviation [deg], the valley (``fit="both"``) and a warning
    when the result sits at the end of its search range.
    """
    sr, dev = segment_ratio, max_deviation_deg
    if fit == "deviation":
        dev, _ = _search_deviation(objective, sr)
        if _at_bound(dev, *DEVIATION_RANGE_DEG, 0.5):
            return sr, dev, [], (f"max_deviation_deg = {dev:g} is at the end of its search range "
                                 f"{DEVIATION_RANGE_DEG}: try fit = segment or both")
        return sr, dev, [], None
    if fit == "segment":
        sr, _ = _search_segment(objective, dev, largest_segment)
        if _at_bound(sr, SEGMENT_RATIO_MIN, largest_segment, 0.05 * sr):
            return sr, dev, [], (
                f"segment_ratio = {sr:g} is at the end of its search range [{SEGMENT_RATIO_MIN:g}, "
                f"{largest_segment:.3g}]: the target is out of reach at max_deviation_deg = "
                f"{dev:g}; try fit = deviation or both")
        return sr, dev, [], None
    usable = [r for r in segment_ratios if SEGMENT_RATIO_MIN <= r <= largest_segment]
    if not usable:
        raise ConfigError(
            f"segment_ratios must hold values in [{SEGMENT_RATIO_MIN:g}, {largest_segment:.3g}] "
            f"(up to a third of the window), got {list(segment_ratios)}"
        )
    valley = []
    for s in usable:
        d, ks = _search_deviation(objective, s)
        valley.append(ValleyPoint(s, d, persistence_ratio(s, d), ks))
    # Points within the sampling spread of the best KS are equally good: keep the one whose
    # segment length is closest to the given (base) one.
    tie = min(v.ks for v in valley) + objective.target.ks_noise(objective.n_virtual)
    best = min((v for v in valley if v.ks <= tie),
               key=lambda v: abs(math.log(v.segment_ratio / segment_ratio)))
    return best.segment_ratio, best.max_deviation_deg, valley, None
