"""The compiled kernels of the batched FE^2 points (espin.specimen.batched_kernels): the sparse
Cholesky factorization with one symbolic analysis reproduces K = P^T L L^T P, solves to the backward
error of a direct solver, and reports a tangent that is not positive definite; the evaluation of a
batch equals the per-point solver's residual."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import espin
from espin.mechanics.equilibrium import StepState
from espin.mechanics.linear_solvers import make_linear_solver
from espin.specimen import batched_kernels
from espin.specimen.batched_points import BatchedRVE
from espin.specimen.rve_points import rve_tolerance


@pytest.fixture(scope="module")
def batch():
    rve = espin.generate("plla", rve__size_ratio=30, rve__layers=2)
    return BatchedRVE(rve.network, rve_tolerance(rve.config, 1e-6))


def _stretched(batch, k):
    """k points under F = diag(1.01 + 0.01 i, 0.995) (tension: positive definite tangents)."""
    F = np.array([np.diag([1.01 + 0.01 * i, 0.995]) for i in range(k)])
    z = np.einsum("nJ,kiJ->kni", batch.X_inner, F).reshape(k, -1)
    p, ok = batch._evaluate(z, F, np.ones((k, len(batch.l0))), 1.0, None)
    assert ok.all()
    return p


def _factorize(batch, p, rows, clipped):
    pattern = batch.cholesky
    K = np.zeros((len(rows), batch._K.nnz))
    L = np.zeros((len(rows), pattern.nnz))
    pd = batched_kernels.factorize(rows, np.arange(len(rows)), p.length, p.unit, p.force, p.stiffness, batch.l0,
                                   clipped, batch.slot, batch._K.nnz, pattern.arrays(), K, L)
    return pd, K, L


def test_cholesky_factors_and_solves_every_point(batch):
    k = 3
    p = _stretched(batch, k)
    pd, K, L = _factorize(batch, p, np.arange(k), clipped=False)
    assert pd.all()
    pattern = batch.cholesky
    n = batch.n
    rng = np.random.default_rng(1)
    B = rng.normal(size=(k, n, 2))
    X = batched_kernels.solve(np.arange(k), K, L, B, pattern.perm, pattern.l_ptr, pattern.l_row, pattern.k_ptr,
                              pattern.k_col)
    for i in range(k):
        matrix = sp.csr_matrix((K[i], batch._K.indices, batch._K.indptr), shape=(n, n))
        factor = pattern.factor(L[i]).toarray()
        permuted = matrix.toarray()[np.ix_(pattern.perm, pattern.perm)]
        scale = np.abs(permuted).max()
        assert np.abs(factor @ factor.T - permuted).max() <= 1e-12 * scale
        backward = np.abs(matrix @ X[i] - B[i]).max() / (scale * np.abs(X[i]).max() + np.abs(B[i]).max())
        assert backward <= 1e-14
        expected = np.linalg.solve(matrix.toarray(), B[i])
        assert np.abs(X[i] - expected).max() <= 1e-8 * np.abs(expected).max()


def test_a_tangent_that_is_not_positive_definite_is_reported(batch):
    """In compression the transverse stiffness T / l of the exact tangent is negative: the
    factorization reports it (the PARDISO LDL^T counts negative eigenvalues in the same tangent);
    the clipped tangent of the same state is positive definite or singular, never indefinite."""
    k = 2
    F = np.array([np.diag([0.9, 0.9]), np.diag([1.02, 0.99])])
    z = np.einsum("nJ,kiJ->kni", batch.X_inner, F).reshape(k, -1)
    p, ok = batch._evaluate(z, F, np.ones((k, len(batch.l0))), 1.0, None)
    pd, K, _ = _factorize(batch, p, np.arange(k), clipped=False)
    fact = make_linear_solver("auto").factorize(sp.csr_matrix((K[0], batch._K.indices, batch._K.indptr)))
    assert (fact.n_negative or 0) > 0 and not pd[0]
    assert pd[1]


def test_the_batch_evaluation_is_the_per_point_residual(batch):
    solver = batch.solver
    k = 2
    F = np.array([np.diag([1.03, 0.99]), [[1.01, 0.02], [0.0, 1.0]]])
    rng = np.random.default_rng(2)
    z = np.einsum("nJ,kiJ->kni", batch.X_inner, F).reshape(k, -1) + rng.normal(scale=1e-3, size=(k, batch.n))
    plastic = 1.0 + rng.uniform(0.0, 0.01, size=(k, len(batch.l0)))
    p, ok = batch._evaluate(z, F, plastic, 0.5, None)
    assert ok.all()
    n_el = len(batch.l0)
    for i in range(k):
        start = StepState(0.0, batch.X_inner, np.zeros(0), np.eye(2), plastic[i], np.zeros(n_el))
        step = solver._context(start, 0.5, F[i], np.zeros((0, 2, 2)), solver.law, None)
        expected = solver._evaluate(z[i], step).residual
        assert np.abs(p.residual[i] - expected).max() <= 1e-12 * np.abs(p.force[i]).max()
    bad = z.copy()
    bad[1, 3] = np.nan
    _, ok = batch._evaluate(bad, F, plastic, 0.5, None)
    assert ok.tolist() == [True, False]
