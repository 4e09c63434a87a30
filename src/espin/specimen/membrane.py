"""Total-Lagrangian membrane finite elements of a specimen (scikit-fem).

The in-plane displacement u(X) [mm] is interpolated by bilinear quadrilaterals (linear
triangles on a triangle mesh) and integrated with the Gauss rule of order 2 (four points per
quadrilateral). At a quadrature point F = I + grad u; the material returns the nominal stress P
and its tangent A = dP/dF. With thickness t [mm] (unchanged: the membrane carries in-plane F
only), the internal forces and their tangent are

    f_a = t integral of P : grad(v_a) dA       [N],
    K_ab = t integral of grad(v_b) : A : grad(v_a) dA   [N / mm],

so the residual of equilibrium is f (no body or surface loads; the grips are prescribed
displacements). Units: mm, MPa, N (MPa mm^2 = N).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from skfem import Basis, BilinearForm, ElementQuad1, ElementTriP1, ElementVector, LinearForm, MeshTri, asm

__all__ = ["Membrane"]


@LinearForm
def _internal(v, w):
    return w.t * np.einsum("ij...,ij...->...", w.P, v.grad)


@BilinearForm
def _tangent(u, v, w):
    return w.t * np.einsum("ijkl...,kl...,ij...->...", w.A, u.grad, v.grad)


class Membrane:
    """The finite-element space of a specimen mesh and its assembled forces.

    Parameters
    ----------
    mesh
        A scikit-fem ``MeshQuad`` or ``MeshTri`` [mm].
    thickness_mm
        Specimen thickness t [mm].

    Attributes
    ----------
    basis : skfem.Basis
        Vector basis; DOF order as scikit-fem's (``basis.nodal_dofs[c]`` = component c).
    n_points : int
        Quadrature points (elements x points per element), the order of every per-point array.
    """

    def __init__(self, mesh, thickness_mm: float) -> None:
        element = ElementTriP1() if isinstance(mesh, MeshTri) else ElementQuad1()
        self.mesh = mesh
        self.thickness = float(thickness_mm)
        self.basis = Basis(mesh, ElementVector(element), intorder=2)
        self.n_elements = mesh.nelements
        self.points_per_element = self.basis.X.shape[-1]
        self.n_points = self.n_elements * self.points_per_element
        self.weight = (self.basis.dx * 1.0).ravel()  # dA of each point [mm^2]

    @property
    def n_dofs(self) -> int:
        return self.basis.N

    def _to_points(self, field: np.ndarray) -> np.ndarray:
        """(..., n_elements, n_qp) -> (n_points, ...)."""
        return np.moveaxis(field.reshape(field.shape[:-2] + (self.n_points,)), -1, 0)

    def _to_field(self, points: np.ndarray) -> np.ndarray:
        """(n_points, ...) -> (..., n_elements, n_qp)."""
        moved = np.moveaxis(points, 0, -1)
        return moved.reshape(moved.shape[:-1] + (self.n_elements, self.points_per_element))

    def deformation_gradient(self, u: np.ndarray) -> np.ndarray:
        """F = I + grad u at every point, (n_points, 2, 2)."""
        grad = self.basis.interpolate(u).grad  # [i, J, element, point]
        return self._to_points(grad) + np.eye(2)

    def internal_force(self, P: np.ndarray) -> np.ndarray:
        """f [N] from the nominal stress (n_points, 2, 2) [MPa]."""
        return asm(_internal, self.basis, P=self._to_field(P), t=self.thickness)

    def tangent(self, A: np.ndarray) -> sp.csr_matrix:
        """K [N/mm] from the tangent (n_points, 2, 2, 2, 2) [MPa]."""
        return asm(_tangent, self.basis, A=self._to_field(A), t=self.thickness).tocsr()

    def element_mean(self, points: np.ndarray) -> np.ndarray:
        """Area-weighted mean over each element's points, (n_elements, ...)."""
        w = self.weight.reshape(self.n_elements, self.points_per_element)
        values = points.reshape((self.n_elements, self.points_per_element) + points.shape[1:])
        shape = (self.n_elements, self.points_per_element) + (1,) * (points.ndim - 1)
        return np.sum(values * w.reshape(shape), axis=1) / w.sum(axis=1).reshape(shape[:1] + shape[2:])

    def point_coordinates(self) -> np.ndarray:
        """Reference coordinates of the points, (n_points, 2) [mm]."""
        return self._to_points(self.basis.mapping.F(self.basis.X))
