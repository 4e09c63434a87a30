"""Homogenized stresses of a network in equilibrium (paper 3.1.5; docs/model.md section 5).

Reference volume V0 = L^2 N_l D. Index convention P_iJ: i spatial, J reference.

* Nominal (first Piola-Kirchhoff) stress, exact for a network in equilibrium whose border
  nodes follow x = F X (virial theorem): P = (1 / V0) sum_e T_e a_e (x) dX_e.
* The paper's Eq. 17: (1 / V0) sum_e t_e A_e L0_e a_e (x) a_e (fiber volume A L0). It differs
  from P F^T by the factor L0 / l per element.
* Kirchhoff stress per reference volume: (1 / V0) sum_e T_e l_e a_e (x) a_e, equal to P F^T
  in equilibrium (virial theorem in the current configuration) and to det F times the Cauchy
  stress; the stress the authors' code reports.
* In-plane Cauchy stress at unchanged thickness: (1 / (det F V0)) sum_e T_e l_e a_e (x) a_e.

With fiber bending on (:mod:`espin.mechanics.bending`), the joints' forces g_n add
(1 / V0) sum_n g_n (x) X_n to P and (1 / (det F V0)) sum_n g_n (x) x_n to the Cauchy stress:
both sums together are the border reactions' virial, exact in equilibrium. The paper's Eq. 17
counts the fibers' axial stresses only.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from espin.geometry.network import Network
from espin.mechanics.assembly import Kinematics
from espin.mechanics.bending import FiberJoints

__all__ = ["nominal_stress", "paper_stress", "kirchhoff_stress", "cauchy_stress"]


def nominal_stress(
    network: Network, force: np.ndarray, kin: Kinematics, joints: FiberJoints | None = None, x: np.ndarray | None = None
) -> np.ndarray:
    """(2, 2) nominal stress P [MPa] from element forces T [uN] (docs/model.md section 5),
    plus the fiber joints' part at node positions ``x`` [um] with bending on."""
    virial = np.einsum("e,ei,eJ->iJ", force, kin.unit, network.element_vector)
    if joints is not None:
        virial = virial + joints.virial(cast(np.ndarray, x), network.node_position)  # x comes with joints
    return virial / network.reference_volume


def paper_stress(network: Network, stress: np.ndarray, kin: Kinematics) -> np.ndarray:
    """(2, 2) stress of the paper's Eq. 17 [MPa] from element stresses t [MPa]."""
    weight = stress * network.element_area * network.element_contour_length
    return np.einsum("e,ei,ej->ij", weight, kin.unit, kin.unit) / network.reference_volume


def kirchhoff_stress(
    network: Network, force: np.ndarray, kin: Kinematics, joints: FiberJoints | None = None, x: np.ndarray | None = None
) -> np.ndarray:
    """(2, 2) Kirchhoff stress tau = P F^T = det F sigma [MPa] per reference volume from element
    forces T [uN], plus the fiber joints' part at node positions ``x`` [um] with bending on."""
    virial = np.einsum("e,ei,ej->ij", force * kin.length, kin.unit, kin.unit)
    if joints is not None:
        x = cast(np.ndarray, x)  # given with joints
        virial = virial + joints.virial(x, x)
    return virial / network.reference_volume


def cauchy_stress(
    network: Network,
    force: np.ndarray,
    kin: Kinematics,
    F: np.ndarray,
    joints: FiberJoints | None = None,
    x: np.ndarray | None = None,
) -> np.ndarray:
    """(2, 2) in-plane Cauchy stress [MPa] at unchanged thickness, plus the fiber joints'
    part at node positions ``x`` [um] with bending on."""
    weight = force * kin.length
    virial = np.einsum("e,ei,ej->ij", weight, kin.unit, kin.unit)
    if joints is not None:
        x = cast(np.ndarray, x)  # given with joints
        virial = virial + joints.virial(x, x)
    return virial / (np.linalg.det(F) * network.reference_volume)
