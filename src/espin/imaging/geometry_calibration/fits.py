"""Closed-form models of the calibration: walk persistence, axial von Mises, truncated normal.

Units: um, degrees at the edge; radians inside.
"""

from __future__ import annotations

import math

import numpy as np

from espin.geometry.targets import MeasurementError

__all__ = [
    "KAPPA_MAX",
    "persistence_ratio",
    "fit_axial_von_mises",
    "truncated_normal_parameters",
]

KAPPA_MAX = 700.0
"""Largest von Mises concentration a config accepts."""


def persistence_ratio(segment_ratio: float, max_deviation_deg: float) -> float:
    """Persistence length of the deposition walk over D, ``-l_s / ln(sin t / t)``.

    Consecutive segments turn by a uniform angle in [-t, t], so the direction correlation
    after n segments is E[cos]^n = (sin t / t)^n = exp(-n l_s / l_p).

    Parameters
    ----------
    segment_ratio : float
        Segment length over D.
    max_deviation_deg : float [deg]
        Largest turn t between consecutive segments.

    Returns
    -------
    float
        l_p / D (infinite for straight fibers).
    """
    t = math.radians(max_deviation_deg)
    if t == 0.0:
        return math.inf
    return -segment_ratio / math.log(math.sin(t) / t)


def _mean_resultant(theta_rad: np.ndarray) -> tuple[float, float]:
    """Axial order |<exp(2 i theta)>| and director [rad] of axes ``theta_rad``."""
    z = np.mean(np.exp(2j * np.asarray(theta_rad)))
    return float(abs(z)), float(np.mod(np.angle(z) / 2.0, np.pi))


def _kappa_from_order(order: float) -> float:
    """Von Mises kappa of the doubled angle whose mean resultant length is ``order``."""
    from scipy import optimize, special

    def a1(k: float) -> float:
        return float(special.i1e(k) / special.i0e(k))

    if order <= 0.0:
        return 0.0
    if a1(KAPPA_MAX) <= order:
        return KAPPA_MAX
    return float(optimize.brentq(lambda k: a1(k) - order, 0.0, KAPPA_MAX, xtol=1e-10))


def fit_axial_von_mises(orientation_deg: np.ndarray) -> tuple[float, float, float]:
    """Axial von Mises fit and isotropy test of measured fiber axes.

    Parameters
    ----------
    orientation_deg : (n,) array [deg]
        Fiber axes in [0, 180).

    Returns
    -------
    mean_deg : float [deg]
        Maximum-likelihood mean axis, in [0, 180).
    kappa : float
        Maximum-likelihood concentration of p ~ exp(kappa cos 2(theta - mean)), <= 700.
    p_isotropy : float
        Rayleigh test of the doubled angles (Zar's approximation): the probability of an
        order at least this large from a uniform distribution.
    """
    n = len(orientation_deg)
    order, director = _mean_resultant(np.radians(orientation_deg))
    r = n * order
    p = math.exp(math.sqrt(1.0 + 4.0 * n + 4.0 * (n * n - r * r)) - (1.0 + 2.0 * n))
    return math.degrees(director) % 180.0, _kappa_from_order(order), min(p, 1.0)


def truncated_normal_parameters(mean_um: float, sd_um: float, lower_um: float | None = None) -> tuple[float, float]:
    """Parent normal (mu, sigma) whose truncation below ``lower_um`` has this mean and sd.

    Parameters
    ----------
    mean_um, sd_um : float [um]
        Target mean and standard deviation of the diameters.
    lower_um : float [um], optional
        Truncation; default 0.1 mu, the config's default ``diameter_min_um``.

    Returns
    -------
    (mu, sigma) : float [um]
        ``rve.diameter_um`` and ``rve.diameter_sd_um``.

    Raises
    ------
    MeasurementError
        If no truncated normal has this mean and sd (the sd is too large for the mean).
    """
    from scipy import optimize, stats

    if sd_um == 0.0:
        return mean_um, 0.0

    def moments(params: np.ndarray) -> np.ndarray:
        mu, sigma = params[0], math.exp(params[1])
        low = 0.1 * mu if lower_um is None else lower_um
        law = stats.truncnorm((low - mu) / sigma, np.inf, loc=mu, scale=sigma)
        return np.array([law.mean() - mean_um, law.std() - sd_um]) / sd_um

    start = np.array([mean_um, math.log(sd_um)])
    if np.max(np.abs(moments(start))) < 1e-9:
        return mean_um, sd_um
    sol = optimize.root(moments, start, method="hybr")
    mu, sigma = float(sol.x[0]), math.exp(sol.x[1])
    if not sol.success or np.max(np.abs(moments(sol.x))) > 1e-6 or mu <= 0.0:
        raise MeasurementError(
            f"no normal truncated at diameter_min_um has mean {mean_um:g} um and sd {sd_um:g} um "
            "(the sd is too large for the mean); give a smaller diameter sd"
        )
    return mu, sigma
