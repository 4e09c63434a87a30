"""Fiber portions seen through a square window, as polylines, and pieces of given contour
lengths cut from them: how a virtual mat is measured like traced SEM fibers
(:mod:`espin.imaging.geometry_calibration.virtual` explains the length-matched sampling).

Units: um; radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "MAX_PIECES_PER_MAT",
    "WindowRuns",
    "window_runs",
    "sample_pieces",
    "border_edges",
    "CrossingStatistics",
    "crossing_statistics",
    "window_crossings",
]

MAX_PIECES_PER_MAT = 5000
"""Most length-matched pieces drawn from one mat."""


@dataclass(frozen=True, eq=False)
class WindowRuns:
    """Fiber portions inside a window as polylines, laid end to end on one arc-length axis.

    Attributes
    ----------
    points : (m, 2) float64 [um]
        Polyline points, portion after portion.
    arc : (m,) float64 [um]
        Arc length of each point on the common axis (portion r spans
        ``[arc[first[r]], arc[last[r]]]``).
    first, last : (n,) int64
        Index of the first and last point of each portion.
    fiber : (n,) int64
        Fiber of each portion.
    """

    points: np.ndarray
    arc: np.ndarray
    first: np.ndarray
    last: np.ndarray
    fiber: np.ndarray

    @property
    def start(self) -> np.ndarray:
        """Arc position [um] where each portion starts."""
        return self.arc[self.first]

    @property
    def end(self) -> np.ndarray:
        """Arc position [um] where each portion ends."""
        return self.arc[self.last]


def window_runs(vertices: np.ndarray, fiber_offsets: np.ndarray, origin: np.ndarray, side: float) -> WindowRuns:
    """Polylines of the maximal fiber portions inside the closed square window.

    The portions are those of :func:`espin.geometry.statistics.window_tortuosity` (same clipping and
    same rule for consecutive pieces), before any chord filter.
    """
    from espin.geometry.statistics import clip_to_window  # the clipping window_tortuosity uses

    pieces = clip_to_window(vertices, fiber_offsets, origin, side)
    run_start, run = pieces.run_start, pieces.run
    n_runs = int(run_start.sum())
    n_pieces = len(run)
    # Points: the start of each run, then the end of each of its pieces.
    n_points = n_runs + n_pieces
    points = np.empty((n_points, 2))
    step = np.zeros(n_points)
    end_pos = np.arange(n_pieces) + run + 1
    first = np.flatnonzero(run_start) + np.arange(n_runs)
    points[first] = pieces.start[run_start]
    points[end_pos] = pieces.end
    step[end_pos] = pieces.length
    last = np.r_[first[1:] - 1, n_points - 1] if n_runs else first
    return WindowRuns(
        points=points,
        arc=np.cumsum(step),
        first=first.astype(np.int64),
        last=np.asarray(last, dtype=np.int64),
        fiber=pieces.fiber[run_start],
    )


def sample_pieces(
    runs: WindowRuns, lengths_um: np.ndarray, min_chord_um: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tortuosity, chord axis [rad] and fiber of pieces of the window portions with the
    contour lengths of a measured sample (:mod:`espin.imaging.geometry_calibration.virtual`).

    As many pieces are drawn as pieces of the measured mean length would tile the portions
    (at most :data:`MAX_PIECES_PER_MAT`). A length longer than every portion cannot be placed
    and is left out.
    """
    empty = np.empty(0), np.empty(0), np.empty(0, dtype=np.int64)
    lengths_um = np.asarray(lengths_um, dtype=float)
    run_start, run_end = runs.start, runs.end
    total = float(np.sum(run_end - run_start))
    if len(runs.first) == 0 or total <= 0.0:
        return empty
    n = int(np.clip(round(total / float(np.mean(lengths_um))), 1, MAX_PIECES_PER_MAT))
    ell = lengths_um[rng.integers(0, len(lengths_um), n)]
    span = run_end - run_start
    # Start uniform over the admissible arc positions: a uniform arc position, kept when the
    # piece ends inside the same portion (rejection, vectorized), then the rest exactly.
    g = np.full(n, np.nan)
    run_of = np.zeros(n, dtype=np.int64)
    todo = np.flatnonzero(ell <= span.max())
    for _ in range(20):
        if not len(todo):
            break
        trial = rng.uniform(0.0, 1.0, len(todo)) * total
        # Position on the axis of the portions laid end to end without gaps.
        cum = np.concatenate([[0.0], np.cumsum(span)])
        r = np.clip(np.searchsorted(cum, trial, side="right") - 1, 0, len(span) - 1)
        u = trial - cum[r]
        ok = u + ell[todo] <= span[r]
        g[todo[ok]] = run_start[r[ok]] + u[ok]
        run_of[todo[ok]] = r[ok]
        todo = todo[~ok]
    for i in todo:  # long pieces that fit only few portions
        room = np.clip(span - ell[i], 0.0, None)
        if room.sum() <= 0.0:
            continue
        chosen = int(rng.choice(len(span), p=room / room.sum()))
        g[i] = run_start[chosen] + rng.uniform(0.0, room[chosen])
        run_of[i] = chosen
    placed = np.isfinite(g)
    g, ell, run_of = g[placed], ell[placed], run_of[placed]
    a = _point_at(runs, run_of, g)
    b = _point_at(runs, run_of, g + ell)
    chord_vec = b - a
    chord = np.hypot(*chord_vec.T)
    keep = (chord > 0.0) & (chord >= min_chord_um)
    chord_vec, chord, ell, run_of = chord_vec[keep], chord[keep], ell[keep], run_of[keep]
    tortuosity = np.maximum(ell / chord, 1.0)
    orientation = np.mod(np.arctan2(chord_vec[:, 1], chord_vec[:, 0]), np.pi)
    return tortuosity, orientation, runs.fiber[run_of]


def _point_at(runs: WindowRuns, run: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Points at arc positions ``g`` of portions ``run`` (linear along each polyline piece)."""
    k = np.searchsorted(runs.arc, g, side="right") - 1
    k = np.clip(k, runs.first[run], np.maximum(runs.last[run] - 1, runs.first[run]))
    k1 = np.minimum(k + 1, runs.last[run])
    da = runs.arc[k1] - runs.arc[k]
    t = np.clip(np.where(da > 0.0, (g - runs.arc[k]) / np.where(da > 0.0, da, 1.0), 0.0), 0.0, 1.0)
    return runs.points[k] + t[:, None] * (runs.points[k1] - runs.points[k])


def border_edges(points: np.ndarray, lower: np.ndarray, upper: np.ndarray, tol: float) -> np.ndarray:
    """Edge of the rectangle [lower, upper] that each point lies on: 0 bottom (y = lower y),
    1 right, 2 top, 3 left, the nearest one; -1 for a point farther than ``tol`` from every
    edge (an end inside the window).

    Parameters
    ----------
    points : (n, 2) float64
        Points (x, y), in the units of ``lower``, ``upper`` and ``tol``.
    lower, upper : (2,) float64
        Corners of the rectangle.
    tol : float
        Largest distance from an edge of a point on it.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    distance = np.c_[p[:, 1] - lower[1], upper[0] - p[:, 0], upper[1] - p[:, 1], p[:, 0] - lower[0]]
    edge = np.argmin(np.abs(distance), axis=1)
    return np.where(np.abs(distance[np.arange(len(p)), edge]) <= tol, edge, -1)


@dataclass(frozen=True)
class CrossingStatistics:
    """Long-range shape of the fiber portions that cross a window from edge to edge.

    Attributes
    ----------
    n_crossing : int
        Portions whose two ends lie on the window's edges.
    u_turn_fraction : float
        Of those, the fraction that leave through the edge they entered (NaN if none).
    straightness : float
        Their mean end-to-end distance over contour length (NaN if none); 1 for straight
        fibers.
    """

    n_crossing: int
    u_turn_fraction: float
    straightness: float


def crossing_statistics(
    first: np.ndarray, last: np.ndarray, contour: np.ndarray, lower: np.ndarray, upper: np.ndarray, tol: float
) -> CrossingStatistics:
    """U-turn fraction and straightness of the portions that cross the window edge to edge.

    Parameters
    ----------
    first, last : (n, 2) float64
        End points of the portions.
    contour : (n,) float64
        Their contour lengths.
    lower, upper : (2,) float64
        Corners of the window.
    tol : float
        Largest distance from an edge of an end on it.
    """
    a = border_edges(first, lower, upper, tol)
    b = border_edges(last, lower, upper, tol)
    crossing = (a >= 0) & (b >= 0) & (np.asarray(contour) > 0.0)
    n = int(crossing.sum())
    if n == 0:
        return CrossingStatistics(0, float("nan"), float("nan"))
    chord = np.hypot(*(np.asarray(last) - np.asarray(first))[crossing].T)
    return CrossingStatistics(
        n, float(np.mean(a[crossing] == b[crossing])), float(np.mean(chord / np.asarray(contour)[crossing]))
    )


def window_crossings(
    runs: WindowRuns, origin: np.ndarray, side: float, min_chord_um: float = 0.0
) -> CrossingStatistics:
    """:func:`crossing_statistics` of the whole window portions ``runs`` of the window
    [origin, origin + side]^2; portions with a chord below ``min_chord_um`` (corner stubs)
    are left out, as from every other window statistic."""
    first, last = runs.points[runs.first], runs.points[runs.last]
    keep = np.hypot(*(last - first).T) >= min_chord_um
    origin = np.asarray(origin, dtype=float)
    return crossing_statistics(
        first[keep], last[keep], (runs.end - runs.start)[keep], origin, origin + side, 1e-9 * max(side, 1.0)
    )
