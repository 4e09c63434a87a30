"""The mechanical network: nodes (border and cross-links) and the fiber elements between them.

Every fiber is cut at its nodes into elements (paper Fig. 8, docs/model.md section 2). Border nodes are the two
ends of each fiber and follow the macroscopic deformation; inner nodes are the cross-links,
with two in-plane degrees of freedom each. Nodes are numbered inner first, then border.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from espin.geometry.crosslinks import Crosslinks
from espin.geometry.mat import FiberMat

__all__ = ["Network", "build_network"]


@dataclass(frozen=True, eq=False)
class Network:
    """Nodes and elements of a fiber network in its reference (as-deposited) state.

    Attributes
    ----------
    node_position : (n_nodes, 2) float64 [um]
        Reference positions X in [0, size]^2. Nodes ``0 .. n_inner - 1`` are inner nodes
        (cross-links), nodes ``n_inner .. n_nodes - 1`` border nodes (fiber ends).
    n_inner : int
        Number of inner nodes.
    element_nodes : (n_elements, 2) int64
        Nodes (e1, e2) of each element, in the order they appear along the fiber.
    element_contour_length : (n_elements,) float64 [um]
        Contour length L0 of the fiber between the element's nodes.
    element_diameter : (n_elements,) float64 [um]
        Fiber diameter D_e.
    element_layer : (n_elements,) int64
        Layer of the element's fiber.
    element_fiber : (n_elements,) int64
        Fiber (index into the FiberMat) the element belongs to.
    size : float [um]
        Side L of the square layers.
    thickness : float [um]
        Layer thickness D (mean fiber diameter).
    n_layers : int
        Number of layers N_l.
    n_merged : int
        Node candidates (cross-links or fiber ends) merged into another node because they
        lay within the merge tolerance along a fiber.
    merge_tolerance : float [um]
        The merge tolerance that was used.
    element_plastic_stretch : (n_elements,) float64 or None
        Plastic stretch lambda_p of each element at the start of a test, for a network read
        from a file that carries it (:mod:`espin.geometry.network_file`); None: 1.
    """

    node_position: np.ndarray
    n_inner: int
    element_nodes: np.ndarray
    element_contour_length: np.ndarray
    element_diameter: np.ndarray
    element_layer: np.ndarray
    element_fiber: np.ndarray
    size: float
    thickness: float
    n_layers: int
    n_merged: int
    merge_tolerance: float
    element_plastic_stretch: np.ndarray | None = None

    @property
    def initial_plastic_stretch(self) -> np.ndarray:
        """(n_elements,) float64: lambda_p at the start of a test (1 unless the network says)."""
        if self.element_plastic_stretch is None:
            return np.ones(self.n_elements)
        return self.element_plastic_stretch

    @property
    def n_nodes(self) -> int:
        """Number of nodes."""
        return len(self.node_position)

    @property
    def n_border(self) -> int:
        """Number of border nodes."""
        return self.n_nodes - self.n_inner

    @property
    def n_elements(self) -> int:
        """Number of elements."""
        return len(self.element_nodes)

    @property
    def n_dof(self) -> int:
        """Degrees of freedom of the equilibrium problem: 2 per inner node."""
        return 2 * self.n_inner

    @property
    def centre(self) -> np.ndarray:
        """(2,) float64 [um]: centre of the RVE, about which x = F X is applied."""
        return np.array([self.size / 2.0, self.size / 2.0])

    @property
    def element_vector(self) -> np.ndarray:
        """(n_elements, 2) float64 [um]: dX = X_e2 - X_e1."""
        return self.node_position[self.element_nodes[:, 1]] - self.node_position[self.element_nodes[:, 0]]

    @property
    def element_length(self) -> np.ndarray:
        """(n_elements,) float64 [um]: end-to-end length l0 = |dX|."""
        return np.hypot(*self.element_vector.T)

    @property
    def element_tortuosity(self) -> np.ndarray:
        """(n_elements,) float64: lambda_r = L0 / l0 >= 1."""
        return self.element_contour_length / self.element_length

    @property
    def element_area(self) -> np.ndarray:
        """(n_elements,) float64 [um^2]: cross-section A_e = pi D_e^2 / 4."""
        return np.pi * self.element_diameter**2 / 4.0

    @property
    def reference_volume(self) -> float:
        """V0 = L^2 N_l D [um^3], the volume that homogenized stresses refer to."""
        return self.size**2 * self.n_layers * self.thickness


def _clusters(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Label of the connected component of each of ``n`` items linked by pairs (a, b)."""
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def build_network(mat: FiberMat, crosslinks: Crosslinks, tolerance: float) -> Network:
    """Cut every fiber at its nodes into elements (paper Fig. 8; docs/model.md section 2).

    Node candidates are the cross-links and the two ends of every fiber. Candidates that
    follow each other along a fiber closer than ``tolerance`` are merged into one node (which
    then joins more than two fibers); a merged node that contains a fiber end is a border
    node. Elements whose end nodes still lie closer than ``tolerance`` have those nodes merged
    too, so no element is shorter than the tolerance and none has zero length. A merged inner
    node sits at the mean of its candidates, a border node at its fiber end. An element's
    tortuosity is that of its piece of fiber (arc over the chord between its own cut points),
    and its contour length L0 is that tortuosity times its end-to-end length between the
    (possibly merged) nodes, so merging never makes a straight piece look wavy; the arc inside
    a merged node (shorter than the tolerance) belongs to no element.

    Parameters
    ----------
    mat
        The deposited fibers.
    crosslinks
        Their cross-links.
    tolerance
        Merge tolerance [um] (``rve.merge_tolerance_ratio`` D).

    Returns
    -------
    Network
        Inner nodes first, then border nodes; elements in fiber order.
    """
    nf, nx = mat.n_fibers, crosslinks.n
    fibers = np.arange(nf)
    first, last = mat.fiber_offsets[:-1], mat.fiber_offsets[1:] - 1
    # Candidates: cross-links 0..nx-1, then fiber f's start nx + 2f and end nx + 2f + 1.
    position = np.concatenate([crosslinks.point, np.stack([mat.vertices[first], mat.vertices[last]], 1).reshape(-1, 2)])
    is_end = np.r_[np.zeros(nx, bool), np.ones(2 * nf, bool)]
    # Cut points along the fibers, sorted by fiber, then arc length (start first, end last).
    cut_fiber = np.concatenate([crosslinks.fiber[:, 0], crosslinks.fiber[:, 1], fibers, fibers])
    cut_arc = np.concatenate([crosslinks.arc[:, 0], crosslinks.arc[:, 1], np.zeros(nf), mat.contour_length])
    cut_rank = np.concatenate([np.ones(2 * nx), np.zeros(nf), np.full(nf, 2.0)])
    cut_node = np.concatenate([np.arange(nx), np.arange(nx), nx + 2 * fibers, nx + 2 * fibers + 1])
    order = np.lexsort((cut_rank, cut_arc, cut_fiber))
    cut_fiber, cut_arc, cut_node = cut_fiber[order], cut_arc[order], cut_node[order]
    along = cut_fiber[1:] == cut_fiber[:-1]
    a, b = cut_node[:-1][along], cut_node[1:][along]
    gap = np.diff(cut_arc)[along]
    fiber_of_pair = cut_fiber[1:][along]

    merge = gap < tolerance
    n_cand = len(position)
    while True:
        label = _clusters(n_cand, a[merge], b[merge])
        n_clusters = label.max() + 1 if n_cand else 0
        border = np.bincount(label, weights=is_end, minlength=n_clusters) > 0
        weight = np.bincount(label, minlength=n_clusters)
        centre: np.ndarray = np.stack(
            [np.bincount(label, weights=position[:, i], minlength=n_clusters) for i in (0, 1)], 1
        )
        centre /= weight[:, None]
        ends = np.flatnonzero(is_end)
        centre[label[ends]] = position[ends]
        la, lb = label[a], label[b]
        distinct = la != lb
        too_short = distinct & (np.hypot(*(centre[lb] - centre[la]).T) < tolerance)
        if not too_short.any():
            break
        merge |= too_short

    # Number the clusters: inner first, then border; drop clusters that no element uses.
    used = np.zeros(n_clusters, bool)
    used[la[distinct]] = used[lb[distinct]] = True
    inner = np.flatnonzero(used & ~border)
    outer = np.flatnonzero(used & border)
    node_of_cluster = np.full(n_clusters, -1, dtype=np.int64)
    node_of_cluster[inner] = np.arange(len(inner))
    node_of_cluster[outer] = len(inner) + np.arange(len(outer))
    node_position = centre[np.concatenate([inner, outer])]

    # Elements: consecutive cut points of a fiber in distinct nodes. An element keeps the
    # waviness of its piece of fiber (arc over the chord between its own cut points), so the
    # small shifts of merged nodes do not show up as tortuosity.
    e1 = node_of_cluster[la[distinct]]
    e2 = node_of_cluster[lb[distinct]]
    fiber = fiber_of_pair[distinct]
    own_chord = np.hypot(*(position[b[distinct]] - position[a[distinct]]).T)
    waviness = np.maximum(gap[distinct] / np.maximum(own_chord, np.finfo(float).tiny), 1.0)
    chord = np.hypot(*(node_position[e2] - node_position[e1]).T)
    return Network(
        node_position=node_position,
        n_inner=len(inner),
        element_nodes=np.c_[e1, e2].astype(np.int64),
        element_contour_length=waviness * chord,
        element_diameter=mat.fiber_diameter[fiber],
        element_layer=mat.fiber_layer[fiber],
        element_fiber=fiber.astype(np.int64),
        size=mat.size,
        thickness=mat.thickness,
        n_layers=mat.n_layers,
        n_merged=int(n_cand - n_clusters),
        merge_tolerance=float(tolerance),
    )
