"""The virtual SEM: generate mats with fixed seeds and measure them in the observation window."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from espin.config import RVEConfig, config_from_dict

__all__ = ["VirtualMeasurement"]


@dataclass(frozen=True)
class VirtualMeasurement:
    """How generated mats are measured: window, seeds and layers (common random numbers).

    Attributes
    ----------
    window_um : float [um]
        Side of the square observation window, centred in the layer.
    min_chord_um : float [um]
        Visible portions with a shorter chord are dropped (as by the SEM tracer).
    seeds : tuple of int
        ``rve.seed`` of each generated mat; the same for every evaluation.
    layers : int
        Layers per mat; all layers are measured through the window and pooled.
    """

    window_um: float
    min_chord_um: float
    seeds: tuple[int, ...]
    layers: int

    def measure(self, rve: dict[str, Any], side_um: float) -> dict[str, np.ndarray]:
        """Visible fiber portions of mats with deposition ``rve`` in layers of ``side_um``.

        Returns
        -------
        dict
            ``tortuosity`` (n,), ``orientation_deg`` (n,) [deg] of the chords and
            ``diameter_um`` (n,) [um] of the fibers they belong to, pooled over the seeds.
        """
        from espin.deposition import deposit
        from espin.statistics import centred_window, window_tortuosity

        parts: dict[str, list[np.ndarray]] = {"tortuosity": [], "orientation_deg": [], "diameter_um": []}
        for seed in self.seeds:
            cfg = _validated_rve(rve | {"size_um": side_um, "layers": self.layers, "seed": seed})
            mat = deposit(cfg)
            origin, side = centred_window(mat.size, self.window_um)
            seen = window_tortuosity(mat.vertices, mat.fiber_offsets, origin, side, self.min_chord_um)
            parts["tortuosity"].append(seen.tortuosity)
            parts["orientation_deg"].append(np.degrees(seen.orientation))
            parts["diameter_um"].append(mat.fiber_diameter[seen.fiber])
        return {k: np.concatenate(v) for k, v in parts.items()}


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
    """Layers per mat so that all seeds together show at least ``min_portions`` portions."""
    probe = VirtualMeasurement(measurement.window_um, measurement.min_chord_um,
                               measurement.seeds[:1], 2)
    per_layer = max(len(probe.measure(rve, side_um)["tortuosity"]) / 2.0, 1.0)
    return int(np.clip(math.ceil(min_portions / (len(measurement.seeds) * per_layer)), 1, 500))
