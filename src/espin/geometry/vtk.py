"""VTK exports (.vtu, unstructured grids of line cells) for ParaView, through meshio.

Every file is centred on the RVE: points are (x - L/2, y - L/2, z) [um], so the deposited
fibers, the network and every step of a tensile test overlay in ParaView.
"""

from __future__ import annotations

import re
from pathlib import Path

import meshio
import numpy as np

from espin.core.atomic import atomic_write, atomic_write_bytes
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network

__all__ = ["write_mat_vtu", "write_network_vtu", "write_collection"]


def _write(
    path: Path,
    points: np.ndarray,
    lines: np.ndarray,
    cell_data: dict[str, np.ndarray],
    point_data: dict[str, np.ndarray] | None = None,
    field_data: dict[str, float] | None = None,
) -> Path:
    mesh = meshio.Mesh(
        points, [("line", lines)], point_data=point_data or {}, cell_data={k: [v] for k, v in cell_data.items()}
    )

    def write(tmp: Path) -> None:
        meshio.write(tmp, mesh, file_format="vtu")
        if field_data:
            _add_field_data(tmp, field_data)

    return atomic_write(path, write)


def _add_field_data(path: Path, values: dict[str, float]) -> None:
    """Insert VTK FieldData (one float64 per name, e.g. the step's time and strain) as the
    first child of the UnstructuredGrid element of a .vtu that meshio wrote (meshio does not
    write field data to .vtu).

    Raises
    ------
    ValueError
        If the file has no UnstructuredGrid element (another writer's layout).
    """
    arrays = "".join(
        f'<DataArray type="Float64" Name="{name}" NumberOfTuples="1" format="ascii">{float(value)!r}</DataArray>\n'
        for name, value in values.items()
    )
    text = path.read_text(encoding="utf-8")
    grid = re.search(r"<UnstructuredGrid\b[^>]*>", text)
    if grid is None:
        raise ValueError(f"{path}: no <UnstructuredGrid> element to add field data to")
    path.write_text(f"{text[: grid.end()]}\n<FieldData>\n{arrays}</FieldData>{text[grid.end() :]}", encoding="utf-8")


def write_mat_vtu(mat: FiberMat, path: str | Path) -> Path:
    """Write the deposited fibers: one line cell per segment, at its layer's height.

    Points are (x - L/2, y - L/2, z) [um] with z = (k + 1/2) D for layer k. Cell data:
    ``layer``, ``fiber``, ``tortuosity`` (of the whole fiber), ``diameter_um``.
    """
    fiber = mat.segment_fiber
    z = (mat.fiber_layer[np.repeat(np.arange(mat.n_fibers), np.diff(mat.fiber_offsets))] + 0.5) * mat.thickness
    points = np.c_[mat.vertices - mat.size / 2.0, z]
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
    displacement: np.ndarray | None = None,
    cell_data: dict[str, np.ndarray] | None = None,
    field_data: dict[str, float] | None = None,
) -> Path:
    """Write the network: one line cell per element, nodes at z = 0, centred on the RVE.

    Parameters
    ----------
    network
        The network.
    path
        Destination ``.vtu`` file.
    displacement : (n_nodes, 2) float64 [um], optional
        Node displacements of a deformed state: written as point data ``displacement_um``
        (3 components, z = 0) on the reference points, so that ParaView's Warp By Vector
        draws the deformed network (any scale factor exaggerates it); with it, the cell data
        ``chord_strain`` (deformed over reference end-to-end length, minus 1).
    cell_data
        Extra per-element arrays (n_elements,), e.g. fiber stress.
    field_data
        Scalars of the whole file (e.g. ``time_s``, ``strain`` of a step), as VTK field data.

    Cell data always include ``layer``, ``fiber``, ``tortuosity`` (element lambda_r) and
    ``diameter_um``. Nodes are shared by adjacent layers, so all sit at z = 0.
    """
    data = {
        "layer": network.element_layer.astype(np.int32),
        "fiber": network.element_fiber.astype(np.int32),
        "tortuosity": network.element_tortuosity,
        "diameter_um": network.element_diameter,
    }
    point_data = None
    if displacement is not None:
        u = np.asarray(displacement, dtype=float)
        point_data = {"displacement_um": np.c_[u, np.zeros(len(u))]}
        e1, e2 = network.element_nodes.T
        deformed = np.hypot(*(network.element_vector + u[e2] - u[e1]).T)
        data["chord_strain"] = deformed / network.element_length - 1.0
    data.update(cell_data or {})
    points = np.c_[network.node_position - network.centre, np.zeros(network.n_nodes)]
    return _write(Path(path), points, network.element_nodes, data, point_data, field_data)


def write_collection(path: str | Path, steps: list[tuple[float, str]]) -> Path:
    """Write a ParaView collection (``.pvd``) indexing ``.vtu`` files by time.

    Parameters
    ----------
    path
        The ``.pvd`` file (written atomically).
    steps
        (time [s], file path relative to the ``.pvd``) of every step, in order.
    """
    datasets = "".join(
        f'    <DataSet timestep="{float(time)!r}" group="" part="0" file="{file}"/>\n' for time, file in steps
    )
    text = (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        f"  <Collection>\n{datasets}  </Collection>\n</VTKFile>\n"
    )
    return atomic_write_bytes(path, text.encode("utf-8"))
