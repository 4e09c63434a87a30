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
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, TypeVar

import numpy as np

from espin.core.errors import InadmissibleState, StepFailureKind, StepNotConverged

__all__ = ["Evaluated", "line_search"]

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
    hi: float | None = None
    s_hi: float | None = None
    best = None  # the trial at ``lo``: the potential still falls there
    alpha = 1.0
    for _ in range(MAX_TRIALS):
        try:
            trial = evaluate(point.z + alpha * direction, point)
        except InadmissibleState:  # overshot into inadmissible states: shorten
            hi, s_hi = alpha, None
            alpha = lo + 0.1 * (alpha - lo)
            continue
        s = float(np.dot(trial.residual, direction))
        if (s <= 0.0 and alpha == 1.0) or abs(s) <= SLOPE_RATIO * abs(s0):
            if _decreases(point, trial, direction, alpha, s0, s, evaluate, weight):
                return trial
            hi, s_hi = alpha, None
        elif s > 0.0:
            hi, s_hi = alpha, s
        else:
            lo, s_lo, best = alpha, s, trial
        if hi is None:
            alpha = min(2.0 * alpha, 1.0)
        elif s_hi is None:
            alpha = lo + 0.5 * (hi - lo)
        else:
            guess = lo - s_lo * (hi - lo) / (s_hi - s_lo)
            width = hi - lo
            alpha = float(np.clip(guess, lo + 0.1 * width, hi - 0.1 * width))
        if hi is not None and hi - lo < SHORTEST:
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
    return alpha / 6.0 * (s0 + 4.0 * s_middle + s_trial) < 0.0
