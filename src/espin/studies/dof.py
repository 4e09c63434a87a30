"""Degrees of freedom of espin's network model against a beam finite-element model (paper 4.3).

espin's reduced kinematics give each inner node (cross-link) two in-plane DOF and nothing else
(docs/model.md section 2): ``Network.n_dof = 2 * n_inner``. The usual model of a fiber network (Zündel et al.,
the paper's ref. 23) meshes every fiber with 3-D beam elements, whose nodes carry three
translations and three rotations. For the same geometry such a model needs (docs/model.md section 7):

* a node at every deposition vertex (the fiber's polyline has a corner there) and at every
  cross-link (shared by the two fibers it joins);
* ``elements_per_segment`` beam elements on every piece of fiber between two consecutive such
  nodes, i.e. ``elements_per_segment - 1`` interior nodes per piece;
* 6 DOF per node.

Counting rules, the same for both models:

* Nodes whose positions are prescribed, the fiber ends on the RVE border, are not counted
  (espin's border nodes follow x = F X; a beam model with affine boundary conditions fixes them
  too). Were the beam ends' rotations left free, the beam model would gain 3 DOF per border
  node, a term linear in the RVE size.
* Cross-links are the network's inner nodes after merging (cross-links closer than the merge
  tolerance along a fiber are one node in both models); a deposition vertex within the merge
  tolerance of a cross-link or a fiber end along its fiber is that node, not a new one.

Default ``elements_per_segment = 1``: one two-node (cubic, Hermite) beam element per piece,
which is exact for a straight beam loaded at its ends, so this is the smallest beam model of
the geometry and the reported ratio is a lower bound. Models that resolve bending between
cross-links use a few elements per piece; the paper's "over 10x" used Zündel's parameters and
meshes, which are not available (docs/model.md section 7), so espin reports the ratio that results from this
count and lets the user choose ``elements_per_segment``.

For a fixed number of layers the DOF of both models grow as the square of the RVE size L_tilde
(paper Fig. 14): the fiber length per layer grows as L^2, so do the cross-links (integral
geometry, docs/model.md section 2) and the vertices, while the border nodes grow only as L.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.polynomial import Polynomial

from espin.core.config import Config
from espin.core.errors import ConfigError
from espin.geometry.crosslinks import Crosslinks
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network

__all__ = ["DofCount", "count_dof", "dof_study", "dof_fit", "dof_fit_table", "plot_dof_study"]

BEAM_DOF_PER_NODE = 6
"""Three translations and three rotations per node of a 3-D beam model."""


@dataclass(frozen=True)
class DofCount:
    """DOF of espin's model and of a beam model of the same geometry (module docs).

    Attributes
    ----------
    espin_dof : int
        2 per inner node of the network.
    beam_nodes : int
        Free nodes of the beam model: interior deposition vertices, cross-links and interior
        nodes of the elements.
    beam_dof : int
        6 per free beam node.
    beam_pieces : int
        Pieces of fiber between consecutive beam nodes (vertices, cross-links, fiber ends).
    elements_per_segment : int
        Beam elements per piece.
    """

    espin_dof: int
    beam_nodes: int
    beam_dof: int
    beam_pieces: int
    elements_per_segment: int

    @property
    def ratio(self) -> float:
        """beam_dof / espin_dof."""
        return self.beam_dof / self.espin_dof if self.espin_dof else float("nan")


def _vertices_on_nodes(mat: FiberMat, crosslinks: Crosslinks, tolerance: float) -> tuple[int, int]:
    """Interior deposition vertices, and how many of them lie on a cross-link or fiber end.

    "On" means within ``tolerance`` [um] along the fiber.
    """
    n_fibers = mat.n_fibers
    per_fiber = np.diff(mat.fiber_offsets)
    fiber_of_vertex = np.repeat(np.arange(n_fibers), per_fiber)
    interior = np.ones(len(mat.vertices), dtype=bool)
    interior[mat.fiber_offsets[:-1]] = interior[mat.fiber_offsets[1:] - 1] = False
    vertex = np.flatnonzero(interior)
    fiber = fiber_of_vertex[vertex]
    arc = mat.segment_arc_start[vertex - fiber]  # segment starting at each interior vertex
    # Node positions along the fibers: cross-link ends and both fiber ends.
    node_fiber = np.concatenate([crosslinks.fiber.ravel(), np.arange(n_fibers), np.arange(n_fibers)])
    node_arc = np.concatenate([crosslinks.arc.ravel(), np.zeros(n_fibers), mat.contour_length])
    span = float(mat.contour_length.max(initial=0.0)) + 4.0 * tolerance + 1.0
    node_key = np.sort(node_fiber * span + node_arc)
    key = fiber * span + arc
    right = np.clip(np.searchsorted(node_key, key), 0, len(node_key) - 1)
    left = np.clip(right - 1, 0, len(node_key) - 1)
    nearest = np.minimum(np.abs(node_key[right] - key), np.abs(node_key[left] - key))
    return len(vertex), int(np.count_nonzero(nearest < tolerance))


def count_dof(mat: FiberMat, crosslinks: Crosslinks, network: Network, elements_per_segment: int = 1) -> DofCount:
    """Count the DOF of espin's network and of a beam model of the same mat (paper 4.3).

    Parameters
    ----------
    mat, crosslinks, network
        One RVE's deposited fibers, cross-links and network (``espin.geometry.rve.RVE`` attributes).
    elements_per_segment
        Beam elements per piece of fiber between consecutive beam nodes (>= 1).

    Returns
    -------
    DofCount
    """
    if elements_per_segment < 1:
        raise ConfigError(f"elements_per_segment must be an integer >= 1, got {elements_per_segment}")
    n_interior, on_nodes = _vertices_on_nodes(mat, crosslinks, network.merge_tolerance)
    corner_nodes = n_interior - on_nodes
    # Every vertex that is not already a node cuts one network element into two pieces.
    pieces = network.n_elements + corner_nodes
    nodes = corner_nodes + network.n_inner + (elements_per_segment - 1) * pieces
    return DofCount(
        espin_dof=network.n_dof,
        beam_nodes=nodes,
        beam_dof=BEAM_DOF_PER_NODE * nodes,
        beam_pieces=pieces,
        elements_per_segment=elements_per_segment,
    )


def _as_tuple(values: int | float | Iterable) -> tuple:
    return tuple(values) if isinstance(values, Iterable) else (values,)


def dof_study(
    size_ratios: Iterable[float],
    layers: int | Iterable[int],
    *,
    base: Config | str = "plla",
    seeds: Iterable[int] = (1,),
    elements_per_segment: int = 1,
) -> pd.DataFrame:
    """DOF of espin's model and of a beam model versus RVE size (paper 4.3, Fig. 14).

    One RVE is generated per (size ratio, layers, seed); all configurations are validated
    before the first one is generated.

    Parameters
    ----------
    size_ratios
        RVE sides L_tilde = L / D.
    layers
        Number(s) of layers N_l.
    base
        Config, preset or TOML config the other keys come from.
    seeds
        Random seeds; one realization each.
    elements_per_segment
        Beam elements per piece of fiber (module docs), >= 1.

    Returns
    -------
    pandas.DataFrame
        One row per RVE: size_ratio, layers, seed, n_fibers, n_crosslinks (inner nodes after
        merging), espin_dof, beam_dof, ratio (beam / espin).
    """
    from espin.geometry.rve import generate, resolve_config

    if elements_per_segment < 1:
        raise ConfigError(f"elements_per_segment must be an integer >= 1, got {elements_per_segment}")
    cases = list(itertools.product(_as_tuple(size_ratios), _as_tuple(layers), _as_tuple(seeds)))
    configs = [resolve_config(base, **{"rve.size_ratio": s, "rve.layers": n, "rve.seed": seed}) for s, n, seed in cases]
    rows = []
    for (size_ratio, n_layers, seed), config in zip(cases, configs):
        rve = generate(config, allow_large=True)  # only generated: the tensile test's memory is not needed
        count = count_dof(rve.mat, rve.crosslinks, rve.network, elements_per_segment)
        rows.append(
            {
                "size_ratio": float(size_ratio),
                "layers": int(n_layers),
                "seed": int(seed),
                "n_fibers": rve.mat.n_fibers,
                "n_crosslinks": rve.network.n_inner,
                "espin_dof": count.espin_dof,
                "beam_dof": count.beam_dof,
                "ratio": count.ratio,
            }
        )
    return pd.DataFrame(rows)


def dof_fit(table: pd.DataFrame, column: str = "espin_dof", layers: int | None = None) -> Polynomial:
    """Least-squares quadratic of a DOF column versus L_tilde (paper Fig. 14), every seed a point.

    Parameters
    ----------
    table
        A :func:`dof_study` table.
    column
        ``"espin_dof"`` or ``"beam_dof"``.
    layers
        The N_l to fit; may be None only when the table has one.

    Returns
    -------
    numpy.polynomial.Polynomial
        In the standard basis: ``fit.coef`` = (c0, c1, c2) with DOF = c0 + c1 L + c2 L^2.
    """
    if layers is None:
        choices = table["layers"].unique()
        if len(choices) != 1:
            raise ConfigError(f"the table has several numbers of layers {sorted(choices)}: choose one with layers=")
        layers = int(choices[0])
    rows = table[table["layers"] == layers]
    if rows["size_ratio"].nunique() < 3:
        raise ConfigError("a quadratic fit needs at least 3 distinct size ratios")
    return Polynomial.fit(rows["size_ratio"], rows[column], 2).convert()


def dof_fit_table(table: pd.DataFrame) -> pd.DataFrame:
    """Quadratic fits DOF = c0 + c1 L + c2 L^2 of both models, one row per (layers, model).

    Numbers of layers with fewer than 3 distinct size ratios are left out (no quadratic fit).
    """
    rows = []
    for n_layers, group in table.groupby("layers"):
        if group["size_ratio"].nunique() < 3:
            continue
        for column in ("espin_dof", "beam_dof"):
            c0, c1, c2 = dof_fit(group, column, int(n_layers)).coef
            rows.append({"layers": int(n_layers), "model": column.removesuffix("_dof"), "c0": c0, "c1": c1, "c2": c2})
    return pd.DataFrame(rows, columns=["layers", "model", "c0", "c1", "c2"])


def plot_dof_study(table: pd.DataFrame, path: str | Path, *, dpi: float = 150.0) -> Path:
    """Fig. 14-like figure: both models' DOF versus L_tilde with their quadratic fits (top), the
    ratio beam / espin (bottom); one colour per number of layers, seeds averaged (error bars:
    sample sd over the seeds, their number n in the title).

    Returns
    -------
    Path
        The written image (format from the suffix).
    """
    from matplotlib.figure import Figure

    from espin.core.figures import save_figure

    fig = Figure(figsize=(6.0, 7.0), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(2, 1))
    palette = ["C0", "C1", "C2", "C3", "C4", "C5"]
    for k, (n_layers, rows) in enumerate(table.groupby("layers")):
        colour = palette[k % len(palette)]
        stats = rows.groupby("size_ratio").agg(["mean", "std"])
        sizes = stats.index.to_numpy(dtype=float)
        smooth = np.linspace(0.0, sizes.max(), 200)
        for column, marker, label in (("espin_dof", "o", "espin"), ("beam_dof", "s", "beam FE")):
            top.errorbar(
                sizes,
                stats[column]["mean"],
                yerr=stats[column]["std"].fillna(0.0),
                fmt=marker,
                color=colour,
                mfc="none" if column == "beam_dof" else colour,
                label=f"{label}, $N_l$ = {n_layers}",
            )
            if len(sizes) >= 3:
                top.plot(
                    smooth,
                    dof_fit(rows, column, n_layers)(smooth),
                    color=colour,
                    ls="-" if column == "espin_dof" else "--",
                    lw=1,
                )
        bottom.errorbar(
            sizes,
            stats["ratio"]["mean"],
            yerr=stats["ratio"]["std"].fillna(0.0),
            fmt="o-",
            color=colour,
            label=f"$N_l$ = {n_layers}",
        )
    top.set_ylabel("degrees of freedom")
    top.ticklabel_format(axis="y", style="sci", scilimits=(0, 0))
    top.legend(fontsize="small")
    seeds = table.groupby(["layers", "size_ratio"]).size()
    n = f"{seeds.min()}" if seeds.min() == seeds.max() else f"{seeds.min()}-{seeds.max()}"
    fig.suptitle(f"DOF versus RVE size (mean ± sd, n = {n} seeds; lines: quadratic fits)", fontsize="medium")
    bottom.set_xlabel(r"RVE size $\tilde L = L / D$")
    bottom.set_ylabel("beam DOF / espin DOF")
    bottom.set_ylim(bottom=0.0)
    if table["layers"].nunique() > 1:
        bottom.legend(fontsize="small")
    return save_figure(fig, path, dpi)
