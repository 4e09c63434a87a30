"""Checks of a specimen mesh before any work: what a user mesh must be, and whether a specimen fits
in memory.

A user mesh (:func:`espin.specimen.shapes.read_specimen`) is refused with a
:class:`~espin.core.errors.ConfigError` naming the file when its coordinates are not finite or
not those of a specimen (beyond :data:`MAX_COORDINATE_MM`, or no extent in x or y), when cells
repeat (the same nodes twice), overlap (an edge shared by more than two cells, or two cells on
the same side of an edge they share: a fold), or when the mesh is in several pieces (listed with
their cells and x-y ranges). Nodes closer than :data:`MERGE_FRACTION` of the shortest cell edge
are one node (an interface whose nodes coincide but were written twice), and the reader says how
many were merged.

A specimen's memory (:func:`check_memory`) is estimated from its elements and quadrature points
(and, for FE^2, the RVE at every point) and refused beyond the memory available, before the
mesh is built when the built-in shape's size says so.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from espin.core.errors import ConfigError

__all__ = [
    "MAX_COORDINATE_MM",
    "MERGE_FRACTION",
    "BYTES_PER_ELEMENT",
    "check_coordinates",
    "merge_nodes",
    "check_cells",
    "check_pieces",
    "inside_cells",
    "specimen_memory",
    "check_memory",
]

MAX_COORDINATE_MM = 1e4
"""Largest |coordinate| of a specimen mesh [mm] (10 m: a tensile specimen is mm to cm)."""
MERGE_FRACTION = 1e-6
"""Nodes closer than this fraction of the shortest cell edge are one node."""
BYTES_PER_ELEMENT = 16e3
"""Peak memory of a specimen run per element of the mesh, beyond the imported libraries [bytes]
(measured 14 kB on a holed strip of 7,700 quads: mesh, basis, tangent and its factorization)."""
BYTES_PER_POINT_DOF = 32.0
"""Memory of an RVE's state at a quadrature point per RVE degree of freedom [bytes] (node
positions, plastic stretches and their trial copies, as float64)."""


def check_coordinates(points: np.ndarray, where: str) -> None:
    """Refuse node coordinates (n, 2) [mm] that are not finite, beyond
    :data:`MAX_COORDINATE_MM`, or without extent in x or y."""
    bad = ~np.all(np.isfinite(points), axis=1)
    if np.any(bad):
        raise ConfigError(
            f"{where}: {np.count_nonzero(bad)} node(s) have non-finite coordinates (first: node "
            f"{int(np.flatnonzero(bad)[0])}); expected finite x, y in mm"
        )
    largest = float(np.abs(points).max()) if points.size else 0.0
    if largest > MAX_COORDINATE_MM:
        raise ConfigError(
            f"{where}: a coordinate of {largest:.3g} mm, beyond {MAX_COORDINATE_MM:g} mm; expected a "
            "specimen in mm (mm to cm)"
        )
    extent = np.ptp(points, axis=0) if points.size else np.zeros(2)
    if not np.all(extent > 0.0):
        raise ConfigError(
            f"{where}: the mesh has no extent in {'x' if extent[0] <= 0.0 else 'y'}; expected a 2-D "
            "specimen in the x-y plane"
        )


def _edges(t: np.ndarray) -> np.ndarray:
    """Directed edges (k, 2) of cells t (corners, n), cell by cell."""
    return np.stack([t, np.roll(t, -1, axis=0)], axis=-1).transpose(1, 0, 2).reshape(-1, 2)


def merge_nodes(p: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nodes p (2, n) of cells t (corners, m) with nodes closer than :data:`MERGE_FRACTION` of
    the shortest cell edge merged: the merged nodes (2, n') and each old node's new number (n,)."""
    edges = _edges(t)
    shortest = float(np.linalg.norm(p[:, edges[:, 0]] - p[:, edges[:, 1]], axis=0).min())
    pairs = cKDTree(p.T).query_pairs(MERGE_FRACTION * shortest, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(p.shape[1],) * 2)
    n, label = connected_components(graph, directed=False)
    merged = np.empty((2, n))
    merged[:, label] = p
    return merged, label


def _at(p: np.ndarray, t: np.ndarray, cell: int) -> str:
    x, y = p[:, t[:, cell]].mean(axis=1)
    return f"cell {cell} at ({x:.4g}, {y:.4g}) mm"


def check_cells(p: np.ndarray, t: np.ndarray, where: str) -> None:
    """Refuse repeated cells and overlapping ones (folds), given counter-clockwise cells t
    (corners, m) on nodes p (2, n).

    In a valid planar mesh each interior edge is shared by two cells that run along it in
    opposite directions; the same direction means the two cells lie on one side of it (a fold),
    and three or more cells on one edge overlap."""
    corners = np.sort(t, axis=0).T
    _, first, counts = np.unique(corners, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 1):
        cell = int(first[np.argmax(counts > 1)])
        raise ConfigError(
            f"{where}: {int(np.sum(counts[counts > 1] - 1))} cell(s) repeat another's nodes (first: "
            f"{_at(p, t, cell)}); expected each cell once"
        )
    directed = _edges(t)
    undirected, inverse, counts = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    if np.any(counts > 2):
        edge = int(np.flatnonzero(counts[inverse] > 2)[0])
        raise ConfigError(
            f"{where}: an edge is shared by {int(counts[inverse[edge]])} cells (at "
            f"{_at(p, t, edge // t.shape[0])}): cells overlap; expected a mesh without folds or layers"
        )
    forward = directed[:, 0] < directed[:, 1]
    along = np.zeros(len(undirected), dtype=int)
    np.add.at(along, inverse, np.where(forward, 1, -1))
    folded = (counts[inverse] == 2) & (np.abs(along[inverse]) == 2)
    if np.any(folded):
        n = int(np.count_nonzero(folded)) // 2
        raise ConfigError(
            f"{where}: the mesh folds over itself at {n} edge(s) (first at "
            f"{_at(p, t, int(np.flatnonzero(folded)[0]) // t.shape[0])}): two cells lie on the same "
            "side of an edge they share (cells overlap, or a cell is inverted); expected a planar mesh "
            "without overlaps"
        )


def check_pieces(p: np.ndarray, t: np.ndarray, where: str) -> None:
    """Refuse a mesh (nodes p (2, n), cells t (corners, m)) whose cells form more than one piece
    (connected through shared nodes), listing the pieces."""
    m = t.shape[1]
    rows = np.repeat(np.arange(m), t.shape[0])
    graph = coo_matrix((np.ones(rows.size), (rows, t.T.ravel())), shape=(m, p.shape[1])).tocsr()
    n, label = connected_components(graph @ graph.T, directed=False)
    if n == 1:
        return
    pieces = []
    for k in range(min(n, 4)):
        nodes = np.unique(t[:, label == k])
        lo, hi = p[:, nodes].min(axis=1), p[:, nodes].max(axis=1)
        pieces.append(
            f"{np.count_nonzero(label == k)} cells in x {lo[0]:.4g}..{hi[0]:.4g}, y {lo[1]:.4g}..{hi[1]:.4g} mm"
        )
    raise ConfigError(
        f"{where}: the mesh is in {n} pieces ({'; '.join(pieces)}{' ...' if n > 4 else ''}) that "
        "share no node; expected one piece (merge the nodes where the pieces meet, e.g. gmsh's "
        "Coherence)"
    )


def specimen_memory(n_elements: int, points_per_element: int, rve_dof: float = 0.0) -> float:
    """Estimated peak memory of a specimen run [bytes]: the libraries, the mesh's elements and,
    for FE^2, an RVE state of ``rve_dof`` degrees of freedom at each quadrature point plus one RVE
    solve."""
    from espin.geometry.size_estimate import BASE_BYTES, BYTES_PER_DOF

    points = n_elements * points_per_element
    return BASE_BYTES + n_elements * BYTES_PER_ELEMENT + rve_dof * (points * BYTES_PER_POINT_DOF + BYTES_PER_DOF)


def check_memory(
    what: str, n_elements: int, points_per_element: int, rve_dof: float = 0.0, available: int | None = None
) -> float:
    """Refuse a specimen whose :func:`specimen_memory` exceeds the memory available.

    Returns
    -------
    float
        The estimate [bytes].

    Raises
    ------
    ConfigError
        With the estimate, what it is made of, and what to change.
    """
    from espin.geometry.size_estimate import available_memory

    need = specimen_memory(n_elements, points_per_element, rve_dof)
    free = available_memory() if available is None else available
    if need > free:
        rve = (
            f" and an RVE of {rve_dof:,.0f} DOF at each of its {n_elements * points_per_element:,} quadrature points"
            if rve_dof
            else ""
        )
        raise ConfigError(
            f"{what}: about {n_elements:,.0f} elements{rve} need about {need / 2**30:.3g} GiB of "
            f"memory, {free / 2**30:.3g} GiB is available; use fewer elements (--elements-across)"
            + (", a smaller RVE or the surrogate model" if rve_dof else "")
        )
    return need


def inside_cells(p: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Whether each of ``points`` (k, 2) [mm] lies in a cell (counter-clockwise triangles or
    quads t (corners, m) on nodes p (2, n); on an edge counts as inside)."""
    triangles = t if t.shape[0] == 3 else np.hstack([t[[0, 1, 2]], t[[0, 2, 3]]])
    a, b, c = (p[:, triangles[i]] for i in range(3))
    size = float(np.ptp(p, axis=1).max())
    found = np.zeros(len(points), dtype=bool)
    for k, (x, y) in enumerate(points):
        q = np.array([[x], [y]])
        sides = [((v - u)[0] * (q - u)[1] - (v - u)[1] * (q - u)[0]) for u, v in ((a, b), (b, c), (c, a))]
        found[k] = bool(np.any(np.all(np.stack(sides) >= -1e-12 * size**2, axis=0)))
    return found
