"""The calibrated mat seen through the SEM tracer: renderings measured like the image.

The search compares the image's traced fibers with *geometric* pieces of virtual mats. The
tracer is not a ruler: on renderings of known mats it reads straight fibers about 0.02 less
straight than they are (jogs onto neighbours at crossings), curling fibers straighter (they
break more often, and the ones traced whole are the straighter ones), and adds a tortuosity
floor to short pieces (docs/sem.md). Mats of a fitted config are therefore rendered as
synthetic SEM images at the image's pixel size and field of view
(:func:`espin.imaging.geometry_calibration.comparison.render_like`) and measured with
``espin measure``'s defaults (:func:`espin.imaging.measurement.measure`), which gives

* the **tracer correction** (:func:`tracer_corrected`): the measured tortuosity sample mapped
  quantile by quantile from what the tracer reads on the renderings to the true tortuosity
  of the same mats' pieces, the target of a second search. Straightness needs none: through
  the tracer the calibrated mats read within 0.02 of the two real images
  (docs/geometry_calibration.md);
* the **rendered check** (:meth:`TracedRenderings.check`): the renderings' traced samples
  against the image's (KS of diameter, orientation and tortuosity; U-turn fraction and
  straightness), whether the calibrated mat looks like the image through the same instrument.

Units: um, degrees.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from espin.core.config import Config

if TYPE_CHECKING:  # pragma: no cover
    from espin.geometry.targets import GeometryTargets
    from espin.imaging.geometry_calibration.result import MeasuredImage

__all__ = ["RENDERINGS", "TracedRenderings", "measure_renderings", "tracer_corrected"]

RENDERINGS = 3
"""Mats (seeds 1, 2, ...) rendered and traced per check: the image's own sample has a few
dozen fibers, so the renderings' pooled sample is a few times larger."""


@dataclass(frozen=True, eq=False)
class TracedRenderings:
    """What ``espin measure`` reads on renderings of a calibrated mat, pooled.

    Attributes
    ----------
    n_images : int
        Renderings measured.
    diameter_um, orientation_deg, tortuosity : (n,) float64
        Per traced fiber [um, deg, -] (NaN diameters left out).
    n_crossing : int
        Fibers traced edge to edge.
    u_turn_fraction, straightness : float
        Of those (NaN if none).
    """

    n_images: int
    diameter_um: np.ndarray
    orientation_deg: np.ndarray
    tortuosity: np.ndarray
    n_crossing: int
    u_turn_fraction: float
    straightness: float

    def check(self, targets: GeometryTargets) -> dict[str, Any]:
        """KS distances of the traced samples against the image's, and the long-range shape
        side by side (JSON-ready; None where the image has no such sample)."""
        from scipy import stats

        out: dict[str, Any] = {"renderings": self.n_images, "fibers": int(len(self.tortuosity))}
        for key in ("diameter_um", "orientation_deg", "tortuosity"):
            target = getattr(targets, key)
            mine = getattr(self, key)
            ok = target is not None and len(target) and len(mine)
            out[f"ks_{key}"] = float(stats.ks_2samp(mine, target).statistic) if ok else None
        out |= {
            "n_crossing": self.n_crossing,
            "u_turn_fraction": _json(self.u_turn_fraction),
            "straightness": _json(self.straightness),
            "target_n_crossing": targets.n_crossing,
            "target_u_turn_fraction": targets.u_turn_fraction,
            "target_straightness": targets.straightness,
        }
        return out


def measure_renderings(config: Config, image: MeasuredImage, renderings: int = RENDERINGS) -> TracedRenderings:
    """Render ``renderings`` mats of ``config`` (seeds 1, 2, ...) like ``image`` and measure
    them with ``espin measure``'s defaults at the image's pixel size."""
    from espin.imaging.geometry_calibration.comparison import render_like
    from espin.imaging.measurement import measure

    parts: dict[str, list[np.ndarray]] = {"diameter_um": [], "orientation_deg": [], "tortuosity": []}
    n_cross, u_sum, s_sum = 0, 0.0, 0.0
    for seed in range(1, renderings + 1):
        mat_config = config.model_copy(update={"rve": config.rve.model_copy(update={"seed": seed})})
        picture = render_like(mat_config, image.pixels.shape, image.um_per_px, seed=seed)
        seen = measure(picture, um_per_px=image.um_per_px)
        for key, values in parts.items():
            column = seen.fibers[key].to_numpy(dtype=float)
            values.append(column[np.isfinite(column)])
        if seen.n_crossing:
            n_cross += seen.n_crossing
            u_sum += seen.u_turn_fraction * seen.n_crossing
            s_sum += seen.straightness * seen.n_crossing
    pooled = {key: np.concatenate(v) for key, v in parts.items()}
    return TracedRenderings(
        renderings,
        pooled["diameter_um"],
        pooled["orientation_deg"],
        pooled["tortuosity"],
        n_cross,
        u_sum / n_cross if n_cross else math.nan,
        s_sum / n_cross if n_cross else math.nan,
    )


def tracer_corrected(
    targets: GeometryTargets, traced: TracedRenderings, geometric_tortuosity: np.ndarray
) -> tuple[GeometryTargets, float]:
    """The targets with the tracer's effect on tortuosity at one walk taken out, by quantile
    mapping: each measured value t becomes the geometric tortuosity of the same quantile,
    Q_geometric(F_traced(t)), both from the same mats (renderings traced like the image, and
    their true pieces of the measured lengths).

    Returns the corrected targets and the median shift it made (0 when a sample is empty).
    """
    if targets.tortuosity is None or not len(traced.tortuosity) or not len(geometric_tortuosity):
        return targets, 0.0
    traced_sorted = np.sort(traced.tortuosity)
    quantile = np.searchsorted(traced_sorted, targets.tortuosity, side="right") / len(traced_sorted)
    quantile = np.clip(quantile - 0.5 / len(traced_sorted), 0.0, 1.0)  # mid-rank
    corrected = np.maximum(np.quantile(geometric_tortuosity, quantile), 1.0)
    shift = float(np.median(corrected) - np.median(targets.tortuosity))
    return dataclasses.replace(targets, tortuosity=corrected), shift


def _json(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
