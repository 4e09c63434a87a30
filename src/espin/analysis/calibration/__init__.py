"""Calibrate the volume fraction and fiber-law parameters to a measured curve (paper 4.2; docs/model.md section 7).

The model curve of a parameter set is the mean, over a fixed set of RVE realizations (the same
seeds for every evaluation: common random numbers), of the simulated stress at the measured
strains. The fit minimizes the sum of squared stress differences [MPa^2] over all measured
points (points at zero strain carry no information and are left out).

- The simulations follow a loading program whose segments end at the measured strains, cut
  into steps of at most ``step_strain`` (0.1 %) up to twice the knee of the measured curve and
  at most 1 % beyond (backward Euler on the flow rule is first order in the step: coarse steps
  bias the knee, and with it the fitted parameters).
- The volume fraction eta changes the network, so it is fitted by a 1-D search: a grid over its
  bounds, then a bounded Brent search between the neighbours of the best grid point (an eta
  where the fit fails scores SSE = inf).
- For each eta the fiber-law parameters are continuous: ``scipy.optimize.least_squares``
  (trust-region reflective, with bounds) on log-parameters (E_t, E_b, a_p, b_p) and on c_p
  itself (its range includes 0), with a forward-difference Jacobian whose columns run as one
  parallel batch; each eta starts from the solution at the nearest eta already solved.
- Uncertainty: the Gauss-Newton covariance s^2 (J^T J)^-1 at the optimum, s^2 = SSE / (m - p),
  with the eta column of J a central difference of +-5 % or one fiber per layer, whichever is
  larger (a secant: the network changes in discrete steps); for eta also the curvature of the
  profile SSE(eta); and the spread over the realizations, linearized: the change of the fit if
  the data were matched by one realization. The Gauss-Newton part scales as 1 / sqrt(points):
  several CSV specimens are averaged onto their measured strains, not an invented grid.
  Log-scale parameters are reported with a factor (``FitResult.sd_factor``); values at a bound,
  relative sd > 1 and |correlation| > 0.99 are flagged (``FitResult.warnings``).

From a single strain rate only b_p * asinh(rate / a_p) is identifiable, so a_p is fitted only
from curves at two or more rates. See ``docs/calibration.md`` for what else is (not)
identifiable.

Units: stress MPa, strain dimensionless, strain rate 1/s.

The package: :mod:`~espin.analysis.calibration.parameters` (what can be fitted, names, bounds),
:mod:`~espin.analysis.calibration.curves` (measured and synthetic curves),
:mod:`~espin.analysis.calibration.problem` (the inputs, checked before any simulation),
:mod:`~espin.analysis.calibration.simulation` (load steps and simulation tasks),
:mod:`~espin.analysis.calibration.model` (model evaluations),
:mod:`~espin.analysis.calibration.search` (least squares per eta, the search over eta),
:mod:`~espin.analysis.calibration.uncertainty` and :mod:`~espin.analysis.calibration.result`
(:class:`FitResult`); :func:`fit` is here.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from espin.analysis.calibration.curves import AverageGrid, CurveLike, FittedCurve, synthetic_curve
from espin.analysis.calibration.model import PENALTY_FACTOR, _describe, _Model
from espin.analysis.calibration.parameters import (
    ETA_KEY,
    FIT_PARAMETERS,
    FitParameter,
    default_bounds,
    parameter_key,
)
from espin.analysis.calibration.problem import _problem
from espin.analysis.calibration.result import FitResult, _result
from espin.analysis.calibration.search import FD_STEP, FTOL, MAX_NFEV, XTOL, _search
from espin.analysis.calibration.simulation import COARSE_STEP_STRAIN, KNEE_FACTOR, STEP_STRAIN, _simulate_task
from espin.analysis.calibration.uncertainty import ETA_SECANT, _uncertainty
from espin.core.config import Config
from espin.core.errors import SolverError
from espin.core.parallel import TaskPlace

__all__ = [
    "FIT_PARAMETERS",
    "FitParameter",
    "FittedCurve",
    "FitResult",
    "default_bounds",
    "fit",
    "parameter_key",
    "synthetic_curve",
    # constants and the curve types (those of the submodules re-exported)
    "CurveLike",
    "AverageGrid",
    "STEP_STRAIN",
    "KNEE_FACTOR",
    "COARSE_STEP_STRAIN",
    "ETA_KEY",
    "ETA_SECANT",
    "FD_STEP",
    "XTOL",
    "FTOL",
    "MAX_NFEV",
    "PENALTY_FACTOR",
]


def fit(
    curve: CurveLike | Mapping[float, CurveLike],
    *,
    base: Config | str | Path = "plla",
    parameters: Sequence[str] = ("volume_fraction", "flow_resistance_MPa", "hardening_exponent"),
    bounds: Mapping[str, tuple[float, float]] | None = None,
    fixed: Mapping[str, float] | None = None,
    realizations: int | None = None,
    seeds: Sequence[int] | None = None,
    strain_rate_per_s: float | None = None,
    step_strain: float = STEP_STRAIN,
    average_grid: AverageGrid = "measured",
    large_strain: bool = False,
    eta_points: int = 5,
    eta_tolerance: float = 0.002,
    workers: int | None = 1,
    scheduler: Any = None,
    security: Any = None,
    read_options: Mapping[str, Any] | None = None,
    on_evaluation: Callable[[dict[str, Any]], None] | None = None,
) -> FitResult:
    """Fit eta and fiber-law parameters to measured stress-strain curve(s) (paper 4.2).

    Every input is checked before the first simulation.

    Parameters
    ----------
    curve
        The measured curve: (strain, stress [MPa]) arrays, an ``espin.analysis.experiments`` Curve or
        AveragedCurve, a CSV path or a sequence of CSV paths (read and averaged). Several
        strain rates: a mapping rate [1/s] -> curve (needed to fit a_p).
    base
        Config, preset name or TOML file holding every value not fitted (and the RVE geometry).
    parameters
        What to fit, by key (``fiber.flow_resistance_MPa``), short name
        (``flow_resistance_MPa``) or symbol (``b_p``): among eta (``volume_fraction``), E_t,
        E_b, a_p, b_p, c_p.
    bounds
        (low, high) per fitted parameter, inside its allowed range; default around the base
        value (:func:`default_bounds`).
    fixed
        Values to hold, applied to ``base`` (same names as ``parameters``).
    realizations
        Number of RVE realizations averaged per evaluation (default 3, or ``len(seeds)``).
    seeds
        Their ``rve.seed`` values (default base seed, base seed + 1, ...), common to every
        evaluation.
    strain_rate_per_s
        Strain rate of a single curve [1/s]; default the base config's.
    step_strain
        Largest load step [strain] from 0 to twice the knee (bilinear yield strain) of each
        measured curve, or over the whole curve when it shows no clear knee; beyond, steps of
        up to 1 % (``COARSE_STEP_STRAIN``). Program segments end at the measured strains (those
        closer than a quarter step to the previous end are read between steps).
    average_grid
        Where several CSV specimens are averaged: ``"measured"`` (default: their common
        strains, else the union of their strains within the common range), a number of evenly
        spaced strains (interpolated), or the strains.
    large_strain
        Accept curves whose strain exceeds 1 (100 %); without it such a curve is refused as
        probably given in percent.
    eta_points
        Points of the eta grid, >= 2.
    eta_tolerance
        Absolute tolerance of the bracket search on eta, in (0, 0.1).
    workers, scheduler, security
        Where simulations run (:class:`espin.core.parallel.TaskPlace`); default serial. A Dask
        scheduler must be trusted (it runs the pickled tasks); ``security`` holds the TLS files
        of a ``tls://`` one (:func:`espin.core.cluster.tls_security`).
    read_options
        Keyword arguments of ``espin.analysis.experiments.read_curve`` for CSV paths.
    on_evaluation
        Called with each history record (progress display). Default: in a Jupyter notebook,
        a line with the evaluations done, the last SSE and the time elapsed; elsewhere nothing.

    Returns
    -------
    FitResult

    Raises
    ------
    ConfigError
        For an unknown parameter, bounds outside the allowed range, a_p with one rate, bad
        curves, an invalid scheduler or security... (before any simulation).
    SolverError
        When the model fails where the fit cannot step around it (the message names the
        parameter values).
    """
    start = time.perf_counter()
    # the pool's options are checked first; its workers start with the first simulation
    pool = TaskPlace(workers, scheduler, 1, security).pool()
    problem = _problem(
        curve,
        base=base,
        parameters=parameters,
        bounds=bounds,
        fixed=fixed,
        realizations=realizations,
        seeds=seeds,
        strain_rate_per_s=strain_rate_per_s,
        step_strain=step_strain,
        eta_points=eta_points,
        eta_tolerance=eta_tolerance,
        read_options=read_options or {},
        average_grid=average_grid,
        large_strain=large_strain,
    )
    with pool:
        # the task function as named in this package (where it can be replaced)
        model = _Model(problem, pool, on_evaluation or _notebook_line(), simulate=_simulate_task)
        search = _search(model)
        best = search.best
        if best.evaluation.failures:
            raise SolverError(
                f"fit: the best point found, {_describe(best.eta, best.evaluation.fiber)}, has failed "
                f"simulations: {best.evaluation.failures[0]}"
            )
        uncertainty = _uncertainty(model, best, search.solved)
    return _result(problem, model, search, uncertainty, fixed or {}, time.perf_counter() - start)


def _notebook_line() -> Callable[[dict[str, Any]], None] | None:
    """In a notebook, a status line updated with each evaluation of the fit; None elsewhere."""
    from espin.core.progress import NotebookProgress, in_notebook

    if not in_notebook():
        return None
    line = NotebookProgress(None, "evaluation")
    return lambda record: line.update(record["evaluation"], f"SSE {record['sse_MPa2']:.4g} MPa^2")
