"""Element kinematics and assembly of nodal forces and tangents into a fixed sparse pattern.

Degrees of freedom: node n has DOF 2n (x) and 2n + 1 (y). Inner nodes come first in a
Network, so the inner DOF are 0 .. 2 n_inner - 1 and the border DOF follow.

For an element with unit vector a (from e1 to e2), axial force T and length l, the gradient of
the stored energy with respect to the node positions is -T a at e1 and +T a at e2 (the force
the element exerts on e1 is +T a), and the 2 x 2 stiffness block is

    k = (dT/dl) a (x) a + (T / l) (I - a (x) a),

entering the 4 x 4 element matrix as [[k, -k], [-k, k]] (paper 3.1.4; docs/model.md section 4).
With fiber bending on (:mod:`espin.mechanics.bending`), each joint's 6 x 6 matrix over its
three nodes is summed into the same pattern.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from espin.geometry.network import Network
from espin.mechanics import kernels
from espin.mechanics.bending import FiberJoints

__all__ = ["Kinematics", "SparsePattern", "NetworkAssembler"]


@dataclass(frozen=True, eq=False)
class Kinematics:
    """Current geometry of every element.

    Attributes
    ----------
    vector : (n_elements, 2) float64 [um]
        x_e2 - x_e1.
    length : (n_elements,) float64 [um]
        l = |x_e2 - x_e1|.
    unit : (n_elements, 2) float64
        a = vector / length (the reference direction where l vanishes).
    """

    vector: np.ndarray
    length: np.ndarray
    unit: np.ndarray


@dataclass(frozen=True, eq=False)
class SparsePattern:
    """A CSR sparsity pattern and where each element-matrix entry is summed into it.

    Attributes
    ----------
    matrix : scipy.sparse.csr_matrix
        Pattern with zero data; copied with new data by :meth:`fill`.
    slot : (n_elements * 16 + n_joints * 36,) int32
        Position in ``matrix.data`` of each element-matrix entry (row-major 4 x 4 blocks,
        then the joints' 6 x 6 blocks), -1 for entries outside this block of the tangent.
    """

    matrix: sp.csr_matrix
    slot: np.ndarray

    def fill(
        self, axial: np.ndarray, transverse: np.ndarray, unit: np.ndarray, joint_values: np.ndarray
    ) -> sp.csr_matrix:
        """A copy of the pattern holding the element (and joint) matrices' sum
        (:func:`espin.mechanics.kernels.fill_tangent`; ``joint_values`` flattened, or empty)."""
        out = self.matrix.copy()
        out.data = kernels.fill_tangent(self.slot, axial, transverse, unit, joint_values, self.matrix.nnz)
        return out


def _pattern(rows: np.ndarray, cols: np.ndarray, keep: np.ndarray, shape: tuple[int, int]) -> SparsePattern:
    entry = np.flatnonzero(keep)
    r, c = rows[entry], cols[entry]
    linear = r * shape[1] + c
    unique, slot = np.unique(linear, return_inverse=True)
    ur, uc = np.divmod(unique, shape[1])
    indptr = np.concatenate([[0], np.cumsum(np.bincount(ur, minlength=shape[0]))])
    matrix = sp.csr_matrix((np.zeros(len(unique)), uc, indptr), shape=shape)
    if len(unique) > np.iinfo(np.int32).max:
        raise ValueError(f"a tangent block with {len(unique)} nonzeros is beyond the 32-bit slot map")
    slot_of_entry = np.full(len(rows), -1, dtype=np.int32)
    slot_of_entry[entry] = slot
    return SparsePattern(matrix=matrix, slot=slot_of_entry)


class NetworkAssembler:
    """Assembly of one network's forces and tangents (patterns computed once).

    Parameters
    ----------
    network
        The network; node positions X are taken relative to its centre.
    joints
        The fiber joints whose bending springs enter the tangents (None: no bending).
    """

    def __init__(self, network: Network, joints: FiberJoints | None = None) -> None:
        self.network = network
        self.joints = joints
        self.n_inner_dof = 2 * network.n_inner
        self.n_dof = 2 * network.n_nodes
        nodes = network.element_nodes
        dof = np.stack([2 * nodes[:, 0], 2 * nodes[:, 0] + 1, 2 * nodes[:, 1], 2 * nodes[:, 1] + 1], 1)
        self._dof = dof
        self._rows = np.repeat(dof, 4, axis=1).ravel()
        self._cols = np.tile(dof, (1, 4)).ravel()
        if joints is not None:
            self._rows = np.concatenate([self._rows, np.repeat(joints.dof, 6, axis=1).ravel()])
            self._cols = np.concatenate([self._cols, np.tile(joints.dof, (1, 6)).ravel()])
        self._patterns: dict[str, SparsePattern] = {}
        self.reference = network.node_position - network.centre
        """(n_nodes, 2) float64 [um]: X relative to the RVE centre."""
        vector = network.element_vector
        self._reference_unit = vector / np.hypot(vector[:, 0], vector[:, 1])[:, None]

    # -- geometry ---------------------------------------------------------------------------
    def positions(self, inner: np.ndarray, F: np.ndarray) -> np.ndarray:
        """(n_nodes, 2) current positions: inner nodes given, border nodes x = F X."""
        border = self.reference[self.network.n_inner :] @ F.T
        return np.concatenate([inner.reshape(-1, 2), border])

    def kinematics(self, x: np.ndarray) -> Kinematics:
        """Element vectors, lengths and unit vectors at node positions ``x`` (n_nodes, 2)."""
        vector, length, unit = kernels.kinematics(
            np.ascontiguousarray(x, dtype=float), self.network.element_nodes, self._reference_unit
        )
        return Kinematics(vector=vector, length=length, unit=unit)

    def lengths(self, x: np.ndarray) -> np.ndarray:
        """(n_elements,) element lengths [um] at node positions ``x`` (n_nodes, 2)."""
        return kernels.lengths(np.ascontiguousarray(x, dtype=float), self.network.element_nodes)

    # -- forces -----------------------------------------------------------------------------
    def gradient(self, force: np.ndarray, kin: Kinematics) -> np.ndarray:
        """(n_dof,) gradient of the stored energy: -T a at e1, +T a at e2, summed per DOF.

        At equilibrium its inner part vanishes; its border part is the force that the
        surroundings exert on the border nodes. Without the joints' part
        (:meth:`espin.mechanics.bending.FiberJoints.gradient`).
        """
        return kernels.gradient(self._dof, force, kin.unit, self.n_dof)

    # -- tangents ---------------------------------------------------------------------------
    def pattern(self, part: str) -> SparsePattern:
        """Pattern of the block ``"II"`` (inner-inner), ``"IB"`` or ``"BB"``, built once."""
        if part not in self._patterns:
            n = self.n_inner_dof
            r, c = self._rows, self._cols
            if part == "II":
                keep, shape, shift = (r < n) & (c < n), (n, n), (0, 0)
            elif part == "IB":
                keep, shape, shift = (r < n) & (c >= n), (n, self.n_dof - n), (0, n)
            elif part == "BB":
                keep, shape, shift = (r >= n) & (c >= n), (self.n_dof - n,) * 2, (n, n)
            else:
                raise ValueError(f"unknown block {part!r}")
            self._patterns[part] = _pattern(r - shift[0], c - shift[1], keep, shape)
        return self._patterns[part]

    def _joint_values(self, joint_blocks: np.ndarray | None) -> np.ndarray:
        """The joints' matrices flattened (zeros where none are given; empty without joints)."""
        if self.joints is None:
            return np.empty(0)
        return np.zeros(36 * len(self.joints.stiffness)) if joint_blocks is None else joint_blocks.ravel()

    def tangent(
        self,
        part: str,
        axial: np.ndarray,
        transverse: np.ndarray,
        kin: Kinematics,
        joint_blocks: np.ndarray | None = None,
    ) -> sp.csr_matrix:
        """Assemble one block of the stiffness matrix (see :meth:`pattern`).

        Parameters
        ----------
        part
            ``"II"``, ``"IB"`` or ``"BB"``.
        axial : (n_elements,) float64 [uN/um]
            dT/dl of each element.
        transverse : (n_elements,) float64 [uN/um]
            T / l of each element (the geometric stiffness; callers may clip it).
        kin
            Current element geometry.
        joint_blocks : (n_joints, 6, 6) float64 [uN/um], optional
            The joints' matrices (:meth:`espin.mechanics.bending.FiberJoints.blocks`), with
            bending on.
        """
        return self.pattern(part).fill(axial, transverse, kin.unit, self._joint_values(joint_blocks))

    def tangents(
        self,
        parts: tuple[str, ...],
        axial: np.ndarray,
        transverse: np.ndarray,
        kin: Kinematics,
        joint_blocks: np.ndarray | None = None,
    ) -> list[sp.csr_matrix]:
        """Several blocks of the stiffness matrix from one evaluation of the element matrices."""
        joint_values = self._joint_values(joint_blocks)
        return [self.pattern(part).fill(axial, transverse, kin.unit, joint_values) for part in parts]
