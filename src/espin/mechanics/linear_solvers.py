"""Sparse symmetric linear solvers for the Newton tangent (docs/model.md section 4).

Newton's method factorizes the tangent stiffness K once per iteration. K is symmetric, may be
indefinite (compressed elements contribute a negative geometric stiffness), and keeps one
sparsity pattern for the whole analysis of a network while its values change. A
:class:`LinearSolver` therefore caches everything that depends on the pattern only (a
fill-reducing ordering, a symbolic analysis) and redoes it only when the pattern changes. Its
:class:`Factorization` solves ``K x = b`` and reports the inertia of K (the number of negative
eigenvalues) so that the equilibrium solver can tell whether the exact tangent is positive
definite.

Backends
--------
``superlu``
    scipy's SuperLU, always available. Symmetric mode with diagonal pivoting only
    (``diag_pivot_thresh=0``), so the factorization is ``P K P^T = L D L^T`` stored as LU and
    the signs of the pivots give the inertia (Sylvester's law). The fill-reducing ordering
    is computed once per pattern, by METIS nested dissection of the node graph (package
    ``pymetis``) before the first factorization, or by SuperLU's ``MMD_AT_PLUS_A`` within
    the first factorization when pymetis is not installed; the other factorizations permute
    K symmetrically and use the natural order.
``pardiso``
    Intel MKL PARDISO (MKL found by the optional package ``pypardiso``): Cholesky
    (``mtype=2``) while the matrices are positive definite, in single precision from
    :data:`SINGLE_PRECISION_FROM` unknowns, else LDL^T of a real symmetric indefinite
    matrix (``mtype=-2``) with Bunch-Kaufman pivoting and inertia; METIS ordering, symbolic
    analysis once per pattern. 2.5-5 times faster than SuperLU on plla tangents.

A factorization in single precision solves to the accuracy its caller asks
(:meth:`Factorization.solve`'s ``rtol``) by iterative refinement against K in double
precision, and factorizes K again in double precision when refinement cannot get there (an
ill-conditioned K). A Newton direction needs no more than a small relative residual of its
own; the converged state is judged by the residual of the equations in double precision.

``make_linear_solver("auto")`` takes PARDISO when it works on this machine, else SuperLU.
MKL runs with the thread count set by the caller (``threadpoolctl.threadpool_limits``).
"""

from __future__ import annotations

import ctypes
import logging
import weakref
from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import cache, cached_property
from types import TracebackType
from typing import TYPE_CHECKING, ClassVar, Self

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from espin.core.errors import ConfigError, SolverError, StepFailureKind, StepNotConverged
from espin.core.mkl import load_mkl

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = [
    "LINEAR_SOLVER_NAMES",
    "Factorization",
    "LinearSolver",
    "PardisoSolver",
    "SuperLUSolver",
    "make_linear_solver",
]

logger = logging.getLogger(__name__)

LINEAR_SOLVER_NAMES: tuple[str, ...] = ("auto", "superlu", "pardiso")
"""Names accepted by :func:`make_linear_solver` (config key ``solver.linear``)."""

_REFINEMENT_STEPS = 2
"""Iterative refinement steps at most per solve of a double-precision factorization."""

_SINGLE_REFINEMENT_STEPS = 4
"""Iterative refinement steps at most per solve of a single-precision factorization before it
is factorized again in double precision (on a plla tangent the error of the solution falls
from 7e-5 to 9e-9, 1e-12 and 4e-14 over three steps)."""

SINGLE_PRECISION_FROM = 5_000
"""Unknowns from which PARDISO factorizes a positive definite K in single precision. Single
against double precision on plla tangents (2 threads, ``benchmarks/bench_single_precision.py``):
factorization 0.86 of the time and solve 0.83 at 4,672 unknowns, 0.72 and 0.72 at 19,068, 0.59
and 0.69 at 60,426; below a few thousand unknowns it gains less than 10 %."""

_BACKWARD_ERROR_TOL = 1e-14
"""Normwise backward error ||K x - b|| / (||K|| ||x|| + ||b||) (max norms) that needs no
refinement; a backward-stable solve gives about 1e-16."""


class _Releasable:
    """Context-manager support for objects holding solver memory: ``release()`` on exit."""

    def release(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()


class Factorization(_Releasable, ABC):
    """A numeric factorization of a symmetric matrix K, ready to solve ``K x = b``.

    A factorization belongs to the solver that made it and stays usable until it is released
    or the solver factorizes another matrix; using it afterwards raises
    :class:`~espin.core.errors.SolverError`. It is a context manager that releases it on exit.

    A solve is as accurate as its caller asks (:meth:`solve`): by default its normwise
    backward error is checked with a product by (a private copy of) K and, if it exceeds
    1e-14, the solution is refined up to two times (unless the factorization is
    :attr:`backward_stable`); a factorization in :attr:`single_precision` is refined until
    it reaches the accuracy asked, else factorized again in double precision.

    Attributes
    ----------
    n : int
        Order of K (number of unknowns).
    n_perturbed : int
        Pivots the backend replaced by a small value to avoid a breakdown (PARDISO on a
        singular or nearly singular K); 0 for SuperLU, which never perturbs. When nonzero,
        the factorization and its inertia are those of a slightly perturbed K.
    nnz_factor : int
        Nonzeros the backend stores for its factors (L and U for SuperLU, L for PARDISO).
    """

    def __init__(self, matrix: sp.csr_matrix, n_perturbed: int, nnz_factor: int) -> None:
        self.n = matrix.shape[0]
        self.n_perturbed = n_perturbed
        self.nnz_factor = nnz_factor
        self._matrix: sp.csr_matrix | None = matrix
        self._valid = True

    @property
    @abstractmethod
    def n_negative(self) -> int | None:
        """Number of negative eigenvalues of K, or None if the backend cannot tell.

        K is positive definite when this is 0 and no pivot was perturbed (``n_perturbed``).
        """

    @property
    def backward_stable(self) -> bool:
        """Whether its solves are backward stable without a check: a Cholesky factorization,
        which exists only for a positive definite K and needs no pivoting (normwise backward
        errors of a few machine epsilons; at most 1.4e-16 over the 192 Newton solves of the
        plla test). The check is skipped for it."""
        return False

    @property
    def single_precision(self) -> bool:
        """Whether the factors are in single precision (refined to the accuracy asked)."""
        return False

    def solve(self, b: ArrayLike, rtol: float = 0.0) -> np.ndarray:
        """Solve ``K x = b``.

        Parameters
        ----------
        b : (n,) or (n, k) array_like of float
            Right-hand side(s), in the units of K times those of x.
        rtol : float
            The accuracy the caller needs, as the relative residual ||K x - b|| / ||b|| (2-norm,
            of every column). 0 (default): the full accuracy of double precision, a normwise
            backward error of at most 1e-14 (checked, and refined if needed, unless the
            factorization is :attr:`backward_stable`). Positive, e.g. a Newton direction's
            forcing term: a double-precision factorization solves as with 0, a
            single-precision one is refined only while its residual is over ``rtol``.
            ``inf``: no check and no refinement (no product by K), for solutions whose use is
            verified otherwise, e.g. the kink correction's columns, whose corrected step is
            kept only if its own residual is lower.

        Returns
        -------
        x : ndarray of float64, same shape as b
            The solution(s).

        Raises
        ------
        SolverError
            If the factorization was released or replaced by a newer one of its solver.
        ValueError
            If b does not have n rows.
        """
        self._check_valid()
        b = np.asarray(b, dtype=np.float64)
        if b.ndim not in (1, 2) or b.shape[0] != self.n:
            raise ValueError(f"b must have shape ({self.n},) or ({self.n}, k), got {b.shape}")
        x = self._solve(b)
        if rtol == np.inf:
            return x
        if self.single_precision:
            refined = self._refined_single(b, x, rtol)
            if refined is not None:
                return refined
            self._promote()
            x = self._solve(b)
        if self.backward_stable:
            return x
        r, error = self._residual(b, x)
        for _ in range(_REFINEMENT_STEPS):
            if error <= _BACKWARD_ERROR_TOL:
                break
            x_new = x + self._solve(r)
            r_new, error_new = self._residual(b, x_new)
            if error_new >= error:  # refinement stalled
                break
            x, r, error = x_new, r_new, error_new
        if error > _BACKWARD_ERROR_TOL:
            logger.debug("%s solve: backward error %.1e after refinement", type(self).__name__, error)
        return x

    def _refined_single(self, b: np.ndarray, x: np.ndarray, rtol: float) -> np.ndarray | None:
        """``x`` from the single-precision factors, refined against K until its relative
        residual is at most ``rtol`` (0: its backward error at most 1e-14); None when
        refinement stalls or runs out of steps first."""
        b_norm = np.maximum(np.linalg.norm(b, axis=0), np.finfo(float).tiny)

        def error_of(x: np.ndarray) -> tuple[np.ndarray, float]:
            if not rtol:
                return self._residual(b, x)
            r = b - self._matrix @ x
            return r, float(np.max(np.linalg.norm(r, axis=0) / b_norm))

        tolerance = rtol or _BACKWARD_ERROR_TOL
        r, error = error_of(x)
        for _ in range(_SINGLE_REFINEMENT_STEPS):
            if error <= tolerance:
                return x
            x_new = x + self._solve(r)
            r_new, error_new = error_of(x_new)
            if error_new >= error:
                break
            x, r, error = x_new, r_new, error_new
        if error <= tolerance:
            return x
        logger.debug("single-precision solve at %.1e against %.1e: factorized in double precision", error, tolerance)
        return None

    def _promote(self) -> None:  # pragma: no cover - only single-precision factorizations are promoted
        """Factorize K again in double precision (a :attr:`single_precision` backend's)."""
        raise NotImplementedError

    def release(self) -> None:
        """Free the factorization's memory; it cannot solve afterwards."""
        if self._valid:
            self._valid = False
            self._matrix = None
            self._free()

    def _check_valid(self) -> None:
        if not self._valid:
            raise SolverError(
                "this factorization was released or replaced by a newer factorize() of its solver; factorize K again"
            )

    @cached_property
    def _norm_inf(self) -> float:
        """Max norm of K (its largest absolute row sum)."""
        assert self._matrix is not None, "released"
        return float(abs(self._matrix).sum(axis=1).max())

    def _residual(self, b: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, float]:
        """Residual ``b - K x`` and the largest normwise backward error over columns."""
        r = b - self._matrix @ x
        scale = self._norm_inf * np.abs(x).max(axis=0) + np.abs(b).max(axis=0)
        return r, float(np.max(np.abs(r).max(axis=0) / np.maximum(scale, np.finfo(float).tiny)))

    @abstractmethod
    def _solve(self, b: np.ndarray) -> np.ndarray:
        """Solve once (no refinement) for a float64 b of shape (n,) or (n, k)."""

    @abstractmethod
    def _free(self) -> None:
        """Drop the factors (called once, by :meth:`release`)."""


class LinearSolver(_Releasable, ABC):
    """Factorizes symmetric sparse matrices that share one sparsity pattern.

    Pattern-dependent work (ordering, symbolic analysis) is done on the first call and again
    only when the pattern changes. A solver holds one factorization at a time: each call to
    :meth:`factorize` releases the previous one. Use two solvers to keep two factorizations.
    A solver is a context manager that releases all its memory on exit.

    Attributes
    ----------
    numeric_factorizations : int
        Numerical factorizations made so far: one per :meth:`factorize`, and one more for each
        single-precision factorization factorized again in double precision.
    """

    name: ClassVar[str]
    """Backend name, as accepted by :func:`make_linear_solver`."""

    uses_openblas: ClassVar[bool]
    """Whether the backend runs on numpy / scipy's OpenBLAS (SuperLU's dense kernels do).
    If not, the Newton loop keeps OpenBLAS on one thread, so that its threads do not spin on
    the cores the backend needs."""

    def __init__(self) -> None:
        self._pattern: _Pattern | None = None
        self._current: Factorization | None = None
        self.numeric_factorizations = 0

    def factorize(self, K: sp.csr_matrix) -> Factorization:
        """Factorize a symmetric matrix.

        Parameters
        ----------
        K : (n, n) scipy.sparse CSR matrix or array of float64
            Symmetric matrix with both triangles stored. Keeping the same pattern (``indptr``
            and ``indices``) across calls lets the solver reuse its symbolic work; explicit
            zeros are part of the pattern.

        Returns
        -------
        Factorization
            Valid until the next call to ``factorize`` or ``release``.

        Raises
        ------
        StepNotConverged
            With kind ``singular`` when K cannot be factorized (exactly singular for SuperLU, a
            zero pivot for PARDISO): a property of the tangent, so the caller's step is cut.
        SolverError
            If the backend itself fails (memory, a matrix too large for its interface).
        TypeError
            If K is not a float64 CSR matrix.
        ValueError
            If K is not square or its pattern is not symmetric.
        """
        K = _canonical_csr(K)
        if self._current is not None:
            previous, self._current = self._current, None
            previous.release()
        pattern = self._pattern
        new_pattern = pattern is None or not pattern.matches(K)
        if pattern is None or new_pattern:
            self._pattern = None
            pattern = _Pattern.of(K)
        factorization = self._factorize(pattern.matrix(K.data), new_pattern)
        self.numeric_factorizations += 1
        self._pattern = pattern
        self._current = factorization
        return factorization

    def release(self) -> None:
        """Free the current factorization and all pattern-dependent data."""
        if self._current is not None:
            self._current.release()
            self._current = None
        self._pattern = None
        self._release_pattern_data()

    @abstractmethod
    def _factorize(self, K: sp.csr_matrix, new_pattern: bool) -> Factorization:
        """Factorize K (a private canonical copy, kept by the factorization for residuals);
        redo the pattern-dependent work first if ``new_pattern``."""

    @abstractmethod
    def _release_pattern_data(self) -> None:
        """Free the pattern-dependent data (ordering, symbolic analysis)."""


# --------------------------------------------------------------------------------------------
# SuperLU


class SuperLUSolver(LinearSolver):
    """scipy's SuperLU in symmetric mode with diagonal pivoting, ordering reused per pattern.

    The first factorization of a pattern computes a symmetric fill-reducing permutation p
    (see :func:`_nested_dissection`): METIS nested dissection of the graph whose vertices
    are the nodes (the 2 x 2 blocks of a network tangent). Every factorization gathers the
    values of ``K[p][:, p]`` through a precomputed index map and factorizes them with
    ``permc_spec="NATURAL"``. On plla tangents (6.5e4 unknowns) the factors have 35-42 %
    fewer nonzeros and factorizations are 2.5-3 times faster than with SuperLU's
    ``MMD_AT_PLUS_A`` (minimum degree on the structure of K + K^T); the ordering costs
    about 0.25 s once per pattern (docs/performance.md).

    Without the ``pymetis`` package the first factorization of a pattern uses
    ``MMD_AT_PLUS_A`` and keeps SuperLU's final column permutation as p; later ones
    factorize ``K[p][:, p]`` in the natural order as above.

    With ``diag_pivot_thresh=0`` SuperLU takes every pivot on the diagonal unless it is
    exactly zero, so ``L U = P K P^T`` with ``U = D L^T``: the signs of diag(U) are the
    inertia of K. If SuperLU had to take an off-diagonal pivot (a zero on the diagonal of a
    Schur complement), the factorization still solves but the inertia is unknown (None).
    Without off-diagonal pivoting an indefinite K could lose accuracy; the backward error
    check of every solve (see :class:`Factorization`) would refine it.
    """

    name = "superlu"
    uses_openblas = True

    def __init__(self) -> None:
        super().__init__()
        self._ordering: _SymmetricPermutation | None = None

    def _factorize(self, K: sp.csr_matrix, new_pattern: bool) -> Factorization:
        if new_pattern:
            self._ordering = None
            perm = _nested_dissection(K)
            if perm is None:
                logger.debug("pymetis not installed: SuperLU orders with MMD_AT_PLUS_A")
                # K is symmetric, so its CSR arrays are also its CSC arrays.
                lu = _splu(sp.csc_matrix((K.data, K.indices, K.indptr), shape=K.shape), "MMD_AT_PLUS_A")
                self._ordering = _SymmetricPermutation.of(K, np.argsort(lu.perm_c))
                return _SuperLUFactorization(lu, K, perm=None)
            self._ordering = _SymmetricPermutation.of(K, perm)
        ordering = self._ordering
        assert ordering is not None, "an ordering is made with the pattern"
        lu = _splu(ordering.apply(K), "NATURAL")
        return _SuperLUFactorization(lu, K, ordering.perm)

    def _release_pattern_data(self) -> None:
        self._ordering = None


_METIS_SEPARATORS = 2
"""Separators METIS computes at each bisection, keeping the smallest (METIS option ``nseps``);
2 instead of METIS' 1 gives 1-3 % fewer nonzeros in SuperLU's factors of plla tangents for
0.07 s more ordering."""


def _nested_dissection(K: sp.csr_matrix) -> np.ndarray | None:
    """METIS nested-dissection ordering of K's node graph, or None without ``pymetis``.

    Network tangents come in 2 x 2 blocks (DOFs 2i and 2i+1 of node i), so DOFs 2i and
    2i+1 whose rows have the same pattern make one vertex of the graph (they are
    indistinguishable for elimination); every other DOF is a vertex of its own, e.g. the
    free components of F appended under mixed control, or all DOFs of a matrix that is not
    2 x 2 blocked. Each vertex weighs its number of DOFs. On plla tangents the node graph
    gives SuperLU's factors as many nonzeros as the scalar graph (within 1 %), is ordered
    in less time (0.23 s against 0.28 s) and keeps the DOFs of a node together.

    Parameters
    ----------
    K : (n, n) canonical CSR matrix
        Symmetric pattern (values unused).

    Returns
    -------
    perm : (n,) int64 ndarray or None
        Row/column ``i`` of the permuted matrix is row/column ``perm[i]`` of K; the DOFs of
        a vertex stay consecutive and in their order. None if pymetis cannot be imported.
    """
    try:
        import pymetis
    except ImportError:
        return None
    n = K.shape[0]
    vertex = _node_vertices(K)
    n_vertices = int(vertex[-1]) + 1 if n else 0
    if n_vertices < 2:  # nothing to order (METIS fails on an empty graph)
        return np.arange(n)
    rows = vertex[np.repeat(np.arange(n), np.diff(K.indptr))]
    cols = vertex[K.indices]
    off_diagonal = rows != cols
    graph = sp.csr_matrix(
        (np.ones(np.count_nonzero(off_diagonal), dtype=bool), (rows[off_diagonal], cols[off_diagonal])),
        shape=(n_vertices, n_vertices),
    )  # duplicates summed: the quotient graph, without self-loops as METIS requires
    order, _ = pymetis.nested_dissection(
        pymetis.CSRAdjacency(graph.indptr, graph.indices),
        vweights=np.bincount(vertex),
        options=pymetis.Options(nseps=_METIS_SEPARATORS),
    )
    position = np.empty(n_vertices, dtype=np.int64)
    position[np.asarray(order)] = np.arange(n_vertices)
    return np.argsort(position[vertex], kind="stable")


def _node_vertices(K: sp.csr_matrix) -> np.ndarray:
    """Graph vertex of each DOF: 2i and 2i+1 share one if their rows have the same pattern.

    Parameters
    ----------
    K : (n, n) canonical CSR matrix
        Pattern with sorted indices.

    Returns
    -------
    vertex : (n,) int64 ndarray
        Nondecreasing vertex numbers 0, 1, ... in DOF order.
    """
    n = K.shape[0]
    n_pairs = n // 2
    length = np.diff(K.indptr)
    paired = length[0 : 2 * n_pairs : 2] == length[1 : 2 * n_pairs : 2]
    # compare the candidate rows entry by entry: sorted rows of equal length align
    entry_row = np.repeat(np.arange(n), length)
    candidate = entry_row < 2 * n_pairs
    candidate[candidate] = paired[entry_row[candidate] // 2]
    rows, columns = entry_row[candidate], K.indices[candidate]
    even = rows % 2 == 0
    differs = columns[even] != columns[~even]
    paired[rows[even][differs] // 2] = False
    starts = np.ones(n, dtype=bool)  # DOF begins a new vertex
    starts[1 : 2 * n_pairs : 2] = ~paired
    return np.cumsum(starts) - 1


def _splu(matrix: sp.csc_matrix, permc_spec: str) -> spla.SuperLU:
    try:
        return spla.splu(
            matrix,
            permc_spec=permc_spec,
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    except RuntimeError as exc:  # "Factor is exactly singular"
        raise StepNotConverged(
            f"SuperLU factorization of the {matrix.shape[0]}-unknown tangent failed: {exc}", StepFailureKind.SINGULAR
        ) from exc


class _SuperLUFactorization(Factorization):
    """SuperLU factors of K, or of ``K[perm][:, perm]`` if ``perm`` is given."""

    def __init__(self, lu: spla.SuperLU, K: sp.csr_matrix, perm: np.ndarray | None) -> None:
        super().__init__(K, n_perturbed=0, nnz_factor=int(lu.nnz))
        self._lu: spla.SuperLU | None = lu
        self._perm = perm
        self._symmetric_pivots = bool(np.array_equal(lu.perm_r, lu.perm_c))
        if not self._symmetric_pivots:
            logger.debug("SuperLU took off-diagonal pivots: inertia unknown")

    @cached_property
    def n_negative(self) -> int | None:
        """Number of negative eigenvalues of K (negative pivots), None after off-diagonal pivots.

        Computed on first access: extracting U costs a quarter to a third of a factorization.
        """
        if not self._symmetric_pivots:
            return None
        self._check_valid()
        assert self._lu is not None
        return int(np.count_nonzero(self._lu.U.diagonal() < 0.0))

    def _solve(self, b: np.ndarray) -> np.ndarray:
        lu = self._lu
        assert lu is not None, "released"
        if self._perm is None:
            return lu.solve(b)
        x = np.empty_like(b)
        x[self._perm] = lu.solve(b[self._perm])
        return x

    def _free(self) -> None:
        self._lu = None


@dataclass(frozen=True, eq=False)
class _SymmetricPermutation:
    """Gathers the values of ``K[perm][:, perm]`` for one pattern of K.

    Attributes
    ----------
    perm : (n,) int64
        Row/column ``i`` of the permuted matrix is row/column ``perm[i]`` of K.
    indptr, indices : int arrays
        CSR (= CSC, the matrix being symmetric) structure of the permuted matrix.
    source : (nnz,) int64
        Position in ``K.data`` of each stored value of the permuted matrix.
    """

    perm: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    source: np.ndarray

    @classmethod
    def of(cls, K: sp.csr_matrix, perm: np.ndarray) -> _SymmetricPermutation:
        """Index map of the symmetric permutation ``perm`` for K's pattern."""
        # 1-based positions: no entry is zero, so indexing cannot drop one
        positions = sp.csr_matrix((np.arange(1, K.nnz + 1), K.indices, K.indptr), shape=K.shape)
        permuted = positions[perm][:, perm]
        permuted.sort_indices()
        return cls(perm, permuted.indptr, permuted.indices, permuted.data - 1)

    def apply(self, K: sp.csr_matrix) -> sp.csc_matrix:
        """The permuted matrix ``K[perm][:, perm]`` (a new array of values)."""
        return sp.csc_matrix((K.data[self.source], self.indices, self.indptr), shape=K.shape)


# --------------------------------------------------------------------------------------------
# PARDISO

# MKL PARDISO error codes (oneMKL reference, pardiso "error" parameter).
_PARDISO_ERRORS = {
    -1: "input inconsistent",
    -2: "not enough memory",
    -3: "reordering problem",
    -4: "zero pivot, numerical factorization or iterative refinement problem",
    -5: "unclassified (internal) error",
    -6: "reordering failed",
    -7: "diagonal matrix is singular",
    -8: "32-bit integer overflow problem",
    -9: "not enough memory for out-of-core solver",
    -10: "error opening out-of-core files",
    -11: "read/write error with out-of-core files",
}
_SINGULAR_ERRORS = (-4, -7)  # a property of the tangent: the step is cut; the others are the machine's


class PardisoSolver(LinearSolver):
    """Intel MKL PARDISO: Cholesky first, LDL^T with inertia when K is not positive definite.

    MKL is found and loaded by the optional package ``pypardiso``; this class calls PARDISO
    itself so that it can keep the analysis of a pattern. PARDISO reads the upper triangle of
    K. It holds two PARDISO states: Cholesky (real symmetric positive definite, ``mtype=2``)
    and LDL^T (real symmetric indefinite, ``mtype=-2``). The first factorization of a pattern
    by either runs its analysis (METIS ordering, symbolic factorization: phase 11); later ones
    run only the numerical factorization (phase 22).

    A matrix is factorized by Cholesky while the previous one was positive definite (the
    Newton tangents of a tensile test nearly always are), as it takes less time than the
    LDL^T, and so do its solves (docs/performance.md). Cholesky stops at
    the first pivot that is not positive (PARDISO error -4); K is then factorized by LDL^T,
    and so is the next matrix unless this one turned out positive definite after all. A
    successful Cholesky factorization proves K positive definite (``n_negative = 0``, no
    perturbed pivot) up to its rounding: a negative eigenvalue smaller than that (about 1e-7
    ||K|| in single precision) can pass unseen, as its direction would in a solve.

    From :data:`SINGLE_PRECISION_FROM` unknowns the Cholesky factorization is in single
    precision (``iparm[27] = 1``, a third state): half the factor's memory, 0.59 of the
    double one's factorization time and 0.69 of its solve's at plla size. Its solves are
    refined against K in double precision to the accuracy asked
    (:meth:`Factorization.solve`); when refinement stalls short of it, K is factorized again
    in double precision (by Cholesky, or LDL^T if that fails), which then serves every later
    solve of this factorization.

    The LDL^T uses Bunch-Kaufman pivoting within supernodes, which keeps it stable on most
    indefinite K, and PARDISO reports the inertia (``iparm[21]``, ``iparm[22]``). Pivots it
    cannot stabilize are perturbed to +-1e-8 ||K|| (``n_perturbed``); PARDISO then refines
    every solution twice. Pivoting is restricted to supernodes, so small pivots can still
    cost accuracy; the backward error check of every solve (see :class:`Factorization`)
    refines it then.

    MKL uses the thread count in force (set it with ``threadpoolctl.threadpool_limits``).
    MKL PARDISO can crash when the thread count drops between the analysis and a later
    factorization, so every call on a PARDISO state runs with the thread count of its
    analysis, and a factorization made under a different thread count redoes the analysis
    first.

    Raises
    ------
    ConfigError
        If ``pypardiso`` or MKL cannot be loaded.
    """

    name = "pardiso"
    uses_openblas = False

    def __init__(self) -> None:
        super().__init__()
        self._cholesky = _PardisoHandle(_POSITIVE_DEFINITE)
        self._single = _PardisoHandle(_POSITIVE_DEFINITE, single_precision=True)
        self._ldlt = _PardisoHandle(_INDEFINITE)
        self._upper: _UpperTriangle | None = None
        self._definite = True  # the last matrix was positive definite: try Cholesky first
        for handle in self._handles:
            finalizer = weakref.finalize(self, handle.free)
            finalizer.atexit = False  # the process frees everything at exit anyway

    @property
    def _handles(self) -> tuple[_PardisoHandle, ...]:
        return self._cholesky, self._single, self._ldlt

    def _factorize(self, K: sp.csr_matrix, new_pattern: bool) -> Factorization:
        if new_pattern:
            self._upper = None
            for handle in self._handles:
                handle.free()
            self._upper = _UpperTriangle.of(K)
        values = self._upper_pattern.values(K)
        if self._definite:
            cholesky = self._cholesky_factors(values, single=K.shape[0] >= SINGLE_PRECISION_FROM)
            if cholesky is not None:
                return _PardisoFactorization(self, *cholesky, K, 0, 0)
        handle, values, n_negative, n_perturbed = self._ldlt_factors(values)
        return _PardisoFactorization(self, handle, values, K, n_negative, n_perturbed)

    def _cholesky_factors(self, values: np.ndarray, single: bool) -> tuple[_PardisoHandle, np.ndarray] | None:
        """The Cholesky factorization of the upper-triangle ``values`` (in single precision if
        asked and K's values fit): its handle and the values it holds; None at a pivot <= 0."""
        handle = self._cholesky
        if single:
            single_values = values.astype(np.float32)
            if np.all(np.isfinite(single_values)):
                handle, values = self._single, single_values
        try:
            handle.factorize(self._upper_pattern, values)
        except StepNotConverged:  # error -4: a pivot <= 0, K is not positive definite
            logger.debug("Cholesky met a pivot <= 0: LDL^T instead")
            return None
        return handle, values

    def _ldlt_factors(self, values: np.ndarray) -> tuple[_PardisoHandle, np.ndarray, int, int]:
        """The LDL^T factorization of the upper-triangle ``values``: its handle, the values,
        K's negative eigenvalues and the perturbed pivots."""
        self._ldlt.factorize(self._upper_pattern, values)
        iparm = self._ldlt.iparm
        if iparm[13]:
            logger.debug("PARDISO perturbed %d pivots (K nearly singular)", iparm[13])
        self._definite = not (iparm[22] or iparm[13])
        return self._ldlt, values, int(iparm[22]), int(iparm[13])

    @property
    def _upper_pattern(self) -> _UpperTriangle:
        assert self._upper is not None, "made with the pattern"
        return self._upper

    def _release_pattern_data(self) -> None:
        self._upper = None
        for handle in self._handles:
            handle.free()
        self._definite = True


_POSITIVE_DEFINITE, _INDEFINITE = 2, -2
"""PARDISO matrix types (``mtype``): real symmetric positive definite, real symmetric indefinite."""


class _PardisoHandle:
    """One PARDISO solver state (``pt``) for one matrix type.

    Parameters
    ----------
    mtype : int
        :data:`_POSITIVE_DEFINITE` (Cholesky) or :data:`_INDEFINITE` (LDL^T with
        Bunch-Kaufman pivoting and inertia).
    single_precision : bool
        Factors, values and right-hand sides in single precision (float32; ``iparm[27]``).

    Attributes
    ----------
    threads : int
        MKL threads of the current analysis; 0 when there is none.
    iparm : (64,) int32
        PARDISO's parameters (0-based), with the outputs of the last call.
    """

    def __init__(self, mtype: int, single_precision: bool = False) -> None:
        self._mkl = load_mkl()
        self.mtype = mtype
        self.single_precision = single_precision
        self._pt = np.zeros(64, dtype=np.int64)  # PARDISO's internal pointers
        self.iparm = np.zeros(64, dtype=np.int32)  # 0 selects MKL's default unless set below
        self.iparm[0] = 1  # use these iparm values
        self.iparm[1] = 2  # METIS nested dissection ordering
        self.iparm[7] = 0  # two steps of iterative refinement after perturbed pivots only
        self.iparm[9] = 8  # LDL^T: perturb pivots smaller than 1e-8 ||K||
        self.iparm[17] = -1  # report nonzeros of the factor in iparm[17]
        self.iparm[20] = 1  # LDL^T: Bunch-Kaufman 1x1 and 2x2 pivoting
        # Two-level factorization for LDL^T: about 10 % faster than the classic one on a plla
        # tangent (65,066 unknowns, 2 threads). Cholesky keeps the classic one: its two-level
        # variant is 10 % faster too but its results change with the MKL thread count (a curve
        # must not depend on the cores it ran on). The improved variant (10) is faster still but
        # neither reports the inertia nor stops Cholesky at a pivot <= 0 (it returns NaN): not used.
        self.iparm[23] = 0 if mtype == 2 else 1
        self.iparm[27] = int(single_precision)
        self.iparm[34] = 1  # zero-based ia, ja
        self.threads = 0

    def max_threads(self) -> int:
        """Threads MKL would use now in this thread (e.g. after threadpool_limits)."""
        return int(self._mkl.get_max_threads())

    def factorize(self, upper: _UpperTriangle, values: np.ndarray) -> None:
        """Numerical factorization (phase 22), after the analysis (phase 11) if this state has
        none for the MKL thread count in force."""
        threads = self.max_threads()
        if self.threads != threads:
            if self.threads:
                logger.debug("MKL threads changed from %d to %d: PARDISO analysis redone", self.threads, threads)
            self.free()
            self.threads = threads
            self.iparm[17] = -1  # ask phase 11 for this pattern's factor size
            self.call(11, upper, values)
        self.call(22, upper, values)

    def call(
        self, phase: int, upper: _UpperTriangle | None, values: np.ndarray | None, b: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Run a PARDISO phase; return x for phase 33 (b: F-ordered float64), else None."""
        c_int = ctypes.c_int32
        if upper is None or values is None:  # releasing memory: PARDISO reads no matrix, give it a valid one
            upper, values = _UpperTriangle.empty(), np.zeros(1)
        n = len(upper.indptr) - 1
        x = None if b is None else np.zeros_like(b, order="F")
        error = c_int(0)
        previous = self._mkl.set_num_threads_local(self.threads)
        try:
            self._mkl.pardiso(
                self._pt.ctypes.data,
                ctypes.byref(c_int(1)),  # maxfct
                ctypes.byref(c_int(1)),  # mnum
                ctypes.byref(c_int(self.mtype)),
                ctypes.byref(c_int(phase)),
                ctypes.byref(c_int(n)),
                values.ctypes.data,
                upper.indptr.ctypes.data_as(ctypes.POINTER(c_int)),
                upper.indices.ctypes.data_as(ctypes.POINTER(c_int)),
                None,  # perm: not used (iparm[4] = 0)
                ctypes.byref(c_int(1 if b is None or b.ndim == 1 else b.shape[1])),  # nrhs
                self.iparm.ctypes.data_as(ctypes.POINTER(c_int)),
                ctypes.byref(c_int(0)),  # msglvl: silent
                None if b is None else b.ctypes.data,
                None if x is None else x.ctypes.data,
                ctypes.byref(error),
            )
        finally:
            self._mkl.set_num_threads_local(previous)
        if error.value:
            reason = _PARDISO_ERRORS.get(error.value, "unknown error")
            message = f"PARDISO phase {phase} on the {n}-unknown tangent failed with error {error.value} ({reason})"
            if error.value in _SINGULAR_ERRORS:
                raise StepNotConverged(message, StepFailureKind.SINGULAR)
            raise SolverError(message)
        return x

    def free(self) -> None:
        """Release all of PARDISO's memory for this handle (phase -1)."""
        if self.threads:
            self.call(-1, None, None)
            self.threads = 0


class _PardisoFactorization(Factorization):
    """The numerical factorization held by one of a :class:`PardisoSolver`'s handles."""

    def __init__(
        self,
        solver: PardisoSolver,
        handle: _PardisoHandle,
        values: np.ndarray,
        K: sp.csr_matrix,
        n_negative: int,
        n_perturbed: int,
    ) -> None:
        super().__init__(K, n_perturbed, int(handle.iparm[17]))
        self._solver = solver
        self._handle = handle  # the PARDISO state (Cholesky, single or double, or LDL^T) holding the factors
        self._values: np.ndarray | None = values  # the factorized values (float32 in single precision)
        self._n_negative = n_negative

    @property
    def n_negative(self) -> int:
        """Number of negative eigenvalues of K (of the perturbed K if ``n_perturbed``)."""
        return self._n_negative

    @property
    def backward_stable(self) -> bool:
        """True for a Cholesky factorization (``mtype=2``), False for LDL^T."""
        return self._handle.mtype == _POSITIVE_DEFINITE

    @property
    def single_precision(self) -> bool:
        """Whether the factors are the single-precision Cholesky's."""
        return self._handle.single_precision

    def _solve(self, b: np.ndarray) -> np.ndarray:
        if self.single_precision:
            x = self._handle.call(33, self._solver._upper, self._values, np.asfortranarray(b, dtype=np.float32))
            assert x is not None, "phase 33 returns the solution"
            return x.astype(np.float64)
        x = self._handle.call(33, self._solver._upper, self._values, np.asfortranarray(b))
        assert x is not None, "phase 33 returns the solution"
        return x

    def _promote(self) -> None:
        assert self._matrix is not None, "valid"
        self._free()
        solver = self._solver
        values = solver._upper_pattern.values(self._matrix)
        cholesky = solver._cholesky_factors(values, single=False)
        if cholesky is not None:
            (self._handle, self._values), self._n_negative, self.n_perturbed = cholesky, 0, 0
        else:
            self._handle, self._values, self._n_negative, self.n_perturbed = solver._ldlt_factors(values)
        self.nnz_factor = int(self._handle.iparm[17])
        solver.numeric_factorizations += 1

    def _free(self) -> None:
        if self._solver._current is self:  # phase 0: free the numerical factors only
            self._handle.call(0, self._solver._upper, self._values)
        self._values = None


@dataclass(frozen=True, eq=False)
class _UpperTriangle:
    """The upper triangle of K's pattern, every diagonal entry stored, as PARDISO reads it.

    Attributes
    ----------
    indptr, indices : int32 arrays
        Zero-based CSR structure of the upper triangle (sorted, full diagonal).
    source : (nnz_upper,) int64
        Position in ``K.data`` of each entry; entries on ``inserted`` are ignored.
    inserted : int64 array
        Entries of diagonal positions missing from K's pattern (stored as zeros).
    """

    indptr: np.ndarray
    indices: np.ndarray
    source: np.ndarray
    inserted: np.ndarray

    @classmethod
    def of(cls, K: sp.csr_matrix) -> _UpperTriangle:
        """Index map of the upper triangle of K's (canonical) pattern."""
        n = K.shape[0]
        rows = np.repeat(np.arange(n), np.diff(K.indptr))
        upper = K.indices >= rows
        rows, cols, source = rows[upper], K.indices[upper], np.flatnonzero(upper)
        missing = np.setdiff1d(np.arange(n), rows[rows == cols])
        if missing.size:
            rows = np.concatenate([rows, missing])
            cols = np.concatenate([cols, missing])
            source = np.concatenate([source, np.full(missing.size, -1)])
            order = np.lexsort((cols, rows))
            rows, cols, source = rows[order], cols[order], source[order]
        if len(cols) > np.iinfo(np.int32).max:
            raise SolverError(f"K has {len(cols)} upper-triangle entries, more than PARDISO's 32-bit interface takes")
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
        return cls(indptr.astype(np.int32), cols.astype(np.int32), source, np.flatnonzero(source < 0))

    @classmethod
    def empty(cls) -> _UpperTriangle:
        """The pattern of a 0 x 0 matrix (with one dummy entry in ``indices``)."""
        return cls(np.zeros(1, np.int32), np.zeros(1, np.int32), np.zeros(0, np.int64), np.zeros(0, np.int64))

    def values(self, K: sp.csr_matrix) -> np.ndarray:
        """Values of the upper triangle of K (a new array)."""
        data = K.data[self.source]
        data[self.inserted] = 0.0
        return data


# --------------------------------------------------------------------------------------------
# Shared helpers and the factory


@dataclass(frozen=True, eq=False)
class _Pattern:
    """A copy of a canonical CSR sparsity pattern, to recognize it again."""

    indptr: np.ndarray
    indices: np.ndarray

    @classmethod
    def of(cls, K: sp.csr_matrix) -> _Pattern:
        """The pattern of K, after checking that it is symmetric."""
        structure = sp.csr_matrix((np.ones(K.nnz, dtype=bool), K.indices, K.indptr), shape=K.shape)
        transposed = structure.T.tocsr()
        transposed.sort_indices()
        if not (np.array_equal(transposed.indptr, K.indptr) and np.array_equal(transposed.indices, K.indices)):
            raise ValueError("K's sparsity pattern is not symmetric; store both triangles")
        return cls(K.indptr.copy(), K.indices.copy())

    def matches(self, K: sp.csr_matrix) -> bool:
        """Whether K has this pattern."""
        return np.array_equal(self.indptr, K.indptr) and np.array_equal(self.indices, K.indices)

    def matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """The matrix of this pattern with a copy of ``data`` as its values."""
        n = len(self.indptr) - 1
        return sp.csr_matrix((data.copy(), self.indices, self.indptr), shape=(n, n))


def _canonical_csr(K: sp.csr_matrix) -> sp.csr_matrix:
    """K checked, in canonical form (sorted indices, no duplicates); copied only if needed."""
    if not sp.issparse(K) or K.format != "csr":
        raise TypeError(f"K must be a scipy.sparse CSR matrix, got {type(K).__name__}")
    if K.dtype != np.float64:
        raise TypeError(f"K must be float64, got {K.dtype}")
    if K.ndim != 2 or K.shape[0] != K.shape[1]:
        raise ValueError(f"K must be square, got shape {K.shape}")
    if not K.has_canonical_format:
        K = K.copy()
        K.sum_duplicates()
    return K


@cache
def _pardiso_problem() -> str | None:
    """Why PARDISO cannot be used on this machine, or None if a self-test passes."""
    K = sp.csr_matrix(np.array([[2.0, 1.0], [1.0, -3.0]]))
    try:
        with PardisoSolver() as solver:
            factorization = solver.factorize(K)
            x = factorization.solve(np.array([3.0, -2.0]))
            n_negative = factorization.n_negative
    except (ConfigError, SolverError) as exc:
        return str(exc)
    if n_negative != 1 or not np.allclose(x, [1.0, 1.0]):
        return f"PARDISO self-test gave x = {x}, {n_negative} negative eigenvalues"
    return None


def make_linear_solver(name: str = "auto") -> LinearSolver:
    """A new linear solver by name (config key ``solver.linear``).

    Parameters
    ----------
    name : {"auto", "superlu", "pardiso"}
        ``"auto"`` is PARDISO when ``pypardiso`` imports and passes a self-test on this
        machine, else SuperLU.

    Returns
    -------
    LinearSolver
        A solver with no cached pattern.

    Raises
    ------
    ConfigError
        If the name is unknown, or ``"pardiso"`` is requested and cannot be used here.
    """
    if name == "superlu":
        return SuperLUSolver()
    if name in ("auto", "pardiso"):
        problem = _pardiso_problem()
        if problem is None:
            return PardisoSolver()
        if name == "pardiso":
            raise ConfigError(f"solver.linear = 'pardiso' is not usable here: {problem}")
        logger.debug("PARDISO not usable (%s): using SuperLU", problem)
        return SuperLUSolver()
    raise ConfigError(
        f"solver.linear = {name!r} is unknown; allowed: " + ", ".join(repr(n) for n in LINEAR_SOLVER_NAMES)
    )
