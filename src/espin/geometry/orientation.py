"""Fiber orientation distributions over axes theta in [0, pi) (docs/model.md section 1).

Each distribution draws samples, and gives its density and cumulative distribution, so the
same object serves the deposition and the statistical comparison with a mat.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from espin.core.config import Histogram, Orientation, VonMises

__all__ = [
    "OrientationDistribution",
    "UniformOrientation",
    "VonMisesOrientation",
    "HistogramOrientation",
    "orientation_distribution",
]


class OrientationDistribution:
    """A probability distribution of fiber axes theta in [0, pi) [rad]."""

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Draw ``n`` axes [rad] in [0, pi)."""
        raise NotImplementedError

    def pdf(self, theta: np.ndarray) -> np.ndarray:
        """Density [1/rad] at axes ``theta`` [rad] (period pi)."""
        raise NotImplementedError

    def cdf(self, theta: np.ndarray) -> np.ndarray:
        """Cumulative probability at ``theta`` in [0, pi] [rad]."""
        raise NotImplementedError

    @property
    def label(self) -> str:
        """Short description for plots and reports."""
        raise NotImplementedError


@dataclass(frozen=True)
class UniformOrientation(OrientationDistribution):
    """Isotropic mat: p(theta) = 1 / pi."""

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.uniform(0.0, np.pi, n)

    def pdf(self, theta: np.ndarray) -> np.ndarray:
        return np.full(np.shape(theta), 1.0 / np.pi)

    def cdf(self, theta: np.ndarray) -> np.ndarray:
        return np.clip(np.asarray(theta, dtype=float) / np.pi, 0.0, 1.0)

    @property
    def label(self) -> str:
        return "uniform"


@dataclass(frozen=True)
class VonMisesOrientation(OrientationDistribution):
    """Aligned mat: p(theta) proportional to exp(kappa cos 2(theta - mean)).

    Attributes
    ----------
    mean : float [rad]
        Preferred axis, in [0, pi).
    kappa : float
        Concentration (0 is uniform).
    """

    mean: float
    kappa: float

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        # phi = 2 theta is a circular von Mises variable with mean 2 mu.
        return np.mod(rng.vonmises(2.0 * self.mean, self.kappa, n) / 2.0, np.pi)

    def pdf(self, theta: np.ndarray) -> np.ndarray:
        return 2.0 * stats.vonmises.pdf(2.0 * (np.asarray(theta) - self.mean), self.kappa)

    def cdf(self, theta: np.ndarray) -> np.ndarray:
        theta = np.clip(np.asarray(theta, dtype=float), 0.0, np.pi)
        # P(0 <= Theta <= theta) with phi = 2 (Theta - mean) wrapped to [-pi, pi).
        lo = -2.0 * self.mean
        hi = 2.0 * (theta - self.mean)
        dist = stats.vonmises(self.kappa)

        def wrapped(a: np.ndarray | float) -> np.ndarray:
            # Cumulative mass of the circular variable from -pi up to a (any real a).
            turns = np.floor((a + np.pi) / (2.0 * np.pi))
            return turns + dist.cdf(a - 2.0 * np.pi * turns)

        return wrapped(hi) - wrapped(lo)

    @property
    def label(self) -> str:
        return f"von Mises (mean {np.degrees(self.mean):.1f} deg, kappa {self.kappa:g})"


@dataclass(frozen=True)
class HistogramOrientation(OrientationDistribution):
    """User histogram: bin masses ``weights`` (normalized) over ``edges`` [rad] in [0, pi]."""

    edges: tuple[float, ...]
    weights: tuple[float, ...]

    @property
    def _mass(self) -> np.ndarray:
        w = np.asarray(self.weights, dtype=float)
        return w / w.sum()

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        edges = np.asarray(self.edges)
        bins = rng.choice(len(self.weights), size=n, p=self._mass)
        return rng.uniform(edges[bins], edges[bins + 1])

    def pdf(self, theta: np.ndarray) -> np.ndarray:
        edges = np.asarray(self.edges)
        density = self._mass / np.diff(edges)
        theta = np.mod(np.asarray(theta, dtype=float), np.pi)
        i = np.searchsorted(edges, theta, side="right") - 1
        inside = (i >= 0) & (i < len(density))
        return np.where(inside, density[np.clip(i, 0, len(density) - 1)], 0.0)

    def cdf(self, theta: np.ndarray) -> np.ndarray:
        edges = np.asarray(self.edges)
        cum = np.concatenate([[0.0], np.cumsum(self._mass)])
        return np.interp(np.asarray(theta, dtype=float), edges, cum)

    @property
    def label(self) -> str:
        return f"histogram ({len(self.weights)} bins)"


def orientation_distribution(spec: Orientation) -> OrientationDistribution:
    """The distribution described by ``rve.orientation`` of a config (degrees -> radians)."""
    if isinstance(spec, VonMises):
        return VonMisesOrientation(np.radians(spec.von_mises.mean_deg), spec.von_mises.kappa)
    if isinstance(spec, Histogram):
        h = spec.histogram
        return HistogramOrientation(tuple(np.radians(h.edges_deg)), tuple(h.weights))
    return UniformOrientation()
