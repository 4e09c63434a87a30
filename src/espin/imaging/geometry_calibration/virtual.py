"""The virtual SEM: generate mats with fixed seeds and measure them in the observation window.

Two ways of measuring, chosen by what the target sample records:

* **Whole window portions** (targets without piece lengths, e.g. typed in): every maximal
  fiber portion inside the window, edge to edge (:func:`espin.geometry.statistics.window_tortuosity`),
  as a person measuring fibers across a whole image would.
* **Length-matched pieces** (targets with the contour lengths of their pieces, as
  ``espin measure`` writes): the SEM tracer cuts fibers where they cross others or are hidden,
  so its pieces are much shorter than the window portions, and tortuosity grows with the
  length over which it is measured. The virtual mat is therefore measured on pieces of the
  *same contour lengths*: for each length l drawn (with replacement) from the measured ones, a
  start point uniform over all arc positions of the window portions from which a piece of
  length l fits (a portion of contour L offers L - l of them), the piece's end point
  interpolated l further along the polyline; its chord gives tortuosity l / chord and the
  orientation. Cuts at crossings fall along a fiber's arc independently of its shape, so the
  piece's contour length (not its chord, which depends on the tortuosity being measured) is
  the length to match. Pieces with a chord below ``min_chord_um`` are dropped, as the tracer
  drops them. The draws use a fixed random generator per mat seed (common random numbers),
  so the objective stays deterministic.

Units: um, degrees at the edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from espin.core.config import RVEConfig, config_from_dict

__all__ = ["VirtualMeasurement", "WindowRuns", "window_runs", "sample_pieces"]

MAX_PIECES_PER_MAT = 5000
"""Most length-matched pieces drawn from one mat."""
SAMPLING_SEED = 20240
"""Seed of the piece draws (combined with each mat's seed)."""


@dataclass(frozen=True, eq=False)
class VirtualMeasurement:
    """How generated mats are measured: window, seeds and layers (common random numbers).

    Attributes
    ----------
    window_um : float [um]
        Side of the square observation window, centred in the layer.
    min_chord_um : float [um]
        Portions (or pieces) with a shorter chord are dropped (as by the SEM tracer).
    seeds : tuple of int
        ``rve.seed`` of each generated mat; the same for every evaluation.
    layers : int
        Layers per mat; all layers are measured through the window and pooled.
    piece_lengths_um : (m,) float64 [um], optional
        Measured contour lengths: when given, the mats are measured on pieces of these
        lengths (length-matched sampling, module doc); else on whole window portions.
    """

    window_um: float
    min_chord_um: float
    seeds: tuple[int, ...]
    layers: int
    piece_lengths_um: np.ndarray | None = None

    @property
    def sampling(self) -> str:
        """``"length-matched"`` or ``"whole portions"``."""
        return "whole portions" if self.piece_lengths_um is None else "length-matched"

    def with_layers(self, layers: int) -> VirtualMeasurement:
        """The same measurement with ``layers`` per mat."""
        return VirtualMeasurement(self.window_um, self.min_chord_um, self.seeds, layers,
                                  self.piece_lengths_um)

    def measure(self, rve: dict[str, Any], side_um: float) -> dict[str, np.ndarray]:
        """Visible fiber portions (or pieces) of mats with deposition ``rve`` in layers of ``side_um``.

        Returns
        -------
        dict
            ``tortuosity`` (n,), ``orientation_deg`` (n,) [deg] of the chords and
            ``diameter_um`` (n,) [um] of the fibers they belong to, pooled over the seeds.
        """
        from espin.geometry.deposition import deposit
        from espin.geometry.statistics import centred_window, window_tortuosity

        parts: dict[str, list[np.ndarray]] = {"tortuosity": [], "orientation_deg": [], "diameter_um": []}
        for seed in self.seeds:
            cfg = _validated_rve(rve | {"size_um": side_um, "layers": self.layers, "seed": seed})
            mat = deposit(cfg)
            origin, side = centred_window(mat.size, self.window_um)
            if self.piece_lengths_um is None:
                seen = window_tortuosity(mat.vertices, mat.fiber_offsets, origin, side,
                                         self.min_chord_um)
                tortuosity, orientation, fiber = seen.tortuosity, seen.orientation, seen.fiber
            else:
                runs = window_runs(mat.vertices, mat.fiber_offsets, origin, side)
                rng = np.random.default_rng([SAMPLING_SEED, seed])
                tortuosity, orientation, fiber = sample_pieces(
                    runs, self.piece_lengths_um, self.min_chord_um, rng)
            parts["tortuosity"].append(tortuosity)
            parts["orientation_deg"].append(np.degrees(orientation))
            parts["diameter_um"].append(mat.fiber_diameter[fiber])
        return {k: np.concatenate(v) for k, v in parts.items()}


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


def window_runs(vertices: np.ndarray, fiber_offsets: np.ndarray, origin: np.ndarray,
                side: float) -> WindowRuns:
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
    return WindowRuns(points=points, arc=np.cumsum(step), first=first.astype(np.int64),
                      last=np.asarray(last, dtype=np.int64),
                      fiber=pieces.fiber[run_start])


def sample_pieces(runs: WindowRuns, lengths_um: np.ndarray, min_chord_um: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tortuosity, chord axis [rad] and fiber of pieces of the window portions with the
    contour lengths of a measured sample (module doc).

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
        r = int(rng.choice(len(span), p=room / room.sum()))
        g[i] = run_start[r] + rng.uniform(0.0, room[r])
        run_of[i] = r
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


def _validated_rve(data: dict[str, Any]) -> RVEConfig:
    """An RVEConfig from plain data, with the sizes given one way only."""
    data = dict(data)
    for chosen, other in (("size_um", "size_ratio"), ("size_ratio", "size_um"),
                          ("segment_ratio", "segment_um"), ("segment_um", "segment_ratio")):
        if chosen in data and other in data:
            data.pop(other)
    return config_from_dict({"rve": data}, "(geometry calibration)").rve


def _layers_per_seed(measurement: VirtualMeasurement, rve: dict[str, Any], side_um: float,
                     min_portions: int) -> int:
    """Layers per mat so that all seeds together show at least ``min_portions`` whole portions."""
    probe = VirtualMeasurement(measurement.window_um, measurement.min_chord_um,
                               measurement.seeds[:1], 2)
    per_layer = max(len(probe.measure(rve, side_um)["tortuosity"]) / 2.0, 1.0)
    return int(np.clip(math.ceil(min_portions / (len(measurement.seeds) * per_layer)), 1, 500))
