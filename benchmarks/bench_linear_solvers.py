"""Benchmark: sparse linear solver backends on network-like tangents of growing size.

Run:  python benchmarks/bench_linear_solvers.py                 (1e4, 6.5e4, 2.5e5 DOF)
      python benchmarks/bench_linear_solvers.py --quick         (1e4 and 6.5e4 DOF)
      python benchmarks/bench_linear_solvers.py --threads 1     (MKL on one thread)

The matrices are tangents K of a mock fiber network built like the paper's RVE (SPEC 1-2) but
with straight fibers: each of N_l = 15 layers holds isotropic random lines (D = 0.45 um) up to
a volume fraction of 0.19, cross-links are the crossings of fibers in the same or adjacent
layers, fibers are cut into elements at their nodes, fiber ends (on the border of the square)
are fixed, and every inner node has 2 DOF. At L = 90 um this gives about 65,000 DOF and the
fill of the plla RVE (SuperLU nnz(L+U) about 1.5e7). Element k_e = (E_t A / l) a (x) a +
(T / l) (I - a (x) a) with E_t = 3000 MPa and a prestress T = 1e-3 E_t A [uN]: the "spd"
matrix. The "indefinite" matrix has the same pattern with T = -1e-3 E_t A on 10 % of the
elements (compressed elements give a negative geometric stiffness).

For every size and backend, in its own Python process (so that the peak resident memory is
its own): factorize spd (first: ordering / symbolic analysis included), solve one
right-hand side, factorize spd again (pattern work reused; PARDISO: Cholesky), indefinite
(PARDISO: Cholesky fails, LDL^T analysed and factorized), indefinite again and spd once more
(PARDISO: both LDL^T, as the matrix before was indefinite), solve after that, and count the
negative eigenvalues. Printed per row: DOF, nnz(K), nnz of the factors, seconds for each step
(rep spd, 1st ind, rep ind, spd/ind: spd after indefinite; solve s: the Cholesky solve for
PARDISO, solv/ind: the LDL^T one), the relative residual ||K x - b|| / ||b||, the number of
negative eigenvalues of the indefinite matrix, and the peak RSS of the process and its
growth during the solver steps.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np
import scipy.sparse as sp

E_T_MPA = 3000.0
"""Taut modulus E_t [MPa]."""


def network_tangents(size_um: float, seed: int = 1) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """SPD and indefinite tangents (same pattern) of a straight-fiber mock network.

    Parameters
    ----------
    size_um : float [um]
        Side L of the square layers.
    seed : int
        Random seed.

    Returns
    -------
    spd, indefinite : (n_dof, n_dof) csr_matrix of float64 [uN/um]
        Tangents with every element in tension, and with 10 % of them compressed.
    """
    rng = np.random.default_rng(seed)
    layers, diameter, eta = 15, 0.45, 0.19
    area = np.pi * diameter**2 / 4
    start, direction, length, layer = [], [], [], []
    centre, half_diagonal = np.full(2, size_um / 2), size_um / np.sqrt(2)
    for k in range(layers):
        total = 0.0
        while total < 4 * eta / (np.pi * diameter) * size_um**2:  # line length per layer
            theta = rng.uniform(0.0, np.pi)
            u = np.array([np.cos(theta), np.sin(theta)])
            p = centre + rng.uniform(-half_diagonal, half_diagonal) * np.array([-u[1], u[0]])
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.stack([-p / u, (size_um - p) / u])
            t_in, t_out = np.nanmax(t.min(axis=0)), np.nanmin(t.max(axis=0))
            if t_out > t_in:
                start.append(p + t_in * u)
                direction.append(u)
                length.append(t_out - t_in)
                layer.append(k)
                total += t_out - t_in
    start, direction, length, layer = map(np.asarray, (start, direction, length, layer))
    n_fibers = len(start)
    i, j = np.triu_indices(n_fibers, 1)
    near = np.abs(layer[i] - layer[j]) <= 1
    i, j = i[near], j[near]
    cross = direction[i, 0] * direction[j, 1] - direction[i, 1] * direction[j, 0]
    d = start[j] - start[i]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_i = (d[:, 0] * direction[j, 1] - d[:, 1] * direction[j, 0]) / cross
        t_j = (d[:, 0] * direction[i, 1] - d[:, 1] * direction[i, 0]) / cross
    hit = (t_i > 0) & (t_i < length[i]) & (t_j > 0) & (t_j < length[j])
    i, j, t_i, t_j = i[hit], j[hit], t_i[hit], t_j[hit]
    n_inner = len(i)
    # nodes: cross-links, then fiber starts, then fiber ends (border nodes, fixed)
    position = np.concatenate([start[i] + t_i[:, None] * direction[i], start,
                               start + length[:, None] * direction])
    fiber = np.concatenate([i, j, np.arange(n_fibers), np.arange(n_fibers)])
    along = np.concatenate([t_i, t_j, np.zeros(n_fibers), length])
    node = np.concatenate([np.arange(n_inner), np.arange(n_inner),
                           n_inner + np.arange(2 * n_fibers)])
    order = np.lexsort((along, fiber))
    fiber, node = fiber[order], node[order]
    same = fiber[1:] == fiber[:-1]
    elements = np.stack([node[:-1][same], node[1:][same]], axis=1)
    vector = position[elements[:, 1]] - position[elements[:, 0]]
    l = np.maximum(np.linalg.norm(vector, axis=1), 1e-6)
    a = vector / l[:, None]
    aa = a[:, :, None] * a[:, None, :]
    dofs = (2 * elements[:, [0, 0, 1, 1]] + [0, 1, 0, 1])
    rows, cols = np.repeat(dofs, 4, axis=1).ravel(), np.tile(dofs, (1, 4)).ravel()
    inner = (rows < 2 * n_inner) & (cols < 2 * n_inner)

    def tangent(tension: np.ndarray) -> sp.csr_matrix:
        k = (E_T_MPA * area / l)[:, None, None] * aa + (tension / l)[:, None, None] * (
            np.eye(2) - aa)
        blocks = np.block([[k, -k], [-k, k]])
        K = sp.csr_matrix((blocks.ravel()[inner], (rows[inner], cols[inner])),
                          shape=(2 * n_inner, 2 * n_inner))
        K.sum_duplicates()
        return K

    tension = np.full(len(elements), 1e-3 * E_T_MPA * area)
    compressed = rng.random(len(elements)) < 0.1
    return tangent(tension), tangent(np.where(compressed, -tension, tension))


def run_case(size_um: float, backend: str, threads: int | None) -> dict:
    """Time one backend on the tangents of one network size (call in a fresh process)."""
    from threadpoolctl import threadpool_limits

    from espin.mechanics.linear_solvers import make_linear_solver

    spd, indefinite = network_tangents(size_um)
    b = np.random.default_rng(0).standard_normal(spd.shape[0])
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with threadpool_limits(threads), make_linear_solver(backend) as solver:
        t0 = time.perf_counter()
        factorization = solver.factorize(spd)
        t1 = time.perf_counter()
        x = factorization.solve(b)
        t2 = time.perf_counter()
        spd_negative = factorization.n_negative
        t3 = time.perf_counter()
        factorization = solver.factorize(spd)  # PARDISO: Cholesky
        t4 = time.perf_counter()
        solver.factorize(indefinite)  # PARDISO: Cholesky fails, LDL^T analysed and factorized
        t5 = time.perf_counter()
        factorization = solver.factorize(indefinite)  # PARDISO: LDL^T (the last was indefinite)
        t6 = time.perf_counter()
        n_negative = factorization.n_negative
        x_indefinite = factorization.solve(b)
        t7 = time.perf_counter()
        factorization = solver.factorize(spd)  # PARDISO: LDL^T (the last was indefinite)
        t8 = time.perf_counter()
        factorization.solve(b)
        t9 = time.perf_counter()
        residual = max(np.linalg.norm(spd @ x - b), np.linalg.norm(indefinite @ x_indefinite - b))
        return {
            "size_um": size_um, "backend": solver.name, "dof": spd.shape[0], "nnz": spd.nnz,
            "nnz_factor": factorization.nnz_factor, "first_s": t1 - t0, "solve_s": t2 - t1,
            "inertia_s": t3 - t2, "repeat_spd_s": t4 - t3, "first_indefinite_s": t5 - t4,
            "repeat_indefinite_s": t6 - t5, "spd_after_indefinite_s": t8 - t7,
            "solve_after_indefinite_s": t9 - t8,
            "residual": residual / np.linalg.norm(b), "spd_negative": spd_negative,
            "n_negative": n_negative, "n_perturbed": factorization.n_perturbed,
            "rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "rss_growth_MB": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                              - rss_before) / 1024,
        }


def in_subprocess(size_um: float, backend: str, threads: int | None) -> dict:
    command = [sys.executable, __file__, "--case", str(size_um), backend]
    if threads:
        command += ["--threads", str(threads)]
    out = subprocess.run(command, check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", nargs=2, metavar=("SIZE_UM", "BACKEND"))
    parser.add_argument("--quick", action="store_true", help="1e4 and 6.5e4 DOF only")
    parser.add_argument("--threads", type=int, help="MKL/BLAS threads (default: all)")
    parser.add_argument("--backends", default="superlu,pardiso")
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(float(args.case[0]), args.case[1], args.threads)))
        return
    sizes = [35.5, 90.0] + ([] if args.quick else [177.0])  # about 1e4, 6.5e4, 2.5e5 DOF
    print(f"{'backend':>8} {'DOF':>7} {'nnz(K)':>8} {'nnz(F)':>9} {'first s':>8} "
          f"{'rep spd':>8} {'1st ind':>8} {'rep ind':>8} {'spd/ind':>8} {'solve s':>8} "
          f"{'solv/ind':>8} {'inert s':>8} {'resid':>8} {'neg s/i':>9} {'pert':>4} {'RSS MB':>7} "
          f"{'+MB':>6}")
    for size_um in sizes:
        for backend in args.backends.split(","):
            r = in_subprocess(size_um, backend, args.threads)
            negatives = f"{r['spd_negative']}/{r['n_negative']}"
            print(f"{r['backend']:>8} {r['dof']:>7d} {r['nnz']:>8d} {r['nnz_factor']:>9d} "
                  f"{r['first_s']:>8.3f} {r['repeat_spd_s']:>8.3f} {r['first_indefinite_s']:>8.3f} "
                  f"{r['repeat_indefinite_s']:>8.3f} {r['spd_after_indefinite_s']:>8.3f} "
                  f"{r['solve_s']:>8.4f} {r['solve_after_indefinite_s']:>8.4f} "
                  f"{r['inertia_s']:>8.3f} {r['residual']:>8.1e} "
                  f"{negatives:>9} "
                  f"{r['n_perturbed']:>4d} {r['rss_MB']:>7.0f} {r['rss_growth_MB']:>6.0f}",
                  flush=True)


if __name__ == "__main__":
    main()
