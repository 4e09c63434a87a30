"""The low-rank change of a factorized tangent at the slack/taut kink (docs/model.md section 4).

An element that crosses the kink of the fiber law within a Newton step enters the step's
linear model with its force linearized on the other side of the kink: its axial stiffness
changes by delta_e along its d l_e / d z = b_e (a change of rank one) and its force by a
shift c_e. The corrected step solves (K + B diag(delta) B^T) d = -r - B c with the
factorization of K alone, by the Sherman-Morrison-Woodbury formula: with dz = K^-1 (-r)
and Y = K^-1 B,

    d = dz - Y (c + w),   (I + diag(delta) B^T Y) w = diag(delta) (B^T dz - B^T Y c).

:class:`KinkColumns` keeps, for one factorized tangent, the columns b_e and K^-1 b_e of the
elements met so far and their Gram matrix B^T K^-1 B, so that each element costs one solve
per tangent (in a batch with the others new to it) and a step over m elements costs one
product by an (n, m) block beyond a few m x m operations.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

__all__ = ["KinkColumns"]


class KinkColumns:
    """Columns b_e and K^-1 b_e of elements at one factorized tangent K.

    Parameters
    ----------
    solve
        K^-1 applied to an (n, m) block of columns.
    """

    def __init__(self, solve: Callable[[np.ndarray], np.ndarray]) -> None:
        self._solve = solve
        self._index: dict[int, int] = {}
        self._modes = sp.csc_matrix((0, 0))  # B, (n, k), sparse: d l_e / d z touches 4 DOF
        self._solved = np.zeros((0, 0), order="F")  # Y = K^-1 B, (n, k)
        self._gram = np.zeros((0, 0))  # B^T Y, (k, k), symmetric

    def missing(self, elements: np.ndarray) -> np.ndarray:
        """The ``elements`` (indices) whose columns are not held yet."""
        return np.array([e for e in elements.tolist() if e not in self._index], dtype=np.int64)

    def add(self, elements: np.ndarray, modes: np.ndarray) -> None:
        """Hold the columns of new ``elements``: ``modes`` (n, m) their b_e (one batched solve).

        Parameters
        ----------
        elements : (m,) int
            Element indices, none held yet.
        modes : (n, m) float64
            d l_e / d z of each, dimensionless.
        """
        solved = np.asfortranarray(self._solve(modes))
        new = sp.csc_matrix(modes)
        k = len(self._index)
        cross = self._modes.T @ solved if k else np.zeros((0, len(elements)))
        corner = new.T @ solved
        self._gram = np.block([[self._gram, cross], [cross.T, 0.5 * (corner + corner.T)]])
        self._modes = sp.hstack([self._modes, new], format="csc") if k else new
        self._solved = np.hstack([self._solved, solved]) if k else solved
        self._index.update((int(e), k + j) for j, e in enumerate(elements.tolist()))

    def step(self, direction: np.ndarray, elements: np.ndarray, delta: np.ndarray, shift: np.ndarray) -> np.ndarray:
        """Solution d of (K + B diag(delta) B^T) d = -r - B shift over held ``elements``.

        Parameters
        ----------
        direction : (n,) float64
            dz = K^-1 (-r).
        elements : (m,) int
            Held elements (indices), the columns of B.
        delta : (m,) float64 [uN/um]
            Change of each element's axial stiffness.
        shift : (m,) float64 [uN]
            Change of each element's force model at the current iterate.
        """
        columns = np.array([self._index[e] for e in elements.tolist()], dtype=np.int64)
        gram = self._gram[np.ix_(columns, columns)]
        projected = self._modes[:, columns].T @ direction - gram @ shift  # B^T u, u = dz - Y c
        capacitance = np.eye(len(columns)) + delta[:, None] * gram
        w = np.linalg.solve(capacitance, delta * projected)
        return direction - self._solved[:, columns] @ (shift + w)
