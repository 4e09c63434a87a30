"""Benchmark: tensile tests of virtual mats; wall time, Newton iterations, where the time goes.

Run:  python benchmarks/bench_simulate.py plla [--linear auto|superlu] [--lateral fixed|free]
      python benchmarks/bench_simulate.py scaling [--linear auto|superlu]
      python benchmarks/bench_simulate.py case SIZE_RATIO LAYERS [--lateral free] [--elastic]

`plla`: the plla RVE (about 6.5e4 DOF), uniaxial to 30 % in 30 steps, with plasticity.
`scaling`: one elastic 1 % step on RVEs from about 1e4 to 5e5 DOF.
Printed per case: DOF, steps, Newton iterations, factorizations, wall seconds, seconds in the
fiber law, in assembly (kinematics, forces, tangents) and in the linear solver, and peak RSS.
Each case runs in a fresh Python process so its peak memory is its own.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from collections import defaultdict


def _timed(owner, name, bucket, totals):
    original = getattr(owner, name)

    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            totals[bucket] += time.perf_counter() - start

    setattr(owner, name, wrapper)


def run_case(size_ratio: float, layers: int, strain: float, steps: int, linear: str,
             lateral: str, elastic: bool) -> dict:
    import espin.mechanics.equilibrium as equilibrium
    import espin.mechanics.linear_solvers as linear_solvers
    from espin.geometry.rve import generate
    from espin.mechanics.assembly import NetworkAssembler
    from espin.mechanics.driver import run_program

    totals: dict[str, float] = defaultdict(float)
    _timed(equilibrium._ThreadedLaw, "__call__", "law", totals)
    for name in ("kinematics", "gradient", "tangent"):
        _timed(NetworkAssembler, name, "assembly", totals)
    solver = linear_solvers.make_linear_solver(linear)
    _timed(solver, "factorize", "linear", totals)
    overrides = dict(rve__size_ratio=size_ratio, rve__layers=layers, loading__max_strain=strain,
                     loading__steps=steps, loading__lateral=lateral, solver__linear=linear)
    if elastic:
        overrides["fiber__flow_rate_per_s"] = 0.0
    rve = generate("plla", **overrides)
    start = time.perf_counter()
    result = run_program(rve.network, rve.config, solver)
    wall = time.perf_counter() - start
    free = result.loading_frame(result.P)[-1]
    return {
        "size_ratio": size_ratio, "layers": layers, "dof": rve.network.n_dof, "steps": steps,
        "linear": type(solver).__name__, "lateral": lateral, "elastic": elastic,
        "iterations": int(result.iterations.sum()), "factorizations": int(result.factorizations.sum()),
        "wall_s": wall, "law_s": totals["law"], "assembly_s": totals["assembly"],
        "linear_s": totals["linear"], "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "P11_MPa": [float(p) for p in result.P[:, 0, 0][[s for s in (10, 20, 30) if s <= steps]]],
        "free_P12_P22_MPa": [float(free[0, 1]), float(free[1, 1])],
        "F22_end": float(result.loading_frame(result.F)[-1, 1, 1]),
    }


def in_subprocess(*args: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "case", *args], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def show(r: dict) -> None:
    per_it = r["wall_s"] / max(r["iterations"], 1)
    print(f"{r['size_ratio']:>5.0f} {r['layers']:>4d} {r['dof']:>8d} {r['linear']:>15s} {r['lateral']:>6s} "
          f"{r['steps']:>5d} {r['iterations']:>6d} {r['factorizations']:>6d} {r['wall_s']:>8.1f} "
          f"{r['law_s']:>7.1f} {r['assembly_s']:>7.1f} {r['linear_s']:>7.1f} {per_it:>7.2f} "
          f"{r['peak_rss_MB']:>8.0f}  P11 {r['P11_MPa']}  F'22 {r['F22_end']:.4f}", flush=True)


HEADER = (f"{'L~':>5} {'N_l':>4} {'DOF':>8} {'linear':>15s} {'lat.':>6s} {'steps':>5} {'iters':>6} "
          f"{'facts':>6} {'wall s':>8} {'law s':>7} {'asm s':>7} {'lin s':>7} {'s/iter':>7} {'peak MB':>8}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["plla", "scaling", "case"])
    parser.add_argument("numbers", nargs="*", type=float)
    parser.add_argument("--linear", default="auto")
    parser.add_argument("--lateral", default="fixed")
    parser.add_argument("--elastic", action="store_true")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--strain", type=float, default=0.30)
    args = parser.parse_args()
    common = ["--linear", args.linear, "--lateral", args.lateral]
    if args.what == "case":
        size_ratio, layers = args.numbers[0], int(args.numbers[1])
        print(json.dumps(run_case(size_ratio, layers, args.strain, args.steps, args.linear,
                                  args.lateral, args.elastic)))
        return
    print(HEADER, flush=True)
    if args.what == "plla":
        show(in_subprocess("200", "15", "--steps", str(args.steps), "--strain", str(args.strain), *common,
                           *(["--elastic"] if args.elastic else [])))
    else:
        for size_ratio, layers in ((100, 6), (200, 8), (200, 15), (400, 15), (480, 20)):
            show(in_subprocess(str(size_ratio), str(layers), "--steps", "1", "--strain", "0.01",
                               "--elastic", *common))


if __name__ == "__main__":
    main()
