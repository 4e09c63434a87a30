"""Calibrate the volume fraction and fiber-law parameters to a measured curve (paper 4.2; SPEC 7).

The model curve of a parameter set is the mean, over a fixed set of RVE realizations (the same
seeds for every evaluation: common random numbers), of the simulated stress at the measured
strains. The fit minimizes the sum of squared stress differences [MPa^2] over all measured
points (points at zero strain carry no information and are left out).

- The volume fraction eta changes the network, so it is fitted by a 1-D search: a grid over its
  bounds, then a bounded Brent search between the neighbours of the best grid point.
- For each eta the fiber-law parameters are continuous: ``scipy.optimize.least_squares``
  (trust-region reflective, with bounds) on log-parameters (E_t, E_b, a_p, b_p) and on c_p
  itself (its range includes 0), with a forward-difference Jacobian whose columns run as one
  parallel batch; each eta starts from the solution at the nearest eta already solved.
- Uncertainty: the Gauss-Newton covariance s^2 (J^T J)^-1 at the optimum, s^2 = SSE / (m - p),
  with the eta column of J a central difference of +-5 % (a secant: the network changes in
  discrete steps); for eta also the curvature of the profile SSE(eta); and the spread over the
  realizations, linearized: the change of the fit if the data were matched by one realization.

From a single strain rate only b_p * asinh(rate / a_p) is identifiable, so a_p is fitted only
from curves at two or more rates. See ``docs/calibration.md`` for what else is (not)
identifiable.

Units: stress MPa, strain dimensionless, strain rate 1/s.
"""

from __future__ import annotations

import functools
import logging
import math
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from espin.config import Config, apply_overrides, config_from_dict, config_to_toml
from espin.errors import ConfigError, SolverError
from espin.parallel import TaskPool

__all__ = [
    "FIT_PARAMETERS",
    "FitParameter",
    "FittedCurve",
    "FitResult",
    "default_bounds",
    "fit",
    "parameter_key",
    "synthetic_curve",
]

log = logging.getLogger(__name__)

ETA_KEY = "rve.volume_fraction"
ETA_SECANT = 0.05
"""Relative half-width of the central difference of the model in eta (for the covariance)."""
FD_STEP = 1e-3
"""Forward-difference step of the Jacobian: in log-parameter (0.1 %) or in c_p itself."""
XTOL, FTOL = 1e-3, 1e-4
"""least_squares stops when a step changes the fit coordinates by < 0.1 % or the SSE by < 0.01 %
(far below the parameters' uncertainty)."""
MAX_NFEV = 40
"""Most model evaluations of one least-squares fit (one eta)."""
PENALTY_FACTOR = 10.0
"""A measured point the model did not reach (failed simulation) costs this times max |stress|."""


# --------------------------------------------------------------------------------------------
# the parameters that can be fitted
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FitParameter:
    """A config key that :func:`fit` can calibrate.

    Attributes
    ----------
    key : str
        Dotted config key, e.g. ``fiber.flow_resistance_MPa``.
    symbol : str
        The paper's symbol (``eta``, ``E_t``, ``E_b``, ``a_p``, ``b_p``, ``c_p``).
    log_scale : bool
        Fitted on log(value) (positive parameters spanning decades) rather than on the value.
    lower, upper : float
        Limits of the allowed range (the config's, tightened to > 0 for a log-scale parameter).
    closed_lower : bool
        Whether ``lower`` itself is allowed.
    default_span : float
        Default bounds: value / span to value * span (log scale); for linear scale see
        :func:`default_bounds`.
    """

    key: str
    symbol: str
    log_scale: bool
    lower: float
    upper: float
    closed_lower: bool
    default_span: float

    @property
    def name(self) -> str:
        """The key without its section, e.g. ``flow_resistance_MPa``."""
        return self.key.split(".", 1)[1]

    @property
    def allowed(self) -> str:
        """The allowed range, in words."""
        low = f">= {self.lower:g}" if self.closed_lower else f"> {self.lower:g}"
        return low if math.isinf(self.upper) else f"{low} and < {self.upper:g}"

    def admits(self, value: float) -> bool:
        """Whether ``value`` lies in the allowed range."""
        above = value >= self.lower if self.closed_lower else value > self.lower
        return bool(np.isfinite(value) and above and value < self.upper)


FIT_PARAMETERS: dict[str, FitParameter] = {
    p.key: p
    for p in (
        FitParameter(ETA_KEY, "eta", False, 0.0, 1.0, False, 2.0),
        FitParameter("fiber.taut_modulus_MPa", "E_t", True, 0.0, math.inf, False, 10.0),
        FitParameter("fiber.slack_modulus_MPa", "E_b", True, 0.0, math.inf, False, 10.0),
        FitParameter("fiber.flow_rate_per_s", "a_p", True, 0.0, math.inf, False, 1e3),
        FitParameter("fiber.flow_resistance_MPa", "b_p", True, 0.0, math.inf, False, 5.0),
        FitParameter("fiber.hardening_exponent", "c_p", False, 0.0, math.inf, True, 3.0),
    )
}
"""The fittable parameters, in the order results are reported."""


def parameter_key(name: str) -> str:
    """The dotted config key of a fit parameter given by key, short name or symbol.

    ``"fiber.flow_resistance_MPa"``, ``"flow_resistance_MPa"`` and ``"b_p"`` all name b_p;
    ``"eta"`` and ``"volume_fraction"`` name ``rve.volume_fraction``.

    Raises
    ------
    ConfigError
        For a name that is none of these, listing the allowed names.
    """
    text = name.strip()
    for p in FIT_PARAMETERS.values():
        if text in (p.key, p.name) or text.lower() == p.symbol.lower():
            return p.key
    choices = ", ".join(f"{p.name} ({p.symbol})" for p in FIT_PARAMETERS.values())
    raise ConfigError(f"unknown fit parameter {name!r}; choose from {choices}")


def default_bounds(parameter: FitParameter, value: float) -> tuple[float, float]:
    """Bounds used when none are given, around the base value.

    Log-scale parameters: value / span to value * span. eta: value / 2 to min(2 value, 0.9).
    c_p: 0 to max(span, span * value).
    """
    if parameter.log_scale:
        return value / parameter.default_span, value * parameter.default_span
    if parameter.key == ETA_KEY:
        return value / parameter.default_span, min(parameter.default_span * value, 0.9)
    return 0.0, max(parameter.default_span, parameter.default_span * value)


# --------------------------------------------------------------------------------------------
# measured curves
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class FittedCurve:
    """A measured curve and the model along it.

    Attributes
    ----------
    strain_rate_per_s : float [1/s]
        Strain rate of the test (and of the simulations).
    strain : (m,) float64
        Measured engineering strains (> 0).
    stress_MPa : (m,) float64 [MPa]
        Measured (mean) stress.
    sd_MPa : (m,) float64 [MPa] or None
        Standard deviation between specimens, when the curve is an average.
    model_MPa : (m,) float64 [MPa] or None
        Mean model stress over the realizations at the fitted values (None before a fit).
    model_sd_MPa : (m,) float64 [MPa] or None
        Standard deviation of the model stress between realizations.
    source : str
        Where the curve came from (file names or ``"arrays"``).
    """

    strain_rate_per_s: float
    strain: np.ndarray
    stress_MPa: np.ndarray
    sd_MPa: np.ndarray | None = None
    model_MPa: np.ndarray | None = None
    model_sd_MPa: np.ndarray | None = None
    source: str = "arrays"

    @property
    def max_strain(self) -> float:
        """Largest measured strain (the simulations run to it)."""
        return float(self.strain[-1])


CurveLike = Any
"""(strain, stress) arrays, an ``espin.experiments`` Curve or AveragedCurve, a CSV path, or
a sequence of CSV paths (read and averaged)."""


def _is_path(value: Any) -> bool:
    return isinstance(value, (str, Path))


def _read_files(paths: Sequence[str | Path], read_options: Mapping[str, Any]) -> Any:
    from espin.experiments import average_curves, read_curve

    curves = [read_curve(p, **read_options) for p in paths]
    return curves[0] if len(curves) == 1 else average_curves(curves)


def _measured(curve: CurveLike, rate: float, read_options: Mapping[str, Any]) -> FittedCurve:
    """A validated :class:`FittedCurve` (no model yet) from any accepted curve form."""
    source = "arrays"
    if _is_path(curve) or (isinstance(curve, Sequence) and curve and all(_is_path(c) for c in curve)):
        paths = [curve] if _is_path(curve) else list(curve)
        source = ", ".join(Path(p).name for p in paths)
        curve = _read_files(paths, read_options)
    sd = None
    if hasattr(curve, "mean_MPa"):
        strain, stress, sd = curve.strain, curve.mean_MPa, curve.sd_MPa
    elif hasattr(curve, "stress_MPa"):
        strain, stress, sd = curve.strain, curve.stress_MPa, getattr(curve, "sd_MPa", None)
        source = str(getattr(curve, "source", source))
    elif isinstance(curve, Sequence) and len(curve) == 2:
        strain, stress = curve
    else:
        raise ConfigError(
            "curve: expected (strain, stress) arrays, a Curve or AveragedCurve, or CSV paths "
            f"(got {type(curve).__name__})"
        )
    return _validated_curve(rate, strain, stress, sd, source)


def _validated_curve(rate: float, strain: Any, stress: Any, sd: Any, source: str) -> FittedCurve:
    strain = np.asarray(strain, dtype=float)
    stress = np.asarray(stress, dtype=float)
    sd = None if sd is None else np.asarray(sd, dtype=float)
    if strain.ndim != 1 or strain.shape != stress.shape or (sd is not None and sd.shape != strain.shape):
        raise ConfigError(f"curve {source}: strain and stress must be 1-D arrays of equal length")
    if not (np.all(np.isfinite(strain)) and np.all(np.isfinite(stress))):
        raise ConfigError(f"curve {source}: strain and stress must be finite")
    if strain.size < 2 or np.any(np.diff(strain) <= 0) or strain[0] < 0:
        raise ConfigError(f"curve {source}: strains must be >= 0 and strictly increasing")
    if not (np.isfinite(rate) and rate > 0):
        raise ConfigError(f"strain_rate_per_s: must be > 0 (got {rate!r})")
    keep = strain > 0  # the origin carries no information
    return FittedCurve(
        strain_rate_per_s=float(rate),
        strain=strain[keep],
        stress_MPa=stress[keep],
        sd_MPa=None if sd is None else sd[keep],
        source=source,
    )


def _measured_curves(
    curve: CurveLike | Mapping[float, CurveLike], rate: float | None, base: Config,
    read_options: Mapping[str, Any],
) -> list[FittedCurve]:
    """The curves to fit, each with its strain rate (a mapping gives one curve per rate)."""
    if isinstance(curve, Mapping):
        if rate is not None:
            raise ConfigError(
                "strain_rate_per_s: give it for a single curve, or give curves as a mapping "
                "rate -> curve, not both"
            )
        if not curve:
            raise ConfigError("curve: the mapping rate -> curve is empty")
        curves = [_measured(c, float(r), read_options) for r, c in sorted(curve.items())]
    else:
        curves = [_measured(curve, base.loading.strain_rate_per_s if rate is None else rate, read_options)]
    rates = [c.strain_rate_per_s for c in curves]
    if len(set(rates)) != len(rates):
        raise ConfigError(f"curve: each strain rate may appear once (got {rates})")
    return curves


# --------------------------------------------------------------------------------------------
# the fit problem, validated before any simulation
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Problem:
    base: Config  # with the fixed values applied
    keys: tuple[str, ...]  # fitted, in FIT_PARAMETERS order
    bounds: dict[str, tuple[float, float]]
    seeds: tuple[int, ...]
    curves: tuple[FittedCurve, ...]
    steps: tuple[int, ...]  # load steps of each curve's simulation
    eta_points: int
    eta_tolerance: float

    @property
    def fiber_keys(self) -> tuple[str, ...]:
        return tuple(k for k in self.keys if k != ETA_KEY)

    @property
    def fits_eta(self) -> bool:
        return ETA_KEY in self.keys

    @property
    def data(self) -> np.ndarray:
        """All measured stresses, concatenated over the curves [MPa]."""
        return np.concatenate([c.stress_MPa for c in self.curves])

    def base_value(self, key: str) -> float:
        section, name = key.split(".")
        return float(getattr(getattr(self.base, section), name))

    def to_internal(self, key: str, value: float) -> float:
        """Value -> the coordinate least_squares works on (log for log-scale parameters)."""
        return math.log(value) if FIT_PARAMETERS[key].log_scale else value

    def to_value(self, key: str, z: float) -> float:
        return math.exp(z) if FIT_PARAMETERS[key].log_scale else z

    def fiber_values(self, z: np.ndarray) -> dict[str, float]:
        return {k: self.to_value(k, float(v)) for k, v in zip(self.fiber_keys, z)}

    def internal_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        pairs = [tuple(self.to_internal(k, b) for b in self.bounds[k]) for k in self.fiber_keys]
        return np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])

    def start(self) -> np.ndarray:
        """Base values of the fiber parameters (clipped just inside their bounds), internal."""
        lo, hi = self.internal_bounds()
        z = np.array([self.to_internal(k, self.base_value(k)) for k in self.fiber_keys])
        margin = 1e-3 * (hi - lo)
        return np.clip(z, lo + margin, hi - margin)


def _keys_of(names: Sequence[str] | Mapping[str, Any] | None, what: str) -> list[str]:
    keys = [parameter_key(n) for n in (names or ())]
    if len(set(keys)) != len(keys):
        raise ConfigError(f"{what}: a parameter is named twice ({', '.join(names or ())})")
    return keys


def _check_bounds(key: str, bound: Sequence[float]) -> tuple[float, float]:
    p = FIT_PARAMETERS[key]
    try:
        lo, hi = (float(b) for b in bound)
    except (TypeError, ValueError):
        raise ConfigError(f"bounds for {key}: expected (low, high), got {bound!r}") from None
    if not lo < hi:
        raise ConfigError(f"bounds for {key}: low must be < high (got {lo:g}, {hi:g})")
    if not (p.admits(lo) and p.admits(hi)):
        raise ConfigError(
            f"bounds for {key} ({p.symbol}): ({lo:g}, {hi:g}) leave the allowed range {p.allowed}"
        )
    return lo, hi


def _check_moduli(base: Config, bounds: Mapping[str, tuple[float, float]]) -> None:
    """E_t must stay above E_b for every point inside the bounds."""
    taut = bounds.get("fiber.taut_modulus_MPa", (base.fiber.taut_modulus_MPa,) * 2)
    slack = bounds.get("fiber.slack_modulus_MPa", (base.fiber.slack_modulus_MPa,) * 2)
    if taut[0] <= slack[1]:
        raise ConfigError(
            f"fiber.taut_modulus_MPa (E_t, lowest {taut[0]:g}) must stay > "
            f"fiber.slack_modulus_MPa (E_b, highest {slack[1]:g}): adjust the bounds"
        )


def _default_steps(base: Config, max_strain: float) -> int:
    """Load steps at the base config's step size (plla: 1 per percent), at least 5."""
    step = base.loading.max_strain / base.loading.steps
    return max(5, math.ceil(max_strain / step - 1e-9))


def _bounds_table(config: Config, keys: Sequence[str], bounds: Mapping[str, Any] | None) -> dict[str, tuple[float, float]]:
    """(low, high) of every fitted key: the given ones checked, the others by default."""
    stray = sorted(set(_keys_of(bounds, "bounds")) - set(keys))
    if stray:
        raise ConfigError(f"bounds given for {', '.join(stray)}, which is not fitted")
    chosen = {parameter_key(k): _check_bounds(parameter_key(k), b) for k, b in (bounds or {}).items()}
    table = {}
    for key in FIT_PARAMETERS:
        if key in keys:
            section, name = key.split(".")
            value = float(getattr(getattr(config, section), name))
            table[key] = chosen.get(key) or _check_bounds(key, default_bounds(FIT_PARAMETERS[key], value))
    _check_moduli(config, table)
    return table


def _seed_list(config: Config, realizations: int | None, seeds: Sequence[int] | None) -> tuple[int, ...]:
    """The realizations' seeds: given, or the base seed and the next ones (default 3)."""
    if seeds is None:
        if realizations is not None and realizations < 1:
            raise ConfigError(f"realizations: must be >= 1 (got {realizations})")
        seeds = [config.rve.seed + k for k in range(3 if realizations is None else realizations)]
    elif realizations is not None and realizations != len(seeds):
        raise ConfigError(f"realizations = {realizations} but {len(seeds)} seeds were given")
    if not seeds or any(int(s) != s or s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ConfigError(f"seeds: need distinct integers >= 0, at least one (got {list(seeds)})")
    return tuple(int(s) for s in seeds)


def _problem(
    curve: Any, *, base: Config | str | Path, parameters: Sequence[str], bounds: Mapping[str, Any] | None,
    fixed: Mapping[str, float] | None, realizations: int | None, seeds: Sequence[int] | None,
    strain_rate_per_s: float | None, steps: int | None, eta_points: int, eta_tolerance: float,
    read_options: Mapping[str, Any],
) -> _Problem:
    from espin.rve import resolve_config

    config = resolve_config(base)
    keys = _keys_of(parameters, "parameters")
    if not keys:
        raise ConfigError("parameters: name at least one parameter to fit")
    fixed_keys = _keys_of(fixed, "fixed")
    both = sorted(set(keys) & set(fixed_keys))
    if both:
        raise ConfigError(f"{', '.join(both)}: both fitted and fixed; choose one")
    if fixed:
        config = apply_overrides(config, {parameter_key(k): v for k, v in fixed.items()})
    if config.loading.program is not None or config.loading.test == "path":
        raise ConfigError(
            "loading.program / loading.test = path: fit simulates one monotonic segment to the "
            "measured strain; use a base config with the loading shorthand"
        )
    table = _bounds_table(config, keys, bounds)
    curves = _measured_curves(curve, strain_rate_per_s, config, read_options)
    if "fiber.flow_rate_per_s" in keys and len(curves) < 2:
        raise ConfigError(
            "fiber.flow_rate_per_s (a_p): from one strain rate only b_p * asinh(rate / a_p) is "
            "identifiable; fix a_p or give curves at two or more rates"
        )
    n_points = sum(c.strain.size for c in curves)
    if n_points <= len(keys):
        raise ConfigError(f"curve: {n_points} points with strain > 0 cannot fit {len(keys)} parameters")
    seeds = _seed_list(config, realizations, seeds)
    if steps is not None and steps < 1:
        raise ConfigError(f"steps: must be >= 1 (got {steps})")
    if eta_points < 2 or not 0 < eta_tolerance < 0.1:
        raise ConfigError(
            f"eta_points must be >= 2 and eta_tolerance in (0, 0.1) (got {eta_points}, {eta_tolerance})"
        )
    return _Problem(
        base=config,
        keys=tuple(k for k in FIT_PARAMETERS if k in keys),
        bounds=table,
        seeds=seeds,
        curves=tuple(curves),
        steps=tuple(steps or _default_steps(config, c.max_strain) for c in curves),
        eta_points=eta_points,
        eta_tolerance=eta_tolerance,
    )


# --------------------------------------------------------------------------------------------
# model evaluations (run by TaskPool workers)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Task:
    """One simulation: an RVE (its config as TOML), fiber values, one curve's loading."""

    rve_toml: str
    fiber: tuple[tuple[str, float], ...]
    strain_rate_per_s: float
    max_strain: float
    steps: int
    strain: np.ndarray  # where the model is read


@functools.lru_cache(maxsize=16)
def _rve(rve_toml: str) -> Any:
    """The RVE of a config, generated once per worker process."""
    from espin.rve import generate

    return generate(config_from_dict(tomllib.loads(rve_toml), "(fit)"))


def _simulate_task(task: _Task) -> tuple[np.ndarray, str | None]:
    """Model stress at the task's strains [MPa] (NaN where a failed run did not reach), and
    the failure message of a run that did not converge (else None)."""
    from espin.driver import SimulationFailed
    from espin.run import simulate

    overrides = {k.replace(".", "__"): v for k, v in task.fiber} | {
        "loading__max_strain": task.max_strain,
        "loading__strain_rate_per_s": task.strain_rate_per_s,
        "loading__steps": task.steps,
    }
    try:
        result, failure = simulate(_rve(task.rve_toml), **overrides), None
    except SimulationFailed as exc:
        result, failure = exc.partial, str(exc)
    if result is None:
        return np.full(task.strain.shape, np.nan), failure
    return np.interp(task.strain, result.strain, result.stress(), right=np.nan), failure


@dataclass(frozen=True, eq=False)
class _Evaluation:
    """The model at one parameter point.

    per_realization : (R, m) model stress at every measured point [MPa] (NaN: not reached)
    """

    eta: float
    fiber: dict[str, float]
    per_realization: np.ndarray
    failures: tuple[str, ...]

    @property
    def mean(self) -> np.ndarray:
        return self.per_realization.mean(axis=0)


@dataclass(eq=False)
class _Model:
    """Evaluates parameter points through one pool, and keeps the objective history."""

    problem: _Problem
    pool: TaskPool
    on_evaluation: Callable[[dict[str, Any]], None] | None = None
    history: list[dict[str, Any]] = field(default_factory=list)
    simulations: int = 0
    failed_simulations: int = 0
    rve_configs: dict[tuple[float, int], str] = field(default_factory=dict)

    def _rve_toml(self, eta: float, seed: int) -> str:
        """The RVE's config as TOML (the task's identity in the workers' RVE cache)."""
        if (eta, seed) not in self.rve_configs:
            config = apply_overrides(self.problem.base, {ETA_KEY: eta, "rve.seed": seed})
            self.rve_configs[eta, seed] = config_to_toml(config)
        return self.rve_configs[eta, seed]

    def evaluate(self, points: Sequence[tuple[float, dict[str, float]]], stage: str) -> list[_Evaluation]:
        """Simulate every realization and curve of each (eta, fiber values) point."""
        problem = self.problem
        tasks = [
            _Task(self._rve_toml(eta, seed), tuple(fiber.items()), c.strain_rate_per_s, c.max_strain,
                  n, c.strain)
            for eta, fiber in points
            for seed in problem.seeds
            for c, n in zip(problem.curves, problem.steps)
        ]
        outcomes = sorted(self.pool.map(_simulate_task, tasks), key=lambda o: o.index)
        self.simulations += len(tasks)
        for outcome in outcomes:
            if not outcome.ok:
                eta, fiber = points[outcome.index // (len(problem.seeds) * len(problem.curves))]
                raise SolverError(f"fit evaluation at {_describe(eta, fiber)} raised {outcome.error}")
        per_point = len(problem.seeds) * len(problem.curves)
        evaluations = []
        for i, (eta, fiber) in enumerate(points):
            values = [o.value for o in outcomes[i * per_point:(i + 1) * per_point]]
            evaluations.append(self._record(eta, fiber, values, stage))
        return evaluations

    def _record(self, eta: float, fiber: dict[str, float], values: list, stage: str) -> _Evaluation:
        n_curves = len(self.problem.curves)
        rows = [np.concatenate([v[0] for v in values[r * n_curves:(r + 1) * n_curves]])
                for r in range(len(self.problem.seeds))]
        failures = tuple(v[1] for v in values if v[1] is not None)
        self.failed_simulations += len(failures)
        evaluation = _Evaluation(eta, dict(fiber), np.array(rows), failures)
        record = {"evaluation": len(self.history) + 1, "stage": stage, ETA_KEY: eta, **fiber,
                  "sse_MPa2": _sse(self.residual(evaluation)), "failed_simulations": len(failures)}
        self.history.append(record)
        if failures:
            log.warning("%d simulation(s) failed at %s: %s", len(failures), _describe(eta, fiber), failures[0])
        if self.on_evaluation is not None:
            self.on_evaluation(record)
        return evaluation

    def residual(self, evaluation: _Evaluation) -> np.ndarray:
        """Model minus data [MPa]; a point no realization reached costs a large penalty."""
        data = self.problem.data
        r = evaluation.mean - data
        return np.where(np.isfinite(r), r, PENALTY_FACTOR * np.max(np.abs(data)))


def _sse(residual: np.ndarray) -> float:
    return float(residual @ residual)


def _describe(eta: float, fiber: Mapping[str, float]) -> str:
    return ", ".join(f"{k} = {v:.6g}" for k, v in {ETA_KEY: eta, **fiber}.items())


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


# --------------------------------------------------------------------------------------------
# uncertainty
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Uncertainty:
    sd: dict[str, float]
    realization_sd: dict[str, float] | None
    correlation: np.ndarray
    eta_profile_sd: float | None


def _full_jacobian(model: _Model, best: _FiberFit) -> np.ndarray:
    """d residual / d (eta, z) at the optimum; the eta column is a central secant of +-5 %."""
    if not model.problem.fits_eta:
        return best.jacobian
    d = ETA_SECANT * best.eta
    fiber = best.evaluation.fiber
    up, down = model.evaluate([(best.eta + d, fiber), (best.eta - d, fiber)], "eta secant")
    eta_column = (up.mean - down.mean) / (2 * d)  # NaN if a run failed: then so is every sd
    return np.column_stack([eta_column, best.jacobian])


def _eta_profile_sd(solved: Sequence[_FiberFit], best: _FiberFit, s2: float, spacing: float) -> float:
    """sd of eta from the profile's curvature: SSE ~ a + c (eta - eta0)^2, sd^2 = s^2 / c."""
    near = [f for f in solved if abs(f.eta - best.eta) <= spacing * (1 + 1e-9)]
    if len({f.eta for f in near}) < 3:
        return math.nan
    curvature = np.polyfit([f.eta for f in near], [f.sse for f in near], 2)[0]
    return math.sqrt(s2 / curvature) if curvature > 0 else math.nan


def _uncertainty(model: _Model, best: _FiberFit, solved: Sequence[_FiberFit]) -> _Uncertainty:
    problem = model.problem
    J = _full_jacobian(model, best)
    m, p = J.shape
    s2 = best.sse / max(m - p, 1)
    internal = np.array([best.eta] * problem.fits_eta + list(best.z))
    to_value = np.array([math.exp(z) if FIT_PARAMETERS[k].log_scale else 1.0 for k, z in zip(problem.keys, internal)])
    try:
        inverse = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
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
    return _Uncertainty(dict(zip(problem.keys, (sd_z * to_value).tolist())), spread, correlation, eta_sd)


# --------------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------------------------
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
    steps: int | None = None,
    eta_points: int = 5,
    eta_tolerance: float = 0.002,
    workers: int | None = 1,
    scheduler: Any = None,
    read_options: Mapping[str, Any] | None = None,
    on_evaluation: Callable[[dict[str, Any]], None] | None = None,
) -> FitResult:
    """Fit eta and fiber-law parameters to measured stress-strain curve(s) (paper 4.2).

    Every input is checked before the first simulation.

    Parameters
    ----------
    curve
        The measured curve: (strain, stress [MPa]) arrays, an ``espin.experiments`` Curve or
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
    steps
        Load steps per simulation; default the base config's step size (plla: 1 per %).
    eta_points
        Points of the eta grid, >= 2.
    eta_tolerance
        Absolute tolerance of the bracket search on eta, in (0, 0.1).
    workers, scheduler
        Where simulations run (:class:`espin.parallel.TaskPool`); default serial.
    read_options
        Keyword arguments of ``espin.experiments.read_curve`` for CSV paths.
    on_evaluation
        Called with each history record (progress display).

    Returns
    -------
    FitResult

    Raises
    ------
    ConfigError
        For an unknown parameter, bounds outside the allowed range, a_p with one rate, bad
        curves... (before any simulation).
    SolverError
        When the model fails where the fit cannot step around it (the message names the
        parameter values).
    """
    start = time.perf_counter()
    problem = _problem(
        curve, base=base, parameters=parameters, bounds=bounds, fixed=fixed, realizations=realizations,
        seeds=seeds, strain_rate_per_s=strain_rate_per_s, steps=steps, eta_points=eta_points,
        eta_tolerance=eta_tolerance, read_options=read_options or {},
    )
    with TaskPool(workers=workers, scheduler=scheduler, blas_threads=1) as pool:
        model = _Model(problem, pool, on_evaluation)
        best, solved = _search(model)
        if best.evaluation.failures:
            raise SolverError(
                f"fit: the best point found, {_describe(best.eta, best.evaluation.fiber)}, has failed "
                f"simulations: {best.evaluation.failures[0]}"
            )
        uncertainty = _uncertainty(model, best, solved)
    return _result(problem, model, best, solved, uncertainty, fixed or {}, time.perf_counter() - start)


def synthetic_curve(
    config: Config | str | Path,
    strain: Sequence[float] | np.ndarray,
    *,
    seeds: Sequence[int],
    strain_rate_per_s: float | None = None,
    steps: int | None = None,
    noise_sd_MPa: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> FittedCurve:
    """A synthetic measured curve: one specimen per seed (an RVE realization) plus noise.

    Each specimen is the simulated stress at ``strain`` with independent normal noise of sd
    ``noise_sd_MPa`` added at every point; the curve is their mean, with their sd.

    Parameters
    ----------
    config
        The true parameters (Config, preset or TOML).
    strain
        Strains where the curve is read, increasing, > 0.
    seeds
        ``rve.seed`` of each specimen.
    strain_rate_per_s
        Strain rate [1/s]; default the config's.
    steps
        Load steps; default the config's step size.
    noise_sd_MPa
        sd of the noise added to each specimen [MPa], >= 0.
    rng
        Generator or seed of the noise.

    Returns
    -------
    FittedCurve
        Without a model (``model_MPa`` None); ``sd_MPa`` None for a single specimen.
    """
    from espin.rve import resolve_config

    config = resolve_config(config)
    rate = config.loading.strain_rate_per_s if strain_rate_per_s is None else strain_rate_per_s
    curve = _validated_curve(rate, strain, np.zeros(len(strain)), None, "synthetic")
    if noise_sd_MPa < 0 or not seeds:
        raise ConfigError("synthetic_curve: need noise_sd_MPa >= 0 and at least one seed")
    fiber = tuple((f"fiber.{k}", v) for k, v in config.fiber.model_dump().items())
    n = steps or _default_steps(config, curve.max_strain)
    generator = np.random.default_rng(rng)
    specimens = []
    for seed in seeds:
        task = _Task(config_to_toml(apply_overrides(config, {"rve.seed": int(seed)})), fiber, rate,
                     curve.max_strain, n, curve.strain)
        stress, failure = _simulate_task(task)
        if failure is not None:
            raise SolverError(f"synthetic_curve: seed {seed}: {failure}")
        specimens.append(stress + noise_sd_MPa * generator.standard_normal(stress.size))
    specimens = np.array(specimens)
    sd = specimens.std(axis=0, ddof=1) if len(seeds) > 1 else None
    return FittedCurve(rate, curve.strain, specimens.mean(axis=0), sd, source=f"synthetic, seeds {list(seeds)}")
