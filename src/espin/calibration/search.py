"""The search: least squares over the fiber parameters at one eta, and the 1-D search over eta
(a grid over its bounds, then a bounded Brent search)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from espin.calibration.model import _describe, _Evaluation, _Model, _sse
from espin.calibration.parameters import ETA_KEY
from espin.errors import SolverError

log = logging.getLogger(__package__)

FD_STEP = 1e-3
"""Forward-difference step of the Jacobian: in log-parameter (0.1 %) or in c_p itself."""
XTOL, FTOL = 1e-3, 1e-4
"""least_squares stops when a step changes the fit coordinates by < 0.1 % or the SSE by < 0.01 %
(far below the parameters' uncertainty)."""
MAX_NFEV = 40
"""Most model evaluations of one least-squares fit (one eta)."""


# --------------------------------------------------------------------------------------------
# least squares over the fiber parameters at one eta
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _FiberFit:
    """The least-squares fit of the fiber parameters at one eta.

    z : (k,) internal coordinates of the fiber parameters (log for log-scale ones)
    jacobian : (m, k) d residual / d z at z [MPa]
    """

    eta: float
    z: np.ndarray
    evaluation: _Evaluation
    sse: float
    jacobian: np.ndarray
    message: str


def _jacobian(model: _Model, eta: float, z: np.ndarray, at: _Evaluation, stage: str) -> np.ndarray:
    """Forward differences in z (backward at an upper bound), all columns in one batch."""
    problem = model.problem
    _, hi = problem.internal_bounds()
    steps = np.where(z + FD_STEP <= hi, FD_STEP, -FD_STEP)
    shifted = [z + h * e for h, e in zip(steps, np.eye(z.size))]
    evaluations = model.evaluate([(eta, problem.fiber_values(s)) for s in shifted], stage)
    for evaluation in (at, *evaluations):
        if evaluation.failures:
            raise SolverError(
                f"fit: the model failed at {_describe(evaluation.eta, evaluation.fiber)} while "
                f"computing the Jacobian: {evaluation.failures[0]}. Narrow the bounds of "
                f"{', '.join(problem.fiber_keys)} or use more load steps"
            )
    r0 = model.residual(at)
    return np.column_stack([(model.residual(e) - r0) / h for e, h in zip(evaluations, steps)])


def _fit_fiber(model: _Model, eta: float, z0: np.ndarray, stage: str) -> _FiberFit:
    """Fit the continuous (fiber) parameters at a fixed eta (the network is fixed)."""
    problem = model.problem
    if not problem.fiber_keys:
        evaluation = model.evaluate([(eta, {})], stage)[0]
        m = problem.data.size
        return _FiberFit(eta, z0, evaluation, _sse(model.residual(evaluation)), np.zeros((m, 0)), "eta only")
    seen: dict[bytes, _Evaluation] = {}

    def at(z: np.ndarray) -> _Evaluation:
        key = np.asarray(z, dtype=float).tobytes()
        if key not in seen:
            seen[key] = model.evaluate([(eta, problem.fiber_values(z))], stage)[0]
        return seen[key]

    solution = least_squares(
        lambda z: model.residual(at(z)),
        z0,
        jac=lambda z: _jacobian(model, eta, z, at(z), stage + " jacobian"),
        bounds=problem.internal_bounds(),
        method="trf",
        xtol=XTOL,
        ftol=FTOL,
        max_nfev=MAX_NFEV,
    )
    evaluation = at(solution.x)
    log.info("eta %.5g: %s (%d evaluations)", eta, solution.message, solution.nfev)
    return _FiberFit(eta, solution.x, evaluation, _sse(model.residual(evaluation)), solution.jac,
                     solution.message)


# --------------------------------------------------------------------------------------------
# the 1-D search over eta
# --------------------------------------------------------------------------------------------
def _search(model: _Model) -> tuple[_FiberFit, list[_FiberFit]]:
    """The best fit and every fit made on the way (one per eta visited).

    eta: a grid over its bounds (from the base value outwards, each fit starting from the
    nearest one solved), then a bounded Brent search between the best grid point's neighbours.
    """
    problem = model.problem
    if not problem.fits_eta:
        only = _fit_fiber(model, problem.base_value(ETA_KEY), problem.start(), "fit")
        return only, [only]
    solved: list[_FiberFit] = []

    def profile(eta: float, stage: str) -> float:
        start = min(solved, key=lambda f: abs(f.eta - eta)).z if solved else problem.start()
        solved.append(_fit_fiber(model, float(eta), start, stage))
        return solved[-1].sse

    grid = np.linspace(*problem.bounds[ETA_KEY], problem.eta_points)
    sse = {eta: profile(eta, "eta grid") for eta in sorted(grid, key=lambda e: abs(e - problem.base_value(ETA_KEY)))}
    k = int(np.argmin([sse[eta] for eta in grid]))
    bracket = (grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)])
    minimize_scalar(lambda eta: profile(eta, "eta bracket"), bounds=bracket, method="bounded",
                    options={"xatol": problem.eta_tolerance})
    return min(solved, key=lambda f: f.sse), solved
