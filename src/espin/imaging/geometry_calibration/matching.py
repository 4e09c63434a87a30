"""Targets as comparable distributions: KS distance of virtual portions against each target."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from espin.geometry.targets import GeometryTargets
from espin.imaging.geometry_calibration.fits import _mean_resultant, fit_axial_von_mises

__all__ = ["DistributionMatch", "FIXED_TOLERANCE", "CrossingTarget", "crossing_target"]

FIXED_TOLERANCE = 1e-6
"""Relative tolerance within which a virtual value equals a typed-in fixed value (sd 0)."""


@dataclass(frozen=True)
class DistributionMatch:
    """How one visible distribution of the calibrated mat matches its target.

    Attributes
    ----------
    quantity : str
        ``"tortuosity"``, ``"orientation_deg"`` or ``"diameter_um"``.
    target : str
        The target: a measured sample or a named distribution.
    n_target : int or None
        Size of the measured sample (None for a typed-in distribution).
    n_virtual : int
        Visible fiber portions of the virtual mats.
    ks : float
        Kolmogorov-Smirnov distance (0 same, 1 disjoint). Against a fixed value (sd 0) it is
        the fraction of virtual values off that value by more than :data:`FIXED_TOLERANCE`
        (relative) on the side where more are.
    p_value : float or None
        Two-sample KS p-value against a measured sample, **descriptive only**: the parameters
        were fitted to this same sample, the virtual pieces are not independent (several
        pieces per fiber, pieces overlap) and their number is a setting, so the p-value is
        optimistic and is no test of the fit. None against a typed-in distribution.
    summary : tuple of (name, target value, virtual value)
        Mean / sd / median (orientation: director [deg] and order |<exp 2i theta>|).
    """

    quantity: str
    target: str
    n_target: int | None
    n_virtual: int
    ks: float
    p_value: float | None
    summary: tuple[tuple[str, float, float], ...]


def _compare(
    quantity: str,
    virtual: np.ndarray,
    sample: np.ndarray | None,
    cdf: Callable[[np.ndarray], np.ndarray] | None,
    label: str,
    target_summary: tuple[tuple[str, float], ...],
) -> DistributionMatch:
    """KS distance (and p-value against a sample) of ``virtual`` against its target."""
    from scipy import stats

    if sample is not None:
        test = stats.ks_2samp(virtual, sample)
        ks, p = float(test.statistic), float(test.pvalue)
    else:
        ks, p = _one_sample_ks(virtual, cast(Callable, cdf)), None  # a target without a sample has a law
    virtual_summary = dict(_summary(quantity, virtual))
    rows = tuple((name, float(t), float(virtual_summary[name])) for name, t in target_summary)
    return DistributionMatch(quantity, label, None if sample is None else len(sample), len(virtual), ks, p, rows)


@dataclass(frozen=True)
class _Fixed:
    """The cdf of a point mass at ``value`` (a typed-in diameter with sd 0)."""

    value: float

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x) >= self.value).astype(float)


def _one_sample_ks(virtual: np.ndarray, cdf: Callable[[np.ndarray], np.ndarray]) -> float:
    """KS distance of ``virtual`` against ``cdf``; against a point mass, with a tolerance.

    ``scipy.stats.kstest`` against the step cdf of a point mass gives D = 1 even when every
    value equals it (D- takes the cdf just left of the step); the exact distance to a point
    mass at m is max(P(X < m), P(X > m)), and values within the tolerance count as m.
    """
    from scipy import stats

    if isinstance(cdf, _Fixed):
        x = np.asarray(virtual, dtype=float)
        tol = FIXED_TOLERANCE * max(abs(cdf.value), 1e-300)
        below, above = np.mean(x < cdf.value - tol), np.mean(x > cdf.value + tol)
        return float(max(below, above))
    return float(stats.kstest(virtual, cdf).statistic)


def _summary(quantity: str, x: np.ndarray) -> tuple[tuple[str, float], ...]:
    if quantity == "orientation_deg":
        order, director = _mean_resultant(np.radians(x))
        return (("director_deg", math.degrees(director)), ("order", order))
    return (("mean", float(np.mean(x))), ("sd", float(np.std(x))), ("median", float(np.median(x))))


def _distribution_summary(law: Any) -> tuple[tuple[str, float], ...]:
    """Summary of a frozen scipy distribution (mean, sd, median)."""
    return (("mean", float(law.mean())), ("sd", float(law.std())), ("median", float(law.median())))


@dataclass(frozen=True)
class _Target:
    """One targeted distribution: a sample, or a cdf with its summary."""

    quantity: str
    sample: np.ndarray | None
    cdf: Callable[[np.ndarray], np.ndarray] | None
    label: str
    summary: tuple[tuple[str, float], ...]

    def ks_noise(self, n_virtual: int) -> float:
        """Typical sampling spread of a KS distance against this target, 1 / sqrt(n_eff)."""
        n = max(n_virtual, 1)
        n_eff = n if self.sample is None else n * len(self.sample) / (n + len(self.sample))
        return 1.0 / math.sqrt(n_eff)

    def ks(self, virtual: np.ndarray) -> float:
        from scipy import stats

        if len(virtual) == 0:
            return 1.0
        if self.sample is not None:
            return float(stats.ks_2samp(virtual, self.sample).statistic)
        return _one_sample_ks(virtual, cast(Callable, self.cdf))  # a target without a sample has a law

    def compare(self, virtual: np.ndarray) -> DistributionMatch:
        return _compare(self.quantity, virtual, self.sample, self.cdf, self.label, self.summary)


def _sample_target(quantity: str, sample: np.ndarray, source: str) -> _Target:
    return _Target(quantity, sample, None, f"measured sample ({source})", _summary(quantity, sample))


def _tortuosity_target(targets: GeometryTargets) -> _Target:
    if targets.tortuosity is not None:
        return _sample_target("tortuosity", targets.tortuosity, targets.source)
    law = targets.tortuosity_distribution()
    return _Target(
        "tortuosity", None, law.cdf, f"halfnorm(loc=1, scale={targets.tortuosity_scale:g})", _distribution_summary(law)
    )


def _diameter_target(targets: GeometryTargets) -> _Target:
    if targets.diameter_um is not None:
        return _sample_target("diameter_um", targets.diameter_um, targets.source)
    from scipy import stats

    mean, sd = cast(float, targets.diameter_mean_um), targets.diameter_sd_um or 0.0  # no sample: a mean
    if sd == 0.0:
        return _Target(
            "diameter_um", None, _Fixed(mean), f"fixed {mean:g} um", (("mean", mean), ("sd", 0.0), ("median", mean))
        )
    law = stats.norm(mean, sd)
    return _Target("diameter_um", None, law.cdf, f"normal({mean:g}, {sd:g}) um", _distribution_summary(law))


def _orientation_spec(targets: GeometryTargets) -> tuple[str | dict[str, Any], _Target, list[str]]:
    """The target orientation as a config value, its comparison target, and notes."""
    from espin.core.config import VonMises
    from espin.geometry.orientation import orientation_distribution

    notes: list[str] = []
    if targets.orientation_deg is not None:
        from espin.imaging.distributions import fit_distributions

        mean, kappa, p = fit_axial_von_mises(targets.orientation_deg)
        # espin measure's rule (smaller AIC), so that the mat follows what measure reported.
        fitted = fit_distributions(np.empty(0), targets.orientation_deg, np.empty(0))
        spec: str | dict[str, Any] = "uniform"
        if fitted.orientation_model == "von_mises":
            spec = {"von_mises": {"mean_deg": round(mean, 2) % 180.0, "kappa": round(kappa, 4)}}
        notes.append(
            f"orientation sample: AIC uniform {fitted.orientation_aic_uniform:.1f}, von Mises "
            f"{fitted.orientation_aic_von_mises:.1f} (Rayleigh p = {p:.3g}) -> "
            f"{'uniform' if spec == 'uniform' else 'von Mises'}"
        )
        return spec, _sample_target("orientation_deg", targets.orientation_deg, targets.source), notes
    if targets.orientation_uniform:
        spec = "uniform"
    else:
        spec = {"von_mises": {"mean_deg": targets.orientation_mean_deg, "kappa": targets.orientation_kappa}}
    law = orientation_distribution("uniform" if spec == "uniform" else VonMises.model_validate(spec))
    # Summary of the exact distribution: director and order I1/I0(kappa).
    from scipy import special

    if spec == "uniform":
        summary: tuple[tuple[str, float], ...] = (("order", 0.0),)
    else:
        k = targets.orientation_kappa
        summary = (
            ("director_deg", cast(float, targets.orientation_mean_deg)),
            ("order", float(special.i1e(k) / special.i0e(k))),
        )
    return spec, _Target("orientation_deg", None, lambda x: law.cdf(np.radians(x)), law.label, summary), notes


@dataclass(frozen=True)
class CrossingTarget:
    """The long-range shape measured on an image: of the traced fibers that cross it edge to
    edge, the U-turn fraction and the straightness (end-to-end over contour), with their count.

    :meth:`misfit` weighs a virtual mat's differences by the standard errors of the target:
    for the fraction p of n fibers sqrt(max(p (1 - p), 1 / n) / n) (a binomial, floored so
    that p = 0 of a few fibers still has an error), for the straightness s
    max(1 - s, 0.005) / sqrt(n) (the spread of a ratio bounded by 1 is of the order of its
    distance from 1).
    """

    u_turn_fraction: float
    straightness: float
    n_crossing: int

    def misfit(self, crossing: np.ndarray) -> float:
        """Sum of the squared standardized differences of a virtual ``crossing`` (count, U-turn
        fraction, straightness; :meth:`VirtualMeasurement.measure`); inf if it has none."""
        n_virtual, u_turn, straightness = crossing
        if n_virtual == 0:
            return math.inf
        n = max(self.n_crossing, 1)
        p = self.u_turn_fraction
        se_u = math.sqrt(max(p * (1.0 - p), 1.0 / n) / n)
        se_s = max(1.0 - self.straightness, 0.005) / math.sqrt(n)
        return ((u_turn - p) / se_u) ** 2 + ((straightness - self.straightness) / se_s) ** 2


def crossing_target(targets: GeometryTargets) -> CrossingTarget | None:
    """The targets' long-range shape, or None when they do not carry it (a plain fibers.csv,
    typed-in targets) or no traced fiber crosses the image."""
    u, s, n = targets.u_turn_fraction, targets.straightness, targets.n_crossing
    if u is None or s is None or not n or not (math.isfinite(u) and math.isfinite(s)):
        return None
    return CrossingTarget(float(u), float(s), int(n))
