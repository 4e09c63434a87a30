"""Every linear solver backend on the same small symmetric matrices (SPD and indefinite)."""

from __future__ import annotations

import sys
from collections.abc import Iterator

import numpy as np
import pytest
import scipy.sparse as sp
from threadpoolctl import threadpool_limits

import espin.mechanics.linear_solvers as ls
from espin.core.errors import ConfigError, SolverError
from espin.mechanics.linear_solvers import LINEAR_SOLVER_NAMES, make_linear_solver


def _pardiso_param() -> object:
    try:
        make_linear_solver("pardiso")
    except ConfigError as exc:
        return pytest.param("pardiso", marks=pytest.mark.skip(reason=f"PARDISO unusable: {exc}"))
    return "pardiso"


BACKENDS = ["superlu", _pardiso_param()]


def hide_pymetis(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make ``import pymetis`` fail, as when it is not installed."""
    monkeypatch.setitem(sys.modules, "pymetis", None)


@pytest.fixture(params=["superlu", "superlu-mmd", *BACKENDS[1:]])
def solver(
    request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch
) -> Iterator[ls.LinearSolver]:
    """Every backend; "superlu-mmd" is SuperLU without pymetis (MMD_AT_PLUS_A ordering)."""
    if request.param == "superlu-mmd":
        hide_pymetis(monkeypatch)
    with make_linear_solver(request.param.removesuffix("-mmd")) as solver:
        yield solver


def laplacian_2dof(m: int) -> sp.csr_matrix:
    """SPD stiffness-like matrix: 5-point Laplacian of an m x m grid (Dirichlet), 2 DOF a node.

    The 2 x 2 node block [[2, 1], [1, 2]] couples the DOFs, so the pattern has 10 entries in
    an interior row, like a network tangent.
    """
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    lap = sp.kron(T, sp.eye(m)) + sp.kron(sp.eye(m), T)
    K = sp.kron(lap, np.array([[2.0, 1.0], [1.0, 2.0]]), format="csr")
    K.sort_indices()
    return K


def same_pattern(K: sp.csr_matrix, data: np.ndarray) -> sp.csr_matrix:
    return sp.csr_matrix((data, K.indices.copy(), K.indptr.copy()), shape=K.shape)


def random_symmetric_values(K: sp.csr_matrix, seed: int) -> sp.csr_matrix:
    """A symmetric indefinite matrix with K's pattern and random values."""
    rng = np.random.default_rng(seed)
    R = same_pattern(K, rng.standard_normal(K.nnz))
    S = ((R + R.T) / 2).tocsr()
    S.sort_indices()
    assert np.array_equal(S.indices, K.indices) and np.array_equal(S.indptr, K.indptr)
    return S


def n_negative_eigenvalues(K: sp.csr_matrix) -> int:
    eigenvalues = np.linalg.eigvalsh(K.toarray())
    assert np.min(np.abs(eigenvalues)) > 1e-8 * np.max(np.abs(eigenvalues))  # nonsingular
    return int(np.count_nonzero(eigenvalues < 0))


def relative_residual(K: sp.csr_matrix, x: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(K @ x - b) / np.linalg.norm(b))


def test_spd_matrix_is_solved_and_positive_definite(solver: ls.LinearSolver) -> None:
    K = laplacian_2dof(12)
    b = np.random.default_rng(0).standard_normal(K.shape[0])
    with solver.factorize(K) as factorization:
        x = factorization.solve(b)
        assert factorization.n == K.shape[0]
        assert factorization.n_negative == 0
        assert factorization.n_perturbed == 0
        assert factorization.nnz_factor >= K.nnz // 2
    assert x.shape == b.shape
    assert relative_residual(K, x, b) < 1e-12


@pytest.mark.parametrize("quantile", [0.003, 0.1, 0.37, 0.5, 0.81, 0.999])
def test_shifted_laplacian_inertia(solver: ls.LinearSolver, quantile: float) -> None:
    """K - sigma I with sigma between two eigenvalues: n_negative = eigenvalues below sigma."""
    K = laplacian_2dof(8)
    eigenvalues = np.unique(np.round(np.linalg.eigvalsh(K.toarray()), 9))
    i = int(quantile * (len(eigenvalues) - 1))
    sigma = (eigenvalues[i] + eigenvalues[i + 1]) / 2
    shifted = (K - sigma * sp.eye(K.shape[0])).tocsr()
    expected = n_negative_eigenvalues(shifted)
    assert expected > 0
    b = np.random.default_rng(1).standard_normal(K.shape[0])
    factorization = solver.factorize(shifted)
    assert factorization.n_negative == expected
    assert relative_residual(shifted, factorization.solve(b), b) < 1e-10


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_indefinite_inertia(solver: ls.LinearSolver, seed: int) -> None:
    K = random_symmetric_values(laplacian_2dof(7), seed)
    b = np.random.default_rng(seed).standard_normal(K.shape[0])
    factorization = solver.factorize(K)
    assert factorization.n_negative == n_negative_eigenvalues(K)
    assert relative_residual(K, factorization.solve(b), b) < 1e-10


def test_saddle_point_matrix_with_missing_diagonal(solver: ls.LinearSolver) -> None:
    """[[A, B^T], [B, 0]]: no diagonal entries stored in the lower right block.

    Its inertia is (n_A positive, n_B negative). SuperLU must pivot off the diagonal here,
    so it may not know the inertia, but what it reports must be right.
    """
    A = laplacian_2dof(5)
    rng = np.random.default_rng(3)
    B = sp.random(10, A.shape[0], density=0.2, random_state=rng) + sp.eye(10, A.shape[0])
    K = sp.bmat([[A, B.T], [B, None]], format="csr")
    K.sort_indices()
    assert n_negative_eigenvalues(K) == 10
    b = rng.standard_normal(K.shape[0])
    factorization = solver.factorize(K)
    assert factorization.n_negative in (None, 10)
    if solver.name == "pardiso":
        assert factorization.n_negative == 10
    assert relative_residual(K, factorization.solve(b), b) < 1e-10


def mixed_control_matrix(extra: int, seed: int) -> sp.csr_matrix:
    """[[A, C], [C^T, D]]: a 2 x 2-blocked indefinite A and ``extra`` appended unknowns.

    Like the free components of F under mixed control: each extra row couples to many DOFs
    (one grid row of nodes, a different one per extra row, so no two extra rows share a
    pattern) and to all other extra rows.
    """
    m = 8
    A = random_symmetric_values(laplacian_2dof(m), seed)
    rng = np.random.default_rng(seed)
    C = np.zeros((A.shape[0], extra))
    for k in range(extra):
        C[2 * m * k : 2 * m * (k + 1), k] = rng.standard_normal(2 * m)
    D = rng.standard_normal((extra, extra))
    K = sp.bmat([[A, sp.csr_matrix(C)], [sp.csr_matrix(C.T), sp.csr_matrix(D + D.T)]],
                format="csr")
    K.sort_indices()
    return K


@pytest.mark.parametrize("extra", [1, 2, 3])
def test_mixed_control_extra_rows(solver: ls.LinearSolver, extra: int) -> None:
    """Extra rows that break the 2 x 2 blocks: same inertia as the dense eigenvalues."""
    K = mixed_control_matrix(extra, seed=10 + extra)
    b = np.random.default_rng(extra).standard_normal(K.shape[0])
    for values in (K, random_symmetric_values(K, seed=20 + extra)):  # first and reused
        factorization = solver.factorize(values)
        assert factorization.n_negative == n_negative_eigenvalues(values)
        assert relative_residual(values, factorization.solve(b), b) < 1e-10


def test_node_vertices() -> None:
    """DOFs 2i, 2i+1 with equal row patterns share a vertex; other DOFs are vertices alone."""
    blocked = laplacian_2dof(5)
    np.testing.assert_array_equal(ls._node_vertices(blocked), np.arange(50) // 2)
    tridiagonal = sp.diags([np.ones(9), np.ones(10), np.ones(9)], [-1, 0, 1], format="csr")
    np.testing.assert_array_equal(ls._node_vertices(tridiagonal), np.arange(10))
    mixed = mixed_control_matrix(3, seed=0)  # 64 nodes, then 3 unpaired extra rows
    np.testing.assert_array_equal(ls._node_vertices(mixed),
                                  np.r_[np.arange(128) // 2, 64, 65, 66])
    # a node coupled to an extra row by one DOF only is split into two vertices
    pattern = mixed.tolil()
    pattern[0, 130] = pattern[130, 0] = 1.0
    split = ls._node_vertices(pattern.tocsr())
    np.testing.assert_array_equal(split[:4], [0, 1, 2, 2])
    assert split[-1] == 67


@pytest.mark.parametrize("K", [laplacian_2dof(9), mixed_control_matrix(3, seed=1),
                               sp.eye(1, format="csr"), sp.eye(3, format="csr")],
                         ids=["blocked", "mixed", "1x1", "diagonal"])
def test_nested_dissection_permutation(K: sp.csr_matrix) -> None:
    """A permutation that keeps the two DOFs of each node consecutive, in their order."""
    pytest.importorskip("pymetis")
    perm = ls._nested_dissection(K)
    np.testing.assert_array_equal(np.sort(perm), np.arange(K.shape[0]))
    vertex = ls._node_vertices(K)[perm]
    same_vertex = np.diff(vertex) == 0
    assert np.count_nonzero(~same_vertex) == vertex.max()  # one run of DOFs per vertex
    assert np.all(np.diff(perm)[same_vertex] == 1)


def test_superlu_ordering_with_and_without_pymetis(monkeypatch: pytest.MonkeyPatch) -> None:
    """With pymetis every factorization is in METIS' order (NATURAL after the symmetric
    permutation); without, the first computes MMD_AT_PLUS_A and the later ones reuse it."""
    pytest.importorskip("pymetis")
    specs = []
    splu = ls._splu
    monkeypatch.setattr(ls, "_splu", lambda matrix, spec: specs.append(spec) or splu(matrix, spec))
    K = laplacian_2dof(12)
    indefinite = random_symmetric_values(K, seed=11)
    b = np.ones(K.shape[0])
    for ordering in ("metis", "mmd"):
        if ordering == "mmd":
            hide_pymetis(monkeypatch)
        specs.clear()
        with ls.SuperLUSolver() as solver:
            for values in (K, indefinite):
                factorization = solver.factorize(values)
                assert factorization.n_negative == n_negative_eigenvalues(values)
                assert relative_residual(values, factorization.solve(b), b) < 1e-10
        assert specs == (["NATURAL", "NATURAL"] if ordering == "metis"
                         else ["MMD_AT_PLUS_A", "NATURAL"])


def test_multiple_right_hand_sides(solver: ls.LinearSolver) -> None:
    K = random_symmetric_values(laplacian_2dof(9), seed=4)
    B = np.random.default_rng(5).standard_normal((K.shape[0], 3))
    factorization = solver.factorize(K)
    X = factorization.solve(B)
    assert X.shape == B.shape
    assert relative_residual(K, X, B) < 1e-10
    for j in range(B.shape[1]):
        np.testing.assert_allclose(factorization.solve(B[:, j]), X[:, j], rtol=1e-8, atol=1e-10)
    # a list and a non-contiguous view are accepted too
    np.testing.assert_allclose(factorization.solve(list(B[:, 1])), X[:, 1], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(factorization.solve(B[:, ::2]), X[:, ::2], rtol=1e-8, atol=1e-10)


def test_an_unchecked_solve_skips_the_product_by_k(solver: ls.LinearSolver, monkeypatch: pytest.MonkeyPatch) -> None:
    """rtol=inf returns the backend's solution without the backward-error check (no
    product by K, no refinement): on a well-conditioned K, the checked solve's."""
    K = laplacian_2dof(9)
    B = np.random.default_rng(8).standard_normal((K.shape[0], 3))
    factorization = solver.factorize(K)
    checked = factorization.solve(B)

    def no_product(*args: object) -> None:
        raise AssertionError("an unchecked solve computed a residual")

    monkeypatch.setattr(type(factorization), "_residual", no_product)
    np.testing.assert_allclose(factorization.solve(B, rtol=np.inf), checked, rtol=1e-12, atol=1e-14)
    if factorization.backward_stable:  # Cholesky: no check even when asked
        np.testing.assert_array_equal(factorization.solve(B), checked)
    else:
        with pytest.raises(AssertionError, match="computed a residual"):
            factorization.solve(B)


def test_only_a_cholesky_factorization_skips_the_check(solver: ls.LinearSolver) -> None:
    """PARDISO's Cholesky (a positive definite K) is backward stable and its solves are not
    checked; its LDL^T (an indefinite K) and SuperLU's LU are. The unchecked solves of a
    positive definite K, badly scaled (stiffnesses over eight decades), stay within a few
    machine epsilons of backward error."""
    rng = np.random.default_rng(12)
    n = 300
    A = sp.random(n, n, density=0.02, random_state=rng, format="csr")
    scale = sp.diags(10.0 ** rng.uniform(-4, 4, n))
    definite = (scale @ (A @ A.T + sp.eye(n)) @ scale).tocsr()
    b = rng.standard_normal(n)
    factorization = solver.factorize(definite)
    x = factorization.solve(b)
    norm_K = abs(definite).sum(axis=1).max()
    assert np.abs(definite @ x - b).max() / (norm_K * np.abs(x).max() + np.abs(b).max()) < 1e-14
    assert factorization.backward_stable == isinstance(solver, ls.PardisoSolver)
    indefinite = random_symmetric_values(laplacian_2dof(9), seed=3)
    assert n_negative_eigenvalues(indefinite) > 0
    assert not solver.factorize(indefinite).backward_stable


def test_pattern_work_is_reused_across_values(
    solver: ls.LinearSolver, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Same pattern, new values: correct results, and the pattern is analysed only once."""
    analysed = []
    of = ls._Pattern.of
    monkeypatch.setattr(ls._Pattern, "of", lambda K: analysed.append(K.shape) or of(K))
    spd = laplacian_2dof(10)
    indefinite = random_symmetric_values(spd, seed=6)
    b = np.random.default_rng(7).standard_normal(spd.shape[0])
    for K in (spd, indefinite, spd, indefinite):
        factorization = solver.factorize(K)
        assert factorization.n_negative == n_negative_eigenvalues(K)
        assert relative_residual(K, factorization.solve(b), b) < 1e-10
    assert len(analysed) == 1
    other = laplacian_2dof(6)  # a new pattern is analysed again
    assert relative_residual(other, solver.factorize(other).solve(b[:72]), b[:72]) < 1e-12
    assert len(analysed) == 2


def test_unsorted_csr_input_is_accepted(solver: ls.LinearSolver) -> None:
    K = laplacian_2dof(6)
    coo = K.tocoo()
    order = np.random.default_rng(8).permutation(K.nnz)
    shuffled = sp.csr_matrix((coo.data[order], (coo.row[order], coo.col[order])), shape=K.shape)
    shuffled.has_sorted_indices = False  # as after some assemblies
    b = np.ones(K.shape[0])
    assert relative_residual(K, solver.factorize(shuffled).solve(b), b) < 1e-12


def test_factorization_is_invalid_after_refactorize_or_release(solver: ls.LinearSolver) -> None:
    K = laplacian_2dof(6)
    b = np.ones(K.shape[0])
    first = solver.factorize(K)
    second = solver.factorize(2.0 * K)
    with pytest.raises(SolverError, match="factorize K again"):
        first.solve(b)
    np.testing.assert_allclose(second.solve(b), solver.factorize(K).solve(b) / 2.0, rtol=1e-10)
    with solver.factorize(K) as third:
        third.solve(b)
    with pytest.raises(SolverError):
        third.solve(b)
    # after a released factorization and a released solver, factorizing works again
    assert relative_residual(K, solver.factorize(K).solve(b), b) < 1e-12
    solver.release()
    assert relative_residual(K, solver.factorize(K).solve(b), b) < 1e-12


def test_zero_row_is_reported(solver: ls.LinearSolver) -> None:
    """An exactly singular K: SuperLU fails loudly, PARDISO reports a perturbed pivot."""
    K = laplacian_2dof(5)
    coo = K.tocoo()
    coo.data[(coo.row == 3) | (coo.col == 3)] = 0.0  # explicit zeros keep the pattern
    K = sp.csr_matrix((coo.data, (coo.row, coo.col)), shape=K.shape)
    if solver.name == "superlu":
        with pytest.raises(SolverError, match="singular"):
            solver.factorize(K)
    else:
        assert solver.factorize(K).n_perturbed >= 1


def test_bad_input_is_rejected(solver: ls.LinearSolver) -> None:
    K = laplacian_2dof(4)
    with pytest.raises(TypeError, match="CSR"):
        solver.factorize(K.tocsc())
    with pytest.raises(TypeError, match="float64"):
        solver.factorize(K.astype(np.float32))
    with pytest.raises(ValueError, match="square"):
        solver.factorize(K[:-1])
    with pytest.raises(ValueError, match="not symmetric"):
        solver.factorize(sp.triu(K, format="csr"))
    with pytest.raises(ValueError, match="shape"):
        solver.factorize(K).solve(np.ones(K.shape[0] + 1))


def test_mkl_thread_count_change_between_factorizations() -> None:
    """MKL PARDISO crashed when threads dropped after an analysis; the solver re-analyses."""
    if "pardiso" not in BACKENDS:
        pytest.skip("PARDISO unusable")
    K = laplacian_2dof(36)  # 2,592 unknowns: large enough to crash an unguarded MKL
    b = np.ones(K.shape[0])
    with make_linear_solver("pardiso") as solver:
        for threads in (2, 1, 2, 1):
            with threadpool_limits(threads):
                factorization = solver.factorize(K)
                x = factorization.solve(b)
            assert relative_residual(K, x, b) < 1e-12
            assert relative_residual(K, factorization.solve(b), b) < 1e-12


def test_pardiso_factorizes_by_cholesky_while_positive_definite() -> None:
    """Cholesky for SPD matrices; an indefinite one falls back to LDL^T with exact inertia,
    and so does the next matrix, until one is positive definite again."""
    if "pardiso" not in BACKENDS:
        pytest.skip("PARDISO unusable")
    spd = laplacian_2dof(10)
    indefinite = random_symmetric_values(spd, seed=3)
    shifted = (spd - 0.5 * sp.eye(spd.shape[0])).tocsr()  # indefinite, positive diagonal
    b = np.random.default_rng(4).standard_normal(spd.shape[0])
    sequence = [(spd, "cholesky"), (indefinite, "ldlt"), (shifted, "ldlt"), (spd, "ldlt"), (spd, "cholesky")]
    with make_linear_solver("pardiso") as solver:
        assert isinstance(solver, ls.PardisoSolver)
        for K, kind in sequence:
            factorization = solver.factorize(K)
            assert factorization._handle is getattr(solver, f"_{kind}")
            assert factorization.n_negative == n_negative_eigenvalues(K)
            assert factorization.n_perturbed == 0
            assert relative_residual(K, factorization.solve(b), b) < 1e-10


def backward_error(K: sp.csr_matrix, x: np.ndarray, b: np.ndarray) -> float:
    norm_K = abs(K).sum(axis=1).max()
    return float(np.abs(K @ x - b).max() / (norm_K * np.abs(x).max() + np.abs(b).max()))


def test_pardiso_factorizes_a_large_positive_definite_matrix_in_single_precision(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """From SINGLE_PRECISION_FROM unknowns PARDISO's Cholesky is in single precision; each
    solve gets the accuracy asked by refinement against K: the full one by default, a
    Newton direction's relative residual with rtol, the raw single-precision solution with
    inf."""
    if "pardiso" not in BACKENDS:
        pytest.skip("PARDISO unusable")
    K = laplacian_2dof(20)  # 800 unknowns
    b = np.random.default_rng(11).standard_normal(K.shape[0])
    with make_linear_solver("pardiso") as solver:
        monkeypatch.setattr(ls, "SINGLE_PRECISION_FROM", K.shape[0] + 1)
        assert not solver.factorize(K).single_precision
        monkeypatch.setattr(ls, "SINGLE_PRECISION_FROM", K.shape[0])
        factorization = solver.factorize(K)
        assert factorization.single_precision and factorization.n_negative == 0
        assert solver.numeric_factorizations == 2
        raw = factorization.solve(b, rtol=np.inf)
        assert 1e-9 < relative_residual(K, raw, b) < 1e-4  # single precision, unrefined
        solves = []
        single_solve = type(factorization)._solve
        monkeypatch.setattr(type(factorization), "_solve", lambda self, r: solves.append(1) or single_solve(self, r))
        np.testing.assert_array_equal(factorization.solve(b, rtol=1e-4), raw)  # already within 1e-4
        assert len(solves) == 1
        x = factorization.solve(b)
        assert backward_error(K, x, b) <= 1e-14 and len(solves) > 2  # refined to double precision
        assert factorization.single_precision and solver.numeric_factorizations == 2


def test_a_single_precision_factorization_that_cannot_be_refined_is_redone_in_double(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """When refinement cannot bring a single-precision solution to the accuracy asked (here:
    no refinement step allowed), K is factorized again in double precision, counted, and
    that factorization serves the solve and every later one."""
    if "pardiso" not in BACKENDS:
        pytest.skip("PARDISO unusable")
    monkeypatch.setattr(ls, "SINGLE_PRECISION_FROM", 0)
    monkeypatch.setattr(ls, "_SINGLE_REFINEMENT_STEPS", 0)
    K = laplacian_2dof(20)
    b = np.random.default_rng(12).standard_normal(K.shape[0])
    with make_linear_solver("pardiso") as solver:
        factorization = solver.factorize(K)
        assert factorization.single_precision
        assert relative_residual(K, factorization.solve(b, rtol=1e-3), b) < 1e-3  # single is enough
        assert factorization.single_precision
        x = factorization.solve(b)  # the full accuracy: not reached without refinement
        assert not factorization.single_precision and factorization.n_negative == 0
        assert solver.numeric_factorizations == 2
        assert backward_error(K, x, b) <= 1e-14
        np.testing.assert_array_equal(factorization.solve(b, rtol=np.inf), x)


def test_make_linear_solver_names(monkeypatch: pytest.MonkeyPatch) -> None:
    assert set(LINEAR_SOLVER_NAMES) == {"auto", "superlu", "pardiso"}
    assert isinstance(make_linear_solver("superlu"), ls.SuperLUSolver)
    assert make_linear_solver("auto").name == ("pardiso" if "pardiso" in BACKENDS else "superlu")
    with pytest.raises(ConfigError, match="'umfpack' is unknown"):
        make_linear_solver("umfpack")
    monkeypatch.setattr(ls, "_pardiso_problem", lambda: "no MKL on this machine")
    assert isinstance(make_linear_solver("auto"), ls.SuperLUSolver)
    with pytest.raises(ConfigError, match="no MKL on this machine"):
        make_linear_solver("pardiso")


def test_small_pivots_are_refined(solver: ls.LinearSolver) -> None:
    """Tridiagonal K with a 1e-9 diagonal: neither backend can pivot around the tiny pivots
    (PARDISO pivots only within supernodes), so the refinement must restore the accuracy."""
    n = 200
    rng = np.random.default_rng(9)
    off = rng.uniform(0.5, 1.5, n - 1)
    K = sp.diags([off, np.full(n, 1e-9), off], [-1, 0, 1], format="csr")
    b = rng.standard_normal(n)
    factorization = solver.factorize(K)
    x = factorization.solve(b)
    norm_K = abs(K).sum(axis=1).max()
    backward_error = np.abs(K @ x - b).max() / (norm_K * np.abs(x).max() + np.abs(b).max())
    assert backward_error < 1e-12
    assert factorization.n_negative == n_negative_eigenvalues(K)


def test_factor_size_follows_a_new_pattern(solver: ls.LinearSolver) -> None:
    """nnz_factor after a pattern change is that of the new pattern, as from a fresh solver."""
    small, large = laplacian_2dof(4), laplacian_2dof(12)
    solver.factorize(small)
    after_change = solver.factorize(large).nnz_factor
    with make_linear_solver(solver.name) as fresh:
        assert after_change == fresh.factorize(large).nnz_factor
    assert after_change > solver.factorize(small).nnz_factor


def test_a_curve_in_single_precision_is_the_double_precision_curve(monkeypatch: pytest.MonkeyPatch) -> None:
    """Newton directions from single-precision factors (every tangent of this small RVE in
    single precision) converge to the equilibria of the double-precision run: the same
    curve to the Newton tolerance, and every factorization counted."""
    if "pardiso" not in BACKENDS:
        pytest.skip("PARDISO unusable")
    from espin.geometry.rve import generate
    from espin.mechanics.driver import run_program

    rve = generate("plla", rve__size_ratio=40, rve__layers=3, loading__max_strain=0.1, loading__steps=10)
    curves = {}
    for single_from in (10**9, 0):
        monkeypatch.setattr(ls, "SINGLE_PRECISION_FROM", single_from)
        with make_linear_solver("pardiso") as solver:
            result = run_program(rve.network, rve.config, solver)
            assert int(result.factorizations.sum()) == solver.numeric_factorizations
        curves[single_from] = result.P[1:, 0, 0]
    np.testing.assert_allclose(curves[0], curves[10**9], rtol=1e-8)


@pytest.mark.parametrize("single_from", [None, 0], ids=["as-is", "single-precision"])
def test_a_curve_does_not_depend_on_the_mkl_thread_count(tmp_path, monkeypatch, single_from):
    """Same inputs, same curve on 1 or 2 MKL threads (PARDISO's factorizations included, in
    single precision too)."""
    import espin
    from threadpoolctl import threadpool_limits

    if single_from is not None:
        monkeypatch.setattr(ls, "SINGLE_PRECISION_FROM", single_from)

    def curve(name: str) -> str:
        espin.simulate("plla", tmp_path / name, loading__steps=40, loading__max_strain=0.03, solver__time_rtol="off",
                       output__figures=False, rve__size_ratio=30, rve__layers=2)
        return (tmp_path / name / "curve.csv").read_text()

    with threadpool_limits(limits=2):
        two = curve("two")
    with threadpool_limits(limits=1):
        one = curve("one")
    assert one == two


@pytest.mark.slow
def test_a_curve_is_the_same_in_every_process(tmp_path):
    """The same run in three processes gives the same curve to the bit. MKL's kernels depend on
    how arrays are aligned in memory unless its reproducibility mode is on (espin sets it):
    without it this test's curves ended up to 1e-15 apart, and a bonded mat at plla size with
    free sides took 40 Newton iterations at one step in one run and stalled for 608 in another."""
    import os
    import subprocess

    script = ("import sys, espin; espin.simulate('plla', sys.argv[1], rve__size_ratio=100, rve__layers=8, "
              "loading__max_strain=0.03, loading__steps=3, loading__lateral={'poisson_ratio': 0.3}, "
              "output__figures=False)")
    env = {key: value for key, value in os.environ.items() if key != "MKL_CBWR"}  # espin's own default
    # The three processes run at once (on 2 cores: about half the time of one after another).
    runs = [subprocess.Popen([sys.executable, "-c", script, str(tmp_path / f"run{k}")], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for k in range(3)]
    for run in runs:
        _, errors = run.communicate(timeout=600)
        assert run.returncode == 0, errors
    curves = [(tmp_path / f"run{k}" / "curve.csv").read_text() for k in range(3)]
    assert curves[0] == curves[1] == curves[2]
