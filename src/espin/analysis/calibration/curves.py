"""Measured curves in (arrays, Curve objects, CSV files), validated; synthetic measured curves."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from espin.analysis.calibration.simulation import (
    STEP_STRAIN,
    _load_steps,
    _simulate_task,
    _steps_are_time_steps,
    _Task,
)
from espin.core.config import Config, apply_overrides, config_to_toml
from espin.core.errors import ConfigError, SolverError


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
    points_from : str
        Where the points came from: the measured strains, or a grid the specimens were
        interpolated onto (the Gauss-Newton sd depends on the number of points).
    model_realizations_MPa : (R, m) float64 [MPa] or None
        Model stress of each realization at the fitted values (order of the fit's seeds).
    """

    strain_rate_per_s: float
    strain: np.ndarray
    stress_MPa: np.ndarray
    sd_MPa: np.ndarray | None = None
    model_MPa: np.ndarray | None = None
    model_sd_MPa: np.ndarray | None = None
    source: str = "arrays"
    points_from: str = "given"
    model_realizations_MPa: np.ndarray | None = None

    @property
    def max_strain(self) -> float:
        """Largest measured strain (the simulations run to it)."""
        return float(self.strain[-1])


CurveLike = Any
"""(strain, stress) arrays, an ``espin.analysis.experiments`` Curve or AveragedCurve, a CSV path, or
a sequence of CSV paths (read and averaged)."""

AverageGrid = Any
"""Where specimens read from CSV files are averaged: ``"measured"`` (their common strains, else
the union of their strains within the common range), a number of evenly spaced strains, or
the strains themselves."""


def _is_path(value: Any) -> bool:
    return isinstance(value, (str, Path))


def _read_files(paths: Sequence[str | Path], read_options: Mapping[str, Any], grid: AverageGrid) -> tuple[Any, str]:
    """The curve of one file, or the average of several; and where its points came from."""
    from espin.analysis.experiments import _shared_strains, average_curves, read_curve

    curves = [read_curve(p, **read_options) for p in paths]
    if len(curves) == 1:
        return curves[0], "the file's measured strains"
    n = len(curves)
    if isinstance(grid, str):
        if grid != "measured":
            raise ConfigError(f'average_grid: "measured", a number of points or strains (got {grid!r})')
        where = (
            f"the measured strains, common to the {n} specimens"
            if _shared_strains(curves)
            else f"the union of the {n} specimens' measured strains within their common range "
            "(each interpolated at the others' strains)"
        )
        return average_curves(curves, grid="measured"), where
    if isinstance(grid, (int, np.integer)) and not isinstance(grid, bool):
        if grid < 2:
            raise ConfigError(f"average_grid: at least 2 points (got {grid})")
        return average_curves(curves, n_points=int(grid)), f"{grid} evenly spaced strains (interpolated)"
    return average_curves(curves, grid=grid), "the given averaging grid (interpolated)"


def _measured(
    curve: CurveLike, rate: float, read_options: Mapping[str, Any], grid: AverageGrid = "measured"
) -> FittedCurve:
    """A validated :class:`FittedCurve` (no model yet) from any accepted curve form."""
    source, points_from = "arrays", "given"
    if _is_path(curve) or (isinstance(curve, Sequence) and curve and all(_is_path(c) for c in curve)):
        paths = [curve] if _is_path(curve) else list(curve)
        source = ", ".join(Path(p).name for p in paths)
        curve, points_from = _read_files(paths, read_options, grid)
    sd = None
    if hasattr(curve, "mean_MPa"):
        strain, stress, sd = curve.strain, curve.mean_MPa, curve.sd_MPa
        if points_from == "given":
            points_from = "the given AveragedCurve's grid"
            source = ", ".join(Path(p).name for p in getattr(curve, "sources", ())) or source
    elif hasattr(curve, "stress_MPa"):
        strain, stress, sd = curve.strain, curve.stress_MPa, getattr(curve, "sd_MPa", None)
        source = str(getattr(curve, "source", source))
        points_from = str(getattr(curve, "points_from", points_from))
    elif isinstance(curve, Sequence) and len(curve) == 2:
        strain, stress = curve
    else:
        raise ConfigError(
            "curve: expected (strain, stress) arrays, a Curve or AveragedCurve, or CSV paths "
            f"(got {type(curve).__name__})"
        )
    return _validated_curve(rate, strain, stress, sd, source, points_from)


def _validated_curve(
    rate: float, strain: Any, stress: Any, sd: Any, source: str, points_from: str = "given"
) -> FittedCurve:
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
        points_from=points_from,
    )


def _measured_curves(
    curve: CurveLike | Mapping[float, CurveLike],
    rate: float | None,
    base: Config,
    read_options: Mapping[str, Any],
    grid: AverageGrid = "measured",
) -> list[FittedCurve]:
    """The curves to fit, each with its strain rate (a mapping gives one curve per rate)."""
    if isinstance(curve, Mapping):
        if rate is not None:
            raise ConfigError(
                "strain_rate_per_s: give it for a single curve, or give curves as a mapping rate -> curve, not both"
            )
        if not curve:
            raise ConfigError("curve: the mapping rate -> curve is empty")
        curves = [_measured(c, float(r), read_options, grid) for r, c in sorted(curve.items())]
    else:
        curves = [_measured(curve, base.loading.strain_rate_per_s if rate is None else rate, read_options, grid)]
    rates = [c.strain_rate_per_s for c in curves]
    if len(set(rates)) != len(rates):
        raise ConfigError(f"curve: each strain rate may appear once (got {rates})")
    return curves


def synthetic_curve(
    config: Config | str | Path,
    strain: Sequence[float] | np.ndarray,
    *,
    seeds: Sequence[int],
    strain_rate_per_s: float | None = None,
    step_strain: float = STEP_STRAIN,
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
    step_strain
        Largest load step [strain], over the whole curve (a fit's default steps are as fine
        only up to twice the knee); segments end at ``strain``.
    noise_sd_MPa
        sd of the noise added to each specimen [MPa], >= 0.
    rng
        Generator or seed of the noise.

    Returns
    -------
    FittedCurve
        Without a model (``model_MPa`` None); ``sd_MPa`` None for a single specimen.
    """
    from espin.geometry.rve import resolve_config

    config = _steps_are_time_steps(resolve_config(config))
    rate = config.loading.strain_rate_per_s if strain_rate_per_s is None else strain_rate_per_s
    curve = _validated_curve(rate, strain, np.zeros(len(strain)), None, "synthetic")
    if noise_sd_MPa < 0 or not seeds:
        raise ConfigError("synthetic_curve: need noise_sd_MPa >= 0 and at least one seed")
    if not (math.isfinite(step_strain) and step_strain > 0):
        raise ConfigError(f"synthetic_curve: step_strain must be > 0 (got {step_strain!r})")
    fiber = tuple((f"fiber.{k}", v) for k, v in config.fiber.model_dump().items())
    steps = _load_steps(curve.strain, step_strain, curve.max_strain)
    generator = np.random.default_rng(rng)
    specimens = []
    for seed in seeds:
        task = _Task(config_to_toml(apply_overrides(config, {"rve.seed": int(seed)})), fiber, rate, steps, curve.strain)
        stress, failure = _simulate_task(task)
        if failure is not None:
            raise SolverError(f"synthetic_curve: seed {seed}: {failure}")
        specimens.append(stress + noise_sd_MPa * generator.standard_normal(stress.size))
    stacked = np.array(specimens)
    sd = stacked.std(axis=0, ddof=1) if len(seeds) > 1 else None
    return FittedCurve(
        rate,
        curve.strain,
        stacked.mean(axis=0),
        sd,
        source=f"synthetic, seeds {list(seeds)}",
        points_from=f"synthetic, {steps.count} load steps of at most {step_strain:g}",
    )
