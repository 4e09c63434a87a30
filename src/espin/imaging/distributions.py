"""Distributions fitted to the measured fibers (maximum likelihood), as the paper reports them.

- Diameter (of the fully visible fibers, :mod:`espin.imaging.visibility`): normal (mean, sd),
  paper Fig. 10 / docs/model.md section 7, and with it (:func:`fit_diameter_families`) a
  lognormal and a mixture of two normals. The family of the smallest Bayesian information
  criterion, BIC = k ln n - 2 ln L, is chosen (k = 2, 2, 5); every fit and both criteria, BIC
  and AIC = 2 k - 2 ln L, are reported. BIC rather than AIC: on the 20 to 100 fibers of an
  image, AIC's penalty of 2 per parameter lets the mixture's three extra parameters fit noise
  (it needs a log-likelihood gain of 3 over the normal, BIC one of 1.5 ln n = 4.5 to 6.9), and a
  mixture is worth reporting only when the two populations are plainly there. Nor is a
  mixture chosen whose smaller component holds fewer than :data:`MIN_COMPONENT` fibers.
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
from typing import Any

import numpy as np
from scipy import special, stats

__all__ = [
    "DiameterFits",
    "FittedDistributions",
    "NormalMixture",
    "fit_diameter_families",
    "fit_distributions",
    "fit_normal_mixture",
    "DIAMETER_FAMILIES",
    "MIN_COMPONENT",
]

DIAMETER_FAMILIES = ("normal", "lognormal", "mixture")
"""The diameter families fitted, in the order of their number of parameters (2, 2, 5)."""
_MIN_MIXTURE = 6  # fewest samples a two-normal mixture is fitted to (5 parameters)
_EM_ITERATIONS = 500
_EM_TOLERANCE = 1e-9  # change of the mean log-likelihood per sample that ends the EM
_SD_FLOOR = 0.05  # a component's sd is at least this times the sample's (no collapse onto one point)
MIN_COMPONENT = 3.0
"""A mixture whose smaller component holds fewer fibers than this (weight x n) is not chosen:
one or two outlying fibers, not a population (a component on one fiber has a likelihood
limited only by its sd floor)."""


@dataclass(frozen=True)
class NormalMixture:
    """A mixture of two normals, p(x) = w N(x; mu_1, sd_1) + (1 - w) N(x; mu_2, sd_2),
    mu_1 <= mu_2 (units of the sample).

    Attributes
    ----------
    weight : float
        w, the weight of the lower component, in (0, 1).
    mean_1, sd_1, mean_2, sd_2 : float
        The two components.
    log_likelihood : float
        ln L of the sample.
    """

    weight: float
    mean_1: float
    sd_1: float
    mean_2: float
    sd_2: float
    log_likelihood: float

    def smaller_share(self, n: int) -> float:
        """Fibers (weight x n) in the smaller component of a sample of n."""
        return min(self.weight, 1.0 - self.weight) * n

    def log_densities(self, x: np.ndarray) -> np.ndarray:
        """(n, 2) ln of each component's weighted density at x."""
        x = np.asarray(x, dtype=float)[:, None]
        weights = np.array([self.weight, 1.0 - self.weight])
        return np.log(weights) + stats.norm.logpdf(x, [self.mean_1, self.mean_2], [self.sd_1, self.sd_2])


@dataclass(frozen=True)
class DiameterFits:
    """Normal, lognormal and two-normal mixture fitted to a diameter sample (NaN where there
    are too few samples: 2 for the normal and lognormal, 6 for the mixture).

    Attributes
    ----------
    n : int
        Sample size (finite diameters).
    mean_um, sd_um, median_um : float [um]
        Of the sample (sd: the maximum-likelihood, 1 / n one, = the normal's).
    normal_mean_um, normal_sd_um : float [um]
        Normal fit.
    lognormal_mu, lognormal_sigma : float
        Lognormal fit: ln d is normal with mean mu (ln um) and sd sigma.
    mixture : NormalMixture or None
        Two-normal mixture fit [um].
    log_likelihood : dict of str to float
        ln L of each family (:data:`DIAMETER_FAMILIES`).
    aic, bic : dict of str to float
        Akaike and Bayesian information criteria of each family.
    chosen : str
        The family of the smallest BIC ("" without a fit); the mixture only when its smaller
        component holds :data:`MIN_COMPONENT` fibers or more.
    """

    n: int
    mean_um: float
    sd_um: float
    median_um: float
    normal_mean_um: float
    normal_sd_um: float
    lognormal_mu: float
    lognormal_sigma: float
    mixture: NormalMixture | None
    log_likelihood: dict[str, float]
    aic: dict[str, float]
    bic: dict[str, float]
    chosen: str

    def pdf(self, family: str, d_um: np.ndarray) -> np.ndarray:
        """Fitted density [1/um] of ``family`` at diameters ``d_um``."""
        d = np.asarray(d_um, dtype=float)
        if family == "normal":
            return stats.norm.pdf(d, self.normal_mean_um, self.normal_sd_um)
        if family == "lognormal":
            return stats.lognorm.pdf(d, self.lognormal_sigma, scale=math.exp(self.lognormal_mu))
        if family == "mixture" and self.mixture is not None:
            return np.exp(self.mixture.log_densities(d.ravel())).sum(axis=1).reshape(d.shape)
        raise ValueError(f"no fitted family {family!r}")

    def summary(self) -> dict[str, object]:
        """The fits by family, for ``measurement.toml`` (NaN for a family not fitted)."""
        mixture = self.mixture
        lognormal_mean = math.exp(self.lognormal_mu + self.lognormal_sigma**2 / 2)
        out: dict[str, Any] = {
            "n": self.n,
            "mean_um": self.mean_um,
            "sd_um": self.sd_um,
            "median_um": self.median_um,
            "selection": "BIC",
            "distribution": self.chosen,
            "normal": {"mean_um": self.normal_mean_um, "sd_um": self.normal_sd_um},
            "lognormal": {
                "mu_ln_um": self.lognormal_mu,
                "sigma": self.lognormal_sigma,
                "mean_um": lognormal_mean,
                "sd_um": lognormal_mean * math.sqrt(math.expm1(self.lognormal_sigma**2)),
            },
            "mixture": (
                {}
                if mixture is None
                else {
                    "weight_1": mixture.weight,
                    "mean_1_um": mixture.mean_1,
                    "sd_1_um": mixture.sd_1,
                    "mean_2_um": mixture.mean_2,
                    "sd_2_um": mixture.sd_2,
                }
            ),
        }
        for family in DIAMETER_FAMILIES:
            out[family] |= {
                "log_likelihood": self.log_likelihood[family],
                "aic": self.aic[family],
                "bic": self.bic[family],
            }
        return out


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
    diameter : DiameterFits
        Normal, lognormal and mixture fits of the diameters (the normal's are
        ``diameter_mean_um`` and ``diameter_sd_um``).
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
    diameter: DiameterFits

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


def fit_distributions(
    diameter_um: np.ndarray, orientation_deg: np.ndarray, tortuosity: np.ndarray
) -> FittedDistributions:
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
    diameter = fit_diameter_families(diameter_um)
    model, mu, kappa, aic_u, aic_vm = _fit_orientation(np.radians(_finite(orientation_deg)))
    t = _finite(tortuosity)
    scale = float(np.sqrt(np.mean((t - 1.0) ** 2))) if len(t) else math.nan
    return FittedDistributions(
        diameter_mean_um=diameter.normal_mean_um,
        diameter_sd_um=diameter.normal_sd_um,
        orientation_model=model,
        orientation_mean_deg=mu,
        orientation_kappa=kappa,
        orientation_aic_uniform=aic_u,
        orientation_aic_von_mises=aic_vm,
        tortuosity_loc=1.0,
        tortuosity_scale=scale,
        diameter=diameter,
    )


def fit_diameter_families(diameter_um: np.ndarray) -> DiameterFits:
    """Fit a normal, a lognormal and a two-normal mixture to diameters (maximum likelihood)
    and choose by BIC (module notes).

    Parameters
    ----------
    diameter_um : (n,) float [um]
        Diameters; NaN are left out.

    Returns
    -------
    DiameterFits
    """
    d = _finite(diameter_um)
    d = d[d > 0]
    n = len(d)
    nan_fits = {family: math.nan for family in DIAMETER_FAMILIES}
    if n < 2 or np.ptp(d) == 0:
        mean = float(np.mean(d)) if n else math.nan
        return DiameterFits(
            n,
            mean,
            0.0 if n else math.nan,
            float(np.median(d)) if n else math.nan,
            mean,
            0.0 if n else math.nan,
            math.log(mean) if n else math.nan,
            0.0 if n else math.nan,
            None,
            nan_fits,
            nan_fits,
            nan_fits,
            "",
        )
    mean, sd = float(np.mean(d)), float(np.std(d))
    log_d = np.log(d)
    mu, sigma = float(np.mean(log_d)), float(np.std(log_d))
    mixture = fit_normal_mixture(d) if n >= _MIN_MIXTURE else None
    log_l = {
        "normal": float(np.sum(stats.norm.logpdf(d, mean, sd))),
        "lognormal": float(np.sum(stats.norm.logpdf(log_d, mu, sigma)) - np.sum(log_d)),
        "mixture": math.nan if mixture is None else mixture.log_likelihood,
    }
    k = {"normal": 2, "lognormal": 2, "mixture": 5}
    aic = {f: 2.0 * k[f] - 2.0 * log_l[f] for f in DIAMETER_FAMILIES}
    bic = {f: k[f] * math.log(n) - 2.0 * log_l[f] for f in DIAMETER_FAMILIES}
    eligible = [
        f
        for f in DIAMETER_FAMILIES
        if math.isfinite(bic[f])
        and (f != "mixture" or (mixture is not None and mixture.smaller_share(n) >= MIN_COMPONENT))
    ]
    chosen = min(eligible, key=bic.__getitem__)
    return DiameterFits(n, mean, sd, float(np.median(d)), mean, sd, mu, sigma, mixture, log_l, aic, bic, chosen)


def fit_normal_mixture(x: np.ndarray) -> NormalMixture:
    """Two-normal mixture fitted to a sample by expectation-maximization.

    Deterministic: it starts from the sample split at its median (each half's mean and sd,
    weights 1/2) and iterates until the mean log-likelihood per sample changes by less than
    1e-9 (at most 500 iterations). A component's sd is kept at least 0.05 times the sample's.

    Parameters
    ----------
    x : (n,) float
        Finite samples, n >= 2, not all equal.

    Returns
    -------
    NormalMixture
        Components ordered by mean.
    """
    x = np.sort(np.asarray(x, dtype=float))
    floor = _SD_FLOOR * float(np.std(x))
    low, high = x[: len(x) // 2], x[len(x) // 2 :]
    weight = np.array([0.5, 0.5])
    mean = np.array([low.mean(), high.mean()])
    sd = np.maximum([low.std(), high.std()], floor)
    previous = -math.inf
    for _ in range(_EM_ITERATIONS):
        log_p = np.log(weight) + stats.norm.logpdf(x[:, None], mean, sd)
        total = special.logsumexp(log_p, axis=1)
        log_l = float(total.sum())
        responsibility = np.exp(log_p - total[:, None])
        share = np.maximum(responsibility.sum(axis=0), 1e-12)
        weight = share / len(x)
        mean = (responsibility * x[:, None]).sum(axis=0) / share
        sd = np.maximum(np.sqrt((responsibility * (x[:, None] - mean) ** 2).sum(axis=0) / share), floor)
        if log_l - previous < _EM_TOLERANCE * len(x):
            break
        previous = log_l
    log_l = float(special.logsumexp(np.log(weight) + stats.norm.logpdf(x[:, None], mean, sd), axis=1).sum())
    order = np.argsort(mean)
    weight, mean, sd = weight[order], mean[order], sd[order]
    return NormalMixture(float(weight[0]), float(mean[0]), float(sd[0]), float(mean[1]), float(sd[1]), log_l)


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
