"""Figures of a loading program: the stress-strain curve and the deformed network.

Built with ``matplotlib.figure.Figure`` and the Agg canvas (no pyplot global state), written
atomically. Stress in MPa, strain in %, lengths in um.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from espin.core.config import Config, PoissonLateral, StressLateral
from espin.core.figures import save_figure

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.lines import Line2D

    from espin.geometry.network import Network
    from espin.mechanics.driver import SimulationResult, StepRecord

__all__ = ["CurveMarks", "draw_marks", "mark_labels", "plot_curve", "plot_deformed"]


class CurveMarks(Protocol):
    """A bilinear description of a curve to mark on it: the elastic line, the yield point and
    the post-yield line (:class:`espin.analysis.properties.CurveProperties` is one; the fit
    lives in the analysis stage, above mechanics, so the caller computes it).

    Strains dimensionless (0.01 = 1 %), stresses and slopes in MPa; the yield strain is
    measured from ``strain_offset``, where the elastic line crosses zero stress.
    """

    @property
    def modulus_MPa(self) -> float: ...
    @property
    def strain_offset(self) -> float: ...
    @property
    def has_yield(self) -> bool: ...
    @property
    def yield_strain(self) -> float: ...
    @property
    def yield_stress_MPa(self) -> float: ...
    @property
    def post_yield_modulus_MPa(self) -> float: ...


_MARK_SYMBOLS = {
    "uniaxial": ("$E$", r"$\sigma_y$", "$H$"),
    "simple_shear": ("$G$", r"$\tau_y$", "post-yield slope"),
}
_SLOPE_SYMBOLS = ("initial slope", "yield", "post-yield slope")


def mark_labels(marks: CurveMarks, test: str = "uniaxial") -> tuple[str, str | None, str | None]:
    """Legend labels of the marks: elastic line, yield point and post-yield line (None without
    a yield), e.g. ``"$E$ = 211 MPa"``, ``"$\\sigma_y$ = 6.2 MPa at 3.0 %"``, ``"$H$ = 12 MPa"``.

    Parameters
    ----------
    marks
        The bilinear description.
    test
        The kind of test: E, sigma_y and H name the uniaxial quantities (docs/model.md), G and
        tau_y those of simple shear; other tests' slopes are named in words.

    Returns
    -------
    tuple of str, str or None, str or None
        Stresses and slopes in MPa, the yield strain in % (from ``strain_offset``).
    """
    slope, point, post = _MARK_SYMBOLS.get(test, _SLOPE_SYMBOLS)
    elastic = f"{slope} = {marks.modulus_MPa:.3g} MPa"
    if not marks.has_yield:
        return elastic, None, None
    return (
        elastic,
        f"{point} = {marks.yield_stress_MPa:.3g} MPa at {100.0 * marks.yield_strain:.3g} %",
        f"{post} = {marks.post_yield_modulus_MPa:.3g} MPa",
    )


def draw_marks(
    ax: Axes, marks: CurveMarks, strain_end: float, *, test: str = "uniaxial", color: str = "k", labelled: bool = True
) -> list[Line2D]:
    """Draw the marks on a stress [MPa] versus strain [%] axes; return the drawn artists.

    The elastic line (dashed) runs from its zero-stress strain to 1.2 times the yield strain
    (to ``strain_end`` without a yield), the post-yield line (dotted) from the yield point to
    ``strain_end``; the yield point is an open circle. Nothing is drawn where the elastic
    line is undefined (NaN offset of a constant stress).

    Parameters
    ----------
    ax
        Axes with strain in % on x and stress in MPa on y.
    marks
        The bilinear description.
    strain_end : float
        Largest strain of the curve (dimensionless).
    test
        The kind of test, for the labels (:func:`mark_labels`).
    color
        Colour of the marks.
    labelled
        Give the artists their legend labels.
    """
    labels = mark_labels(marks, test) if labelled else (None, None, None)
    e0, modulus = marks.strain_offset, marks.modulus_MPa
    if not (np.isfinite(e0) and np.isfinite(modulus)):
        return []
    e_elastic = min(e0 + 1.2 * marks.yield_strain, strain_end) if marks.has_yield else strain_end
    e = np.array([e0, max(e_elastic, e0)])
    artists = ax.plot(100.0 * e, modulus * (e - e0), color=color, ls="--", lw=1.0, label=labels[0])
    if marks.has_yield:
        e_y = e0 + marks.yield_strain
        e = np.array([e_y, max(strain_end, e_y)])
        artists += ax.plot(
            100.0 * e_y, marks.yield_stress_MPa, "o", color=color, mfc="none", ms=8, mew=1.5, zorder=5, label=labels[1]
        )
        artists += ax.plot(
            100.0 * e,
            marks.yield_stress_MPa + marks.post_yield_modulus_MPa * (e - e_y),
            color=color,
            ls=":",
            lw=1.2,
            label=labels[2],
        )
    return artists


_MEASURE_LABEL = {
    "nominal": "nominal $P'_{{{}}}$",
    "paper": "paper Eq. 17 $\\sigma'_{{{}}}$",
    "kirchhoff": "Kirchhoff $\\tau'_{{{}}}$",
}
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
        elif isinstance(lateral, StressLateral):
            text += f", lateral stress {lateral.stress_MPa:g} MPa ({config.output.stress_measure})"
        else:
            text += f", lateral from {lateral.transverse_csv.name}"
    return text


def plot_curve(
    result: SimulationResult,
    path: str | Path,
    measure: str | None = None,
    *,
    marks: CurveMarks | None = None,
    dpi: float = 150.0,
) -> Path:
    """Draw the stress-strain curve with the recruited and yielded fractions.

    Left axis: the curve's stress [MPa] in the loading frame (P'11, or P'12 for simple shear)
    in ``measure``, and the other measure (nominal P or the paper's Eq. 17) as a thin
    dash-dotted line; with ``marks``, the elastic line, the yield point and the post-yield line of the
    curve's bilinear fit (:func:`draw_marks`), their values in the legend (E, sigma_y, H). Right
    axis: volume fractions of recruited and yielded elements, 0 to 1. The x axis is the
    program's strain [%] (time [s] for a ``path`` test, which gets no marks). The legend sits
    below the axes.

    Parameters
    ----------
    result
        The recorded loading program.
    path
        Output file; the format follows the suffix (``.png`` by default).
    measure
        ``"nominal"``, ``"paper"`` or ``"kirchhoff"``; default ``output.stress_measure``.
    marks
        Bilinear fit of the curve in ``measure`` (e.g.
        :func:`espin.analysis.properties.simulation_properties`); None: no marks.
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
    lines += ax.plot(
        x,
        result.stress(other),
        color="C0",
        linestyle="-.",
        linewidth=0.8,
        label=_MEASURE_LABEL[other].format(component),
    )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"stress, {label} [MPa]")
    right = ax.twinx()
    lines += right.plot(x, result.recruited_fraction, color="C2", linewidth=1.0, label="recruited")
    lines += right.plot(x, result.yielded_fraction, color="C3", linewidth=1.0, label="yielded")
    right.set_ylim(-0.04, 1.04)  # fractions at 0 or 1 stay off the spines
    right.set_ylabel("fraction of fiber volume")
    if marks is not None and test != "path":
        lines += draw_marks(ax, marks, float(result.strain[-1]), test=test)
    fig.legend(handles=lines, loc="outside lower center", ncols=4, fontsize="small")
    ax.set_title(_test_label(result.config))
    return save_figure(fig, path, dpi)


def plot_deformed(
    network: Network,
    record: StepRecord,
    path: str | Path,
    *,
    outline: bool = True,
    linewidth: float = 0.6,
    cmap: str = "viridis",
    dpi: float = 200.0,
) -> Path:
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
        whole.add_patch(
            Polygon(
                square,
                closed=True,
                fill=False,
                edgecolor="0.5",
                linestyle="--",
                linewidth=0.8,
                zorder=3,
                label="reference RVE",
            )
        )
        whole.add_patch(
            Polygon(
                square @ record.F.T,
                closed=True,
                fill=False,
                edgecolor="k",
                linewidth=0.8,
                zorder=3,
                label=r"deformed RVE $\mathbf{F}\,X$",
            )
        )
    whole.autoscale_view()
    whole.set_title(f"step {record.index}: strain {100.0 * record.strain:.3g} %, time {record.time:.4g} s")
    if zoom:
        h = window / 2.0
        whole.add_patch(
            Polygon(
                h * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]),
                closed=True,
                fill=False,
                edgecolor="C3",
                linewidth=1.5,
                zorder=3,
                label="magnified window",
            )
        )
        axes[1].set_xlim(-h, h)
        axes[1].set_ylim(-h, h)
        axes[1].set_title(f"centre window, {window:.3g} µm wide")
        for spine in axes[1].spines.values():
            spine.set_edgecolor("C3")
    if outline or zoom:
        fig.legend(loc="outside lower center", ncols=3, fontsize="small")
    fig.colorbar(whole.collections[0], ax=axes, label="element stress $t$ [MPa]", shrink=0.85, extend="both")
    return save_figure(fig, path, dpi)
