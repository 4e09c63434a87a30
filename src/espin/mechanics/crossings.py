"""Fused (bonded) crossings: an opt-in rotational spring between the fibers meeting at a cross-link.

In the paper's model a cross-link is a pin: the fibers meeting there turn freely about it. A
crossing joins four element ends (coordination z = 4), Maxwell's isostatic threshold for
central-force networks in 2-D, so the network has (almost) no lateral stiffness and lateral
``free`` contracts without bound. In an electrospun mat many crossings are fused (solvent or
thermal welding while the jet lands), and a fused crossing resists the relative rotation of
its fibers.

With ``fiber.fused_crossing_fraction`` = phi > 0, a fraction phi of the cross-links (each node
where two or more fibers meet is fused with probability phi, drawn once from the RVE's seed)
carries, for every pair of element ends (arms) b-a of one fiber and b-c of another fiber, the
spring of :mod:`espin.mechanics.bending`

    W = k (1 - cos(theta - theta_0)),    k = c E I / lbar,    I = pi D^4 / 64,

theta the angle between the two arms at b, theta_0 its as-deposited value, lbar the mean
contour length of the two arms and D their mean diameter; E is the fiber's Young's modulus,
``fiber.bending_modulus_MPa`` (the same E I bends the fibers between crossings: a fiber stiff
enough in bending to hold a welded junction also bends along itself) and c =
``fiber.fused_crossing_stiffness_ratio`` the weld's rotational stiffness relative to that of a
fiber joint of the same two elements (1, default: the weld is as compliant as the fiber bent
over one element; larger: a stiffer weld, infinity a rigid one; the relative angle of the
fibers is then fixed and all compliance is the fibers' bending). A fused crossing of two
fibers carries four such springs (A1-B1, A1-B2, A2-B1, A2-B2), which lock the angle between
the fibers; rigid motions cost nothing. phi = 0 (default) adds no term: the paper's model.

The springs are :class:`~espin.mechanics.bending.FiberJoints` triples (a, b, c) with a on one
fiber and c on another, so their energy, gradient, Hessian blocks and virial (the stress they
carry) are those of the fiber joints; :func:`with_crossings` appends them to the fiber joints.
docs/model.md section 3.
"""

from __future__ import annotations

import numpy as np

from espin.geometry.network import Network
from espin.mechanics.bending import FiberJoints
from espin.mechanics.fiber_law import STRETCH_FLOOR

__all__ = ["crossing_joints", "with_crossings"]

_SEED_STREAM = 0x6675736564  # "fused": the draw of fused crossings has its own stream of the RVE seed


def crossing_joints(
    network: Network, modulus_MPa: float, fraction: float, seed: int, stiffness_ratio: float = 1.0
) -> FiberJoints:
    """The springs of the fused crossings of a network (module notes).

    Parameters
    ----------
    network : Network
    modulus_MPa : float [MPa]
        E of the bond stiffness E I / lbar, > 0.
    fraction : float
        phi in (0, 1]: probability that a crossing is fused (1: all).
    seed : int
        Seed of the draw (the RVE's seed; the draw uses its own stream of it).
    stiffness_ratio : float
        c: the springs are c E I / lbar (1: as stiff as a fiber joint of the same elements).

    Returns
    -------
    FiberJoints
        One joint per pair of arms of different fibers at each fused crossing, ordered by node.
    """
    nodes = network.element_nodes
    n_el = len(nodes)
    # Arms: every element seen from each of its two ends (centre b, far end a).
    centre = np.concatenate([nodes[:, 0], nodes[:, 1]])
    far = np.concatenate([nodes[:, 1], nodes[:, 0]])
    element = np.concatenate([np.arange(n_el), np.arange(n_el)])
    order = np.lexsort((element, centre))
    centre, far, element = centre[order], far[order], element[order]
    fiber = network.element_fiber[element]
    starts = np.flatnonzero(np.r_[True, centre[1:] != centre[:-1]])
    counts = np.diff(np.r_[starts, len(centre)])
    # A crossing: a node where arms of two or more fibers meet.
    crossing_of_group = np.array([len(np.unique(fiber[s : s + c])) > 1 for s, c in zip(starts, counts)], dtype=bool)
    groups = np.flatnonzero(crossing_of_group)
    rng = np.random.default_rng([int(seed), _SEED_STREAM])
    fused = groups[rng.random(len(groups)) < fraction] if fraction < 1.0 else groups
    first, second = [], []
    for g in fused:
        arms = np.arange(starts[g], starts[g] + counts[g])
        i, j = np.triu_indices(len(arms), k=1)
        other = fiber[arms[i]] != fiber[arms[j]]
        first.append(arms[i][other])
        second.append(arms[j][other])
    if first:
        p, q = np.concatenate(first), np.concatenate(second)
    else:
        p = q = np.zeros(0, dtype=np.int64)
    triple = np.column_stack([far[p], centre[p], far[q]]).astype(np.int64)
    ep, eq = element[p], element[q]
    length = network.element_contour_length
    diameter = 0.5 * (network.element_diameter[ep] + network.element_diameter[eq])
    mean_length = 0.5 * (length[ep] + length[eq])
    stiffness = float(stiffness_ratio) * float(modulus_MPa) * np.pi * diameter**4 / 64.0 / mean_length
    floor = STRETCH_FLOOR * np.column_stack([network.element_length[ep], network.element_length[eq]])
    reference = FiberJoints(triple, stiffness, np.zeros(len(triple)), floor)
    angle = reference._geometry(network.node_position)[0]
    return FiberJoints(triple, stiffness, angle, floor)


def with_crossings(joints: FiberJoints | None, crossings: FiberJoints) -> FiberJoints:
    """The fiber joints followed by the crossing springs, as one set of joints."""
    if joints is None:
        return crossings
    return FiberJoints(
        np.concatenate([joints.nodes, crossings.nodes]),
        np.concatenate([joints.stiffness, crossings.stiffness]),
        np.concatenate([joints.reference_angle, crossings.reference_angle]),
        np.concatenate([joints.floor, crossings.floor]),
    )
