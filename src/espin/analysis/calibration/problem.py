"""The fit problem: every input of :func:`espin.analysis.calibration.fit` checked before any simulation."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from espin.analysis.calibration.curves import AverageGrid, FittedCurve, _measured_curves
from espin.analysis.calibration.parameters import ETA_KEY, FIT_PARAMETERS, _bounds_table, _keys_of, parameter_key
from espin.analysis.calibration.simulation import _curve_steps, _loading_config, _Steps, _steps_are_time_steps
from espin.core.config import Config, apply_overrides
from espin.core.errors import ConfigError


@dataclass(frozen=True, eq=False)
class _Problem:
    base: Config  # with the fixed values applied
    keys: tuple[str, ...]  # fitted, in FIT_PARAMETERS order
    bounds: dict[str, tuple[float, float]]
    seeds: tuple[int, ...]
    curves: tuple[FittedCurve, ...]
    steps: tuple[_Steps, ...]  # load steps of each curve's simulations
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


def _checked_steps(
    config: Config, curves: Sequence[FittedCurve], step_strain: float, large_strain: bool
) -> tuple[_Steps, ...]:
    """Each curve's load steps, its loading validated as the simulations will run it."""
    if not (isinstance(step_strain, (int, float)) and math.isfinite(step_strain) and 0 < step_strain <= 0.1):
        raise ConfigError(f"step_strain: the largest load step must be in (0, 0.1] (got {step_strain!r})")
    steps = []
    for c in curves:
        if c.max_strain > 1.0 and not large_strain:
            raise ConfigError(
                f"curve {c.source}: its largest strain is {c.max_strain:g} (= {100 * c.max_strain:g} %): "
                "strain in percent? use --percent-strain (read_options={'percent_strain': True}); "
                "if strains above 1 are intended, pass --large-strain (large_strain=True)"
            )
        s = _curve_steps(c.strain, c.stress_MPa, step_strain)
        try:
            _loading_config(config, s, c.strain_rate_per_s)
        except ConfigError as err:
            raise ConfigError(f"curve {c.source} at {c.strain_rate_per_s:g} 1/s: {err}") from None
        steps.append(s)
    return tuple(steps)


def _problem(
    curve: Any,
    *,
    base: Config | str | Path,
    parameters: Sequence[str],
    bounds: Mapping[str, Any] | None,
    fixed: Mapping[str, float] | None,
    realizations: int | None,
    seeds: Sequence[int] | None,
    strain_rate_per_s: float | None,
    step_strain: float,
    eta_points: int,
    eta_tolerance: float,
    read_options: Mapping[str, Any],
    average_grid: AverageGrid = "measured",
    large_strain: bool = False,
) -> _Problem:
    from espin.geometry.rve import resolve_config

    config = _steps_are_time_steps(resolve_config(base))
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
    curves = _measured_curves(curve, strain_rate_per_s, config, read_options, average_grid)
    if "fiber.flow_rate_per_s" in keys and len(curves) < 2:
        raise ConfigError(
            "fiber.flow_rate_per_s (a_p): from one strain rate only b_p * asinh(rate / a_p) is "
            "identifiable; fix a_p or give curves at two or more rates"
        )
    n_points = sum(c.strain.size for c in curves)
    if n_points <= len(keys):
        raise ConfigError(f"curve: {n_points} points with strain > 0 cannot fit {len(keys)} parameters")
    seeds = _seed_list(config, realizations, seeds)
    steps = _checked_steps(config, curves, step_strain, large_strain)
    if eta_points < 2 or not 0 < eta_tolerance < 0.1:
        raise ConfigError(f"eta_points must be >= 2 and eta_tolerance in (0, 0.1) (got {eta_points}, {eta_tolerance})")
    return _Problem(
        base=config,
        keys=tuple(k for k in FIT_PARAMETERS if k in keys),
        bounds=table,
        seeds=seeds,
        curves=tuple(curves),
        steps=steps,
        eta_points=eta_points,
        eta_tolerance=eta_tolerance,
    )
