"""Mat structure of an SEM image: porosity, pore sizes and fiber intersection density.

What DiameterJ (pores), and fiber-network tools such as CT-FIRE (intersections), report
beside the fiber diameters, from the binary fiber mask of the analysed image:

- **Porosity**: the non-fiber fraction of the mask's pixels. It is the *apparent* (surface)
  porosity of an SEM image, what the fibers the segmentation sees leave open, not the volume
  porosity of the mat: it depends on how deep the image shows fibers and on the threshold.
- **Pores**: the connected regions of non-fiber pixels, 4-connected (the fibers are
  8-connected, so a one-pixel diagonal fiber line separates two pores). Each pore's size is
  its **equivalent-circle diameter** sqrt(4 A / pi), A its area (DiameterJ's pore area
  through ImageJ's Analyze Particles, and the usual "pore size" of image analyses of
  electrospun mats); its **largest inscribed circle** diameter 2 d_max - 1 px, d_max the
  largest Euclidean distance from a pore pixel to a fiber pixel (the largest sphere that
  fits, what the pore-size distributions of porous-media tools such as PoreSpy's local
  thickness and the bubble point of capillary flow porometry see) is reported beside it. A
  pore touching the image border is cut by it: its size is not known, so it counts for the
  porosity but not in the size distribution (as Analyze Particles' "exclude on edges").
- **Intersection density**: junctions of the traced skeleton
  (:func:`espin.imaging.trace.trace_fibers`: fibers crossing, or ending on another fiber)
  per um^2 of analysed area, and per um of fiber length (the length of the mask's skeleton).
  A shallow crossing whose two fibers share a stretch of skeleton gives two junctions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

__all__ = ["PoreStructure", "mat_structure", "skeleton_length_px"]

_FOUR = ndimage.generate_binary_structure(2, 1)  # 4-connectivity of the pores


@dataclass(frozen=True, eq=False)
class PoreStructure:
    """Porosity, pores and intersections of one analysed image.

    Attributes
    ----------
    porosity : float
        Non-fiber fraction of the analysed area, in [0, 1].
    pore_diameter_um : (n,) float64 [um]
        Equivalent-circle diameter sqrt(4 A / pi) of each pore not touching the image border.
    pore_inscribed_um : (n,) float64 [um]
        Largest inscribed circle diameter of the same pores.
    n_pores_on_border : int
        Pores cut by the image border (left out of the sizes).
    area_um2 : float [um^2]
        Analysed area.
    n_junctions : int
        Skeleton junctions (fiber intersections).
    fiber_length_um : float [um]
        Length of the fiber mask's skeleton.
    """

    porosity: float
    pore_diameter_um: np.ndarray
    pore_inscribed_um: np.ndarray
    n_pores_on_border: int
    area_um2: float
    n_junctions: int
    fiber_length_um: float

    @property
    def intersection_density_per_um2(self) -> float:
        """Junctions per um^2 of analysed area [1 / um^2]."""
        return self.n_junctions / self.area_um2

    @property
    def intersections_per_um(self) -> float:
        """Junctions per um of fiber length [1 / um]; NaN without fibers."""
        return self.n_junctions / self.fiber_length_um if self.fiber_length_um > 0 else math.nan

    @property
    def pore_diameter_median_um(self) -> float:
        """Median equivalent-circle diameter of the pores inside the image [um]; NaN if none."""
        return _median(self.pore_diameter_um)

    @property
    def pore_inscribed_median_um(self) -> float:
        """Median largest-inscribed-circle diameter of the pores inside the image [um]."""
        return _median(self.pore_inscribed_um)

    def summary(self) -> dict[str, Any]:
        """A ``[pores]`` section for a TOML file (units in the key names)."""
        d, i = self.pore_diameter_um, self.pore_inscribed_um
        return {
            "porosity": self.porosity,
            "pore_size": "equivalent-circle diameter sqrt(4 A / pi) of the non-fiber regions "
            "(4-connected) not touching the image border",
            "n_pores": len(d),
            "n_pores_on_border": self.n_pores_on_border,
            "pore_diameter_median_um": self.pore_diameter_median_um,
            "pore_diameter_mean_um": _mean(d),
            "pore_diameter_p10_um": _quantile(d, 0.1),
            "pore_diameter_p90_um": _quantile(d, 0.9),
            "pore_area_mean_um2": _mean(np.pi / 4.0 * d**2),
            "pore_area_median_um2": _median(np.pi / 4.0 * d**2),
            "pore_inscribed_median_um": self.pore_inscribed_median_um,
            "pore_inscribed_max_um": float(i.max()) if len(i) else math.nan,
            "area_um2": self.area_um2,
            "n_junctions": self.n_junctions,
            "fiber_length_um": self.fiber_length_um,
            "intersection_density_per_um2": self.intersection_density_per_um2,
            "intersections_per_um_fiber": self.intersections_per_um,
        }

    def table_rows(self) -> list[tuple[str, str]]:
        """(quantity, value) pairs for a short printed table."""
        return [
            ("porosity", f"{self.porosity:.3f} (non-fiber area fraction of the mask)"),
            (
                "pore size",
                f"median {self.pore_diameter_median_um:.3g} um equivalent-circle, "
                f"{self.pore_inscribed_median_um:.3g} um inscribed ({len(self.pore_diameter_um)} "
                f"pores inside the image, {self.n_pores_on_border} on its border)",
            ),
            (
                "intersections",
                f"{self.intersection_density_per_um2:.4g} per um^2, "
                f"{self.intersections_per_um:.3g} per um of fiber "
                f"({self.n_junctions} junctions)",
            ),
        ]


def mat_structure(mask: np.ndarray, junctions_px: np.ndarray, um_per_px: float) -> PoreStructure:
    """Porosity, pore sizes and intersection density of a fiber mask (module notes).

    Parameters
    ----------
    mask : (rows, cols) bool
        Fiber pixels of the analysed image.
    junctions_px : (n, 2) float64 [px]
        Junction centres (row, col) of its traced skeleton
        (:attr:`espin.imaging.trace.TracedFibers.junctions`).
    um_per_px : float [um / px]
        Pixel size.

    Returns
    -------
    PoreStructure
    """
    mask = np.asarray(mask, dtype=bool)
    pores, n = ndimage.label(~mask, structure=_FOUR)
    index = np.arange(1, n + 1)
    area_px = ndimage.sum_labels(np.ones(mask.shape), pores, index)
    distance = ndimage.distance_transform_edt(pores > 0)
    inscribed_px = 2.0 * ndimage.maximum(distance, pores, index) - 1.0 if n else np.zeros(0)
    border = np.unique(np.concatenate([pores[0], pores[-1], pores[:, 0], pores[:, -1]]))
    inside = ~np.isin(index, border)
    return PoreStructure(
        porosity=float(1.0 - mask.mean()),
        pore_diameter_um=np.sqrt(4.0 * area_px[inside] / np.pi) * um_per_px,
        pore_inscribed_um=np.asarray(inscribed_px, dtype=float)[inside] * um_per_px,
        n_pores_on_border=int(np.count_nonzero(~inside)),
        area_um2=float(mask.size * um_per_px**2),
        n_junctions=len(junctions_px),
        fiber_length_um=skeleton_length_px(mask) * um_per_px,
    )


def skeleton_length_px(mask: np.ndarray) -> float:
    """Length of the skeleton of a fiber mask [px].

    The mask is padded by replication (as :func:`espin.imaging.trace.trace_fibers` does), so
    a skeleton runs out to the image edge. Its length counts each link between 8-neighbouring
    skeleton pixels, 1 across an edge and sqrt(2) across a corner, a corner link only where
    no pixel shares an edge with both (a staircase is not counted twice).

    Parameters
    ----------
    mask : (rows, cols) bool
        Fiber pixels.

    Returns
    -------
    float [px]
    """
    from skimage.morphology import skeletonize

    if not mask.any():
        return 0.0
    pad = int(np.ceil(ndimage.distance_transform_edt(mask).max()))
    s = skeletonize(np.pad(mask, pad, mode="edge"))[pad:-pad, pad:-pad]
    straight = np.count_nonzero(s[1:] & s[:-1]) + np.count_nonzero(s[:, 1:] & s[:, :-1])
    down_right = s[1:, 1:] & s[:-1, :-1] & ~s[:-1, 1:] & ~s[1:, :-1]
    down_left = s[1:, :-1] & s[:-1, 1:] & ~s[:-1, :-1] & ~s[1:, 1:]
    return float(straight + math.sqrt(2.0) * (np.count_nonzero(down_right) + np.count_nonzero(down_left)))


def _median(x: np.ndarray) -> float:
    return float(np.median(x)) if len(x) else math.nan


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if len(x) else math.nan


def _quantile(x: np.ndarray, q: float) -> float:
    return float(np.quantile(x, q)) if len(x) else math.nan
