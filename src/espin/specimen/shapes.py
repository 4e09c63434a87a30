"""Tensile specimens between the grips as mapped structured quad meshes (scikit-fem), or read with meshio.

Every generated specimen is a :class:`skfem.MeshQuad` of bilinear quads, counter-clockwise (positive
Jacobian everywhere), in mm, with the loading axis along x: the mesh spans ``-grip_length/2 <= x <=
grip_length/2`` (only the part between the grips is modelled: the grips clamp the two end faces) and
is centred on ``y = 0``. The mesh carries three named boundaries (facet index arrays): ``grip_left``
(the face at the smallest x), ``grip_right`` (the face at the largest x) and ``edge`` (every other
boundary facet: free sides, hole, notch).

``elements_across`` is the refinement knob of every generator: the number of elements across the
narrowest width of the specimen; elements are kept near aspect ratio 1 along x (graded near holes
and notches). Blocks are built as mapped grids and joined by merging coincident nodes.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import meshio
import numpy as np
import skfem
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from espin.core.errors import ConfigError
from espin.specimen.mesh_checks import (
    MERGE_FRACTION,
    check_cells,
    check_coordinates,
    check_memory,
    check_pieces,
    inside_cells,
    merge_nodes,
)

__all__ = [
    "Specimen",
    "strip",
    "dogbone",
    "dogbone_half_width",
    "holed_strip",
    "notched_strip",
    "read_specimen",
    "SHAPES",
]

_MERGE_TOL = 1e-9  # relative to the mesh size: nodes closer than this are one node, facets on a grip face


@dataclass(frozen=True, eq=False)
class Specimen:
    """A specimen geometry between the grips (mm).

    Attributes
    ----------
    name : str
        ``"strip"``, ``"dogbone"``, ``"holed_strip"``, ``"notched_strip"``, or the file name of a user mesh.
    mesh : skfem.Mesh
        :class:`skfem.MeshQuad` (generated) or :class:`skfem.MeshTri` / :class:`skfem.MeshQuad` (user
        mesh); node coordinates in mm, x the loading axis. ``mesh.boundaries`` holds the facet index
        arrays ``"grip_left"`` (x = x_min face), ``"grip_right"`` (x = x_max face) and ``"edge"``
        (every other boundary facet).
    grip_length_mm : float
        Initial distance between the grips, mm (the grip strain is grip displacement / this).
    gauge_length_mm : float
        Gauge length for the engineering strain of the gauge section, mm, centred at ``x_centre``.
    gauge_width_mm : float
        Reference width of the gauge section, mm (engineering stress = force / (width * thickness)).
    dimensions : dict[str, float]
        Every dimension used, named, mm (documented per shape).
    notes : tuple of str
        What reading a user mesh changed (nodes merged).
    """

    name: str
    mesh: skfem.Mesh
    grip_length_mm: float
    gauge_length_mm: float
    gauge_width_mm: float
    dimensions: dict[str, float]
    notes: tuple[str, ...] = ()

    @property
    def n_elements(self) -> int:
        """Number of elements of the mesh."""
        return int(self.mesh.nelements)

    @property
    def x_centre(self) -> float:
        """x midway between the grips, mm: the centre of the gauge section."""
        return float(0.5 * (self.mesh.p[0].min() + self.mesh.p[0].max()))

    def __repr__(self) -> str:
        return (
            f"Specimen({self.name!r}: {self.n_elements} elements, {self.mesh.nvertices} nodes, "
            f"grips {self.grip_length_mm:g} mm apart, gauge {self.gauge_length_mm:g} x "
            f"{self.gauge_width_mm:g} mm)"
        )


# ---------------------------------------------------------------------------------------------------
# input checks


def _positive(**values: float) -> None:
    for name, value in values.items():
        if isinstance(value, bool) or not (isinstance(value, numbers.Real) and math.isfinite(value) and value > 0):
            raise ConfigError(f"{name} must be a finite number > 0 (mm or factor), got {value!r}")


def _count(elements_across: int) -> int:
    if isinstance(elements_across, bool) or not isinstance(elements_across, (int, np.integer)) or elements_across < 1:
        raise ConfigError(f"elements_across must be an integer >= 1, got {elements_across!r}")
    return int(elements_across)


# ---------------------------------------------------------------------------------------------------
# mapped blocks and their assembly into one mesh


def _columns(bottom: np.ndarray, top: np.ndarray, n_rows: int) -> np.ndarray:
    """A block of nodes (2, n_columns, n_rows + 1) evenly spaced on straight lines from bottom to top points."""
    f = np.linspace(0.0, 1.0, n_rows + 1)
    return bottom[:, :, None] * (1.0 - f) + top[:, :, None] * f


def _block_quads(shape: tuple[int, int], offset: int) -> np.ndarray:
    """Quads (4, n) of a block of nodes of ``shape`` numbered row-major from ``offset``, counter-clockwise."""
    idx = offset + np.arange(shape[0] * shape[1]).reshape(shape)
    return np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]]).reshape(4, -1)


def _merge(p: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge coincident nodes (within a tolerance relative to the mesh size)."""
    tol = _MERGE_TOL * max(np.ptp(p[0]), np.ptp(p[1]))
    pairs = cKDTree(p.T).query_pairs(tol, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(p.shape[1],) * 2)
    n, label = connected_components(graph, directed=False)
    merged = np.empty((2, n))
    merged[:, label] = p
    return merged, label[t]


def _assemble(blocks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and quads of mapped blocks (each (2, n0, n1) with (axis 1, axis 2) counter-clockwise)."""
    offsets = np.cumsum([0] + [b[0].size for b in blocks])
    p = np.hstack([b.reshape(2, -1) for b in blocks])
    t = np.hstack([_block_quads(b.shape[1:], o) for b, o in zip(blocks, offsets)])
    return _merge(p, t)


def _corner_jacobians(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Jacobian determinant of every element at each of its corners (corners, elements)."""
    x = p[:, t]
    after, before = np.roll(x, -1, axis=1) - x, np.roll(x, 1, axis=1) - x
    return after[0] * before[1] - after[1] * before[0]


def _tag_boundaries(mesh: skfem.Mesh, named: dict[str, np.ndarray] | None = None) -> skfem.Mesh:
    """``mesh`` with grip_left/grip_right (given facets, or the boundary facets at min/max x) and edge (the rest)."""
    boundary = mesh.boundary_facets()
    if named is None:
        x = mesh.p[0, mesh.facets[:, boundary]]
        tol = _MERGE_TOL * max(np.ptp(mesh.p[0]), np.ptp(mesh.p[1]))
        named = {
            "grip_left": boundary[np.all(np.abs(x - mesh.p[0].min()) <= tol, axis=0)],
            "grip_right": boundary[np.all(np.abs(x - mesh.p[0].max()) <= tol, axis=0)],
        }
    edge = np.setdiff1d(boundary, np.concatenate(list(named.values())))
    return mesh.with_boundaries({**named, "edge": edge.astype(boundary.dtype)})


def _specimen(
    name: str,
    blocks: list[np.ndarray],
    grip_length: float,
    gauge_length: float,
    gauge_width: float,
    dimensions: dict[str, float],
) -> Specimen:
    p, t = _assemble(blocks)
    if np.any(_corner_jacobians(p, t) <= 0):
        raise ConfigError(
            f"{name}: the dimensions {dimensions} give inverted elements in the mapped mesh; "
            "use less extreme proportions (e.g. a longer specimen or a smaller notch)"
        )
    mesh = _tag_boundaries(skfem.MeshQuad(p, t))
    return Specimen(
        name,
        mesh,
        float(grip_length),
        float(gauge_length),
        float(gauge_width),
        {k: float(v) for k, v in dimensions.items()},
    )


def _stations(length: float, spacing: float) -> np.ndarray:
    """Evenly spaced parameters 0..length, about ``spacing`` apart (at least one interval)."""
    return np.linspace(0.0, length, max(1, round(length / spacing)) + 1)


# ---------------------------------------------------------------------------------------------------
# strip


def strip(
    length_mm: float = 50.0, width_mm: float = 10.0, *, element_size_mm: float | None = None, elements_across: int = 4
) -> Specimen:
    """A rectangular strip between the grips.

    Parameters
    ----------
    length_mm : float
        Initial distance between the grips, mm (> 0): the mesh spans x in [-length/2, length/2].
    width_mm : float
        Width, mm (> 0): y in [-width/2, width/2].
    element_size_mm : float, optional
        Target element size, mm (> 0); when given it sets the number of elements across
        (``ceil(width / size)``) and ``elements_across`` is not used.
    elements_across : int
        Elements across the width (>= 1); the element length along x is about width / elements_across.

    Returns
    -------
    Specimen
        Gauge length = length / 2 (centred), gauge width = width. ``dimensions``: ``length``, ``width``,
        ``element_size`` (the size across, width / elements across).
    """
    _positive(length_mm=length_mm, width_mm=width_mm)
    n_across = _count(elements_across)
    if element_size_mm is not None:
        _positive(element_size_mm=element_size_mm)
        n_across = max(1, math.ceil(width_mm / element_size_mm - 1e-9))
    size = width_mm / n_across
    x = _stations(length_mm, size) - length_mm / 2
    bottom, top = np.vstack([x, np.full_like(x, -width_mm / 2)]), np.vstack([x, np.full_like(x, width_mm / 2)])
    return _specimen(
        "strip",
        [_columns(bottom, top, n_across)],
        length_mm,
        length_mm / 2,
        width_mm,
        {"length": length_mm, "width": width_mm, "element_size": size},
    )


# ---------------------------------------------------------------------------------------------------
# dogbone: ISO 527-2 type 5A

_ISO_527_2_5A = {
    "overall_length": 75.0,
    "end_width": 12.5,
    "narrow_width": 4.0,
    "narrow_length": 25.0,
    "gauge_length": 20.0,
    "grip_distance": 50.0,
    "large_radius": 12.5,
    "small_radius": 8.0,
}


def _dogbone_dimensions(scale: float) -> dict[str, float]:
    d = {k: v * scale for k, v in _ISO_527_2_5A.items()}
    radii, rise = d["large_radius"] + d["small_radius"], (d["end_width"] - d["narrow_width"]) / 2
    d["transition_length"] = math.sqrt(radii**2 - (radii - rise) ** 2)
    d["inflection_offset"] = d["transition_length"] * d["large_radius"] / radii
    return d


def dogbone_half_width(x: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Half width w(x)/2 of the ISO 527-2 type 5A dogbone profile at x (mm; x = 0 at the centre).

    The narrow parallel part (|x| <= narrow_length/2), then an arc of the large radius tangent to it,
    an arc of the small radius tangent to the wide end, and the wide end (see :func:`dogbone`).
    """
    d = _dogbone_dimensions(scale)
    u = np.abs(np.asarray(x, dtype=float))
    r_in, r_out, run = d["large_radius"], d["small_radius"], d["transition_length"]
    start, narrow, wide = d["narrow_length"] / 2, d["narrow_width"] / 2, d["end_width"] / 2
    inflection = start + d["inflection_offset"]
    s_in = np.clip(u - start, 0.0, None)
    s_out = np.clip(start + run - u, 0.0, None)
    inner = narrow + r_in - np.sqrt(np.clip(r_in**2 - s_in**2, 0.0, None))
    outer = wide - r_out + np.sqrt(np.clip(r_out**2 - s_out**2, 0.0, None))
    return np.where(u <= start, narrow, np.where(u <= inflection, inner, np.where(u < start + run, outer, wide)))


def _graded_stations(breaks: list[float], half_width: Callable[[np.ndarray], np.ndarray], n_across: int) -> np.ndarray:
    """Stations from breaks[0] to breaks[-1], every break a station, about the local width / n_across apart."""
    pieces = []
    for a, b in zip(breaks[:-1], breaks[1:]):
        fine = np.linspace(a, b, 501)
        density = n_across / (2 * half_width(fine))
        cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(fine))])
        n = max(1, round(cumulative[-1]))
        pieces.append(np.interp(np.linspace(0.0, cumulative[-1], n + 1), cumulative, fine)[:-1])
    return np.concatenate(pieces + [breaks[-1:]])


def dogbone(scale: float = 1.0, *, elements_across: int = 4) -> Specimen:
    """The part between the grips of an ISO 527-2 type 5A dumb-bell specimen.

    Dimensions (mm, each times ``scale``), as named in ISO 527-2 for type 5A: overall length 75, width at
    ends 12.5, width of narrow portion 4, length of narrow parallel-sided portion 25, gauge length 20,
    initial distance between grips 50, large radius 12.5, small radius 8. Only the 50 mm between the
    grips is modelled (x in [-25, 25]); the overall length is kept in ``dimensions`` but does not enter
    the mesh.

    Reading of the profile (ours; the standard names the radii, the tangent construction is our
    reading): from the narrow parallel part (|x| <= 12.5) the half width rises by (12.5 - 4)/2 = 4.25
    through two tangent arcs, first the large radius (12.5, tangent to the narrow part, concave
    outward), then the small radius (8, tangent to the wide end). Two tangent arcs with radii summing to
    20.5 that rise 4.25 run ``sqrt(20.5**2 - 16.25**2) = 12.497`` mm along x, so the full end width is
    reached at |x| = 24.997, 0.003 mm inside the grips: the listed radii fit the 12.5 mm available on
    each side, and the profile is flat at the end width over those last 0.003 mm. Placing the small
    radius at the narrow part instead gives an equally consistent profile of the same run.

    Parameters
    ----------
    scale : float
        Factor on every dimension (> 0); 1 is the standard's size.
    elements_across : int
        Elements across the narrow width (>= 1); columns are graded to the local width.

    Returns
    -------
    Specimen
        Grip length 50 * scale, gauge length 20 * scale, gauge width 4 * scale. ``dimensions``: the
        standard's dimensions above (``overall_length``, ``end_width``, ``narrow_width``,
        ``narrow_length``, ``gauge_length``, ``grip_distance``, ``large_radius``, ``small_radius``) and
        ``transition_length`` (the x run of the two arcs) and ``inflection_offset`` (x from the end of the
        narrow part to where the arcs meet), all mm.
    """
    _positive(scale=scale)
    n_across = _count(elements_across)
    d = _dogbone_dimensions(scale)
    half_length = d["grip_distance"] / 2
    inflection = d["narrow_length"] / 2 + d["inflection_offset"]
    breaks = [-half_length, -inflection, -d["narrow_length"] / 2, d["narrow_length"] / 2, inflection, half_length]
    x = _graded_stations(breaks, lambda s: dogbone_half_width(s, scale), n_across)
    h = dogbone_half_width(x, scale)
    block = _columns(np.vstack([x, -h]), np.vstack([x, h]), n_across)
    return _specimen("dogbone", [block], d["grip_distance"], d["gauge_length"], d["narrow_width"], d)


# ---------------------------------------------------------------------------------------------------
# strip with a central circular hole


def holed_strip(
    length_mm: float = 50.0, width_mm: float = 10.0, hole_diameter_mm: float = 3.0, *, elements_across: int = 4
) -> Specimen:
    """A strip with a central circular hole.

    The mesh is an O-grid: four mapped blocks from the hole to the square of side ``width`` around it
    (the circle's angle and the square's side are divided alike; radial lines are straight), then one
    rectangular block from each side of the square to the grip. The hole is a polygon through nodes
    on the circle, so the mesh area exceeds the exact area by an amount that shrinks with refinement.

    Parameters
    ----------
    length_mm : float
        Initial distance between the grips, mm (> width).
    width_mm : float
        Width, mm (> 0).
    hole_diameter_mm : float
        Diameter of the hole, mm (0 < diameter < width).
    elements_across : int
        Elements across the net section through the hole (>= 1; rounded up to an even number: the two
        ligaments beside the hole share it).

    Returns
    -------
    Specimen
        Gauge length = the whole length, gauge width = the full width (nominal stress on the gross
        section). ``dimensions``: ``length``, ``width``, ``hole_diameter``.
    """
    _positive(length_mm=length_mm, width_mm=width_mm, hole_diameter_mm=hole_diameter_mm)
    n_across = _count(elements_across)
    if hole_diameter_mm >= width_mm:
        raise ConfigError(f"hole_diameter_mm must be in (0, width_mm = {width_mm:g}), got {hole_diameter_mm!r}")
    if length_mm <= width_mm:
        raise ConfigError(f"length_mm must be > width_mm = {width_mm:g} for the holed strip, got {length_mm!r}")
    radius, half = hole_diameter_mm / 2, width_mm / 2
    n_radial = math.ceil(n_across / 2)
    radial_size = (half - radius) / n_radial
    n_side = max(1, round((math.pi / 2 * radius + 2 * half) / 2 / radial_size))
    u = np.linspace(-1.0, 1.0, n_side + 1)
    circle = radius * np.vstack([np.cos(u * np.pi / 4), np.sin(u * np.pi / 4)])
    square = half * np.vstack([np.ones_like(u), u])
    ring = _columns(square, circle, n_radial)  # counter-clockwise: angle along axis 1, inward along axis 2
    quarter = np.array([[0.0, -1.0], [1.0, 0.0]])
    blocks = [np.einsum("ij,jkl->ikl", np.linalg.matrix_power(quarter, k), ring) for k in range(4)]
    x = _stations(length_mm / 2 - half, width_mm / n_side) + half
    y = np.linspace(-half, half, n_side + 1)
    right = np.stack(np.meshgrid(x, y, indexing="ij"))
    blocks += [right, -right]
    return _specimen(
        "holed_strip",
        blocks,
        length_mm,
        length_mm,
        width_mm,
        {"length": length_mm, "width": width_mm, "hole_diameter": hole_diameter_mm},
    )


# ---------------------------------------------------------------------------------------------------
# strip with a U notch


def _notch_pieces(half_width: float, depth: float, radius: float, reach: float) -> list[tuple]:
    """The top boundary over |x| <= reach as pieces ("line", p0, p1) or ("arc", centre, angle0, angle1)."""
    centre_y = half_width - depth + radius
    beta = math.asin(max(min((depth - radius) / radius, 0.0), -1.0))  # 0 when the walls are straight
    mouth = radius * math.cos(beta)
    pieces: list[tuple] = [("line", (-reach, half_width), (-mouth, half_width))]
    if depth > radius:
        pieces.append(("line", (-radius, half_width), (-radius, centre_y)))
    pieces += [
        ("arc", (0.0, centre_y), math.pi - beta, 1.5 * math.pi),  # the root of the notch is a node
        ("arc", (0.0, centre_y), 1.5 * math.pi, 2 * math.pi + beta),
    ]
    if depth > radius:
        pieces.append(("line", (radius, centre_y), (radius, half_width)))
    pieces.append(("line", (mouth, half_width), (reach, half_width)))
    return pieces


def _piece_length(piece: tuple, radius: float) -> float:
    if piece[0] == "line":
        return math.dist(piece[1], piece[2])
    return radius * (piece[3] - piece[2])


def _piece_points(piece: tuple, radius: float, f: np.ndarray) -> np.ndarray:
    """Points (2, n) at fractions f of the arc length of a piece."""
    if piece[0] == "line":
        p0, p1 = np.array(piece[1])[:, None], np.array(piece[2])[:, None]
        return p0 + (p1 - p0) * f
    angle = piece[2] + (piece[3] - piece[2]) * f
    return np.array(piece[1])[:, None] + radius * np.vstack([np.cos(angle), np.sin(angle)])


def _outline(pieces: list[tuple], radius: float, spacings: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Arc lengths (n,) and points (2, n) along the pieces, each about its spacing apart, every piece end a node."""
    lengths = [_piece_length(piece, radius) for piece in pieces]
    starts = np.concatenate([[0.0], np.cumsum(lengths)])
    fractions = [
        np.linspace(0.0, 1.0, max(1, math.ceil(length / spacing - 1e-9)) + 1)[:-1]
        for length, spacing in zip(lengths, spacings)
    ]
    s = np.concatenate([start + length * f for start, length, f in zip(starts, lengths, fractions)] + [starts[-1:]])
    points = np.hstack(
        [_piece_points(piece, radius, f) for piece, f in zip(pieces, fractions)] + [np.array(pieces[-1][2])[:, None]]
    )
    return s, points


def notched_strip(
    length_mm: float = 50.0,
    width_mm: float = 10.0,
    notch_depth_mm: float = 2.0,
    notch_radius_mm: float = 1.0,
    *,
    elements_across: int = 4,
) -> Specimen:
    """A strip with one U (round-bottomed) edge notch at mid-length on the top edge y = +width/2.

    The notch bottom is a circular arc of radius ``notch_radius_mm`` whose lowest point is at depth
    ``notch_depth_mm`` below the top edge; when depth > radius the arc is a half circle with straight
    walls of height depth - radius up to the top edge (a slot of width 2 * radius), when depth <= radius
    the notch is the circular segment of that depth. The mesh is column-wise mapped: each column is a
    straight line from the bottom edge to a node of the top boundary (flat, then the notch, then flat);
    around the notch the columns end on nodes along the notch outline (about width / elements_across
    apart on the flat top, and at most ligament / elements_across and pi * radius / elements_across
    apart on the notch walls and bottom, so a half circle gets at least elements_across elements) and
    fan out on the bottom edge (in proportion to the arc length of the outline), so they lean away
    from the notch walls. The notch outline is a polygon through nodes on it,
    so the mesh area exceeds the exact area by an amount that shrinks with refinement.

    Parameters
    ----------
    length_mm : float
        Initial distance between the grips, mm (> 0).
    width_mm : float
        Width, mm (> 0).
    notch_depth_mm : float
        Depth of the notch, mm (0 < depth < width).
    notch_radius_mm : float
        Radius of the notch bottom, mm (> 0; the notch, 2 * radius wide, must fit in the region of
        half-length ``notch_region`` = min(length/2, 2 * (depth + radius)) around the centre).
    elements_across : int
        Elements across the ligament (width - depth) under the notch (>= 1), the same number across
        every column.

    Returns
    -------
    Specimen
        Gauge length = the whole length, gauge width = the full width (nominal stress on the gross
        section). ``dimensions``: ``length``, ``width``, ``notch_depth``, ``notch_radius``,
        ``notch_region`` (half-length of the region of fanned columns). ``mesh.boundaries["notch"]``:
        the facets of the notch outline (also in ``"edge"``; ``lateral = "fixed"`` leaves them free).
    """
    _positive(length_mm=length_mm, width_mm=width_mm, notch_depth_mm=notch_depth_mm, notch_radius_mm=notch_radius_mm)
    n_across = _count(elements_across)
    if notch_depth_mm >= width_mm:
        raise ConfigError(f"notch_depth_mm must be in (0, width_mm = {width_mm:g}), got {notch_depth_mm!r}")
    radius, depth, half = notch_radius_mm, notch_depth_mm, width_mm / 2
    reach = min(length_mm / 2, 2 * (depth + radius))
    if radius >= reach:
        raise ConfigError(
            f"notch_radius_mm must be < {reach:g} (the notch must fit within the length "
            f"{length_mm:g} mm), got {radius!r}"
        )
    pieces = _notch_pieces(half, depth, radius, reach)
    fine = min((width_mm - depth) / n_across, math.pi * radius / n_across)
    spacings = [width_mm / n_across] + [fine] * (len(pieces) - 2) + [width_mm / n_across]
    s, top = _outline(pieces, radius, spacings)
    bottom = np.vstack([-reach + 2 * reach * s / s[-1], np.full_like(s, -half)])
    blocks = [_columns(bottom, top, n_across)]
    if length_mm / 2 > reach:
        x = _stations(length_mm / 2 - reach, width_mm / n_across) + reach
        side = _columns(np.vstack([x, np.full_like(x, -half)]), np.vstack([x, np.full_like(x, half)]), n_across)
        blocks += [side, side[:, ::-1] * np.array([-1.0, 1.0])[:, None, None]]
    specimen = _specimen(
        "notched_strip",
        blocks,
        length_mm,
        length_mm,
        width_mm,
        {"length": length_mm, "width": width_mm, "notch_depth": depth, "notch_radius": radius, "notch_region": reach},
    )
    # the notch outline (walls and bottom: below the top edge, above the bottom one), a part of "edge"
    mesh = specimen.mesh
    edge = mesh.boundaries["edge"]
    y = mesh.p[1, mesh.facets[:, edge]]
    tol = _MERGE_TOL * width_mm
    notch = edge[np.any(y < half - tol, axis=0) & np.all(y > -half + tol, axis=0)]
    return replace(specimen, mesh=mesh.with_boundaries({"notch": notch}))


# ---------------------------------------------------------------------------------------------------
# user meshes


def _named_lines(m, name: str) -> np.ndarray | None:
    """Node pairs (n, 2) of the line cells in the set or gmsh physical group ``name``, or None."""
    if name in m.cell_sets:
        found = [
            block.data[np.asarray(idx, dtype=int)]
            for block, idx in zip(m.cells, m.cell_sets[name])
            if block.type == "line" and idx is not None
        ]
        return np.vstack(found) if found else None
    physical = m.cell_data.get("gmsh:physical")
    if physical is None or name not in m.field_data:
        return None
    tag = m.field_data[name][0]
    found = [block.data[tags == tag] for block, tags in zip(m.cells, physical) if block.type == "line"]
    return np.vstack(found) if found and sum(map(len, found)) else None


def _orient(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cells reordered counter-clockwise (positive signed area)."""
    x = p[:, t]
    area = 0.5 * np.sum(x[0] * np.roll(x[1], -1, axis=0) - np.roll(x[0], -1, axis=0) * x[1], axis=0)
    if np.any(area == 0):
        raise ConfigError(f"the mesh has {np.count_nonzero(area == 0)} cells of zero area; expected a valid 2-D mesh")
    return np.where(area > 0, t, t[::-1])


def _facet_index(mesh: skfem.Mesh, pairs: np.ndarray, name: str, path: Path) -> np.ndarray:
    n = mesh.p.shape[1]
    facets = np.sort(mesh.facets, axis=0)
    keys = facets[0].astype(np.int64) * n + facets[1]
    pairs = np.sort(pairs, axis=1)
    wanted = pairs[:, 0].astype(np.int64) * n + pairs[:, 1]
    order = np.argsort(keys)
    pos = np.clip(np.searchsorted(keys[order], wanted), 0, len(keys) - 1)
    found = order[pos]
    if np.any(keys[found] != wanted):
        raise ConfigError(
            f"{path}: the line cells of {name!r} are not edges of the 2-D cells; "
            "expected line cells on the mesh boundary"
        )
    return np.unique(found).astype(np.int32)


def read_specimen(
    path: str | Path, *, gauge_length_mm: float | None = None, gauge_width_mm: float | None = None
) -> Specimen:
    """A user mesh read with meshio (any format meshio reads: .msh, .vtu, .xdmf, ...).

    Parameters
    ----------
    path : str or Path
        The mesh file: triangle or quad cells (linear, one kind), coordinates in mm, x the loading axis,
        2-D (a z coordinate is allowed if it is zero everywhere). Cells are reordered counter-clockwise.
    gauge_length_mm : float, optional
        Gauge length, mm (> 0); default the distance between the grips (x extent of the mesh).
    gauge_width_mm : float, optional
        Reference width, mm (> 0); default the y extent of the mesh (gross section).

    Returns
    -------
    Specimen
        Named after the file. The grips are the line cells of the cell sets (gmsh physical groups)
        named ``grip_left`` and ``grip_right`` when the file has both, else the boundary facets at the
        smallest and the largest x (within 1e-9 relative to the mesh size). ``dimensions``: ``length``
        (x extent), ``width`` (y extent).

    Raises
    ------
    ConfigError
        The file is missing or unreadable, has no triangle or quad cells, mixes them, is not planar,
        has coordinates that are not finite or not a specimen's, repeated or overlapping cells, is
        in several pieces (:mod:`espin.specimen.mesh_checks`; nodes that coincide are merged
        first), has no boundary facet at the smallest or largest x, or gauge marks off the
        specimen.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"specimen mesh {path} does not exist; expected a mesh file meshio reads (.msh, .vtu, ...)")
    for name, value in {"gauge_length_mm": gauge_length_mm, "gauge_width_mm": gauge_width_mm}.items():
        if value is not None:
            _positive(**{name: value})
    if path.stat().st_size == 0:
        raise ConfigError(f"specimen mesh {path} is empty; expected a mesh file meshio reads (.msh, .vtu, ...)")
    try:
        m = meshio.read(path)
    except (Exception, SystemExit) as err:  # noqa: BLE001 - meshio raises many types, and exits on some files
        raise ConfigError(f"specimen mesh {path} cannot be read by meshio ({err}); expected a mesh file") from None
    kinds = {block.type for block in m.cells} & {"triangle", "quad"}
    if len(kinds) != 1:
        found = sorted({block.type for block in m.cells})
        raise ConfigError(
            f"specimen mesh {path} has cells {found}; expected 2-D cells of one kind, 'triangle' or 'quad' (linear)"
        )
    kind = kinds.pop()
    where = f"specimen mesh {path}"
    points = np.asarray(m.points, dtype=float)
    cells = np.vstack([block.data for block in m.cells if block.type == kind]).T
    used = np.unique(cells)
    check_coordinates(points[used, :2], where)
    if points.shape[1] > 2 and np.any(np.abs(points[used, 2:]) > _MERGE_TOL * np.ptp(points[used, :2], axis=0).max()):
        raise ConfigError(f"{where} is not planar (z != 0); expected a 2-D mesh in the x-y plane")
    p, label = merge_nodes(points[used, :2].T, np.searchsorted(used, cells))
    t = _orient(p, label[np.searchsorted(used, cells)])
    check_cells(p, t, where)
    check_pieces(p, t, where)
    mesh_type = skfem.MeshTri if kind == "triangle" else skfem.MeshQuad
    mesh = mesh_type(p, t)
    lines = {name: _named_lines(m, name) for name in ("grip_left", "grip_right")}
    named = None
    if all(v is not None for v in lines.values()):
        remap = np.full(points.shape[0], -1)
        remap[used] = label
        named = {name: _facet_index(mesh, remap[v], name, path) for name, v in lines.items()}
    mesh = _tag_boundaries(mesh, named)
    for name in ("grip_left", "grip_right"):
        if mesh.boundaries[name].size == 0:
            side = "smallest" if name == "grip_left" else "largest"
            raise ConfigError(
                f"{where} has no boundary facet at the {side} x ({name}); expected "
                "straight grip faces normal to x at both ends, or line sets grip_left/grip_right"
            )
    length, width = float(np.ptp(mesh.p[0])), float(np.ptp(mesh.p[1]))
    merged = used.size - p.shape[1]
    notes = (f"{merged} node(s) closer than {MERGE_FRACTION:g} of the shortest edge merged",) if merged else ()
    specimen = Specimen(
        path.name,
        mesh,
        length,
        gauge_length_mm or length,
        gauge_width_mm or width,
        {"length": length, "width": width},
        notes,
    )
    _check_extensometer(specimen, where)
    return specimen


def _check_extensometer(specimen: Specimen, where: str) -> None:
    """Refuse a mesh whose gauge marks (on the centre line, the gauge length apart around the
    middle between the grips) are not on the specimen."""
    p = specimen.mesh.p
    half = 0.5 * specimen.gauge_length_mm
    y = 0.5 * (p[1].min() + p[1].max())
    marks = np.array([[specimen.x_centre - half, y], [specimen.x_centre + half, y]])
    missed = marks[~inside_cells(p, specimen.mesh.t, marks)]
    if len(missed):
        shown = " and ".join(f"({x:.4g}, {y:.4g})" for x, y in missed)
        raise ConfigError(
            f"{where}: the extensometer's gauge mark(s) at {shown} mm (the centre line, "
            f"{specimen.gauge_length_mm:g} mm apart around the middle) are not on the specimen; "
            "expected a specimen whose centre line is material there (give a shorter gauge_length_mm, "
            "or centre the mesh's gauge section)"
        )


def check_size(shape: str, elements_across: int, options: dict[str, float]) -> None:
    """Refuse a built-in ``shape`` whose mesh at ``elements_across`` would not fit in memory,
    before it is built: its elements estimated from the shape at 4 across (they grow as the
    square of the count; :func:`espin.specimen.mesh_checks.check_memory`)."""
    n = _count(elements_across)
    if n <= 16:
        return
    probe = SHAPES[shape](elements_across=4, **options)
    check_memory(f"elements_across = {n}", round(probe.n_elements * (n / 4.0) ** 2), points_per_element(probe))


def points_per_element(specimen: Specimen) -> int:
    """Quadrature points per element of the specimen's membrane model (4 in a quad, 3 in a
    triangle: the second-order rules of :mod:`espin.specimen.membrane`)."""
    return 3 if isinstance(specimen.mesh, skfem.MeshTri) else 4


SHAPES: dict[str, Callable[..., Specimen]] = {
    "strip": strip,
    "dogbone": dogbone,
    "holed_strip": holed_strip,
    "notched_strip": notched_strip,
}
