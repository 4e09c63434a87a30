"""Figures of a loading program: the stress-strain curve and the deformed network.

Built with ``matplotlib.figure.Figure`` and the Agg canvas (no pyplot global state), written
atomically. Stress in MPa, strain in %, lengths in um.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from espin.core.config import Config, PoissonLateral
from espin.core.figures import save_figure

if TYPE_CHECKING:  # pragma: no cover
    from espin.geometry.network import Network
    from espin.mechanics.driver import SimulationResult, StepRecord

__all__ = ["plot_curve", "plot_deformed"]

_MEASURE_LABEL = {"nominal": "nominal P'{}", "paper": "paper Eq. 17 sigma'{}"}
_STRAIN_LABEL = {
    "uniaxial": "strain F'11 - 1 [%]",
    "equibiaxial": "stretch - 1 [%]",
    "pure_shear": "stretch F'11 - 1 [%]",
    "simple_shear": "shear gamma [%]",
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
            text += f", lateral nu = {lateral.poisson_ratio:g}"
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
    right.set_ylim(0.0, 1.0)
    right.set_ylabel("fraction of fiber volume")
    fig.legend(handles=lines, loc="outside lower center", ncols=4, fontsize="small")
    ax.set_title(_test_label(result.config))
    return save_figure(fig, path, dpi)


def plot_deformed(network: Network, record: StepRecord, path: str | Path, *,
                  outline: bool = True, linewidth: float = 0.6, cmap: str = "viridis",
                  dpi: float = 200.0) -> Path:
    """Draw the deformed network, elements coloured by their stress t [MPa].

    Elements are drawn as straight lines between their nodes at ``record.positions``
    (relative to the RVE centre), the most stressed on top.

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
        Line width of every element.
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
    fig = Figure(figsize=(7.5, 6.5), layout="constrained")
    ax = fig.add_subplot()
    lc = LineCollection(segments, linewidths=linewidth, cmap=cmap, capstyle="round")
    lc.set_array(record.stress[order])
    ax.add_collection(lc)
    if outline:
        half = network.size / 2.0
        square = half * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        ax.add_patch(Polygon(square, closed=True, fill=False, edgecolor="0.5", linestyle="--",
                             linewidth=0.8, label="reference RVE"))
        ax.add_patch(Polygon(square @ record.F.T, closed=True, fill=False, edgecolor="k",
                             linewidth=0.8, label="deformed RVE (F X)"))
        fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x [um]")
    ax.set_ylabel("y [um]")
    ax.set_title(f"step {record.index}: strain {100.0 * record.strain:.3g} %, t = {record.time:.4g} s")
    fig.colorbar(lc, ax=ax, label="element stress t [MPa]", shrink=0.85)
    return save_figure(fig, path, dpi)
