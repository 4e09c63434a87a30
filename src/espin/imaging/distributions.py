"""Distributions fitted to the measured fibers (maximum likelihood), as the paper reports them.

- Diameter: normal (mean, sd), paper Fig. 10 / docs/model.md section 7.
- Orientation (axes in [0, 180) deg): uniform, p = 1 / pi, or axial von Mises,
  p(theta) = exp(kappa cos 2 (theta - mu)) / (pi I0(kappa)) (espin's ``rve.orientation``
  form). The one with the smaller Akaike information criterion, AIC = 2 k - 2 ln L
  (k = 0 for uniform, 2 for von Mises), is chosen; both AICs are reported.
- Tortuosity: half-normal with location 1, ``halfnorm(loc=1, scale)``; the MLE of the scale
  is sqrt(mean((t - 1)^2)).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import special, stats

__all__ = ["FittedDistributions", "fit_distributions"]


@dataclass(frozen=True)
class FittedDistributions:
    """Fitted parameters (NaN where there are too few samples).

    Attributes
    ----------
    diameter_mean_um, diameter_sd_um : float [um]
        Normal fit of the per-fiber diameters.
    orientation_model : str
        ``"uniform"`` or ``"von_mises"`` (smaller AIC).
    orientation_mean_deg : float [deg]
        von Mises mean axis mu, in [0, 180).
    orientation_kappa : float
        von Mises concentration kappa (p ~ exp(kappa cos 2 (theta - mu))).
    orientation_aic_uniform, orientation_aic_von_mises : float
        Akaike information criteria of the two models.
    tortuosity_loc : float
        1 (fixed).
    tortuosity_scale : float
        Half-normal scale.
    """

    diameter_mean_um: float
    diameter_sd_um: float
    orientation_model: str
    orientation_mean_deg: float
    orientation_kappa: float
    orientation_aic_uniform: float
    orientation_aic_von_mises: float
    tortuosity_loc: float
    tortuosity_scale: float

    def as_dict(self) -> dict[str, float | str]:
        """Parameters by name (for the summary file)."""
        return asdict(self)

    def orientation_pdf(self, theta_deg: np.ndarray) -> np.ndarray:
        """Fitted orientation density [1/deg] at axes ``theta_deg``."""
        theta = np.radians(np.asarray(theta_deg, dtype=float))
        if self.orientation_model == "uniform":
            return np.full(theta.shape, 1.0 / 180.0)
        mu, kappa = math.radians(self.orientation_mean_deg), self.orientation_kappa
        # exp(kappa cos 2(theta - mu)) / (pi I0(kappa)), scaled to stay finite at large kappa
        density = np.exp(kappa * (np.cos(2.0 * (theta - mu)) - 1.0)) / (np.pi * special.i0e(kappa))
        return density * (np.pi / 180.0)


def fit_distributions(diameter_um: np.ndarray, orientation_deg: np.ndarray,
                      tortuosity: np.ndarray) -> FittedDistributions:
    """Fit the three distributions of the module notes to per-fiber samples.

    Parameters
    ----------
    diameter_um : (n,) float [um]
    orientation_deg : (n,) float [deg], axes in [0, 180)
    tortuosity : (n,) float, >= 1

    Returns
    -------
    FittedDistributions
    """
    d = _finite(diameter_um)
    mean = float(np.mean(d)) if len(d) else math.nan
    sd = float(np.std(d)) if len(d) > 1 else math.nan
    model, mu, kappa, aic_u, aic_vm = _fit_orientation(np.radians(_finite(orientation_deg)))
    t = _finite(tortuosity)
    scale = float(np.sqrt(np.mean((t - 1.0) ** 2))) if len(t) else math.nan
    return FittedDistributions(diameter_mean_um=mean, diameter_sd_um=sd, orientation_model=model,
                               orientation_mean_deg=mu, orientation_kappa=kappa,
                               orientation_aic_uniform=aic_u, orientation_aic_von_mises=aic_vm,
                               tortuosity_loc=1.0, tortuosity_scale=scale)


def _fit_orientation(theta: np.ndarray) -> tuple[str, float, float, float, float]:
    """(model, mu [deg], kappa, AIC uniform, AIC von Mises) for axes theta [rad]."""
    n = len(theta)
    if n < 3:
        return "uniform", math.nan, math.nan, math.nan, math.nan
    log_l_uniform = -n * math.log(math.pi)
    phi = np.angle(np.exp(2j * theta))  # doubled angles in [-pi, pi]: a von Mises sample
    kappa, loc, _ = stats.vonmises.fit(phi, fscale=1.0)
    log_l_vm = float(np.sum(stats.vonmises.logpdf(phi, kappa, loc=loc))) + n * math.log(2.0)
    aic_u, aic_vm = -2.0 * log_l_uniform, 4.0 - 2.0 * log_l_vm
    mu = math.degrees(float(np.mod(loc / 2.0, np.pi)))
    model = "von_mises" if aic_vm < aic_u else "uniform"
    return model, mu, float(kappa), aic_u, aic_vm


def _finite(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return x[np.isfinite(x)]
