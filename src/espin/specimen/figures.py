"""Figures of a specimen test: the deformed specimen coloured by a field, and its force curve."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from espin.core.figures import save_figure
from espin.specimen.solver import SpecimenStep

__all__ = ["plot_deformed", "plot_force", "FIELD_LABELS"]

FIELD_LABELS = {
    "P11": "nominal stress $P_{11}$ [MPa]",
    "E11": "Green-Lagrange strain $E_{11}$",
    "E22": "Green-Lagrange strain $E_{22}$",
    "yielded_fraction": "yielded fiber fraction",
    "recruited_fraction": "recruited fiber fraction",
}
"""Axis label of each field the figures colour by."""


def plot_deformed(
    mesh,
    u: np.ndarray,
    dofs: tuple[np.ndarray, np.ndarray],
    values: np.ndarray,
    field: str,
    path: str | Path,
    title: str,
) -> Path:
    """The specimen at displacement ``u`` [mm] (true scale), each element coloured by its
    ``values`` of ``field``; the undeformed outline in grey."""
    cells = mesh.t.T
    reference = mesh.p.T
    moved = reference + np.column_stack([u[dofs[0]], u[dofs[1]]])
    fig = Figure(figsize=(8.0, 3.6), layout="constrained")
    ax = fig.add_subplot()
    ax.add_collection(PolyCollection(reference[cells], facecolors="none", edgecolors="0.75", linewidths=0.4))
    polygons = PolyCollection(moved[cells], array=values, cmap="viridis", edgecolors="face", linewidths=0.2)
    ax.add_collection(polygons)
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm] (loading axis)")
    ax.set_ylabel("y [mm]")
    ax.set_title(title, fontsize=10)
    fig.colorbar(polygons, ax=ax, label=FIELD_LABELS.get(field, field), shrink=0.8)
    return save_figure(fig, path, dpi=150)


def plot_force(
    steps: Sequence[SpecimenStep],
    path: str | Path,
    title: str,
    others: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
    gauge_others: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> Path:
    """Grip force against grip displacement (left) and the gauge section's engineering stress
    against its strain (right); ``others`` / ``gauge_others``: labelled (x, y) curves to compare."""
    fig = Figure(figsize=(10.0, 4.0), layout="constrained")
    left, right = fig.subplots(1, 2)
    d = np.array([s.displacement_mm for s in steps])
    force = np.array([s.force_N for s in steps])
    left.plot(d, force, "o-", ms=3, color="C0", label="specimen")
    for k, (label, (x, y)) in enumerate((others or {}).items()):
        left.plot(x, y, "--", color=f"C{k + 1}", label=label)
    left.set_xlabel("grip displacement [mm]")
    left.set_ylabel("grip force [N]")
    left.set_title("force-displacement", fontsize=10)
    right.plot(
        [100.0 * s.gauge_strain for s in steps],
        [s.gauge_stress_MPa for s in steps],
        "o-",
        ms=3,
        color="C0",
        label="gauge section",
    )
    for k, (label, (x, y)) in enumerate((gauge_others or {}).items()):
        right.plot(100.0 * np.asarray(x), y, "--", color=f"C{k + 1}", label=label)
    right.set_xlabel("gauge engineering strain [%]")
    right.set_ylabel("force / (gauge width x thickness) [MPa]")
    right.set_title("gauge section", fontsize=10)
    for ax in (left, right):
        ax.grid(alpha=0.3)
        if min(line.get_ydata().min() for line in ax.get_lines()) >= 0.0:
            ax.set_ylim(bottom=0.0)  # a tensile test: from the origin (a compressive one keeps its axis)
        ax.set_xlim(left=0.0)
        if len(ax.get_legend_handles_labels()[0]) > 1:
            ax.legend(fontsize=8, loc="lower right")
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path, dpi=150)
