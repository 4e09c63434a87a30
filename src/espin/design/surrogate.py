"""Gaussian-process surrogates of the properties over the design space.

One scikit-learn ``GaussianProcessRegressor`` per (property, direction), on the unit cube,
fitted to the logarithm of the property (properties are positive and vary by factors; a
property that is not positive everywhere is modelled as it is). The kernel is a constant
times an anisotropic Matern 5/2 (one length scale per variable, so a variable the property
does not respond to gets a long one) plus a white-noise term: the realization scatter left
after common random numbers, estimated with the other hyperparameters by maximum likelihood.
Hyperparameter restarts draw from a fixed seed, so the same evaluations give the same
surrogate.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["PropertySurrogate", "fit_surrogate"]

NOISE_BOUNDS = (1e-8, 1e-1)
"""Bounds of the white-noise variance, in units of the normalized (unit-variance) output."""
RESTARTS = 3
"""Restarts of the likelihood optimization (from length scales drawn with a fixed seed)."""


@dataclass
class PropertySurrogate:
    """A fitted surrogate of one property.

    Attributes
    ----------
    model : sklearn.gaussian_process.GaussianProcessRegressor
    log : bool
        Fitted to log(property).
    noise_sd : float
        Standard deviation of the fitted white noise, in the modelled scale (log: relative).
    """

    model: Any  # a fitted GaussianProcessRegressor (scikit-learn is untyped)
    log: bool
    noise_sd: float

    def predict(self, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and sd of the latent (noise-free) property in the modelled scale (log if
        :attr:`log`) at the rows of ``unit`` (n, d)."""
        mean, sd = self.model.predict(np.atleast_2d(unit), return_std=True)
        # return_std includes the white noise; the latent function's variance excludes it
        latent = np.sqrt(np.maximum(sd**2 - self.noise_sd**2, 0.0))
        return mean, latent

    def median(self, unit: np.ndarray) -> np.ndarray:
        """The property (back from the log scale) at the rows of ``unit``."""
        mean, _ = self.predict(unit)
        return np.exp(mean) if self.log else mean

    def to_property(self, modelled: np.ndarray) -> np.ndarray:
        """Values in the modelled scale back to the property's unit."""
        return np.exp(modelled) if self.log else modelled


def fit_surrogate(unit: np.ndarray, values: np.ndarray, *, seed: int = 0) -> PropertySurrogate:
    """Fit a surrogate to property ``values`` observed at unit-cube points ``unit`` (n, d).

    Parameters
    ----------
    unit
        Evaluated points, (n, d), in [0, 1].
    values
        The property at each point (finite).
    seed
        Seed of the hyperparameter restarts.
    """
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    unit = np.atleast_2d(np.asarray(unit, dtype=float))
    values = np.asarray(values, dtype=float)
    log = bool(np.all(values > 0.0))
    y = np.log(values) if log else values
    d = unit.shape[1]
    kernel = ConstantKernel(1.0, (1e-3, 1e3)) * Matern(np.full(d, 0.5), (1e-2, 1e2), nu=2.5) + WhiteKernel(
        1e-4, NOISE_BOUNDS
    )
    model = GaussianProcessRegressor(
        kernel, normalize_y=True, n_restarts_optimizer=RESTARTS, random_state=np.random.RandomState(seed)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)  # a bound reached is a fit, not a failure
        model.fit(unit, y)
    scale = float(model._y_train_std) if np.ndim(model._y_train_std) == 0 else float(np.ravel(model._y_train_std)[0])
    noise_sd = float(np.sqrt(model.kernel_.k2.noise_level)) * scale
    return PropertySurrogate(model, log, noise_sd)
