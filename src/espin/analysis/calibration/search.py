"""The search: least squares over the fiber parameters at one eta, and the 1-D search over eta
(a grid over its bounds, then a bounded Brent search)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from espin.analysis.calibration.model import PENALTY_FACTOR, _describe, _Evaluation, _Model, _sse
from espin.analysis.calibration.parameters import ETA_KEY, FIT_PARAMETERS
from espin.core.errors import SolverError

log = logging.getLogger(__package__)

FD_STEP = 1e-3
"""Forward-difference step of the Jacobian: in log-parameter (0.1 %) or in c_p itself."""
XTOL, FTOL = 1e-3, 1e-4
"""least_squares stops when a step changes the fit coordinates by < 0.1 % or the SSE by < 0.01 %
(far below the parameters' uncertainty)."""
MAX_NFEV = 40
"""Most residual evaluations of one least-squares fit (one eta); each Jacobian adds one model
evaluation per fiber parameter, which this limit does not count."""


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


def _hint(model: _Model, eta: float, keys: list[str]) -> str:
    """What to change after a failure: at a fitted eta the network may be the cause."""
    named = ", ".join(f"{k} ({FIT_PARAMETERS[k].symbol})" for k in keys)
    hint = f"Narrow the bounds of {named} or use finer load steps (step_strain)"
    if model.problem.fits_eta:
        return f"{hint}; at this eta ({ETA_KEY} = {eta:.6g}) the network itself may be the cause"
    return hint


def _jacobian(model: _Model, eta: float, z: np.ndarray, at: _Evaluation, stage: str) -> np.ndarray:
    """Forward differences in z (backward at an upper bound), all columns in one batch; a
    column whose run failed is tried once more with the step of the other sign."""
    problem = model.problem
    if at.failures:
        raise SolverError(
            f"fit: the model failed at {_describe(eta, at.fiber)}, where the Jacobian is needed: "
            f"{at.failures[0]}. {_hint(model, eta, list(problem.fiber_keys))}"
        )
    lo, hi = problem.internal_bounds()
    steps = np.where(z + FD_STEP <= hi, FD_STEP, -FD_STEP)
    evaluations = model.evaluate([(eta, problem.fiber_values(z + h * e)) for h, e in zip(steps, np.eye(z.size))], stage)
    failed = [j for j, e in enumerate(evaluations) if e.failures and lo[j] <= z[j] - steps[j] <= hi[j]]
    if failed:
        log.warning("Jacobian at %s: %d column(s) failed; trying the other sign", _describe(eta, at.fiber), len(failed))
        again = model.evaluate(
            [(eta, problem.fiber_values(z - steps[j] * np.eye(z.size)[j])) for j in failed], stage + " retry"
        )
        for j, evaluation in zip(failed, again):
            if not evaluation.failures:
                evaluations[j], steps[j] = evaluation, -steps[j]
    for j, evaluation in enumerate(evaluations):
        if evaluation.failures:
            key = problem.fiber_keys[j]
            raise SolverError(
                f"fit: the model failed when {key} ({FIT_PARAMETERS[key].symbol}) was stepped from "
                f"{_describe(eta, at.fiber)} for the Jacobian (both directions tried where the bounds "
                f"allow): {evaluation.failures[0]}. {_hint(model, eta, [key])}"
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

    solution = least_squares(  # a SolverError from the Jacobian ends the fit at this eta
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
    return _FiberFit(eta, solution.x, evaluation, _sse(model.residual(evaluation)), solution.jac, solution.message)


# --------------------------------------------------------------------------------------------
# the 1-D search over eta
# --------------------------------------------------------------------------------------------
@dataclass
class _Search:
    """The outcome of the search: the best fit, every fit made on the way (one per eta
    visited), and the etas where the fit failed (their SSE counts as infinite)."""

    best: _FiberFit
    solved: list[_FiberFit]
    failed_etas: list[dict[str, float | str]] = field(default_factory=list)


def _search(model: _Model) -> _Search:
    """eta: a grid over its bounds (from the base value outwards, each fit starting from the
    nearest one solved), then a bounded Brent search between the best grid point's neighbours.

    Where the fit at an eta fails (a simulation the Jacobian needs does not converge, or the
    best point at that eta has failed runs), that eta scores SSE = inf (logged, and listed in
    ``failed_etas``); Brent sees the SSE of a model that reached no point instead.
    """
    problem = model.problem
    if not problem.fits_eta:
        only = _fit_fiber(model, problem.base_value(ETA_KEY), problem.start(), "fit")
        return _Search(only, [only])
    solved: list[_FiberFit] = []
    failed: list[dict[str, float | str]] = []
    worst = problem.data.size * (PENALTY_FACTOR * float(np.max(np.abs(problem.data)))) ** 2

    def profile(eta: float, stage: str) -> float:
        eta = float(eta)
        start = min(solved, key=lambda f: abs(f.eta - eta)).z if solved else problem.start()
        try:
            fitted = _fit_fiber(model, eta, start, stage)
        except SolverError as err:
            message = str(err)
        else:
            if not fitted.evaluation.failures:
                solved.append(fitted)
                return fitted.sse
            message = (
                f"the best point at this eta, {_describe(eta, fitted.evaluation.fiber)}, has "
                f"failed simulations: {fitted.evaluation.failures[0]}"
            )
        log.warning("%s = %.6g: the fit failed there, SSE counted as infinite: %s", ETA_KEY, eta, message)
        failed.append({ETA_KEY: eta, "stage": stage, "message": message})
        return worst

    grid = np.linspace(*problem.bounds[ETA_KEY], problem.eta_points)
    sse = {eta: profile(eta, "eta grid") for eta in sorted(grid, key=lambda e: abs(e - problem.base_value(ETA_KEY)))}
    if not solved:
        raise SolverError(
            f"fit: the fit failed at every eta of the grid ({', '.join(f'{e:.4g}' for e in grid)}); "
            f"first: {failed[0]['message']}"
        )
    k = int(np.argmin([sse[eta] for eta in grid]))
    bracket = (grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)])
    minimize_scalar(
        lambda eta: profile(eta, "eta bracket"),
        bounds=bracket,
        method="bounded",
        options={"xatol": problem.eta_tolerance},
    )
    return _Search(min(solved, key=lambda f: f.sse), solved, failed)


def _profile_sse(search: _Search) -> np.ndarray:
    """(eta, least SSE) of every eta visited, sorted by eta; inf where the fit failed."""
    rows = [(f.eta, f.sse) for f in search.solved] + [(float(f[ETA_KEY]), math.inf) for f in search.failed_etas]
    return np.array(sorted(rows))
