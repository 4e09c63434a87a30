"""Compiled loops over the FE^2 points of a batch (numba): evaluation, tangent and Cholesky.

:class:`espin.specimen.batched_points.BatchedRVE` calls each of these once per Newton round for
all the points that need it (no Python per point):

* :func:`evaluate`: the kinematics, the fiber law's return mapping
  (:func:`espin.mechanics.kernels.law_update`), the element forces and stiffnesses and the
  residual of the inner DOF of every point;
* :func:`factorize`: the tangent K_II of every point filled into the shared pattern
  (:func:`espin.mechanics.kernels.fill_tangent`) and factorized by a sparse Cholesky
  factorization with one symbolic analysis (:class:`CholeskyPattern`) for all points, reporting
  per point whether K_II is positive definite;
* :func:`solve`: the two triangular solves of every point, with the backward-error check and
  refinement of :class:`espin.mechanics.linear_solvers.Factorization`.

The Cholesky factorization is left-looking by 2 x 2 node blocks (a node's two DOFs share their
pattern): each index read serves 8 multiply-adds, and every entry of L gets the updates of the
scalar left-looking factorization in the same order, so the factors are those of the scalar one.
At the default RVE (L/D 60 x 3, 930 inner DOF) it takes 0.16 ms per point against 0.28 ms for
the scalar one, and it has no per-call cost (docs/performance.md, FE^2 points in batches).
Compiled code is cached on disk like :mod:`espin.mechanics.kernels`.

Units as in the callers: um, uN, uN/um, MPa.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp

from espin.mechanics import kernels
from espin.mechanics.linear_solvers import _nested_dissection

__all__ = ["CholeskyPattern", "evaluate", "factorize", "solve"]

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

_REFINEMENT_STEPS = 2  # as espin.mechanics.linear_solvers
_BACKWARD_ERROR_TOL = 1e-14


@dataclass(frozen=True, eq=False)
class CholeskyPattern:
    """The symbolic Cholesky factorization P K P^T = L L^T of one symmetric sparsity pattern
    of 2 x 2 node blocks (the DOFs 2 i, 2 i + 1 of node i), L stored by node blocks.

    Attributes
    ----------
    perm : (n,) int64
        Row i of P K P^T is row ``perm[i]`` of K (METIS nested dissection of the node graph,
        the ordering of :mod:`espin.mechanics.linear_solvers`; a node's two DOFs stay together).
    a_ptr, a_row, a_src : int64
        The lower triangle of P K P^T by columns: column j holds rows ``a_row[a_ptr[j]:a_ptr[j+1]]``
        (>= j) whose values are ``K.data[a_src[...]]``.
    l_ptr, l_row : int64
        The block pattern of L by block columns (node J: DOFs 2 J, 2 J + 1 of the permuted
        order): block rows ``l_row[l_ptr[J]:l_ptr[J+1]]``, the diagonal block first, ascending.
        Block q holds L[2 R + a, 2 J + b] at 4 q + 2 a + b (the diagonal block's upper entry 0).
    r_ptr, r_col : int64
        The block pattern of L by block rows, without the diagonal: the block columns C < J
        with a block L[J, C] != 0.
    k_ptr, k_col : int64
        K's own CSR pattern (for the residual of a solve).
    """

    perm: np.ndarray
    a_ptr: np.ndarray
    a_row: np.ndarray
    a_src: np.ndarray
    l_ptr: np.ndarray
    l_row: np.ndarray
    r_ptr: np.ndarray
    r_col: np.ndarray
    k_ptr: np.ndarray
    k_col: np.ndarray

    @classmethod
    def of(cls, K: sp.csr_matrix) -> CholeskyPattern:
        """The analysis of the sorted CSR pattern ``K`` (values unused) of 2 x 2 node blocks."""
        n = K.shape[0]
        if n % 2:
            raise ValueError(f"K has {n} rows: the batched Cholesky factorization takes 2 x 2 node blocks")
        nodes = sp.csr_matrix((np.ones(K.nnz), K.indices // 2, K.indptr), shape=(n, n // 2))
        nodes = sp.csr_matrix(nodes[::2] + nodes[1::2])  # the node graph
        perm = _nested_dissection(K)
        if perm is None or np.any(perm[1::2] != perm[::2] + 1) or np.any(perm[::2] % 2):
            order = sp.csgraph.reverse_cuthill_mckee(nodes, symmetric_mode=True)
            perm = np.stack([2 * order, 2 * order + 1], axis=1).ravel()
        position = np.empty(n, dtype=np.int64)
        position[perm] = np.arange(n)
        row = position[np.repeat(np.arange(n), np.diff(K.indptr))]
        col = position[K.indices]
        lower = np.flatnonzero(row >= col)
        order = lower[np.lexsort((row[lower], col[lower]))]
        a_ptr = np.searchsorted(col[order], np.arange(n + 1)).astype(np.int64)
        a_row = row[order].astype(np.int64)
        # The lower triangle of the permuted node graph by columns, and L's block pattern.
        node_row, node_col = row[lower] // 2, col[lower] // 2
        node_lower = sp.csc_matrix((np.ones(len(lower)), (node_row, node_col)), shape=(n // 2, n // 2))
        node_lower.sum_duplicates()
        node_lower.sort_indices()
        l_ptr, l_row = _symbolic(n // 2, node_lower.indptr.astype(np.int64), node_lower.indices.astype(np.int64))
        m = n // 2
        by_row = sp.csr_matrix((np.ones(len(l_row)), l_row, l_ptr), shape=(m, m)).T.tocsr()  # CSC of L^T
        by_row.sort_indices()
        row_of = np.repeat(np.arange(m), np.diff(by_row.indptr))
        strict = by_row.indices < row_of
        r_col = by_row.indices[strict].astype(np.int64)
        r_ptr = np.concatenate([[0], np.cumsum(np.bincount(row_of[strict], minlength=m))])
        return cls(
            perm=perm.astype(np.int64),
            a_ptr=a_ptr,
            a_row=a_row,
            a_src=order.astype(np.int64),
            l_ptr=l_ptr,
            l_row=l_row,
            r_ptr=r_ptr.astype(np.int64),
            r_col=r_col,
            k_ptr=K.indptr.astype(np.int64),
            k_col=K.indices.astype(np.int64),
        )

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The arrays :func:`factorize` takes: a_ptr, a_row, a_src, l_ptr, l_row, r_ptr, r_col."""
        return (self.a_ptr, self.a_row, self.a_src, self.l_ptr, self.l_row, self.r_ptr, self.r_col)

    @property
    def nnz(self) -> int:
        """Values of L as stored (4 per block)."""
        return 4 * len(self.l_row)

    def factor(self, values: np.ndarray) -> sp.csc_matrix:
        """L from its stored ``values`` (nnz,), as a sparse matrix in the permuted order."""
        block_col = np.repeat(np.arange(len(self.l_ptr) - 1), np.diff(self.l_ptr))
        a, b = np.divmod(np.arange(4), 2)
        rows = (2 * self.l_row[:, None] + a).ravel()
        cols = (2 * block_col[:, None] + b).ravel()
        n = len(self.perm)
        return sp.csc_matrix((values, (rows, cols)), shape=(n, n))


def _symbolic(n: int, a_ptr: np.ndarray, a_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column patterns of L from the lower triangle's: column j is its own rows united with
    those of its children in the elimination tree (below j)."""
    children: list[list[int]] = [[] for _ in range(n)]
    columns: list[np.ndarray] = []
    for j in range(n):
        parts = [a_row[a_ptr[j] : a_ptr[j + 1]], np.array([j])]
        parts += [columns[c][1:] for c in children[j]]
        rows = np.unique(np.concatenate(parts))
        columns.append(rows)
        if len(rows) > 1:
            children[int(rows[1])].append(j)
    sizes = np.array([len(c) for c in columns], dtype=np.int64)
    l_ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    l_row = np.concatenate(columns).astype(np.int64) if n else np.zeros(0, dtype=np.int64)
    return l_ptr, l_row


@_jit
def evaluate(
    z: np.ndarray,
    F: np.ndarray,
    plastic_start: np.ndarray,
    near: np.ndarray,
    border: np.ndarray,
    nodes: np.ndarray,
    reference_unit: np.ndarray,
    l0: np.ndarray,
    area: np.ndarray,
    tortuosity: np.ndarray,
    adt: float,
    law: tuple[float, float, float, float],
    length: np.ndarray,
    unit: np.ndarray,
    stress: np.ndarray,
    plastic: np.ndarray,
    recruited: np.ndarray,
    force: np.ndarray,
    stiffness: np.ndarray,
    residual: np.ndarray,
) -> np.ndarray:
    """Every point's network at its inner DOF ``z`` (k, n) and its border at x = F X.

    ``plastic_start``: (k, e) plastic stretches at the step's start; ``near``: (k, e) plastic
    stretches that start the return mapping, or (0, 0) for none; ``border``: (n_border, 2)
    reference border positions [um] (relative to the centre); ``law``: E_t, E_b, b_p, c_p;
    ``adt``: a_p dt (capped). The outputs (points first) are filled for the admissible points.
    Returns (k,) bool: admissible (z finite, every element's return mapping converged).
    """
    k, n = z.shape
    n_inner = n // 2
    e_count = l0.size
    n_nodes = n_inner + border.shape[0]
    x = np.empty((n_nodes, 2))
    stretch = np.empty(e_count)
    adt_all = np.full(e_count, adt)
    tangent = np.empty(e_count)
    plastic_rate = np.empty(e_count)
    no_guess = np.empty(0)
    ok = np.ones(k, dtype=np.bool_)
    Et, Eb, bp, cp = law
    for i in range(k):
        for j in range(n):
            if not math.isfinite(z[i, j]):
                ok[i] = False
        if not ok[i]:
            continue
        for j in range(n_inner):
            x[j, 0], x[j, 1] = z[i, 2 * j], z[i, 2 * j + 1]
        for j in range(border.shape[0]):
            X0, X1 = border[j, 0], border[j, 1]
            x[n_inner + j, 0] = F[i, 0, 0] * X0 + F[i, 0, 1] * X1
            x[n_inner + j, 1] = F[i, 1, 0] * X0 + F[i, 1, 1] * X1
        for e in range(e_count):
            vx = x[nodes[e, 1], 0] - x[nodes[e, 0], 0]
            vy = x[nodes[e, 1], 1] - x[nodes[e, 0], 1]
            size = math.hypot(vx, vy)
            length[i, e] = size
            if size > 0.0:
                unit[i, e, 0], unit[i, e, 1] = vx / size, vy / size
            else:
                unit[i, e, 0], unit[i, e, 1] = reference_unit[e, 0], reference_unit[e, 1]
            stretch[e] = size / l0[e]
        guess = near[i] if near.shape[0] else no_guess
        failed = kernels.law_update(
            stretch,
            plastic_start[i],
            tortuosity,
            adt_all,
            guess,
            Et,
            Eb,
            bp,
            cp,
            stress[i],
            plastic[i],
            tangent,
            recruited[i],
            plastic_rate,
        )
        if failed:
            ok[i] = False
            continue
        for j in range(n):
            residual[i, j] = 0.0
        for e in range(e_count):
            T = stress[i, e] * area[e]
            force[i, e] = T
            stiffness[i, e] = tangent[e] * area[e] / l0[e]
            tx, ty = T * unit[i, e, 0], T * unit[i, e, 1]
            a, b = 2 * nodes[e, 0], 2 * nodes[e, 1]
            if a < n:
                residual[i, a] += -tx
                residual[i, a + 1] += -ty
            if b < n:
                residual[i, b] += tx
                residual[i, b + 1] += ty
    return ok


@_jit
def element_stiffness(
    length: np.ndarray, force: np.ndarray, stiffness: np.ndarray, l0: np.ndarray, clipped: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Axial dT/dl and transverse T / l stiffness [uN/um] of one point's elements (the
    per-point solver's; ``clipped``: both at least 0)."""
    e_count = l0.size
    axial = np.empty(e_count)
    transverse = np.empty(e_count)
    for e in range(e_count):
        floor = kernels.STRETCH_FLOOR * l0[e]
        t = force[e] / max(length[e], floor) if length[e] > floor else 0.0
        a = stiffness[e]
        if clipped:
            a, t = max(a, 0.0), max(t, 0.0)
        axial[e], transverse[e] = a, t
    return axial, transverse


@_jit
def factorize(
    rows: np.ndarray,
    targets: np.ndarray,
    length: np.ndarray,
    unit: np.ndarray,
    force: np.ndarray,
    stiffness: np.ndarray,
    l0: np.ndarray,
    clipped: bool,
    slot: np.ndarray,
    nnz: int,
    pattern: tuple[np.ndarray, ...],
    K: np.ndarray,
    L: np.ndarray,
) -> np.ndarray:
    """The tangents K_II of the points ``rows`` of the element arrays ((k, e): length, unit,
    force, stiffness) into rows ``targets`` of ``K`` (., nnz) and their Cholesky factors into
    the same rows of ``L`` (., nnz(L)). ``pattern``: :meth:`CholeskyPattern.arrays`.
    Returns (len(rows),) bool: positive definite (factorized)."""
    a_ptr, a_row, a_src, l_ptr, l_row, r_ptr, r_col = pattern[:7]
    n = len(a_ptr) - 1
    out = np.zeros(len(rows), dtype=np.bool_)
    no_joints = np.empty(0)
    x = np.zeros((n, 2))
    following = np.empty(n // 2, dtype=np.int64)
    for j in range(len(rows)):
        i, t = rows[j], targets[j]
        axial, transverse = element_stiffness(length[i], force[i], stiffness[i], l0, clipped)
        K[t] = kernels.fill_tangent(slot, axial, transverse, unit[i], no_joints, nnz)
        out[j] = _cholesky(K[t], a_ptr, a_row, a_src, l_ptr, l_row, r_ptr, r_col, L[t], x, following)
    return out


@_jit
def _cholesky(
    values: np.ndarray,
    a_ptr: np.ndarray,
    a_row: np.ndarray,
    a_src: np.ndarray,
    l_ptr: np.ndarray,
    l_row: np.ndarray,
    r_ptr: np.ndarray,
    r_col: np.ndarray,
    Lx: np.ndarray,
    x: np.ndarray,
    following: np.ndarray,
) -> bool:
    """Left-looking Cholesky factorization of the permuted K (``values`` in K's pattern) into
    ``Lx`` by 2 x 2 node blocks (:class:`CholeskyPattern`); False at a pivot that is not
    positive (K not positive definite). ``x``: (n, 2) workspace. Every entry of L gets its
    updates in the order of the scalar left-looking factorization (column by column)."""
    m = len(l_ptr) - 1
    for J in range(m):
        following[J] = l_ptr[J] + 1  # the next block row of block column J to meet
    for J in range(m):
        j0 = 2 * J
        for p in range(l_ptr[J], l_ptr[J + 1]):
            R = 2 * l_row[p]
            x[R, 0] = x[R, 1] = x[R + 1, 0] = x[R + 1, 1] = 0.0
        for b in range(2):
            for q in range(a_ptr[j0 + b], a_ptr[j0 + b + 1]):
                x[a_row[q], b] += values[a_src[q]]
        for t in range(r_ptr[J], r_ptr[J + 1]):
            C = r_col[t]
            p = following[C]  # l_row[p] == J: the block L[J, C]
            a00, a01, a10, a11 = Lx[4 * p], Lx[4 * p + 1], Lx[4 * p + 2], Lx[4 * p + 3]
            for q in range(p, l_ptr[C + 1]):
                R = 2 * l_row[q]
                b00, b01, b10, b11 = Lx[4 * q], Lx[4 * q + 1], Lx[4 * q + 2], Lx[4 * q + 3]
                x[R, 0] = x[R, 0] - b00 * a00 - b01 * a01
                x[R + 1, 0] = x[R + 1, 0] - b10 * a00 - b11 * a01
                x[R, 1] = x[R, 1] - b00 * a10 - b01 * a11
                x[R + 1, 1] = x[R + 1, 1] - b10 * a10 - b11 * a11
            following[C] = p + 1
        # Column 2 J, then column 2 J + 1 with its last update from column 2 J.
        d = x[j0, 0]
        if not d > 0.0:
            return False
        s0 = math.sqrt(d)
        first = l_ptr[J]
        Lx[4 * first] = s0
        Lx[4 * first + 1] = 0.0
        l10 = x[j0 + 1, 0] / s0
        Lx[4 * first + 2] = l10
        for p in range(first + 1, l_ptr[J + 1]):
            R = 2 * l_row[p]
            Lx[4 * p] = x[R, 0] / s0
            Lx[4 * p + 2] = x[R + 1, 0] / s0
        d = x[j0 + 1, 1] - l10 * l10
        if not d > 0.0:
            return False
        s1 = math.sqrt(d)
        Lx[4 * first + 3] = s1
        for p in range(first + 1, l_ptr[J + 1]):
            R = 2 * l_row[p]
            Lx[4 * p + 1] = (x[R, 1] - Lx[4 * p] * l10) / s1
            Lx[4 * p + 3] = (x[R + 1, 1] - Lx[4 * p + 2] * l10) / s1
    return True


@_jit
def _triangular(Lx: np.ndarray, l_ptr: np.ndarray, l_row: np.ndarray, y: np.ndarray) -> None:
    """y <- (L L^T)^-1 y in place (permuted order; L by 2 x 2 node blocks)."""
    m = len(l_ptr) - 1
    for J in range(m):
        j0, first = 2 * J, l_ptr[J]
        y0 = y[j0] / Lx[4 * first]
        y1 = (y[j0 + 1] - Lx[4 * first + 2] * y0) / Lx[4 * first + 3]
        y[j0], y[j0 + 1] = y0, y1
        for p in range(first + 1, l_ptr[J + 1]):
            R = 2 * l_row[p]
            y[R] = y[R] - Lx[4 * p] * y0 - Lx[4 * p + 1] * y1
            y[R + 1] = y[R + 1] - Lx[4 * p + 2] * y0 - Lx[4 * p + 3] * y1
    for J in range(m - 1, -1, -1):
        j0, first = 2 * J, l_ptr[J]
        s0, s1 = y[j0], y[j0 + 1]
        for p in range(first + 1, l_ptr[J + 1]):
            R = 2 * l_row[p]
            s1 = s1 - Lx[4 * p + 1] * y[R] - Lx[4 * p + 3] * y[R + 1]
        y1 = s1 / Lx[4 * first + 3]
        s0 -= Lx[4 * first + 2] * y1
        for p in range(first + 1, l_ptr[J + 1]):
            R = 2 * l_row[p]
            s0 = s0 - Lx[4 * p] * y[R] - Lx[4 * p + 2] * y[R + 1]
        y[j0], y[j0 + 1] = s0 / Lx[4 * first], y1


@_jit
def _solve_once(Lx: np.ndarray, perm: np.ndarray, l_ptr: np.ndarray, l_row: np.ndarray, b: np.ndarray) -> np.ndarray:
    y = np.empty(b.size)
    for i in range(b.size):
        y[i] = b[perm[i]]
    _triangular(Lx, l_ptr, l_row, y)
    out = np.empty(b.size)
    for i in range(b.size):
        out[perm[i]] = y[i]
    return out


@_jit
def _backward_error(
    K: np.ndarray, k_ptr: np.ndarray, k_col: np.ndarray, norm: float, b: np.ndarray, x: np.ndarray
) -> tuple[np.ndarray, float]:
    """b - K x and ||b - K x|| / (||K|| ||x|| + ||b||) (max norms)."""
    n = b.size
    r = np.empty(n)
    big_x, big_b, big_r = 0.0, 0.0, 0.0
    for i in range(n):
        s = 0.0
        for p in range(k_ptr[i], k_ptr[i + 1]):
            s += K[p] * x[k_col[p]]
        r[i] = b[i] - s
        big_x, big_b, big_r = max(big_x, abs(x[i])), max(big_b, abs(b[i])), max(big_r, abs(r[i]))
    return r, big_r / max(norm * big_x + big_b, 2.2250738585072014e-308)


@_jit
def solve(
    rows: np.ndarray,
    K: np.ndarray,
    L: np.ndarray,
    B: np.ndarray,
    perm: np.ndarray,
    l_ptr: np.ndarray,
    l_row: np.ndarray,
    k_ptr: np.ndarray,
    k_col: np.ndarray,
) -> np.ndarray:
    """X with K_i X[j, :, c] = B[j, :, c], i = ``rows[j]`` (K (., nnz) in K's pattern, L its
    factor from :func:`factorize`, B (len(rows), n, m)): a solve per column, refined (at most
    twice) while its backward error exceeds 1e-14, as :meth:`espin.mechanics.linear_solvers.Factorization.solve`."""
    k, n, m = B.shape
    X = np.empty((k, n, m))
    for j in range(k):
        Kj, Lj = K[rows[j]], L[rows[j]]
        norm = 0.0
        for i in range(n):
            s = 0.0
            for p in range(k_ptr[i], k_ptr[i + 1]):
                s += abs(Kj[p])
            norm = max(norm, s)
        for c in range(m):
            b = B[j, :, c].copy()
            x = _solve_once(Lj, perm, l_ptr, l_row, b)
            r, error = _backward_error(Kj, k_ptr, k_col, norm, b, x)
            for _ in range(_REFINEMENT_STEPS):
                if error <= _BACKWARD_ERROR_TOL:
                    break
                x_new = x + _solve_once(Lj, perm, l_ptr, l_row, r)
                r_new, error_new = _backward_error(Kj, k_ptr, k_col, norm, b, x_new)
                if error_new >= error:
                    break
                x, r, error = x_new, r_new, error_new
            X[j, :, c] = x
    return X
