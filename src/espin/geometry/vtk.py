"""VTK exports (.vtu, unstructured grids of line cells) for ParaView, through meshio."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from espin.core.atomic import atomic_write
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network

__all__ = ["write_mat_vtu", "write_network_vtu"]


def _write(path: Path, points: np.ndarray, lines: np.ndarray, cell_data: dict[str, np.ndarray]) -> Path:
    mesh = meshio.Mesh(points, [("line", lines)], cell_data={k: [v] for k, v in cell_data.items()})
    return atomic_write(path, lambda tmp: meshio.write(tmp, mesh, file_format="vtu"))


def write_mat_vtu(mat: FiberMat, path: str | Path) -> Path:
    """Write the deposited fibers: one line cell per segment, at its layer's height.

    Points are (x, y, z) [um] with z = (k + 1/2) D for layer k. Cell data: ``layer``,
    ``fiber``, ``tortuosity`` (of the whole fiber), ``diameter_um``.
    """
    fiber = mat.segment_fiber
    z = (mat.fiber_layer[np.repeat(np.arange(mat.n_fibers), np.diff(mat.fiber_offsets))] + 0.5) * mat.thickness
    points = np.c_[mat.vertices, z]
    lines = np.c_[mat.segment_start, mat.segment_start + 1]
    return _write(
        Path(path),
        points,
        lines,
        {
            "layer": mat.fiber_layer[fiber].astype(np.int32),
            "fiber": fiber.astype(np.int32),
            "tortuosity": mat.tortuosity[fiber],
            "diameter_um": mat.fiber_diameter[fiber],
        },
    )


def write_network_vtu(
    network: Network,
    path: str | Path,
    positions: np.ndarray | None = None,
    cell_data: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write the network: one line cell per element, nodes at z = 0.

    Parameters
    ----------
    network
        The network.
    path
        Destination ``.vtu`` file.
    positions : (n_nodes, 2) float64 [um], optional
        Node positions to draw (e.g. deformed); default the reference positions.
    cell_data
        Extra per-element arrays (n_elements,), e.g. fiber stress.

    Cell data always include ``layer``, ``fiber``, ``tortuosity`` (element lambda_r) and
    ``diameter_um``; point data none. Nodes are shared by adjacent layers, so all sit at z = 0.
    """
    xy = network.node_position if positions is None else positions
    data = {
        "layer": network.element_layer.astype(np.int32),
        "fiber": network.element_fiber.astype(np.int32),
        "tortuosity": network.element_tortuosity,
        "diameter_um": network.element_diameter,
        **(cell_data or {}),
    }
    return _write(Path(path), np.c_[xy, np.zeros(len(xy))], network.element_nodes, data)
