"""Searches of the deposition walk (tortuosity, with its valley) and of the orientation kappa."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from espin.core.config import WALK_DEFAULTS
from espin.core.errors import ConfigError
from espin.imaging.geometry_calibration.fits import KAPPA_MAX, _mean_resultant, persistence_ratio
from espin.imaging.geometry_calibration.matching import CrossingTarget, _Target
from espin.imaging.geometry_calibration.virtual import VirtualMeasurement

__all__ = [
    "DEVIATION_RANGE_DEG",
    "DEVIATION_GRID_STEP_DEG",
    "SEGMENT_RATIO_MIN",
    "SEGMENT_RATIO_MAX_FRACTION",
    "VALLEY_SEGMENT_RATIOS",
    "ValleyPoint",
    "WalkScore",
    "SEGMENTS_PER_WAVINESS_LENGTH",
    "smooth_walk",
    "WAVINESS_RANGE_DEG",
    "WAVINESS_GRID_STEP_DEG",
    "WAVINESS_LENGTH_RATIOS",
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
WAVINESS_RANGE_DEG = (0.0, 45.0)
"""Search range of ``rve.waviness_deg`` [deg] (the smooth walk)."""
WAVINESS_GRID_STEP_DEG = 5.0
WAVINESS_LENGTH_RATIOS = (2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0)
"""Correlation lengths [D] of the smooth walk's grid (those longer than four windows are
skipped: they look straight in the window)."""


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


@dataclass(frozen=True)
class WalkScore:
    """How well one walk matches the targets, as measured on the virtual mats.

    Attributes
    ----------
    walk : dict
        The walk's config keys (``walk`` and its parameters).
    ks : float
        Tortuosity KS distance of the virtual pieces against the target.
    u_turn_fraction, straightness : float
        Of the virtual window portions that cross the window edge to edge.
    score : float
        What the search minimizes: (KS / its sampling spread)^2, plus the crossing misfit
        (:meth:`CrossingTarget.misfit`) when the targets carry the long-range shape.
    """

    walk: dict[str, Any]
    ks: float
    u_turn_fraction: float
    straightness: float
    score: float


SEGMENTS_PER_WAVINESS_LENGTH = 4.0
"""The smooth walk is drawn with segments of at most its correlation length over this, so
that the wiggles the correlation length sets are resolved."""


def smooth_walk(waviness_deg: float, waviness_length_ratio: float, segment_ratio: float) -> dict[str, Any]:
    """Config keys of a smooth walk, its segment the shorter of ``segment_ratio`` and the
    correlation length over :data:`SEGMENTS_PER_WAVINESS_LENGTH` (three digits)."""
    segment = min(segment_ratio, waviness_length_ratio / SEGMENTS_PER_WAVINESS_LENGTH)
    return {
        "walk": "smooth",
        "waviness_deg": waviness_deg,
        "waviness_length_ratio": waviness_length_ratio,
        "segment_ratio": float(f"{segment:.3g}"),
    }


class _Objective:
    """Score of a walk against the tortuosity (and the long-range shape), cached.
    ``segment_ratio`` is the longest segment [D] of the smooth walk."""

    def __init__(
        self,
        measurement: VirtualMeasurement,
        rve: dict[str, Any],
        side_um: float,
        target: _Target,
        crossing: CrossingTarget | None,
        segment_ratio: float,
        progress: Callable[[str], None] | None,
    ) -> None:
        self.measurement, self.rve, self.side_um = measurement, rve, side_um
        self.target, self.crossing, self.progress = target, crossing, progress
        self.cache: dict[tuple[Any, ...], WalkScore] = {}
        self.n_virtual = 0
        self.segment_ratio = float(segment_ratio)

    def evaluate(self, walk: dict[str, Any]) -> WalkScore:
        """Measure mats of ``walk`` (config keys; the other walk's keys of the base dropped)."""
        walk = {k: round(v, 6) if isinstance(v, float) else v for k, v in walk.items()}
        key = tuple(sorted(walk.items()))
        if key not in self.cache:
            other = {k for name, keys in WALK_DEFAULTS.items() if name != walk["walk"] for k in keys}
            rve = {k: v for k, v in self.rve.items() if k not in other} | walk
            seen = self.measurement.measure(rve, self.side_um)
            ks = self.target.ks(seen["tortuosity"])
            self.n_virtual = len(seen["tortuosity"])
            score = (ks / self.target.ks_noise(self.n_virtual)) ** 2
            if self.crossing is not None:
                score += self.crossing.misfit(seen["crossing"])
            result = WalkScore(dict(walk), ks, float(seen["crossing"][1]), float(seen["crossing"][2]), float(score))
            self.cache[key] = result
            if self.progress is not None:
                shown = ", ".join(f"{k} {v:.3g}" for k, v in walk.items() if k != "walk")
                self.progress(
                    f"{walk['walk']} walk, {shown}: KS {ks:.4f}, U-turns "
                    f"{result.u_turn_fraction:.3f}, straightness {result.straightness:.4f}"
                )
        return self.cache[key]

    def __call__(self, segment_ratio: float, max_deviation_deg: float) -> float:
        """Score of the paper walk (segment_ratio, max_deviation_deg)."""
        return self.evaluate(
            {"walk": "paper", "segment_ratio": segment_ratio, "max_deviation_deg": max_deviation_deg}
        ).score

    def smooth(self, waviness_deg: float, waviness_length_ratio: float) -> float:
        """Score of the smooth walk, with segments of :func:`smooth_walk`."""
        return self.evaluate(smooth_walk(waviness_deg, waviness_length_ratio, self.segment_ratio)).score


def _grid_then_refine(f: Callable[[float], float], grid: np.ndarray, xatol: float) -> tuple[float, float]:
    """Minimize ``f`` over a grid, then refine in the bracket around the best grid point."""
    from scipy import optimize

    values = [f(x) for x in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    best_x, best_f = float(grid[i]), float(values[i])
    if hi > lo:
        res = optimize.minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": xatol})
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


def _correct_kappa(
    measurement: VirtualMeasurement,
    rve: dict[str, Any],
    side_um: float,
    mean_deg: float,
    kappa: float,
    order: float,
    progress: Callable[[str], None] | None,
) -> tuple[float, str | None, int]:
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
        return (
            KAPPA_MAX,
            (
                f"the visible orientation order {order:.3f} is out of reach: even kappa = {KAPPA_MAX:g} "
                f"at deposition gives {highest:.3f}, because the deposition walk forgets its direction "
                "over about a quarter of its persistence length; kappa set to its maximum"
            ),
            calls[0],
        )
    root = optimize.brentq(
        lambda u: counted(math.exp(u)) - order, math.log(max(kappa, 1e-3)), math.log(KAPPA_MAX), xtol=0.01
    )
    return float(f"{math.exp(root):.4g}"), None, calls[0]


def _fit_walk(
    objective: _Objective,
    fit: str,
    segment_ratio: float,
    max_deviation_deg: float,
    largest_segment: float,
    segment_ratios: tuple[float, ...],
) -> tuple[float, float, list[ValleyPoint], str | None]:
    """Search the walk parameter(s) named by ``fit``; the other keeps its given value.

    Returns the segment ratio, the deviation [deg], the valley (``fit="both"``) and a warning
    when the result sits at the end of its search range.
    """
    sr, dev = segment_ratio, max_deviation_deg
    if fit == "deviation":
        dev, _ = _search_deviation(objective, sr)
        if _at_bound(dev, *DEVIATION_RANGE_DEG, 0.5):
            return (
                sr,
                dev,
                [],
                (
                    f"max_deviation_deg = {dev:g} is at the end of its search range "
                    f"{DEVIATION_RANGE_DEG}: try fit = segment or both"
                ),
            )
        return sr, dev, [], None
    if fit == "segment":
        sr, _ = _search_segment(objective, dev, largest_segment)
        if _at_bound(sr, SEGMENT_RATIO_MIN, largest_segment, 0.05 * sr):
            return (
                sr,
                dev,
                [],
                (
                    f"segment_ratio = {sr:g} is at the end of its search range [{SEGMENT_RATIO_MIN:g}, "
                    f"{largest_segment:.3g}]: the target is out of reach at max_deviation_deg = "
                    f"{dev:g}; try fit = deviation or both"
                ),
            )
        return sr, dev, [], None
    usable = [r for r in segment_ratios if SEGMENT_RATIO_MIN <= r <= largest_segment]
    if not usable:
        raise ConfigError(
            f"segment_ratios must hold values in [{SEGMENT_RATIO_MIN:g}, {largest_segment:.3g}] "
            f"(up to a third of the window), got {list(segment_ratios)}"
        )
    valley = []
    for s in usable:
        d, _ = _search_deviation(objective, s)
        ks = objective.evaluate({"walk": "paper", "segment_ratio": s, "max_deviation_deg": d}).ks
        valley.append(ValleyPoint(s, d, persistence_ratio(s, d), ks))
    # Points within the sampling spread of the best KS are equally good: keep the one whose
    # segment length is closest to the given (base) one.
    tie = min(v.ks for v in valley) + objective.target.ks_noise(objective.n_virtual)
    best = min((v for v in valley if v.ks <= tie), key=lambda v: abs(math.log(v.segment_ratio / segment_ratio)))
    return best.segment_ratio, best.max_deviation_deg, valley, None


def _search_smooth(objective: _Objective, window_ratio: float, length_ratio: float | None) -> tuple[float, float]:
    """Waviness [deg] and correlation length [D] of the smooth walk of least score: a grid,
    then bounded refinements of each at the best grid point. With ``length_ratio`` given
    (no long-range target: only one combination is identifiable) only the waviness is
    searched.

    Returns the waviness [deg] and the correlation length over D.
    """
    lo, hi = WAVINESS_RANGE_DEG
    sigmas = np.arange(lo, hi + 1e-9, WAVINESS_GRID_STEP_DEG)
    if length_ratio is not None:
        x, _ = _grid_then_refine(lambda w: objective.smooth(w, length_ratio), sigmas, xatol=0.05)
        return round(x, 1), length_ratio
    lengths = [r for r in WAVINESS_LENGTH_RATIOS if r <= 4.0 * window_ratio] or [WAVINESS_LENGTH_RATIOS[0]]
    scores = np.array([[objective.smooth(w, r) for r in lengths] for w in sigmas])
    i, j = np.unravel_index(np.argmin(scores), scores.shape)
    grid = np.log(lengths)
    sigma, _ = _grid_then_refine(lambda w: objective.smooth(w, lengths[j]), sigmas[max(i - 1, 0) : i + 2], xatol=0.05)
    u, _ = _grid_then_refine(
        lambda v: objective.smooth(round(sigma, 1), float(f"{math.exp(v):.3g}")),
        grid[max(j - 1, 0) : j + 2],
        xatol=0.02,
    )
    return round(sigma, 1), float(f"{math.exp(u):.3g}")


@dataclass(frozen=True)
class WalkFit:
    """The walks fitted and the one kept.

    Attributes
    ----------
    scores : dict of WalkScore
        The best point of each walk fitted, by walk name.
    chosen : str
        The walk of smallest score.
    valley : tuple of ValleyPoint
        The paper walk's valley (``fit="both"``).
    problem : str or None
        A warning about the chosen walk (a result at the end of its range).
    evaluations : int
        Walks measured.
    """

    scores: dict[str, WalkScore]
    chosen: str
    valley: tuple[ValleyPoint, ...]
    problem: str | None
    evaluations: int


def _fit_walks(
    objective: _Objective,
    walk: str,
    fit: str,
    segment_ratio: float,
    max_deviation_deg: float,
    length_ratio: float,
    largest_segment: float,
    segment_ratios: tuple[float, ...],
    window_ratio: float,
) -> WalkFit:
    """Fit the walks ``walk`` names (``auto``: both when the objective has the long-range
    shape, else the paper walk) and keep the one of smallest score.

    The paper walk searches what ``fit`` says from (``segment_ratio``,
    ``max_deviation_deg``); the smooth walk its waviness and correlation length, or only the
    waviness at ``length_ratio`` when the objective has no long-range shape.
    """
    models = (
        ("paper", "smooth")
        if walk == "auto" and objective.crossing is not None
        else ("paper",)
        if walk == "auto"
        else (walk,)
    )
    scores: dict[str, WalkScore] = {}
    problems: dict[str, str | None] = {}
    valley: list[ValleyPoint] = []
    if "paper" in models:
        sr, dev, valley, problems["paper"] = _fit_walk(
            objective, fit, segment_ratio, max_deviation_deg, largest_segment, segment_ratios
        )
        scores["paper"] = objective.evaluate({"walk": "paper", "segment_ratio": sr, "max_deviation_deg": dev})
    if "smooth" in models:
        fixed = None if objective.crossing is not None else length_ratio
        sigma, length = _search_smooth(objective, window_ratio, fixed)
        scores["smooth"] = objective.evaluate(smooth_walk(sigma, length, segment_ratio))
        problems["smooth"] = None
        lengths = [r for r in WAVINESS_LENGTH_RATIOS if r <= 4.0 * window_ratio]
        if sigma >= WAVINESS_RANGE_DEG[1] - 0.5:
            problems["smooth"] = f"waviness_deg = {sigma:g} is at the end of its search range {WAVINESS_RANGE_DEG}"
        elif fixed is None and lengths and (length <= lengths[0] or length >= lengths[-1]):
            problems["smooth"] = (
                f"waviness_length_ratio = {length:g} is at the end of its search range "
                f"[{lengths[0]:g}, {lengths[-1]:g}]"
            )
    chosen = min(scores, key=lambda name: scores[name].score)
    return WalkFit(scores, chosen, tuple(valley), problems[chosen], len(objective.cache))


def _with_walk(rve: dict[str, Any], fitted: WalkFit) -> dict[str, Any]:
    """``rve`` keys with the chosen walk's keys, the other walk's (and ``segment_um``) removed."""
    keys = fitted.scores[fitted.chosen].walk
    other = {k for name, names in WALK_DEFAULTS.items() if name != fitted.chosen for k in names}
    return {k: v for k, v in rve.items() if k not in other | {"segment_um"}} | keys
