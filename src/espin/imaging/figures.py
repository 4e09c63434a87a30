"""Figures of an SEM measurement: histograms with fitted distributions, and an overlay.

The overlay draws every traced fiber (its centre line, one colour per fiber; twice as thick
for a fiber traced from edge to edge of the image) and, at every fourth width sample, a white
tick across the fiber as long as the width measured there, on the analysed image: a user sees
at a glance what was traced and measured.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np
import pandas as pd
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from scipy import stats

from espin.core.figures import save_figure
from espin.imaging.distributions import FittedDistributions
from espin.imaging.widths import WidthSamples

__all__ = ["MeasuredImage", "save_histograms", "save_overlay"]


class MeasuredImage(Protocol):
    """What the figures draw of a measurement (:class:`espin.imaging.measurement.SEMMeasurement`)."""

    @property
    def source(self) -> str: ...
    @property
    def um_per_px(self) -> float: ...
    @property
    def fibers(self) -> pd.DataFrame: ...
    @property
    def fits(self) -> FittedDistributions: ...
    @property
    def widths_um(self) -> np.ndarray: ...
    @property
    def dominant_direction_deg(self) -> float: ...
    @property
    def coherency(self) -> float: ...
    @property
    def image(self) -> np.ndarray: ...
    @property
    def paths_px(self) -> list[np.ndarray]: ...
    @property
    def width_samples(self) -> WidthSamples: ...
    @property
    def junctions_px(self) -> np.ndarray: ...

_TICK_EVERY = 4  # width samples per drawn width tick
_COLOURS = [f"C{k}" for k in (0, 1, 2, 3, 4, 5, 6, 8, 9)]  # not C7, grey on a grey image


def save_histograms(m: MeasuredImage, path: str | Path) -> Path:
    """Diameter, orientation and tortuosity histograms with their fitted densities."""
    f, fits = m.fibers, m.fits
    fig = Figure(figsize=(12, 3.6), layout="constrained")
    ax_d, ax_o, ax_t = fig.subplots(1, 3)

    d = _finite(f["diameter_um"])
    if len(d):
        ax_d.hist(m.widths_um, bins=40, density=True, color="0.85", label="local widths")
        ax_d.hist(d, bins="auto", density=True, alpha=0.7, label="per fiber")
        x = np.linspace(0.0, max(d.max(), np.percentile(m.widths_um, 99)) * 1.1, 200)
        if np.isfinite(fits.diameter_sd_um) and fits.diameter_sd_um > 0:
            ax_d.plot(x, stats.norm.pdf(x, fits.diameter_mean_um, fits.diameter_sd_um), "k-",
                      label=f"normal {fits.diameter_mean_um:.3g} +- {fits.diameter_sd_um:.2g}")
    ax_d.set(xlabel="diameter [um]", ylabel="density [1/um]")
    ax_d.legend(fontsize=7)

    theta = _finite(f["orientation_deg"])
    ax_o.hist(theta, bins=np.linspace(0, 180, 19), density=True, alpha=0.7, label="fibers")
    grid = np.linspace(0, 180, 361)
    label = ("uniform" if fits.orientation_model == "uniform" else
             f"von Mises mu {fits.orientation_mean_deg:.0f}, kappa {fits.orientation_kappa:.2g}")
    ax_o.plot(grid, fits.orientation_pdf(grid), "k-", label=f"{label} (AIC)")
    ax_o.axvline(m.dominant_direction_deg, color="C3", ls="--",
                 label=f"structure tensor {m.dominant_direction_deg:.0f} deg, "
                       f"coherency {m.coherency:.2f}")
    ax_o.set(xlabel="orientation [deg]", ylabel="density [1/deg]", xlim=(0, 180))
    ax_o.legend(fontsize=7)

    t = _finite(f["tortuosity"])
    if len(t):
        ax_t.hist(t, bins="auto", density=True, alpha=0.7, label="fibers")
        x = np.linspace(1.0, max(t.max(), 1.0 + 3 * fits.tortuosity_scale) * 1.02, 200)
        if fits.tortuosity_scale > 0:
            ax_t.plot(x, stats.halfnorm.pdf(x, 1.0, fits.tortuosity_scale), "k-",
                      label=f"half-normal loc 1, scale {fits.tortuosity_scale:.3g}")
    ax_t.set(xlabel="tortuosity (contour / end-to-end)", ylabel="density")
    ax_t.legend(fontsize=7)
    fig.suptitle(f"{Path(m.source).name}: {len(f)} fibers, {m.um_per_px:.4g} um/px", fontsize=10)
    return save_figure(fig, path, dpi=120)


def save_overlay(m: MeasuredImage, path: str | Path) -> Path:
    """The analysed image with traced centre lines and measured widths drawn on it."""
    rows, cols = m.image.shape
    scale = min(1.0, 1600.0 / max(rows, cols))  # figure pixels per image pixel, at most 1600
    fig = Figure(figsize=(cols * scale / 100.0, rows * scale / 100.0))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(m.image, cmap="gray", interpolation="nearest")
    lines = [p[:, ::-1] for p in m.paths_px]
    crossing = ((m.fibers["start_edge"] != "") & (m.fibers["end_edge"] != "")).to_numpy()
    colours = [_COLOURS[i % len(_COLOURS)] for i in range(len(lines))]
    ax.add_collection(LineCollection(lines, colors=colours, linewidths=np.where(crossing, 2.4, 1.2)))
    s = m.width_samples
    pick = np.arange(0, len(s.width_px), _TICK_EVERY)
    half = 0.5 * s.width_px[pick, None] * s.normal[pick]
    ticks = np.stack([s.point[pick] - half, s.point[pick] + half], axis=1)[:, :, ::-1]
    ax.add_collection(LineCollection(ticks, colors="white", linewidths=0.6, alpha=0.8))
    if len(m.junctions_px):
        ax.plot(m.junctions_px[:, 1], m.junctions_px[:, 0], ".", color="C3", ms=2)
    ax.set(xlim=(-0.5, cols - 0.5), ylim=(rows - 0.5, -0.5))
    ax.axis("off")
    return save_figure(fig, path, dpi=100)


def _finite(x: object) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    return a[np.isfinite(a)]
