"""The line search of Newton's method on an incremental potential (docs/model.md section 4).

Along a Newton direction dz from the iterate z the potential's derivative is
s(alpha) = r(z + alpha dz) . dz, one residual evaluation per trial. A trial is accepted when
the full step still descends (s(1) <= 0) or when |s(alpha)| <= 0.5 |s(0)| (the potential near
its minimum along the line); otherwise the zero of s is bracketed and found by safeguarded
regula falsi. Where the residual grew, the decrease of the potential itself is checked: its
increment from z to the trial, by Simpson's rule on s along the line (the derivative is
continuous because the stress is; never a difference of two large totals).

The search knows the problem only through ``evaluate(z, near)``: it returns the point at z
(anything with ``z`` and ``residual``; ``near`` an evaluated point of the same step, a warm
start) or raises :class:`~espin.core.errors.InadmissibleState` where z lies outside the model's
domain (the search then shortens the step).

The rules of a trial (:func:`accepts`, :func:`next_step`, :func:`shortened`,
:func:`simpson_decrease`) take floats or arrays, so that the line searches of many problems in
lockstep (:mod:`espin.specimen.batched_points`) follow them too.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol, TypeVar

import numpy as np

from espin.core.errors import InadmissibleState, StepFailureKind, StepNotConverged

__all__ = ["Evaluated", "line_search", "accepts", "next_step", "shortened", "simpson_decrease"]

SLOPE_RATIO = 0.5
"""|s(alpha)| <= SLOPE_RATIO |s(0)| accepts a trial."""
MAX_TRIALS = 10
SHORTEST = 1e-6
"""A bracket narrower than this (in alpha) ends the search."""


class Evaluated(Protocol):
    """An evaluated iterate: its unknowns and the potential's gradient there."""

    @property
    def z(self) -> np.ndarray: ...

    @property
    def residual(self) -> np.ndarray: ...


P = TypeVar("P", bound=Evaluated)
Value = float | np.ndarray  # one trial or many in lockstep


def accepts(s: Value, alpha: Value, s0: Value) -> np.ndarray:
    """Whether a trial at step ``alpha`` with slope ``s`` passes the slope test (before the
    check that the potential fell): the full step still descends, or |s| <= SLOPE_RATIO |s0|."""
    return np.asarray(((s <= 0.0) & (alpha == 1.0)) | (np.abs(s) <= SLOPE_RATIO * np.abs(s0)))


def next_step(alpha: Value, lo: Value, hi: Value, s_lo: Value, s_hi: Value) -> np.ndarray:
    """The next trial's step after a rejected one at ``alpha``: the bracket [lo, hi] with the
    slopes at its ends (``hi`` NaN: no upper end yet, the step doubles up to 1; ``s_hi`` NaN:
    the upper end's slope is unknown, bisection), else safeguarded regula falsi (at least a
    tenth of the bracket from either end)."""
    width = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        guess = lo - s_lo * width / (s_hi - s_lo)
    bracketed = np.clip(guess, lo + 0.1 * width, hi - 0.1 * width)
    return np.where(np.isnan(hi), np.minimum(2.0 * alpha, 1.0), np.where(np.isnan(s_hi), lo + 0.5 * width, bracketed))


def shortened(alpha: Value, lo: Value) -> Value:
    """The step after a trial at ``alpha`` that left the admissible states (its bracket's upper end)."""
    return lo + 0.1 * (alpha - lo)


def simpson_decrease(alpha: Value, s0: Value, s_middle: Value, s_trial: Value) -> Value:
    """The potential's increment from the iterate to the trial at ``alpha`` by Simpson's rule on
    the slopes at 0, alpha / 2 and alpha."""
    return alpha / 6.0 * (s0 + 4.0 * s_middle + s_trial)


def line_search(point: P, direction: np.ndarray, evaluate: Callable[[np.ndarray, P], P], weight: np.ndarray) -> P:
    """The accepted trial along ``direction`` from ``point`` (module docstring).

    Parameters
    ----------
    point
        The current iterate.
    direction
        The Newton direction dz (a descent direction: r . dz < 0).
    evaluate
        The problem at an iterate (module docstring).
    weight
        Scales of the residual's rows for its norm (all in one unit).

    Raises
    ------
    StepNotConverged
        Of kind ``uphill`` when no trial lowers the potential.
    """
    s0 = float(np.dot(point.residual, direction))
    lo, s_lo = 0.0, s0
    hi = s_hi = math.nan  # no upper end yet; its slope unknown
    best = None  # the trial at ``lo``: the potential still falls there
    alpha = 1.0
    for _ in range(MAX_TRIALS):
        try:
            trial = evaluate(point.z + alpha * direction, point)
        except InadmissibleState:  # overshot into inadmissible states: shorten
            hi, s_hi = alpha, math.nan
            alpha = float(shortened(alpha, lo))
            continue
        s = float(np.dot(trial.residual, direction))
        if accepts(s, alpha, s0):
            if _decreases(point, trial, direction, alpha, s0, s, evaluate, weight):
                return trial
            hi, s_hi = alpha, math.nan
        elif s > 0.0:
            hi, s_hi = alpha, s
        else:
            lo, s_lo, best = alpha, s, trial
        alpha = float(next_step(alpha, lo, hi, s_lo, s_hi))
        if hi - lo < SHORTEST:
            break
    if best is not None and _decreases(point, best, direction, lo, s0, s_lo, evaluate, weight):
        return best  # no better point found, but the potential falls up to it
    raise StepNotConverged("line search could not lower the incremental potential", StepFailureKind.UPHILL)


def _decreases(
    point: P,
    trial: P,
    direction: np.ndarray,
    alpha: float,
    s0: float,
    s_trial: float,
    evaluate: Callable[[np.ndarray, P], P],
    weight: np.ndarray,
) -> bool:
    """Whether the potential at ``trial`` is below that at ``point``; checked by quadrature only
    when the residual grew (Simpson's rule with s at 0, alpha / 2 and alpha: one more evaluation)."""
    if np.linalg.norm(weight * trial.residual) <= np.linalg.norm(weight * point.residual):
        return True
    middle = evaluate(point.z + 0.5 * alpha * direction, point)
    s_middle = float(np.dot(middle.residual, direction))
    return bool(simpson_decrease(alpha, s0, s_middle, s_trial) < 0.0)
