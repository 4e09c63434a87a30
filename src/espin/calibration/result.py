"""The result of a fit: :class:`FitResult`, its report and files, and how a fit makes one."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from espin.calibration.curves import FittedCurve
from espin.calibration.model import _Evaluation, _Model
from espin.calibration.parameters import ETA_KEY, FIT_PARAMETERS, parameter_key
from espin.calibration.problem import _Problem
from espin.calibration.search import _FiberFit
from espin.calibration.uncertainty import _Uncertainty
from espin.config import Config, apply_overrides


@dataclass(frozen=True, eq=False)
class FitResult:
    """A calibrated parameter set and how well, and how surely, it matches the curve(s).

    Attributes
    ----------
    parameters : tuple of str
        Fitted config keys (``rve.volume_fraction``, ``fiber.flow_resistance_MPa``, ...).
    values : dict
        Fitted value of each key (units in the key's name).
    uncertainties : dict
        1-sd standard error of each value:
        sqrt(gauss_newton_sd^2 + realization_sd^2 / R) (just gauss_newton_sd for R = 1).
    gauss_newton_sd : dict
        sqrt(diag(s^2 (J^T J)^-1)) at the optimum, s^2 = SSE / (m - p), on the fit coordinates
        (log for log-scale parameters, then times the value): the misfit's share.
    realization_sd : dict or None
        Spread of each value over the RVE realizations (linearized: sd of the fits to each
        realization alone); the mean of R realizations carries sd / sqrt(R) of it. None for
        R = 1.
    eta_profile_sd : float or None
        sd of eta from the curvature of the profile SSE(eta) (None when eta is not fitted).
    correlation : (p, p) float64
        Correlation matrix of the fitted values (order of ``parameters``).
    bounds : dict
        (low, high) of each fitted key.
    fixed : dict
        Values held fixed by the caller.
    r_squared : float
        1 - SSE / SST over every measured point.
    rmse_MPa : float [MPa]
        Root mean square stress residual.
    config : Config
        The base config with the fitted and fixed values, loaded like the first curve, seed
        the first realization's: ``espin simulate`` runs it as is.
    curves : tuple of FittedCurve
        The measured curves with the model at the fitted values.
    seeds : tuple of int
        ``rve.seed`` of the realizations (the same for every evaluation).
    eta_profile : (k, 2) float64 or None
        (eta, least SSE [MPa^2] at that eta) for every eta visited, sorted by eta.
    history : tuple of dict
        Every model evaluation: stage, eta, fiber values, SSE, failed simulations.
    simulations, failed_simulations : int
        Tensile simulations run, and those that did not converge.
    elapsed_s : float [s]
        Wall time of the fit.
    pool : str
        Where the simulations ran.
    """

    parameters: tuple[str, ...]
    values: dict[str, float]
    uncertainties: dict[str, float]
    gauss_newton_sd: dict[str, float]
    realization_sd: dict[str, float] | None
    eta_profile_sd: float | None
    correlation: np.ndarray
    bounds: dict[str, tuple[float, float]]
    fixed: dict[str, float]
    r_squared: float
    rmse_MPa: float
    config: Config
    curves: tuple[FittedCurve, ...]
    seeds: tuple[int, ...]
    eta_profile: np.ndarray | None
    history: tuple[dict[str, Any], ...]
    simulations: int
    failed_simulations: int
    elapsed_s: float
    pool: str

    def report(self) -> dict[str, Any]:
        """Everything about the fit as JSON-ready data (what ``fit.json`` holds)."""
        import espin

        def number(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "espin_version": espin.__version__,
            "units": "stress MPa, strain 1, strain rate 1/s",
            "parameters": [
                {
                    "key": key,
                    "symbol": FIT_PARAMETERS[key].symbol,
                    "value": self.values[key],
                    "uncertainty": number(self.uncertainties[key]),
                    "gauss_newton_sd": number(self.gauss_newton_sd[key]),
                    "realization_sd": number(self.realization_sd[key]) if self.realization_sd else None,
                    "bounds": list(self.bounds[key]),
                }
                for key in self.parameters
            ],
            "uncertainty_method": "uncertainty = sqrt(gauss_newton_sd^2 + realization_sd^2 / R); "
            "Gauss-Newton s^2 (J^T J)^-1 on the fit coordinates (log for E_t, E_b, a_p, b_p), eta "
            "column of J a central secant of +-5 %; realization_sd: linearized fits to each "
            "realization alone",
            "eta_profile_sd": number(self.eta_profile_sd),
            "correlation": np.where(np.isfinite(self.correlation), self.correlation, np.nan).tolist(),
            "fixed": self.fixed,
            "r_squared": self.r_squared,
            "rmse_MPa": self.rmse_MPa,
            "seeds": list(self.seeds),
            "curves": [
                {"strain_rate_per_s": c.strain_rate_per_s, "points": int(c.strain.size),
                 "max_strain": c.max_strain, "source": c.source}
                for c in self.curves
            ],
            "stress_measure": self.config.output.stress_measure,
            "eta_profile": None if self.eta_profile is None else self.eta_profile.tolist(),
            "history": list(self.history),
            "simulations": self.simulations,
            "failed_simulations": self.failed_simulations,
            "elapsed_s": self.elapsed_s,
            "pool": self.pool,
        }

    def write(self, folder: str | Path) -> dict[str, Path]:
        """Write ``fitted.toml``, ``fit.csv``, ``fit.json`` and ``fit.png`` into ``folder``.

        Returns
        -------
        dict
            File kind -> path written.
        """
        import json

        import pandas as pd

        from espin.config import write_config
        from espin.figures.fit import plot_fit
        from espin.io.atomic import atomic_write, atomic_write_bytes

        folder = Path(folder)
        table = pd.concat([_curve_table(c) for c in self.curves], ignore_index=True)
        report = json.dumps(self.report(), indent=2, allow_nan=False, default=float)
        return {
            "config": write_config(self.config, folder / "fitted.toml"),
            "curve": atomic_write(folder / "fit.csv", lambda tmp: table.to_csv(tmp, index=False)),
            "report": atomic_write_bytes(folder / "fit.json", (report + "\n").encode("utf-8")),
            "figure": plot_fit(self, folder / "fit.png"),
        }


def _curve_table(curve: FittedCurve) -> Any:
    import pandas as pd

    missing = np.full(curve.strain.shape, np.nan)
    return pd.DataFrame({
        "strain_rate_per_s": curve.strain_rate_per_s,
        "strain": curve.strain,
        "stress_MPa": curve.stress_MPa,
        "sd_MPa": missing if curve.sd_MPa is None else curve.sd_MPa,
        "model_MPa": curve.model_MPa,
        "model_sd_MPa": curve.model_sd_MPa,
    })


def _model_curves(problem: _Problem, evaluation: _Evaluation) -> tuple[FittedCurve, ...]:
    """The measured curves with the model's mean and sd over realizations."""
    curves, start = [], 0
    ddof = 1 if len(problem.seeds) > 1 else 0
    for c in problem.curves:
        block = evaluation.per_realization[:, start:start + c.strain.size]
        start += c.strain.size
        curves.append(FittedCurve(c.strain_rate_per_s, c.strain, c.stress_MPa, c.sd_MPa,
                                  block.mean(axis=0), block.std(axis=0, ddof=ddof), c.source))
    return tuple(curves)


def _fitted_config(problem: _Problem, values: Mapping[str, float]) -> Config:
    first, steps = problem.curves[0], problem.steps[0]
    return apply_overrides(problem.base, {
        **values,
        "rve.seed": problem.seeds[0],
        "loading.max_strain": first.max_strain,
        "loading.strain_rate_per_s": first.strain_rate_per_s,
        "loading.steps": steps,
    })


def _combined(misfit: dict[str, float], spread: dict[str, float] | None, n: int) -> dict[str, float]:
    """sqrt(misfit^2 + spread^2 / n) per key: both the data's and the realizations' share."""
    if spread is None:
        return dict(misfit)
    return {k: math.hypot(misfit[k], spread[k] / math.sqrt(n)) for k in misfit}


def _result(problem: _Problem, model: _Model, best: _FiberFit, solved: Sequence[_FiberFit],
            uncertainty: _Uncertainty, fixed: Mapping[str, float], elapsed_s: float) -> FitResult:
    values = {ETA_KEY: best.eta, **best.evaluation.fiber} if problem.fits_eta else dict(best.evaluation.fiber)
    data = problem.data
    sst = float(np.sum((data - data.mean()) ** 2))
    profile = None
    if problem.fits_eta:
        profile = np.array(sorted((f.eta, f.sse) for f in solved))
    return FitResult(
        parameters=problem.keys,
        values={k: float(values[k]) for k in problem.keys},
        uncertainties=_combined(uncertainty.sd, uncertainty.realization_sd, len(problem.seeds)),
        gauss_newton_sd=uncertainty.sd,
        realization_sd=uncertainty.realization_sd,
        eta_profile_sd=uncertainty.eta_profile_sd,
        correlation=uncertainty.correlation,
        bounds=dict(problem.bounds),
        fixed={parameter_key(k): float(v) for k, v in fixed.items()},
        r_squared=1.0 - best.sse / sst if sst > 0 else math.nan,
        rmse_MPa=math.sqrt(best.sse / data.size),
        config=_fitted_config(problem, values),
        curves=_model_curves(problem, best.evaluation),
        seeds=problem.seeds,
        eta_profile=profile,
        history=tuple(model.history),
        simulations=model.simulations,
        failed_simulations=model.failed_simulations,
        elapsed_s=elapsed_s,
        pool=model.pool.description,
    )
