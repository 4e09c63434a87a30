"""Benchmark: is the default curve converged in time on mats other than plla?

Run:  python benchmarks/bench_time_accuracy.py [--cases 0,11,20,29,37] [--tolerances 3e-3,1e-3]
                                               [--loading fixed|unload]

For each case of the robustness sample (``bench_robustness.py``, plla fiber law), the
uniaxial test (lateral fixed) to 20 % in 20 reported steps, or the load-unload program of
that benchmark: a reference P11 Richardson-extrapolated from 24x and 48x as many uniform time
steps (solver.time_rtol = "off"), then the default settings and each tolerance. Printed per
run: DOF, time steps, Newton iterations, factorizations, wall seconds and the largest
|P11 - P11_ref| at the reported strains >= 0.5 %, relative to |P11_ref| there (load-unload:
relative to the largest |P11_ref|, since P11 passes near zero on unloading).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_robustness  # noqa: E402  (the sample's definition)

FACTORS = (24, 48)


def run(rve, loading: dict, factor: int, tolerance) -> tuple[object, float]:
    from espin.core.config import apply_overrides
    from espin.mechanics.driver import run_program
    from espin.mechanics.linear_solvers import make_linear_solver

    overrides = dict(loading)
    if "loading.program" in overrides:
        overrides["loading.program"] = [dict(s, steps=s["steps"] * factor) for s in overrides["loading.program"]]
    else:
        overrides |= {"loading.max_strain": bench_robustness.STRAIN, "loading.steps": bench_robustness.STEPS * factor}
    if tolerance is not None:
        overrides["solver.time_rtol"] = tolerance
    config = apply_overrides(rve.config, overrides)
    start = time.perf_counter()
    result = run_program(rve.network, config, make_linear_solver("auto"))
    return result, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="0,11,20,29,37")
    parser.add_argument("--tolerances", default="3e-3,1e-3")
    parser.add_argument("--loading", default="fixed", choices=["fixed", "unload"])
    args = parser.parse_args()
    from espin.geometry.rve import generate

    loading = bench_robustness.LOADINGS[args.loading]
    cases = bench_robustness.geometries()
    print(f"{'case':>4} {'DOF':>6} {'time_rtol':>9} {'dt':>5} {'iters':>6} {'facts':>6} {'wall s':>7} {'error %':>8}")
    for index in (int(i) for i in args.cases.split(",")):
        case = cases[index]
        rve = generate(case["source"], **bench_robustness._overrides(case))
        coarse, _ = run(rve, loading, FACTORS[0], "off")
        fine, _ = run(rve, loading, FACTORS[1], "off")
        reference = 2.0 * fine.P[:: FACTORS[1], 0, 0] - coarse.P[:: FACTORS[0], 0, 0]
        for tolerance in [None, *(float(t) for t in args.tolerances.split(","))]:
            result, wall = run(rve, loading, 1, tolerance)
            check = np.abs(result.program.strain) >= 0.005 - 1e-12
            scale = np.abs(reference[check]) if args.loading == "fixed" else np.abs(reference).max()
            error = np.max(np.abs(result.P[check, 0, 0] - reference[check]) / scale)
            print(f"{index:>4} {rve.network.n_dof:>6} {tolerance or 'default':>9} {int(result.substeps[1:].sum()):>5} "
                  f"{int(result.iterations.sum()):>6} {int(result.factorizations.sum()):>6} {wall:>7.1f} "
                  f"{100 * error:>8.3f}", flush=True)


if __name__ == "__main__":
    main()
