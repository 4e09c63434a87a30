"""The result of a fit: :class:`FitResult`, its report and files, and how a fit makes one."""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from espin.analysis.calibration.curves import FittedCurve
from espin.analysis.calibration.model import _Evaluation, _Model
from espin.analysis.calibration.parameters import ETA_KEY, FIT_PARAMETERS, parameter_key
from espin.analysis.calibration.problem import _Problem
from espin.analysis.calibration.search import _profile_sse, _Search
from espin.analysis.calibration.simulation import _loading_config
from espin.analysis.calibration.uncertainty import _Uncertainty, eta_resolution
from espin.core.config import Config
from espin.core.html import html_table

log = logging.getLogger(__name__)  # espin.analysis.calibration.result: the result's warnings

AT_BOUND = 0.01
"""A value within this fraction of its bounds' range (in the fit coordinate: log for E_t,
E_b, a_p, b_p) of a bound is reported at that bound."""
UNIDENTIFIABLE_SD, UNIDENTIFIABLE_CORRELATION = 1.0, 0.99
"""A relative sd above the first, or a |correlation| above the second, is warned about."""


REPR_LENGTH = 200
"""``repr(FitResult)`` leaves out the sds when they would make it this long or longer."""


def _unit(key: str) -> str:
    """The unit in a config key's name: `` MPa``, `` 1/s`` or "" (dimensionless)."""
    return " MPa" if key.endswith("_MPa") else " 1/s" if key.endswith("_per_s") else ""


@dataclass(frozen=True, eq=False, repr=False)
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
    eta_resolution : float or None
        Volume fraction of one fiber in a layer, about pi D / (4 L): eta changes the network in
        steps of this size, so no sd of eta below it is meaningful (None when eta is not fitted).
    at_bound : dict
        ``"lower"`` or ``"upper"`` for a value within 1 % of its bounds' range of that bound
        (in the fit coordinate), else None.
    warnings : tuple of str
        What the fit warns about: values at a bound, relative sd > 1, |correlation| > 0.99,
        failed etas, a failed eta secant.
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
        (eta, least SSE [MPa^2] at that eta) for every eta visited, sorted by eta; SSE inf
        where the fit at that eta failed.
    failed_etas : tuple of dict
        Each eta whose fit failed (``rve.volume_fraction``, stage, message).
    history : tuple of dict
        Every model evaluation: stage, eta, fiber values, SSE, failed simulations.
    simulations, failed_simulations : int
        Tensile simulations run, and those that did not converge.
    load_steps : tuple of dict
        Each curve's load steps: how many, the largest step up to the fine zone's end
        (``step_strain``), that end (``fine_steps_to_strain``), the largest step overall, and
        how many measured strains end a program segment.
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
    eta_resolution: float | None
    at_bound: dict[str, str | None]
    warnings: tuple[str, ...]
    correlation: np.ndarray
    bounds: dict[str, tuple[float, float]]
    fixed: dict[str, float]
    r_squared: float
    rmse_MPa: float
    config: Config
    curves: tuple[FittedCurve, ...]
    seeds: tuple[int, ...]
    eta_profile: np.ndarray | None
    failed_etas: tuple[dict[str, Any], ...]
    history: tuple[dict[str, Any], ...]
    simulations: int
    failed_simulations: int
    elapsed_s: float
    pool: str
    load_steps: tuple[dict[str, float | int], ...]

    def __repr__(self) -> str:
        """One line: each fitted value (the paper's symbol, +- 1 sd, unit), RMS residual [MPa],
        R^2, simulations run; the sds are left out when the line would reach 200 characters."""
        n = len(self.warnings)
        tail = (
            f"; RMS {self.rmse_MPa:.3g} MPa, R^2 {self.r_squared:.4f}, {self.simulations} simulations, "
            f"{n} warning{'s' * (n != 1)})"
        )
        for with_sd in (True, False):
            values = ", ".join(
                f"{FIT_PARAMETERS[key].symbol} {self.values[key]:.4g}"
                + (f" +- {self.uncertainties[key]:.3g}" if with_sd else "")
                + _unit(key)
                for key in self.parameters
            )
            text = f"FitResult({values}{tail}"
            if len(text) < REPR_LENGTH:
                break
        return text

    def _repr_html_(self) -> str:
        """The fitted values with their 1-sd intervals and the fit's quality as an HTML table
        (Jupyter)."""
        rows = []
        for key in self.parameters:
            low, high = self.interval(key)
            bound = f", at the {self.at_bound[key]} bound" if self.at_bound[key] else ""
            rows.append(
                (
                    f"{FIT_PARAMETERS[key].symbol} ({key})",
                    (
                        f"{self.values[key]:.4g} +- {self.uncertainties[key]:.3g}{_unit(key)} "
                        f"(1 sd: {low:.4g} .. {high:.4g}{bound})"
                    ),
                )
            )
        rows += [
            ("RMS residual", f"{self.rmse_MPa:.4g} MPa"),
            ("R^2", f"{self.r_squared:.4f}"),
            ("curves", str(len(self.curves))),
            ("realizations (seeds)", f"{len(self.seeds)} ({', '.join(map(str, self.seeds))})"),
            ("evaluations", str(len(self.history))),
            ("simulations", f"{self.simulations} ({self.failed_simulations} failed)"),
            ("elapsed", f"{self.elapsed_s:.4g} s"),
            ("warnings", str(len(self.warnings))),
        ]
        return html_table("FitResult", rows)

    def to_dataframe(self) -> Any:
        """The model evaluations of the fit (:attr:`history`) as a pandas DataFrame, one row
        per evaluation: ``evaluation`` (1, 2, ...), ``stage``, ``rve.volume_fraction``, the
        fiber values by config key (units in the names), ``sse_MPa2`` (sum of squared stress
        residuals [MPa^2]; a point no realization reached costs a large penalty) and
        ``failed_simulations``."""
        import pandas as pd

        return pd.DataFrame(list(self.history))

    def sd_factor(self, key: str) -> float | None:
        """exp(sd of log(value)) of a log-scale parameter (None for eta and c_p): the value is
        known within a factor of this (1 sd)."""
        if not FIT_PARAMETERS[key].log_scale:
            return None
        log_sd = self.uncertainties[key] / self.values[key]
        return math.exp(log_sd) if log_sd < 700 else math.inf  # nan stays nan

    def interval(self, key: str) -> tuple[float, float]:
        """The 1-sd interval of a value: value / f .. value * f with f = :meth:`sd_factor` for a
        log-scale parameter (its sd is symmetric in log), value -+ sd otherwise."""
        value, sd = self.values[key], self.uncertainties[key]
        factor = self.sd_factor(key)
        if factor is not None:
            return value / factor, value * factor
        return value - sd, value + sd

    def report(self) -> dict[str, Any]:
        """Everything about the fit as JSON-ready data (what ``fit.json`` holds)."""
        from espin.core.version import __version__

        def number(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "espin_version": __version__,
            "units": "stress MPa, strain 1, strain rate 1/s",
            "parameters": [
                {
                    "key": key,
                    "symbol": FIT_PARAMETERS[key].symbol,
                    "value": self.values[key],
                    "uncertainty": number(self.uncertainties[key]),
                    "interval_1sd": [number(x) for x in self.interval(key)],
                    "sd_factor": number(self.sd_factor(key)),
                    "gauss_newton_sd": number(self.gauss_newton_sd[key]),
                    "realization_sd": number(self.realization_sd[key]) if self.realization_sd else None,
                    "bounds": list(self.bounds[key]),
                    "at_bound": self.at_bound[key],
                }
                for key in self.parameters
            ],
            "uncertainty_method": "uncertainty = sqrt(gauss_newton_sd^2 + realization_sd^2 / R); "
            "Gauss-Newton s^2 (J^T J)^-1 on the fit coordinates (log for E_t, E_b, a_p, b_p), eta "
            "column of J a central secant of +-5 % (at least eta_resolution); realization_sd: "
            "linearized fits to each realization alone. Log-scale values: sd = value * sd(log value), interval_1sd = "
            "value / sd_factor .. value * sd_factor. Gauss-Newton sd scales as 1 / sqrt(points): "
            "it depends on the point density (see curves[].points)",
            "eta_profile_sd": number(self.eta_profile_sd),
            "eta_resolution": number(self.eta_resolution),
            "warnings": list(self.warnings),
            "correlation": [[number(float(x)) for x in row] for row in self.correlation],
            "fixed": self.fixed,
            "r_squared": number(self.r_squared),
            "rmse_MPa": number(self.rmse_MPa),
            "seeds": list(self.seeds),
            "curves": [
                {
                    "strain_rate_per_s": c.strain_rate_per_s,
                    "points": int(c.strain.size),
                    "points_from": c.points_from,
                    "max_strain": c.max_strain,
                    "source": c.source,
                    **steps,
                }
                for c, steps in zip(self.curves, self.load_steps)
            ],
            "stress_measure": self.config.output.stress_measure,
            "eta_profile": None
            if self.eta_profile is None
            else [[float(eta), number(sse)] for eta, sse in self.eta_profile],
            "failed_etas": list(self.failed_etas),
            "history": [{k: number(v) if isinstance(v, float) else v for k, v in h.items()} for h in self.history],
            "simulations": self.simulations,
            "failed_simulations": self.failed_simulations,
            "elapsed_s": self.elapsed_s,
            "pool": self.pool,
        }

    def write(self, folder: str | Path, *, overwrite: bool = False) -> dict[str, Path]:
        """Write ``fitted.toml``, ``fit.csv``, ``fit.json`` and ``fit.png`` into ``folder``,
        with its ``run.json`` manifest (:mod:`espin.core.output_folder`).

        Parameters
        ----------
        folder
            Output folder (created if needed).
        overwrite
            Replace another run's results in ``folder`` instead of refusing (a folder holding
            the same fit is rewritten without it).

        Returns
        -------
        dict
            File kind -> path written.
        """
        from espin.core.config import config_digest
        from espin.core.output_folder import OutputFolder

        with OutputFolder.claim(
            folder, "fit", config_digest(self.config), FIT_OUTPUTS, overwrite=overwrite, resume="same-inputs"
        ):
            return self.write_files(folder)

    def write_files(self, folder: str | Path) -> dict[str, Path]:
        """Write the files of :meth:`write` into a folder the caller has claimed."""
        import json

        import pandas as pd

        from espin.analysis.calibration.figures import plot_fit
        from espin.core.atomic import atomic_write, atomic_write_bytes
        from espin.core.config import write_config

        folder = Path(folder)
        table = pd.concat([_curve_table(c, self.seeds) for c in self.curves], ignore_index=True)
        report = json.dumps(self.report(), indent=2, allow_nan=False, default=float)
        return {
            "config": write_config(self.config, folder / "fitted.toml"),
            "curve": atomic_write(folder / "fit.csv", lambda tmp: table.to_csv(tmp, index=False)),
            "report": atomic_write_bytes(folder / "fit.json", (report + "\n").encode("utf-8")),
            "figure": plot_fit(self, folder / "fit.png"),
        }


FIT_OUTPUTS = ("fitted.toml", "fit.csv", "fit.json", "fit.png")
"""The files a fit writes into its folder."""


def _curve_table(curve: FittedCurve, seeds: Sequence[int]) -> Any:
    import pandas as pd

    missing = np.full(curve.strain.shape, np.nan)
    return pd.DataFrame(
        {
            "strain_rate_per_s": curve.strain_rate_per_s,
            "strain": curve.strain,
            "stress_MPa": curve.stress_MPa,
            "sd_MPa": missing if curve.sd_MPa is None else curve.sd_MPa,
            "model_MPa": curve.model_MPa,
            "model_sd_MPa": curve.model_sd_MPa,
            # A fit's curves carry the model (its realizations included).
            **{
                f"model_seed{seed}_MPa": row for seed, row in zip(seeds, cast(np.ndarray, curve.model_realizations_MPa))
            },
        }
    )


def _model_curves(problem: _Problem, evaluation: _Evaluation) -> tuple[FittedCurve, ...]:
    """The measured curves with the model's mean and sd over realizations, and each one."""
    curves, start = [], 0
    ddof = 1 if len(problem.seeds) > 1 else 0
    for c in problem.curves:
        block = evaluation.per_realization[:, start : start + c.strain.size]
        start += c.strain.size
        curves.append(
            FittedCurve(
                c.strain_rate_per_s,
                c.strain,
                c.stress_MPa,
                c.sd_MPa,
                block.mean(axis=0),
                block.std(axis=0, ddof=ddof),
                c.source,
                c.points_from,
                block.copy(),
            )
        )
    return tuple(curves)


def _fitted_config(problem: _Problem, values: Mapping[str, float]) -> Config:
    """The base config with the fitted values, the first seed, loaded like the first curve (its
    program of load steps): ``espin simulate`` reproduces the first realization's curve."""
    first = problem.curves[0]
    return _loading_config(
        problem.base, problem.steps[0], first.strain_rate_per_s, {**values, "rve.seed": problem.seeds[0]}
    )


def _at_bound(problem: _Problem, values: Mapping[str, float]) -> dict[str, str | None]:
    """Which values sit at (within AT_BOUND of the range of) a bound, in the fit coordinate."""
    flags = {}
    for key in problem.keys:
        lo, hi, z = (problem.to_internal(key, v) for v in (*problem.bounds[key], values[key]))
        tolerance = AT_BOUND * (hi - lo)
        flags[key] = "lower" if z - lo <= tolerance else "upper" if hi - z <= tolerance else None
    return flags


def _warnings(
    problem: _Problem,
    values: Mapping[str, float],
    total: Mapping[str, float],
    at_bound: Mapping[str, str | None],
    correlation: np.ndarray,
    notes: Sequence[str],
    failed_etas: Sequence[Mapping[str, Any]],
) -> tuple[str, ...]:
    """What a user should know before trusting the values (each also logged)."""
    out = []
    for key in problem.keys:
        symbol = FIT_PARAMETERS[key].symbol
        if at_bound[key]:
            out.append(
                f"{key} ({symbol}) = {values[key]:.4g} is at its {at_bound[key]} bound "
                f"{problem.bounds[key][at_bound[key] == 'upper']:.4g}: the data do not pin it "
                "inside the bounds (widen them, or fix it)"
            )
        relative = total[key] / abs(values[key]) if values[key] else math.inf
        if relative > UNIDENTIFIABLE_SD:  # NaN (no sd): said by the note that explains it
            out.append(
                f"{key} ({symbol}): relative sd {relative:.3g} > {UNIDENTIFIABLE_SD:g}: not "
                "identifiable from these data; fix it"
            )
    p = len(problem.keys)
    for i in range(p):
        for j in range(i + 1, p):
            c = correlation[i, j]
            if np.isfinite(c) and abs(c) > UNIDENTIFIABLE_CORRELATION:
                a, b = (FIT_PARAMETERS[problem.keys[k]].symbol for k in (i, j))
                out.append(
                    f"corr({a}, {b}) = {c:+.3f}: {a} and {b} are not separately identifiable "
                    "(the data fix a combination); fix one of them"
                )
    if failed_etas:
        out.append(
            f"the fit failed at {len(failed_etas)} eta(s) "
            f"({', '.join(f'{f[ETA_KEY]:.4g}' for f in failed_etas)}); their SSE counted as infinite"
        )
    out.extend(notes)
    for message in out:
        log.warning(message)
    return tuple(out)


def _combined(misfit: dict[str, float], spread: dict[str, float] | None, n: int) -> dict[str, float]:
    """sqrt(misfit^2 + spread^2 / n) per key: both the data's and the realizations' share."""
    if spread is None:
        return dict(misfit)
    return {k: math.hypot(misfit[k], spread[k] / math.sqrt(n)) for k in misfit}


def _result(
    problem: _Problem,
    model: _Model,
    search: _Search,
    uncertainty: _Uncertainty,
    fixed: Mapping[str, float],
    elapsed_s: float,
) -> FitResult:
    best = search.best
    values = {ETA_KEY: best.eta, **best.evaluation.fiber} if problem.fits_eta else dict(best.evaluation.fiber)
    values = {k: float(values[k]) for k in problem.keys}
    data = problem.data
    sst = float(np.sum((data - data.mean()) ** 2))
    total = _combined(uncertainty.sd, uncertainty.realization_sd, len(problem.seeds))
    at_bound = _at_bound(problem, values)
    return FitResult(
        parameters=problem.keys,
        values=values,
        uncertainties=total,
        gauss_newton_sd=uncertainty.sd,
        realization_sd=uncertainty.realization_sd,
        eta_profile_sd=uncertainty.eta_profile_sd,
        eta_resolution=eta_resolution(problem) if problem.fits_eta else None,
        at_bound=at_bound,
        warnings=_warnings(
            problem, values, total, at_bound, uncertainty.correlation, uncertainty.notes, search.failed_etas
        ),
        correlation=uncertainty.correlation,
        bounds=dict(problem.bounds),
        fixed={parameter_key(k): float(v) for k, v in fixed.items()},
        r_squared=1.0 - best.sse / sst if sst > 0 else math.nan,
        rmse_MPa=math.sqrt(best.sse / data.size),
        config=_fitted_config(problem, values),
        curves=_model_curves(problem, best.evaluation),
        seeds=problem.seeds,
        eta_profile=_profile_sse(search) if problem.fits_eta else None,
        failed_etas=tuple(search.failed_etas),
        history=tuple(model.history),
        simulations=model.simulations,
        failed_simulations=model.failed_simulations,
        elapsed_s=elapsed_s,
        pool=model.pool.description,
        load_steps=tuple(s.describe() for s in problem.steps),
    )
