"""Uncertainty of the fit: Gauss-Newton covariance at the optimum, the curvature of the eta
profile, and the spread over the realizations."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from espin.analysis.calibration.model import _Model
from espin.analysis.calibration.parameters import ETA_KEY, FIT_PARAMETERS
from espin.analysis.calibration.search import _FiberFit

log = logging.getLogger(__package__)
ETA_SECANT = 0.05
"""Relative half-width of the central difference of the model in eta (for the covariance); at
least one fiber per layer (:func:`eta_resolution`), else the secant may not change the network."""


def eta_resolution(problem) -> float:
    """Volume fraction of one fiber in a layer, pi D / (4 L) (a random chord of the square
    layer is pi L / 4 long on average): eta changes the network in steps of about this."""
    rve = problem.base.rve
    return math.pi * rve.diameter_um / (4 * rve.side_um)


@dataclass(frozen=True, eq=False)
class _Uncertainty:
    sd: dict[str, float]
    realization_sd: dict[str, float] | None
    correlation: np.ndarray
    eta_profile_sd: float | None
    notes: tuple[str, ...] = ()


def _full_jacobian(model: _Model, best: _FiberFit, notes: list[str]) -> np.ndarray:
    """d residual / d (eta, z) at the optimum; the eta column is a central secant of +-5 % (at
    least one fiber per layer); one-sided where one side's runs failed; NaN (so every sd NaN)
    when both failed."""
    if not model.problem.fits_eta:
        return best.jacobian
    d = max(ETA_SECANT * best.eta, eta_resolution(model.problem))
    d = min(d, 0.5 * best.eta, 0.5 * (1 - best.eta))
    fiber = best.evaluation.fiber
    up, down = model.evaluate([(best.eta + d, fiber), (best.eta - d, fiber)], "eta secant")
    if not (up.failures or down.failures):
        eta_column = (up.mean - down.mean) / (2 * d)
    elif up.failures and down.failures:
        eta_column = np.full(best.evaluation.mean.shape, np.nan)
        notes.append(
            f"the eta secant failed on both sides of {ETA_KEY} = {best.eta:.6g} ({up.failures[0]}): no Gauss-Newton sd"
        )
    else:
        side = down if up.failures else up
        eta_column = (side.mean - best.evaluation.mean) / (side.eta - best.eta)
        notes.append(
            f"the eta secant failed at {ETA_KEY} = {(up if up.failures else down).eta:.6g}; one-sided secant used"
        )
    for note in notes:
        log.warning(note)
    return np.column_stack([eta_column, best.jacobian])


def _eta_profile_sd(solved: Sequence[_FiberFit], best: _FiberFit, s2: float, spacing: float) -> float:
    """sd of eta from the profile's curvature: SSE ~ a + c (eta - eta0)^2, sd^2 = s^2 / c."""
    near = [f for f in solved if abs(f.eta - best.eta) <= spacing * (1 + 1e-9) and math.isfinite(f.sse)]
    if len({f.eta for f in near}) < 3:
        return math.nan
    curvature = np.polyfit([f.eta for f in near], [f.sse for f in near], 2)[0]
    return math.sqrt(s2 / curvature) if curvature > 0 else math.nan


def _uncertainty(model: _Model, best: _FiberFit, solved: Sequence[_FiberFit]) -> _Uncertainty:
    problem = model.problem
    notes: list[str] = []
    J = _full_jacobian(model, best, notes)
    m, p = J.shape
    s2 = best.sse / max(m - p, 1)
    internal = np.array([best.eta] * problem.fits_eta + list(best.z))
    to_value = np.array([math.exp(z) if FIT_PARAMETERS[k].log_scale else 1.0 for k, z in zip(problem.keys, internal)])
    try:
        inverse = np.linalg.inv(J.T @ J)
    except (np.linalg.LinAlgError, ValueError):
        inverse = np.full((p, p), np.inf)
    sd_z = np.sqrt(np.abs(np.diag(s2 * inverse)))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = s2 * inverse / np.outer(sd_z, sd_z)
    spread = None
    if len(problem.seeds) > 1:
        deviation = best.evaluation.per_realization - best.evaluation.mean  # (R, m)
        shifts = -(inverse @ J.T @ np.nan_to_num(deviation).T).T  # (R, p): fit to one realization
        spread = dict(zip(problem.keys, (shifts.std(axis=0, ddof=1) * to_value).tolist()))
    eta_sd = None
    if problem.fits_eta:
        spacing = np.diff(problem.bounds[ETA_KEY])[0] / (problem.eta_points - 1)
        eta_sd = _eta_profile_sd(solved, best, s2, spacing)
    return _Uncertainty(dict(zip(problem.keys, (sd_z * to_value).tolist())), spread, correlation, eta_sd, tuple(notes))
