"""Figures of a loading program: the stress-strain curve and the deformed network.

Built with ``matplotlib.figure.Figure`` and the Agg canvas (no pyplot global state), written
atomically. Stress in MPa, strain in %, lengths in um.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from espin.core.config import Config, PoissonLateral
from espin.core.figures import save_figure

if TYPE_CHECKING:  # pragma: no cover
    from espin.geometry.network import Network
    from espin.mechanics.driver import SimulationResult, StepRecord

__all__ = ["plot_curve", "plot_deformed"]

_MEASURE_LABEL = {"nominal": "nominal $P'_{{{}}}$", "paper": "paper Eq. 17 $\\sigma'_{{{}}}$"}
_STRAIN_LABEL = {
    "uniaxial": "strain $F'_{11} - 1$ [%]",
    "equibiaxial": "stretch - 1 [%]",
    "pure_shear": "stretch $F'_{11} - 1$ [%]",
    "simple_shear": "shear $\\gamma$ [%]",
}


def _test_label(config: Config) -> str:
    """The test kind, its direction and (uniaxial) its lateral condition, in words."""
    loading = config.loading
    text = loading.test.replace("_", " ")
    if loading.test != "path" and loading.direction_deg:
        text += f" at {loading.direction_deg:g} deg"
    if loading.test == "uniaxial":
        lateral = loading.lateral
        if isinstance(lateral, str):
            text += f", lateral {lateral}"
        elif isinstance(lateral, PoissonLateral):
            text += f", lateral $\\nu$ = {lateral.poisson_ratio:g}"
        else:
            text += f", lateral from {lateral.transverse_csv.name}"
    return text


def plot_curve(result: SimulationResult, path: str | Path, measure: str | None = None,
               *, dpi: float = 150.0) -> Path:
    """Draw the stress-strain curve with the recruited and yielded fractions.

    Left axis: the curve's stress [MPa] in the loading frame (P'11, or P'12 for simple shear)
    in ``measure``, and the other measure (nominal P or the paper's Eq. 17) as a thin dashed
    line. Right axis: volume fractions of recruited and yielded elements, 0 to 1. The x axis
    is the program's strain [%] (time [s] for a ``path`` test).

    Parameters
    ----------
    result
        The recorded loading program.
    path
        Output file; the format follows the suffix (``.png`` by default).
    measure
        ``"nominal"`` or ``"paper"``; default ``output.stress_measure``.
    dpi
        Resolution of raster output.

    Returns
    -------
    Path
        The written file.
    """
    measure = measure or result.config.output.stress_measure
    other = "paper" if measure == "nominal" else "nominal"
    test = result.program.test
    if test == "path":
        x, xlabel = result.time, "time [s]"
    else:
        x, xlabel = 100.0 * result.strain, _STRAIN_LABEL[test]
    component = "12" if test == "simple_shear" else "11"

    fig = Figure(figsize=(7.5, 5.0), layout="constrained")
    ax = fig.add_subplot()
    label = _MEASURE_LABEL[measure].format(component)
    lines = ax.plot(x, result.stress(measure), color="C0", marker="o", markersize=3, label=label)
    lines += ax.plot(x, result.stress(other), color="C0", linestyle="--", linewidth=0.8,
                     label=_MEASURE_LABEL[other].format(component))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"stress, {label} [MPa]")
    right = ax.twinx()
    lines += right.plot(x, result.recruited_fraction, color="C2", linewidth=1.0, label="recruited")
    lines += right.plot(x, result.yielded_fraction, color="C3", linewidth=1.0, label="yielded")
    right.set_ylim(-0.04, 1.04)  # fractions at 0 or 1 stay off the spines
    right.set_ylabel("fraction of fiber volume")
    fig.legend(handles=lines, loc="outside lower center", ncols=4, fontsize="small")
    ax.set_title(_test_label(result.config))
    return save_figure(fig, path, dpi)


def plot_deformed(network: Network, record: StepRecord, path: str | Path, *,
                  outline: bool = True, linewidth: float = 0.6, cmap: str = "viridis",
                  dpi: float = 200.0) -> Path:
    """Draw the deformed network, elements coloured by their stress t [MPa].

    Elements are drawn as straight lines between their nodes at ``record.positions``
    (relative to the RVE centre), the most stressed on top. Beside the whole RVE, a window at
    its centre (a sixth of the side, at least 20 D) is drawn magnified when it is at most
    half the side, so that single fibers and cross-links can be seen in a large RVE. The
    colour range spans the 1st to 99th percentile of the stresses (the colour bar extends
    beyond it).

    Parameters
    ----------
    network
        The network (reference state; gives the elements).
    record
        The step to draw.
    path
        Output file; the format follows the suffix (``.png`` by default).
    outline
        Also draw the reference square [-L/2, L/2]^2 (dashed) and its image F X (solid),
        on which the border nodes lie.
    linewidth : float [pt]
        Line width of the elements in the window and, up to 20,000 elements, in the whole
        view (thinner beyond, as 1 / sqrt(elements)); the window's are 2.5 times wider.
    cmap
        Matplotlib colormap of the stress.
    dpi
        Resolution of raster output.

    Returns
    -------
    Path
        The written file.
    """
    order = np.argsort(record.stress, kind="stable")
    segments = record.positions[network.element_nodes[order]]
    stress = record.stress[order]
    low, high = np.percentile(stress, [1.0, 99.0]) if stress.size else (0.0, 1.0)
    norm = Normalize(vmin=low, vmax=high if high > low else low + 1.0)
    window = max(network.size / 6.0, 20.0 * network.thickness)
    zoom = window <= network.size / 2.0
    fig = Figure(figsize=(12.5, 6.5) if zoom else (7.5, 6.5), layout="constrained")
    axes = fig.subplots(1, 2) if zoom else [fig.add_subplot()]
    # Thinner lines in the whole view of a large network, so that it does not fill solid.
    whole_width = linewidth * min(1.0, float(np.sqrt(2.0e4 / max(len(stress), 1))))
    for ax, width in zip(axes, (whole_width, 2.5 * linewidth)):
        lc = LineCollection(segments, linewidths=width, cmap=cmap, norm=norm, capstyle="round")
        lc.set_array(stress)
        ax.add_collection(lc)
        ax.set_aspect("equal")
        ax.set_xlabel("x [µm]")
        ax.set_ylabel("y [µm]")
    whole = axes[0]
    if outline:
        half = network.size / 2.0
        square = half * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        whole.add_patch(Polygon(square, closed=True, fill=False, edgecolor="0.5", linestyle="--",
                                linewidth=0.8, zorder=3, label="reference RVE"))
        whole.add_patch(Polygon(square @ record.F.T, closed=True, fill=False, edgecolor="k",
                                linewidth=0.8, zorder=3, label="deformed RVE (F X)"))
    whole.autoscale_view()
    whole.set_title(f"step {record.index}: strain {100.0 * record.strain:.3g} %, t = {record.time:.4g} s")
    if zoom:
        h = window / 2.0
        whole.add_patch(Polygon(h * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]), closed=True,
                                fill=False, edgecolor="C3", linewidth=1.5, zorder=3, label="magnified window"))
        axes[1].set_xlim(-h, h)
        axes[1].set_ylim(-h, h)
        axes[1].set_title(f"centre window, {window:.3g} µm wide")
        for spine in axes[1].spines.values():
            spine.set_edgecolor("C3")
    if outline or zoom:
        fig.legend(loc="outside lower center", ncols=3, fontsize="small")
    fig.colorbar(whole.collections[0], ax=axes, label="element stress $t$ [MPa]", shrink=0.85, extend="both")
    return save_figure(fig, path, dpi)
