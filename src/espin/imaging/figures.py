"""Figures of an SEM measurement: histograms with fitted distributions, an overlay and an
orientation colour map.

The diameter histogram shows the fully visible fibers (filled; their fitted family, chosen by
BIC, as a curve) and the partly hidden ones (outlined) apart, over all local widths. The
overlay draws every traced fiber (its centre line, amber for a fully visible fiber, blue for a
partly hidden one; twice as thick for a fiber traced from edge to edge of the image) and, at every
fourth width sample, a white tick across the fiber as long as the width measured there, on the
analysed image: a user sees at a glance what was traced and measured. A legend below the image
says so, and a scale bar (a round length, at most a fifth of the image width) sits in its lower
right corner.

The orientation map is OrientationJ's colour survey: hue = the local fiber direction of the
structure tensor (:func:`espin.imaging.orientation.local_orientation`, window sigma w / 2),
saturation = its coherency, brightness = the image; a colour disc beside it is the key
(direction around it, coherency from its centre out).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import hsv_to_rgb
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from scipy import stats

from espin.core.figures import save_figure
from espin.imaging.distributions import FittedDistributions
from espin.imaging.orientation import local_orientation
from espin.imaging.widths import WidthSamples

__all__ = ["MeasuredImage", "save_histograms", "save_overlay", "save_orientation_map", "scale_bar_um"]


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
    @property
    def typical_width_px(self) -> float: ...


_TICK_EVERY = 4  # width samples per drawn width tick
_VISIBLE, _HIDDEN = "#ffb000", "#4fa3ff"  # centre lines of fully visible / partly hidden fibers
_MIN_SIDE, _MAX_SIDE = 1000.0, 1600.0  # figure pixels of the image's longer side
_STRIP = "0.12"  # background of the legend strip below an image


def save_histograms(m: MeasuredImage, path: str | Path) -> Path:
    """Diameter, orientation and tortuosity histograms with their fitted densities."""
    f, fits = m.fibers, m.fits
    fig = Figure(figsize=(12, 3.6), layout="constrained")
    ax_d, ax_o, ax_t = fig.subplots(1, 3)

    visible = f["visible"].to_numpy(dtype=bool)
    d = _finite(f["diameter_um"][visible])
    hidden = _finite(f["diameter_um"][~visible])
    if len(d) or len(hidden):
        top = max(np.max(d, initial=0.0), np.max(hidden, initial=0.0), np.percentile(m.widths_um, 99))
        bins = np.linspace(0.0, 1.1 * top, 31)
        ax_d.hist(m.widths_um, bins=bins, density=True, color="0.85", label="local widths (all)")
        if len(hidden):
            ax_d.hist(
                hidden,
                bins=bins,
                density=True,
                histtype="step",
                color="C0",
                lw=1.5,
                label=f"partly hidden fibers ({len(hidden)})",
            )
        if len(d):
            ax_d.hist(d, bins=bins, density=True, color="C1", alpha=0.75, label=f"fully visible fibers ({len(d)})")
        chosen = fits.diameter.chosen
        if chosen:
            x = np.linspace(bins[1] / 10.0, bins[-1], 300)
            ax_d.plot(
                x,
                fits.diameter.pdf(chosen, x),
                "k-",
                label=f"{chosen} fit, visible (BIC): {fits.diameter.mean_um:.3g} ± {fits.diameter.sd_um:.2g} µm",
            )
    ax_d.set(xlabel="diameter [µm]", ylabel="density [1/µm]")

    theta = _finite(f["orientation_deg"])
    ax_o.hist(theta, bins=np.linspace(0, 180, 19), density=True, alpha=0.7, label="fibers")
    grid = np.linspace(0, 180, 361)
    label = (
        "uniform"
        if fits.orientation_model == "uniform"
        else rf"von Mises $\mu$ = {fits.orientation_mean_deg:.0f} deg, $\kappa$ = {fits.orientation_kappa:.2g}"
    )
    ax_o.plot(grid, fits.orientation_pdf(grid), "k-", label=f"{label} (AIC)")
    ax_o.axvline(
        m.dominant_direction_deg,
        color="C3",
        ls="--",
        label=f"structure tensor {m.dominant_direction_deg:.0f} deg, coherency {m.coherency:.2f}",
    )
    ax_o.set(xlabel="orientation [deg]", ylabel="density [1/deg]", xlim=(0, 180))

    t = _finite(f["tortuosity"])
    if len(t):
        ax_t.hist(t, bins="auto", density=True, alpha=0.7, label="fibers")
        x = np.linspace(1.0, max(t.max(), 1.0 + 3 * fits.tortuosity_scale) * 1.02, 200)
        if fits.tortuosity_scale > 0:
            ax_t.plot(
                x,
                stats.halfnorm.pdf(x, 1.0, fits.tortuosity_scale),
                "k-",
                label=f"half-normal loc 1, scale {fits.tortuosity_scale:.3g}",
            )
    ax_t.set(xlabel="tortuosity (contour / end-to-end)", ylabel="density")
    for ax in (ax_d, ax_o, ax_t):  # headroom, so that the legend sits above the bars
        ax.set_ylim(0.0, 1.45 * ax.get_ylim()[1])
        ax.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"{Path(m.source).name}: {len(f)} fibers, {m.um_per_px:.4g} µm/px", fontsize=10)
    return save_figure(fig, path, dpi=120)


def save_overlay(m: MeasuredImage, path: str | Path) -> Path:
    """The analysed image with traced centre lines and measured widths drawn on it, a legend
    below it and a scale bar on it."""
    rows, cols = m.image.shape
    fig, ax, ax_key, fontsize = _image_figure(m.image.shape, key_rows=2)
    ax.imshow(m.image, cmap="gray", interpolation="nearest")
    lines = [p[:, ::-1] for p in m.paths_px]
    crossing = ((m.fibers["start_edge"] != "") & (m.fibers["end_edge"] != "")).to_numpy()
    visible = m.fibers["visible"].to_numpy(dtype=bool)
    colours = np.where(visible, _VISIBLE, _HIDDEN)
    ax.add_collection(LineCollection(lines, colors=colours, linewidths=np.where(crossing, 2.4, 1.2)))
    s = m.width_samples
    pick = np.arange(0, len(s.width_px), _TICK_EVERY)
    half = 0.5 * s.width_px[pick, None] * s.normal[pick]
    ticks = np.stack([s.point[pick] - half, s.point[pick] + half], axis=1)[:, :, ::-1]
    # matplotlib's stubs ask for a Sequence; an (n, 2, 2) array is what it documents and takes.
    ax.add_collection(LineCollection(ticks, colors="white", linewidths=0.6, alpha=0.8))  # type: ignore[arg-type]
    if len(m.junctions_px):
        ax.plot(m.junctions_px[:, 1], m.junctions_px[:, 0], ".", color="C3", ms=4)
    ax.set(xlim=(-0.5, cols - 0.5), ylim=(rows - 0.5, -0.5))
    ax.axis("off")
    _add_scale_bar(ax, m.um_per_px, cols, fontsize)
    key = [
        Line2D(
            [],
            [],
            color=_VISIBLE,
            lw=1.2,
            label=f"fully visible fiber ({visible.sum()}), its diameter is the primary one",
        ),
        Line2D([], [], color=_HIDDEN, lw=1.2, label=f"partly hidden fiber ({(~visible).sum()})"),
        Line2D([], [], color="0.8", lw=2.4, label="thick: traced from edge to edge of the image"),
        Line2D([], [], color="white", lw=1.2, label=f"measured width (every {_TICK_EVERY}th sample)"),
        Line2D([], [], color="C3", ls="", marker=".", ms=6, label="junction (crossing)"),
    ]
    ax_key.legend(
        handles=key,
        loc="center",
        ncol=2,
        frameon=False,
        labelcolor="white",
        fontsize=fontsize,
        handlelength=2.5,
        columnspacing=2.0,
    )
    return save_figure(fig, path, dpi=100)


def save_orientation_map(m: MeasuredImage, path: str | Path) -> Path:
    """OrientationJ-style colour map of the local fiber direction (module notes), with its
    colour key and a scale bar."""
    rows, cols = m.image.shape
    w = float(m.typical_width_px)
    window = max(2.0, w / 2.0)
    direction, coherency = local_orientation(m.image, window_px=window, sigma_px=max(1.0, w / 8.0))
    lo, hi = np.percentile(m.image, [0.5, 99.5])
    value = np.clip((m.image - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    fig, ax, ax_key, fontsize = _image_figure(m.image.shape, key_rows=4)
    ax.imshow(hsv_to_rgb(np.stack([direction / 180.0, coherency, value], axis=-1)), interpolation="nearest")
    ax.set(xlim=(-0.5, cols - 0.5), ylim=(rows - 0.5, -0.5))
    ax.axis("off")
    _add_scale_bar(ax, m.um_per_px, cols, fontsize)
    right = _colour_disc(fig, ax_key, fontsize)
    ax_key.text(
        right + 0.02,
        0.5,
        "hue: local fiber direction, 0-180° counter-clockwise from "
        "horizontal (key: the disc)\nsaturation: coherency, 0 (grey) at the centre to 1 "
        f"at the rim\nbrightness: the image. Structure tensor, window $\\sigma$ = {window:.0f} px"
        f"\nwhole image: dominant direction {m.dominant_direction_deg:.0f}°, coherency "
        f"{m.coherency:.2f}",
        transform=ax_key.transAxes,
        ha="left",
        va="center",
        color="white",
        fontsize=fontsize,
        linespacing=1.5,
    )
    return save_figure(fig, path, dpi=100)


def scale_bar_um(width_um: float) -> float:
    """A round scale-bar length [um]: the largest 1, 2 or 5 times a power of ten that is at most
    a fifth of ``width_um`` [um]."""
    target = width_um / 5.0
    power = 10.0 ** np.floor(np.log10(target))
    return float(max(k * power for k in (1.0, 2.0, 5.0) if k * power <= target * (1 + 1e-9)))


def _image_figure(shape: tuple[int, int], key_rows: int) -> tuple[Figure, Axes, Axes, float]:
    """A figure holding an image with its longer side drawn over :data:`_MIN_SIDE` to
    :data:`_MAX_SIDE` figure pixels (1 per image pixel in between), over a dark strip of
    ``key_rows`` lines of text for its key; and the legend font size [pt]."""
    rows, cols = shape
    longest = max(rows, cols)
    scale = min(max(1.0, _MIN_SIDE / longest), _MAX_SIDE / longest)
    width, height = cols * scale / 100.0, rows * scale / 100.0  # inches at 100 dpi
    fontsize = float(np.clip(10.0 * width / 9.0, 6.0, 10.0))  # 10 pt from 900 px wide
    strip = (0.25 + 0.2 * key_rows) * fontsize / 9.0
    fig = Figure(figsize=(width, height + strip), facecolor=_STRIP)
    total = height + strip
    ax = fig.add_axes((0, strip / total, 1, height / total))
    ax_key = fig.add_axes((0, 0, 1, strip / total))
    ax_key.axis("off")
    return fig, ax, ax_key, fontsize


def _add_scale_bar(ax: Axes, um_per_px: float, cols: int, fontsize: float) -> None:
    """A white scale bar with its length in µm in the lower right corner of an image axes."""
    from matplotlib.font_manager import FontProperties
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    length = scale_bar_um(cols * um_per_px)
    bar = AnchoredSizeBar(
        ax.transData,
        length / um_per_px,
        f"{length:g} µm",
        "lower right",
        pad=0.4,
        borderpad=0.8,
        sep=4,
        color="white",
        frameon=True,
        size_vertical=max(1.0, 0.008 * cols),
        fontproperties=FontProperties(size=1.3 * fontsize),
    )
    bar.patch.set(facecolor="black", alpha=0.55, edgecolor="none")
    ax.add_artist(bar)


def _colour_disc(fig: Figure, ax_key: Axes, fontsize: float) -> float:
    """The orientation map's key at the left of its strip: direction around the disc (opposite
    points are one axis), coherency from the centre (0) to the rim (1); returns its right end
    as a fraction of the strip's width."""
    box = ax_key.get_position()
    side = 0.62 * box.height * fig.get_figheight()  # inches
    left = 3.0 * fontsize / 72.0  # room for the "180°" label
    ax = fig.add_axes(
        (left / fig.get_figwidth(), box.y0 + 0.1 * box.height, side / fig.get_figwidth(), 0.62 * box.height)
    )
    n = 201
    y, x = np.mgrid[1 : -1 : n * 1j, -1 : 1 : n * 1j]
    radius = np.hypot(x, y)
    hue = np.degrees(np.mod(np.arctan2(y, x), np.pi)) / 180.0
    rgba = np.ones((n, n, 4))
    rgba[..., :3] = hsv_to_rgb(np.stack([hue, np.clip(radius, 0, 1), np.ones_like(hue)], axis=-1))
    rgba[..., 3] = radius <= 1.0
    ax.imshow(rgba, extent=(-1, 1, -1, 1), interpolation="bilinear")
    for angle, ha, va in (
        (0, "left", "center"),
        (45, "left", "bottom"),
        (90, "center", "bottom"),
        (135, "right", "bottom"),
        (180, "right", "center"),
    ):
        a = np.radians(angle)
        ax.text(1.1 * np.cos(a), 1.1 * np.sin(a), f"{angle}°", ha=ha, va=va, color="white", fontsize=0.9 * fontsize)
    ax.set(xlim=(-1, 1), ylim=(-1, 1), aspect="equal")
    ax.axis("off")
    return (left + side) / fig.get_figwidth() + 0.03


def _finite(x: object) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    return a[np.isfinite(a)]
