"""Benchmark: PARDISO's Cholesky in single against double precision on real plla tangents.

Run:  python benchmarks/bench_single_precision.py              (L/D 30, 60, 100, 140, 200: plla)
      python benchmarks/bench_single_precision.py --ratios 200:15 --repeats 6

For each RVE size (``rve.size_ratio`` L/D and layers, plla otherwise) the tensile test is run
for two steps of 1 %, and the last tangent its Newton iterations factorized is kept. That
tangent is analysed once per precision, then factorized and solved (one right-hand side)
``--repeats`` times, the two precisions alternating; printed: DOF, nonzeros of the factor,
median milliseconds of a factorization and a solve in each precision and their ratios
(single / double), the relative residual ||K x - b|| / ||b|| of the single-precision solution
and after each of three refinement steps against K in double precision (``espin`` asks 1e-4
of a Newton direction, 1e-14 of backward error otherwise: docs/model.md section 4).
``SINGLE_PRECISION_FROM`` in ``espin.mechanics.linear_solvers`` was chosen from these ratios.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp

from espin.geometry.rve import generate
from espin.mechanics import linear_solvers as ls
from espin.mechanics.driver import run_program


def last_tangent(size_ratio: float, layers: int) -> sp.csr_matrix:
    """The last tangent factorized in two 1 % steps of the plla tensile test at this size."""
    rve = generate("plla", rve__size_ratio=size_ratio, rve__layers=layers, loading__max_strain=0.02, loading__steps=2)
    tangents: list[sp.csr_matrix] = []

    class Keeping(ls.PardisoSolver):
        def factorize(self, K: sp.csr_matrix) -> ls.Factorization:
            tangents.append(K.copy())
            return super().factorize(K)

    with Keeping() as solver:
        run_program(rve.network, rve.config, solver)
    return tangents[-1]


def compare(K: sp.csr_matrix, repeats: int) -> str:
    """One printed row: times of both precisions on K, and the single precision's residuals."""
    upper = ls._UpperTriangle.of(K)
    values = {False: upper.values(K)}
    values[True] = values[False].astype(np.float32)
    handles = {single: ls._PardisoHandle(2, single_precision=single) for single in (False, True)}
    for single, handle in handles.items():
        handle.factorize(upper, values[single])
    b = np.random.default_rng(1).standard_normal(K.shape[0])
    times: dict[str, list[float]] = {"fact64": [], "fact32": [], "solve64": [], "solve32": []}
    for _ in range(repeats):
        for single, handle in handles.items():
            bits = 32 if single else 64
            rhs = b.astype(np.float32) if single else b
            start = time.perf_counter()
            handle.call(22, upper, values[single])
            times[f"fact{bits}"].append(time.perf_counter() - start)
            start = time.perf_counter()
            handle.call(33, upper, values[single], rhs)
            times[f"solve{bits}"].append(time.perf_counter() - start)
    ms = {key: 1e3 * float(np.median(value)) for key, value in times.items()}

    def solve32(r: np.ndarray) -> np.ndarray:
        x = handles[True].call(33, upper, values[True], r.astype(np.float32))
        assert x is not None
        return x.astype(np.float64)

    x = solve32(b)
    residuals = []
    for _ in range(4):
        r = b - K @ x
        residuals.append(np.linalg.norm(r) / np.linalg.norm(b))
        x = x + solve32(r)
    for handle in handles.values():
        handle.free()
    return (
        f"{K.shape[0]:8d} {int(handles[False].iparm[17]):10d} {ms['fact64']:9.2f} {ms['fact32']:9.2f} "
        f"{ms['fact32'] / ms['fact64']:6.2f} {ms['solve64']:9.2f} {ms['solve32']:9.2f} "
        f"{ms['solve32'] / ms['solve64']:6.2f}   " + " ".join(f"{r:8.1e}" for r in residuals)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--ratios", default="30:3,60:3,100:5,140:10,200:15", help="L/D:layers of each RVE (default: %(default)s)"
    )
    parser.add_argument("--repeats", type=int, default=0, help="timed pairs per size (default: by size)")
    args = parser.parse_args()
    print(
        "     DOF  nnz(L)     fact64 ms fact32 ms  ratio solve64ms solve32ms  ratio   "
        "||Kx-b||/||b||: single, refined 1, 2, 3 times",
        flush=True,
    )
    for item in args.ratios.split(","):
        ratio, layers = item.split(":")
        K = last_tangent(float(ratio), int(layers))
        repeats = args.repeats or max(5, int(2e5 / K.shape[0]))
        print(compare(K, repeats), flush=True)


if __name__ == "__main__":
    main()
