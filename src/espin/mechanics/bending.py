"""Bending of fibers across their nodes: an opt-in rotational spring at every fiber joint.

In the paper's model a fiber is a chain of axial elements pinned at its cross-links, so a
compressed chain resists nothing but its slack modulus and buckles freely: states dominated by
compression (lateral contraction, lateral ``free``) are nearly mechanisms. With
``fiber.bending_modulus_MPa`` = E > 0 every joint of one fiber (the node b between its
consecutive elements a-b and b-c) carries a rotational spring

    W = k (1 - cos(theta - theta_0)),    k = E I / lbar,    I = pi D^4 / 64,

theta the turning angle from a-b to b-c (counter-clockwise), theta_0 its as-deposited value,
lbar the mean contour length of the two elements and D their mean diameter. For small angle
changes W = k / 2 (theta - theta_0)^2, the discrete elastic rod, whose energy tends to
E I / 2 * integral of the curvature change squared as the elements shrink; the cosine keeps W
smooth and bounded when a joint folds over (a squared angle would jump where the angle wraps
at +-pi). The physical value of E is the fiber's Young's modulus (E_t for a fiber
whose taut modulus is its material's); 0 switches the term off (the paper's model). The spring
is elastic (no plastic flow), acts at fixed theta_0 and adds no term at cross-links between
two fibers (they stay pin joints). A joint one of whose elements is shorter than the element
law's length floor (:data:`espin.mechanics.fiber_law.STRETCH_FLOOR` times its reference
length) carries nothing: its angle is undefined there, and its derivatives grow as 1 / l. docs/model.md section 3.

With u = x_b - x_a and v = x_c - x_b, theta = angle(v) - angle(u) and, with perp(w) = (-w_y,
w_x), d theta / d x_a = perp(u) / |u|^2, d theta / d x_c = perp(v) / |v|^2 and d theta / d x_b
= -(d theta / d x_a + d theta / d x_c). With Delta = theta - theta_0, the joint's gradient is
k sin(Delta) d theta/dx and its Hessian k cos(Delta) (d theta/dx)(d theta/dx)^T (positive
semi-definite where |Delta| < pi / 2) plus k sin(Delta) d^2 theta / dx^2.

A joint's force is known only to the rounding of its nodes' positions: an element vector
u = x_b - x_a carries an error of order eps |x| (eps the float64 epsilon), so the angle one of
order eps |x| / |u| and the force one of order k eps |x| (1 / |u|^2 + 1 / |v|^2). Next to an
element much shorter than the RVE (a merge tolerance of 1e-6 D leaves elements of 2e-6 D) that
exceeds the equilibrium's force tolerance by orders of magnitude, and Newton stalls on rounding;
:meth:`FiberJoints.force_resolution` is that floor, node by node, and the equilibrium accepts a
residual within it. The reference angles are taken in the solver's coordinates (relative to the
RVE centre), so the undeformed state has none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from espin.geometry.network import Network
from espin.mechanics import joint_kernels
from espin.mechanics.fiber_law import STRETCH_FLOOR

__all__ = ["FiberJoints", "fiber_joints"]


@dataclass(frozen=True, eq=False)
class FiberJoints:
    """The joints of every fiber of a network and their rotational springs.

    Attributes
    ----------
    nodes : (n_joints, 3) int64
        Nodes (a, b, c) of each joint: the fiber runs a -> b -> c.
    stiffness : (n_joints,) float64 [uN um]
        k = E I / lbar (twice the energy per squared radian of a small angle change).
    reference_angle : (n_joints,) float64 [rad]
        Turning angle theta_0 in the reference state, in (-pi, pi].
    floor : (n_joints, 2) float64 [um]
        Length floor of the elements a-b and b-c (below it the joint carries nothing).
    """

    nodes: np.ndarray
    stiffness: np.ndarray
    reference_angle: np.ndarray
    floor: np.ndarray

    @property
    def dof(self) -> np.ndarray:
        """(n_joints, 6) int64: DOF (x, y) of a, b and c."""
        return np.stack([2 * self.nodes, 2 * self.nodes + 1], axis=2).reshape(-1, 6)

    def _geometry(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Angle change theta - theta_0 (wrapped to [-pi, pi)), d theta / d(x_a, x_b, x_c), |u|^2
        and |v|^2 (:func:`espin.mechanics.joint_kernels.geometry`); change and derivative are
        zero, |u|^2 and |v|^2 one, for a joint with an element below its floor."""
        return joint_kernels.geometry(
            np.ascontiguousarray(x, dtype=float), self.nodes, self.floor, self.reference_angle
        )

    def energy(self, x: np.ndarray) -> float:
        """Stored bending energy [uN um] at node positions ``x`` (n_nodes, 2) [um]."""
        change = self._geometry(x)[0]
        return float(np.sum(self.stiffness * (1.0 - np.cos(change))))

    def gradient(self, x: np.ndarray, n_dof: int) -> np.ndarray:
        """(n_dof,) gradient of the bending energy [uN] (the force the surroundings exert)."""
        change, jacobian, _, _ = self._geometry(x)
        values = (self.stiffness * np.sin(change))[:, None] * jacobian
        return np.bincount(self.dof.ravel(), values.ravel(), minlength=n_dof)

    def blocks(self, x: np.ndarray, exact: bool) -> np.ndarray:
        """(n_joints, 6, 6) Hessian of each joint's energy [uN / um] over (x_a, x_b, x_c).

        ``exact`` False keeps only k max(cos(Delta), 0) (d theta/dx)(d theta/dx)^T, positive
        semi-definite.
        """
        x = np.ascontiguousarray(x, dtype=float)
        return joint_kernels.blocks(x, self.nodes, self.floor, self.reference_angle, self.stiffness, exact)

    def force_resolution(self, x: np.ndarray, n_dof: int) -> np.ndarray:
        """(n_dof,) how precisely the joints' forces at each DOF are known at positions ``x``
        [uN]: 4 eps max |x| sum over the node's joints of k (1 / |u|^2 + 1 / |v|^2) (module
        notes); zero at nodes without joints."""
        _, jacobian, uu, vv = self._geometry(x)
        active = np.any(jacobian != 0.0, axis=1)
        sensitivity = self.stiffness * (1.0 / uu + 1.0 / vv)
        per_node = np.where(active, sensitivity, 0.0)[:, None] * np.ones((1, 6))
        scale = 4.0 * np.finfo(float).eps * float(np.max(np.abs(x)))
        return scale * np.bincount(self.dof.ravel(), per_node.ravel(), minlength=n_dof)

    def virial(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(2, 2) sum over joint nodes of g_n (x) y_n [uN um]: the joints' part of V0 P with
        ``y`` the reference positions X, of det F V0 sigma with ``y`` = ``x``.

        Each joint's forces sum to zero, so the origin of ``y`` does not matter.
        """
        change, jacobian, _, _ = self._geometry(x)
        force = ((self.stiffness * np.sin(change))[:, None] * jacobian).reshape(-1, 3, 2)
        return np.einsum("nki,nkj->ij", force, y[self.nodes])


def fiber_joints(network: Network, modulus_MPa: float) -> FiberJoints:
    """The joints of a network's fibers with springs of modulus ``modulus_MPa`` (module notes).

    Parameters
    ----------
    network : Network
        Elements are listed in order along each fiber.
    modulus_MPa : float [MPa]
        E of the bending stiffness E I, > 0.

    Returns
    -------
    FiberJoints
    """
    nodes = network.element_nodes
    fiber = network.element_fiber
    joined = np.flatnonzero((fiber[:-1] == fiber[1:]) & (nodes[:-1, 1] == nodes[1:, 0]))
    triple = np.column_stack([nodes[joined, 0], nodes[joined, 1], nodes[joined + 1, 1]])
    length = network.element_contour_length
    diameter = 0.5 * (network.element_diameter[joined] + network.element_diameter[joined + 1])
    mean_length = 0.5 * (length[joined] + length[joined + 1])
    stiffness = float(modulus_MPa) * np.pi * diameter**4 / 64.0 / mean_length
    floor = STRETCH_FLOOR * np.column_stack([network.element_length[joined], network.element_length[joined + 1]])
    reference = FiberJoints(triple.astype(np.int64), stiffness, np.zeros(len(joined)), floor)
    angle = reference._geometry(network.node_position - network.centre)[0]  # the solver's coordinates
    return FiberJoints(triple.astype(np.int64), stiffness, angle, floor)
