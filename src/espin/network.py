"""The mechanical network: nodes (border and cross-links) and the fiber elements between them.

Every fiber is cut at its nodes into elements (paper Fig. 8, SPEC 2). Border nodes are the two
ends of each fiber and follow the macroscopic deformation; inner nodes are the cross-links,
with two in-plane degrees of freedom each. Nodes are numbered inner first, then border.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Network"]


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
