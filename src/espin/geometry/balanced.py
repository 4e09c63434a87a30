"""Balanced sampling of a mat's fibers (``rve.sampling = "balanced"``; docs/geometry.md).

Random sampling (the paper) draws every fiber's axis, start and diameter independently, so one
RVE of the paper's size carries a few percent of orientation noise: its modulus follows its
own length-weighted <cos^4> and its yield stress its <cos^2>, which scatter from seed to seed.
Balanced sampling keeps the law of every fiber (its axis, start, diameter and shape) and
removes most of that noise
(:func:`espin.geometry.deposition.deposit` uses this module):

1. **Low-discrepancy draws.** The fibers of the whole RVE take consecutive points of one
   scrambled Sobol' sequence (Owen scrambling, seeded by the RVE seed) in the unit cube of
   (axis quantile, start quantile, diameter quantile). Each point is uniform on the cube, so
   each fiber has exactly the law of a randomly drawn one; and every prefix of the sequence
   fills the cube evenly, so whatever the fiber count the sample's axes, starts and diameters
   follow their distributions far more closely than independent draws do. The layers are
   filled together (each fiber to a random open layer), so that fibers of one layer are not
   neighbours in the sequence. With ``border`` seeding the start coordinate chooses the third
   of the fiber's straight chord's law given its axis (the chord drawn at random within it),
   and the start is drawn among the border points of that chord
   (:func:`espin.geometry.deposition.deposit`): the chord lengths, which weight the
   orientation content, are balanced to their thirds, while the start points are not spread
   evenly along the border (an even spread made near-coincident starts 12 times rarer than
   independent draws do and merged cross-links 9-10 % fewer; the chord's exact quantile still
   2-5 % fewer; issue 35).
2. **Walk or mirror image, chosen by herding.** The directions of a fiber's walk are drawn
   once and the fiber is laid twice: as drawn, and as its mirror image about its first axis
   (the paper walk's turns all negated, the smooth walk's deviation negated), which has the
   same law. Of the two, the one is kept that brings the RVE's running sum R of (content -
   mean of the two) nearest zero, the content c = sum over segments of A l (1, cos 2 phi,
   sin 2 phi, cos 4 phi, sin 4 phi): that sum stays bounded instead of growing as sqrt(N), so
   the walks' drift, which balanced axes cannot reach, cancels to first order.
   **Each fiber keeps exactly the walk's law**: the two deviations are d and -d, so the walk
   is kept when R . d < 0 (as drawn on a tie); R comes from the fibers before, independent of
   this one, and its law is symmetric (the rule is odd), so either variant is kept with
   probability 1/2 whatever its shape, and a fair choice between a walk and its mirror image
   has the walk's law. More variants (turns negated in some blocks) break this: the herding
   then prefers variants of extreme content, which have a shape of their own (16 variants made
   the tortuosity - 1 of 5 deg paper walks 20 % lower, of 15 deg ones 4 % higher).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import qmc

from espin.geometry.orientation import HistogramOrientation, OrientationDistribution

__all__ = ["BalancedSampler", "axis_quantiles", "orientation_content"]

# Sobol' dimensions: axis quantile, start (border arc length or line offset) quantile,
# diameter quantile.
_DIMENSIONS = 3
# Spawn key of the Sobol' scramble's stream: beyond the layers' keys (0 .. layers - 1), so
# that it does not depend on the layer count.
_SCRAMBLE_KEY = 1_000_000
_FIRST_BLOCK_LOG2 = 10
# Cells of the tabulated axis distribution over [0, pi].
_AXIS_CELLS = 4096


class BalancedSampler:
    """The Sobol' points and the herding state of one RVE's balanced deposition.

    Points and herding choices are offered for a batch of candidate fibers without being
    used (:meth:`points`, :meth:`herd`); :meth:`accept` then uses those of the first fibers
    kept, so the next batch continues the sequence where the kept fibers stopped.

    Parameters
    ----------
    seed
        The RVE seed (``rve.seed``).
    """

    def __init__(self, seed: int) -> None:
        stream = np.random.SeedSequence(seed, spawn_key=(_SCRAMBLE_KEY,))
        self._sobol = qmc.Sobol(_DIMENSIONS, scramble=True, seed=np.random.default_rng(stream))
        self._points = self._sobol.random_base2(_FIRST_BLOCK_LOG2)
        self._used = 0
        self._content = np.zeros(5)
        self._offered: np.ndarray | None = None

    def points(self, n: int) -> np.ndarray:
        """The next ``n`` points (n, 3) of the sequence in [0, 1)^3, not yet used."""
        while self._used + n > len(self._points):
            # Doubling keeps the drawn count a power of 2 (the sequence's balanced blocks).
            self._points = np.vstack([self._points, self._sobol.random(len(self._points))])
        return self._points[self._used : self._used + n]

    def herd(self, contents: np.ndarray) -> np.ndarray:
        """Choose, fiber after fiber, one variant of its walk.

        Parameters
        ----------
        contents : (n_variants, n, 5) float64 [um^3]
            Orientation contents (:func:`orientation_content`) of the candidate fibers'
            variants: the walk as drawn and its mirror image (two variants keep each
            fiber's law exactly, module docstring).

        Returns
        -------
        (n,) int64
            The variant each fiber keeps, given that all the fibers before it in the batch
            are kept: the one that brings the running sum of (content - mean of the
            fiber's variants) nearest to zero (ties: the lowest index).
        """
        deviation = contents - contents.mean(axis=0)
        running = self._content.copy()
        chosen = np.empty(contents.shape[1], dtype=np.int64)
        offered = np.empty(contents.shape[1:])
        for i in range(contents.shape[1]):
            candidates = running + deviation[:, i]
            chosen[i] = int(np.argmin(np.einsum("vk,vk->v", candidates, candidates)))
            running = candidates[chosen[i]]
            offered[i] = running
        self._offered = offered
        return chosen

    def accept(self, n_kept: int) -> None:
        """Use the points and herding choices of the first ``n_kept`` fibers offered."""
        self._used += n_kept
        if n_kept and self._offered is not None:
            self._content = self._offered[n_kept - 1].copy()
        self._offered = None


def orientation_content(vertices: np.ndarray, counts: np.ndarray, diameters: np.ndarray) -> np.ndarray:
    """Volume-weighted orientation content of each fiber [um^3].

    Parameters
    ----------
    vertices : (n_vertices, 2) float64 [um]
        Vertices of the fibers, fiber after fiber.
    counts : (n,) int64
        Vertices per fiber.
    diameters : (n,) float64 [um]
        Fiber diameters.

    Returns
    -------
    (n, 5) float64 [um^3]
        sum over the fiber's segments of A l (1, cos 2 phi, sin 2 phi, cos 4 phi, sin 4 phi),
        A the cross-section, l and phi the segment's length and angle.
    """
    ends = np.cumsum(counts)
    seg = np.diff(vertices, axis=0)
    inside = np.ones(len(seg), dtype=bool)
    inside[ends[:-1] - 1] = False  # the step from one fiber to the next is not a segment
    seg = seg[inside]
    fiber = np.repeat(np.arange(len(counts)), counts - 1)
    length = np.hypot(seg[:, 0], seg[:, 1])
    phi = np.arctan2(seg[:, 1], seg[:, 0])
    terms = np.c_[np.ones_like(phi), np.cos(2 * phi), np.sin(2 * phi), np.cos(4 * phi), np.sin(4 * phi)]
    content = np.zeros((len(counts), 5))
    np.add.at(content, fiber, (np.pi / 4.0 * diameters[fiber] ** 2 * length)[:, None] * terms)
    return content


def axis_quantiles(dist: OrientationDistribution, u: np.ndarray, width_weighted: bool) -> np.ndarray:
    """Axes [rad] in [0, pi) at cumulative probabilities ``u`` of the distribution ``dist``,
    or, with ``width_weighted``, of the density proportional to p(theta) (|cos| + |sin|)
    that the ``lines`` seeding draws (docs/model.md section 1).

    The distribution is tabulated on 4,096 cells of [0, pi] (and the histogram's edges): the
    cell masses are the density at the cell's middle times the weight's exact integral, the
    quantile is linear within a cell (exact for the uniform and histogram distributions of
    the border seeding).
    """
    cuts: list[ArrayLike] = [np.linspace(0.0, np.pi, _AXIS_CELLS + 1), [np.pi / 2.0]]
    if isinstance(dist, HistogramOrientation):
        cuts.append(np.clip(dist.edges, 0.0, np.pi))
    grid = np.unique(np.concatenate(cuts))
    if width_weighted:
        # Antiderivative of |cos| + |sin| over [0, pi]: W(0) = 0, W(pi / 2) = 2, W(pi) = 4.
        w = np.where(grid <= np.pi / 2.0, np.sin(grid) - np.cos(grid) + 1.0, 3.0 - np.sin(grid) - np.cos(grid))
        weight = np.diff(w)
    else:
        weight = np.diff(grid)
    mass = dist.pdf(0.5 * (grid[1:] + grid[:-1])) * weight
    mass = mass / mass.sum()
    cdf = np.concatenate([[0.0], np.cumsum(mass)])
    cdf[-1] = 1.0
    cell = np.clip(np.searchsorted(cdf, u, side="right") - 1, 0, len(mass) - 1)
    # A cell without mass is reached only at its cumulative level (or by rounding at 1):
    # take the next cell with mass, or the last one.
    positive = np.flatnonzero(mass > 0.0)
    cell = positive[np.minimum(np.searchsorted(positive, cell), len(positive) - 1)]
    fraction = np.clip((u - cdf[cell]) / mass[cell], 0.0, 1.0)
    return np.mod(grid[cell] + fraction * (grid[cell + 1] - grid[cell]), np.pi)
