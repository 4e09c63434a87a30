"""Figures of the deposited mat and of its statistics (paper Fig. 12).

``plot_mat`` draws the mat seen from above with fibers coloured by layer (Fig. 12a);
``plot_statistics`` draws histograms of orientation, tortuosity, diameter and element length
against their targets (Fig. 12b-c). Figures are built with ``matplotlib.figure.Figure`` and the
Agg canvas (no pyplot global state) and written atomically. Lengths in um, angles in degrees.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import BoundaryNorm
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from espin.core.figures import save_figure

if TYPE_CHECKING:  # pragma: no cover
    from espin.geometry.mat import FiberMat
    from espin.geometry.statistics import NetworkStatistics, Target, VisibleFibers

__all__ = ["plot_mat", "plot_statistics"]


def plot_mat(
    mat: FiberMat,
    path: str | Path,
    *,
    linewidth: float | None = None,
    window: VisibleFibers | None = None,
    title: str | None = None,
    size_in: float = 7.0,
    dpi: float = 200.0,
    cmap: str = "viridis",
) -> Path:
    """Draw the mat seen from above, fibers coloured by layer (paper Fig. 12a).

    Layers are drawn bottom (0) to top, so upper layers cover lower ones as in an SEM image.

    Parameters
    ----------
    mat : FiberMat
        The deposited fibers.
    path : str or Path
        Output file; the format follows the suffix (``.png`` by default).
    linewidth : float, optional [pt]
        Line width of every fiber. Default: each fiber's diameter at the plot's scale (at
        least 0.15 pt), so the picture shows the true coverage.
    window : VisibleFibers, optional
        Draw the outline of this observation window.
    title : str, optional
        Axes title; default states the fiber and layer counts.
    size_in : float [in]
        Width of the square axes region.
    dpi : float
        Resolution of raster output.
    cmap : str
        Matplotlib colormap of the layers.

    Returns
    -------
    Path
        The written file.
    """
    import matplotlib

    n_layers = max(int(mat.n_layers), 1)
    s = mat.segment_start
    order = np.argsort(mat.fiber_layer[mat.segment_fiber], kind="stable")
    s = s[order]
    fiber = mat.segment_fiber[order]
    segments = np.stack([mat.vertices[s], mat.vertices[s + 1]], axis=1)
    layer = mat.fiber_layer[fiber]

    fig = Figure(figsize=(size_in * 1.22, size_in), layout="constrained")
    ax = fig.add_subplot()
    if linewidth is None:
        # Diameter [um] -> points: axes width ~ size_in inches spans mat.size um.
        widths = np.maximum(mat.fiber_diameter[fiber] / mat.size * size_in * 72.0 * 0.85, 0.15)
    else:
        widths = linewidth
    norm = BoundaryNorm(np.arange(n_layers + 1) - 0.5, n_layers)
    colormap = matplotlib.colormaps[cmap].resampled(n_layers)
    # matplotlib's stubs ask for a Sequence; an (n, 2, 2) array is what it documents and takes.
    lc = LineCollection(segments, linewidths=widths, cmap=colormap, norm=norm, capstyle="round")  # type: ignore[arg-type]
    lc.set_array(layer)
    ax.add_collection(lc)
    if window is not None:
        ax.add_patch(
            Rectangle(
                tuple(window.origin),
                window.side,
                window.side,
                fill=False,
                edgecolor="red",
                linewidth=1.8,
                linestyle="--",
                zorder=5,
                label=f"observation window ({window.side:.3g} µm)",
            )
        )
        ax.legend(loc="upper right", fontsize="small")
    ax.set_xlim(0.0, mat.size)
    ax.set_ylim(0.0, mat.size)
    ax.set_aspect("equal")
    ax.set_xlabel("x [µm]")
    ax.set_ylabel("y [µm]")
    ax.set_title(title or f"{mat.n_fibers:,} fibers in {mat.n_layers} layers, L = {mat.size:g} µm")
    ticks = np.arange(0, n_layers, -(-n_layers // 10))  # at most 10 evenly spaced layers
    fig.colorbar(lc, ax=ax, label="layer", ticks=ticks, shrink=0.85)
    return save_figure(fig, path, dpi)


def _hist(ax, sample: np.ndarray, bins: np.ndarray, label: str, color: str = "C0") -> None:
    sample = np.asarray(sample, dtype=float)
    sample = sample[np.isfinite(sample)]
    if len(sample):
        ax.hist(
            sample,
            bins=bins,
            density=True,
            color=color,
            alpha=0.6,
            edgecolor="white",
            linewidth=0.4,
            label=f"{label} (n = {len(sample):,})",
        )
    else:
        ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center")


def along_an_edge(orientation: np.ndarray) -> np.ndarray:
    """Which end-to-end chords lie exactly along an edge of the square layer (0 or 90 deg).

    Parameters
    ----------
    orientation : (n,) float [rad]
        Chord axes in [0, pi).

    Returns
    -------
    (n,) bool
        True for the fibers that enter and leave the layer through the same edge (with
        ``border`` seeding, a few percent), whose chord is then that edge: a boundary artefact
        of the chord, not alignment. Another fiber's chord lies exactly on an axis with
        probability zero.
    """
    quarter = np.mod(np.asarray(orientation, dtype=float), np.pi / 2.0)
    return np.minimum(quarter, np.pi / 2.0 - quarter) < 1e-9


def _ks(value: float) -> str:
    return "KS -" if not np.isfinite(value) else f"KS = {value:.3f}"


def _typeset(label: str) -> str:
    """A target's plain-text label for a figure: micrometres with a mu."""
    return label.removesuffix(" um") + " µm" if label.endswith(" um") else label


def _against_target(ax, values: np.ndarray, target: Target | None, label: str, floor: float) -> None:
    """Histogram of a mat's ``values`` against a measured target: the distribution's density,
    the measured sample's histogram, or a note that there is none; bins over both, from at
    least ``floor``."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    ends = [float(values.min()), float(values.max())] if len(values) else []
    if target is not None:
        ends += [target.quantile(0.0005), target.quantile(0.9995)]
    lo = max(min(ends, default=floor), floor)
    hi = max(ends, default=lo)
    hi = hi if hi > lo else lo + max(0.1 * abs(lo), 1e-3)  # one value: a bin around it
    bins = np.linspace(lo, hi, 41)
    mean = f", mean {np.mean(values):.4g}" if len(values) else ""
    _hist(ax, values, bins, label + mean)
    if target is None:
        ax.plot([], [], " ", label="no measured target in the config")
    elif target.law is not None:
        x = np.linspace(lo, hi, 400)
        ax.plot(x, target.law.pdf(x), color="k", label=f"measured {_typeset(target.label)}, mean {target.mean:.4g}")
    else:
        ax.hist(
            np.clip(cast(np.ndarray, target.sample), lo, hi),  # a target without a law has a sample
            bins=bins,
            density=True,
            histtype="step",
            color="k",
            label=f"measured {_typeset(target.label)}, mean {target.mean:.4g}",
        )
    ax.legend(fontsize="small")


def plot_statistics(stats: NetworkStatistics, path: str | Path, *, dpi: float = 150.0) -> Path:
    """Histograms of the mat's statistics against their targets (paper Fig. 12b-c).

    Panels: fiber orientation (end-to-end chords) and the orientation of the portions visible
    in the observation window, both against the configured distribution; tortuosity in the
    window (of the portions or pieces graded) and diameter, against the measured targets of
    the config (``[targets]``: a distribution or a sample; none without it); element
    tortuosity; element length (log scale). Panel titles carry the KS statistics. With the
    paper's Table 2 parameters the tortuosity panel of ``plla`` shows virtual fibers far
    straighter than the measured ones: that is the model's result (docs/model.md section 7),
    not a plotting problem.

    Parameters
    ----------
    stats : NetworkStatistics
        From :func:`espin.geometry.statistics.network_statistics`.
    path : str or Path
        Output file; the format follows the suffix (``.png`` by default).
    dpi : float
        Resolution of raster output.

    Returns
    -------
    Path
        The written file.
    """
    fig = Figure(figsize=(14.0, 8.0), layout="constrained")
    axes = fig.subplots(2, 3)
    target = stats.orientation_target
    w = stats.window

    # Orientation [deg]: density per degree, target pdf [1/rad] * pi / 180.
    edges = np.linspace(0.0, 180.0, 37)
    grid = np.linspace(0.0, 180.0, 361)
    pdf_deg = target.pdf(np.radians(grid)) * np.pi / 180.0
    for ax, sample, name, ks in (
        (axes[0, 0], stats.fiber_orientation, "fibers (end-to-end)", stats.ks_fiber_orientation),
        (axes[1, 0], w.orientation, "visible portions", stats.ks_window_orientation),
    ):
        _hist(ax, np.degrees(sample), edges, name)
        edge = along_an_edge(sample) if sample is stats.fiber_orientation else np.zeros(len(sample), bool)
        if edge.any():  # their share of the same density, drawn over the bars of 0 and 90 deg
            width = edges[1] - edges[0]
            ax.hist(
                np.degrees(sample[edge]),
                bins=edges,
                weights=np.full(edge.sum(), 1.0 / (len(sample) * width)),
                color="C3",
                alpha=0.8,
                edgecolor="white",
                linewidth=0.4,
                label=f"of which {edge.sum():,} ({edge.mean():.1%}) enter and leave through one edge:\n"
                "their chord lies along it (a boundary artefact, not alignment)",
            )
        ax.plot(grid, pdf_deg, color="k", label=f"target: {target.label}")
        ax.set_xlim(0.0, 180.0)
        ax.set_xticks(np.arange(0, 181, 30))
        ax.set_xlabel("orientation [deg]")
        ax.set_ylabel("density [1/deg]")
        ax.set_title(f"orientation, {name}: {_ks(ks)}")
        ax.set_ylim(0.0, 1.4 * ax.get_ylim()[1])  # room for the legend above the bars
        ax.legend(fontsize="small", loc="upper center")

    # Tortuosity in the window and diameter against their measured targets.
    g = stats.grading
    ax = axes[0, 1]
    graded = g.tortuosity
    tortuosity = w.tortuosity if graded is None else graded.mat
    name = "visible portions" if graded is None else cast(str, g.tortuosity_sampling)  # set with graded
    _against_target(ax, tortuosity, None if graded is None else graded.target, name, floor=1.0)
    ax.set_yscale("log")
    low, high = ax.get_ylim()
    ax.set_ylim(low, high * (high / low) ** 0.35)  # headroom above the bars for the legend
    ax.set_xlabel("tortuosity (contour / chord)")
    ax.set_ylabel("density (log)")
    ks = math.nan if graded is None else graded.ks
    ax.set_title(f"tortuosity in a {w.side:.3g} µm window: {_ks(ks)}")

    ax = axes[0, 2]
    d = stats.diameter_um
    _against_target(ax, d, None if g.diameter is None else g.diameter.target, "fibers", floor=0.0)
    ax.set_ylim(0.0, 1.4 * ax.get_ylim()[1])  # headroom above the bars for the legend
    ax.set_xlabel("diameter [µm]")
    ax.set_ylabel("density [1/µm]")
    fixed = len(d) > 0 and np.ptp(d) == 0.0
    ks = math.nan if g.diameter is None else g.diameter.ks
    ax.set_title(f"diameter: {_ks(ks)}" + (" (fixed diameter)" if fixed else ""))

    # Element tortuosity, as lambda_r - 1: the elements are nearly straight, so the values
    # differ in the fourth decimal and ticks of lambda_r itself would run into each other.
    ax = axes[1, 1]
    et = np.asarray(stats.element_tortuosity, dtype=float)
    et = et[np.isfinite(et)] - 1.0
    hi = max(float(np.quantile(et, 0.999)) if len(et) else 0.0, 1e-6)
    power = int(np.floor(np.log10(hi)))  # the axis in units of 10^power, stated in its label
    bins = np.linspace(0.0, hi, 41) / 10.0**power
    _hist(ax, np.clip(et / 10.0**power, 0.0, bins[-1]), bins, "elements, clipped at 99.9 %", color="C2")
    ax.set_yscale("log")
    ax.set_xlabel(rf"element tortuosity $\lambda_r - 1 = L_0 / l_0 - 1$ [$10^{{{power}}}$]")
    ax.set_ylabel("density (log)")
    ax.set_title(rf"element tortuosity: mean $\lambda_r - 1$ = {np.mean(et) if len(et) else np.nan:.3g}")
    ax.legend(fontsize="small")

    # Element length (log-spaced bins: l0 spans several decades).
    ax = axes[1, 2]
    el = np.asarray(stats.element_length_um, dtype=float)
    el = el[np.isfinite(el) & (el > 0)]
    if len(el):
        bins = np.geomspace(el.min(), max(el.max(), el.min() * 1.0001), 41)
        ax.hist(
            el, bins=bins, color="C3", alpha=0.6, edgecolor="white", linewidth=0.4, label=f"elements (n = {len(el):,})"
        )
        ax.set_xscale("log")
        ax.axvline(np.mean(el), color="k", linestyle="--", label=f"mean {np.mean(el):.3g} µm")
        ax.legend(fontsize="small")
    ax.set_xlabel("element length $l_0$ [µm]")
    ax.set_ylabel("count")
    ax.set_title("element length")
    return save_figure(fig, path, dpi)
