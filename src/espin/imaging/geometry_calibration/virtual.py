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
from espin.geometry.pieces import sample_pieces, window_crossings, window_runs

__all__ = ["VirtualMeasurement"]

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
        return VirtualMeasurement(self.window_um, self.min_chord_um, self.seeds, layers, self.piece_lengths_um)

    def measure(self, rve: dict[str, Any], side_um: float) -> dict[str, np.ndarray]:
        """Visible fiber portions (or pieces) of mats with deposition ``rve`` in layers of ``side_um``.

        Returns
        -------
        dict
            ``tortuosity`` (n,), ``orientation_deg`` (n,) [deg] of the chords and
            ``diameter_um`` (n,) [um] of the fibers they belong to, pooled over the seeds;
            and ``crossing``, a (3,) array: the number of whole window portions (edge to
            edge, chord >= ``min_chord_um``), their U-turn fraction and straightness
            (:func:`espin.geometry.pieces.window_crossings`), pooled.
        """
        from espin.geometry.deposition import deposit
        from espin.geometry.statistics import centred_window, window_tortuosity

        parts: dict[str, list[np.ndarray]] = {"tortuosity": [], "orientation_deg": [], "diameter_um": []}
        crossings = []
        for seed in self.seeds:
            cfg = _validated_rve(rve | {"size_um": side_um, "layers": self.layers, "seed": seed})
            mat = deposit(cfg)
            origin, side = centred_window(mat.size, self.window_um)
            runs = window_runs(mat.vertices, mat.fiber_offsets, origin, side)
            crossings.append(window_crossings(runs, origin, side, self.min_chord_um))
            if self.piece_lengths_um is None:
                visible = window_tortuosity(mat.vertices, mat.fiber_offsets, origin, side, self.min_chord_um)
                tortuosity, orientation, fiber = visible.tortuosity, visible.orientation, visible.fiber
            else:
                rng = np.random.default_rng([SAMPLING_SEED, seed])
                tortuosity, orientation, fiber = sample_pieces(runs, self.piece_lengths_um, self.min_chord_um, rng)
            parts["tortuosity"].append(tortuosity)
            parts["orientation_deg"].append(np.degrees(orientation))
            parts["diameter_um"].append(mat.fiber_diameter[fiber])
        seen = {k: np.concatenate(v) for k, v in parts.items()}
        n = np.array([c.n_crossing for c in crossings], dtype=float)
        if n.sum() == 0:
            seen["crossing"] = np.array([0.0, np.nan, np.nan])
        else:
            pooled = [
                np.nansum(n * [getattr(c, key) for c in crossings]) / n.sum()
                for key in ("u_turn_fraction", "straightness")
            ]
            seen["crossing"] = np.array([n.sum(), *pooled])
        return seen


def _validated_rve(data: dict[str, Any]) -> RVEConfig:
    """An RVEConfig from plain data, with the sizes given one way only."""
    data = dict(data)
    for chosen, other in (
        ("size_um", "size_ratio"),
        ("size_ratio", "size_um"),
        ("segment_ratio", "segment_um"),
        ("segment_um", "segment_ratio"),
    ):
        if chosen in data and other in data:
            data.pop(other)
    return config_from_dict({"rve": data}, "(geometry calibration)").rve


def _layers_per_seed(measurement: VirtualMeasurement, rve: dict[str, Any], side_um: float, min_portions: int) -> int:
    """Layers per mat so that all seeds together show at least ``min_portions`` whole portions."""
    probe = VirtualMeasurement(measurement.window_um, measurement.min_chord_um, measurement.seeds[:1], 2)
    per_layer = max(len(probe.measure(rve, side_um)["tortuosity"]) / 2.0, 1.0)
    return int(np.clip(math.ceil(min_portions / (len(measurement.seeds) * per_layer)), 1, 500))
