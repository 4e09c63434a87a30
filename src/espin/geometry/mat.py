"""The deposited mat: fibers as polylines, layer by layer (output of the virtual deposition)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["FiberMat"]


@dataclass(frozen=True, eq=False)
class FiberMat:
    """Fibers of a virtual mat as polylines, stored flat (CSR style).

    Fiber ``f`` has the vertices ``vertices[fiber_offsets[f]:fiber_offsets[f + 1]]``, from its
    start point on the border of the square [0, size]^2 to its end point on the border.
    Consecutive vertices of a fiber bound one of its segments.

    Attributes
    ----------
    vertices : (n_vertices, 2) float64 [um]
        Vertex positions in the layer plane, inside [0, size]^2.
    fiber_offsets : (n_fibers + 1,) int64
        Start of each fiber in ``vertices``; ``fiber_offsets[-1] == n_vertices``.
    fiber_layer : (n_fibers,) int64
        Layer index k of each fiber, 0 <= k < n_layers; layer k sits at height (k + 1/2) D.
    fiber_diameter : (n_fibers,) float64 [um]
        Diameter D_f of each fiber.
    size : float [um]
        Side L of the square layer.
    thickness : float [um]
        Layer thickness, the mean fiber diameter D.
    n_layers : int
        Number of layers N_l.
    """

    vertices: np.ndarray
    fiber_offsets: np.ndarray
    fiber_layer: np.ndarray
    fiber_diameter: np.ndarray
    size: float
    thickness: float
    n_layers: int

    @property
    def n_fibers(self) -> int:
        """Number of fibers."""
        return len(self.fiber_offsets) - 1

    @property
    def n_segments(self) -> int:
        """Number of segments (vertices minus one per fiber)."""
        return len(self.vertices) - self.n_fibers

    @cached_property
    def segment_start(self) -> np.ndarray:
        """(n_segments,) int64: vertex index of each segment's first end (the next is +1)."""
        is_last = np.zeros(len(self.vertices), dtype=bool)
        is_last[self.fiber_offsets[1:] - 1] = True
        return np.flatnonzero(~is_last)

    @cached_property
    def segment_fiber(self) -> np.ndarray:
        """(n_segments,) int64: fiber of each segment."""
        counts = np.diff(self.fiber_offsets) - 1
        return np.repeat(np.arange(self.n_fibers), counts)

    @cached_property
    def segment_length(self) -> np.ndarray:
        """(n_segments,) float64 [um]: length of each segment."""
        s = self.segment_start
        return np.hypot(*(self.vertices[s + 1] - self.vertices[s]).T)

    @cached_property
    def segment_arc_start(self) -> np.ndarray:
        """(n_segments,) float64 [um]: arc length along its fiber at each segment's start."""
        cum = np.cumsum(self.segment_length)
        first = self.fiber_offsets[:-1] - np.arange(self.n_fibers)  # first segment per fiber
        before = np.concatenate([[0.0], cum])[first]
        return np.concatenate([[0.0], cum[:-1]]) - np.repeat(before, np.diff(self.fiber_offsets) - 1)

    @cached_property
    def contour_length(self) -> np.ndarray:
        """(n_fibers,) float64 [um]: contour length of each fiber."""
        return np.bincount(self.segment_fiber, self.segment_length, minlength=self.n_fibers)

    @property
    def end_to_end(self) -> np.ndarray:
        """(n_fibers, 2) float64 [um]: last vertex minus first vertex of each fiber."""
        return self.vertices[self.fiber_offsets[1:] - 1] - self.vertices[self.fiber_offsets[:-1]]

    @property
    def tortuosity(self) -> np.ndarray:
        """(n_fibers,) float64: contour over end-to-end length of each fiber (>= 1)."""
        chord = np.hypot(*self.end_to_end.T)
        return self.contour_length / np.maximum(chord, np.finfo(float).tiny)

    @property
    def orientation(self) -> np.ndarray:
        """(n_fibers,) float64 [rad]: axis of each fiber's end-to-end line, in [0, pi)."""
        dx, dy = self.end_to_end.T
        return np.mod(np.arctan2(dy, dx), np.pi)

    def layer_volume_fraction(self) -> np.ndarray:
        """(n_layers,) float64: sum(pi D_f^2 / 4 * contour) / (L^2 D) per layer."""
        volume = np.pi * self.fiber_diameter**2 / 4.0 * self.contour_length
        per_layer = np.bincount(self.fiber_layer, volume, minlength=self.n_layers)
        return per_layer / (self.size**2 * self.thickness)
