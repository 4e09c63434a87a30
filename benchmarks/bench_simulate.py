"""Benchmark: tensile tests of virtual mats; wall time, Newton iterations, where the time goes.

Run:  python benchmarks/bench_simulate.py plla [--linear auto|superlu] [--lateral fixed|free]
      python benchmarks/bench_simulate.py accuracy [--reference plla_reference.json]
                                                   [--tolerances 3e-3,1e-3]
      python benchmarks/bench_simulate.py scaling [--linear auto|superlu]
      python benchmarks/bench_simulate.py case SIZE_RATIO LAYERS [--lateral free] [--elastic]
Any of them takes --set KEY=VALUE (TOML value) to override a config key, e.g.
--set solver.time_rtol=3e-3 or --set rve.merge_tolerance_ratio=0.1.

`plla`: the plla RVE (about 6.5e4 DOF), uniaxial to 30 % in 30 reported steps, with
plasticity, default settings.
`accuracy`: the same test's error in time: a reference P11 Richardson-extrapolated from 480
and 960 uniform time steps (solver.time_rtol = "off"; computed once, cached in the
--reference file), then the default and each of --tolerances, with the largest
|P11 / P11_ref - 1| over the reported strains >= 0.5 %.
`scaling`: one elastic 1 % step on RVEs from about 1e4 to 5e5 DOF.
Printed per case: DOF, reported steps, time steps, Newton iterations, factorizations, wall
seconds, seconds in the fiber law, in assembly (kinematics, forces, tangents), in
factorizations, in solves, in the line search (which includes law and assembly of its
trials) and in the node relaxation after it (the same: its evaluations included), and peak
RSS. Each case runs in a fresh Python process so its peak memory is its own.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
import tomllib
from collections import defaultdict
from pathlib import Path


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
             lateral: str, elastic: bool, sets: dict) -> dict:
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
    _timed(solver, "factorize", "factorize", totals)
    _timed(linear_solvers.Factorization, "solve", "solve", totals)
    _timed(equilibrium, "line_search", "line_search", totals)  # the name equilibrium calls
    _timed(equilibrium.EquilibriumSolver, "_relax_nodes", "relax", totals)
    overrides = dict(rve__size_ratio=size_ratio, rve__layers=layers, loading__max_strain=strain,
                     loading__steps=steps, loading__lateral=lateral, solver__linear=linear)
    if elastic:
        overrides["fiber__flow_rate_per_s"] = 0.0
    overrides |= {key.replace(".", "__"): value for key, value in sets.items()}
    rve = generate("plla", **overrides)
    start = time.perf_counter()
    result = run_program(rve.network, rve.config, solver)
    wall = time.perf_counter() - start
    free = result.loading_frame(result.P)[-1]
    return {
        "size_ratio": size_ratio, "layers": layers, "dof": rve.network.n_dof, "steps": steps,
        "linear": type(solver).__name__, "lateral": lateral, "elastic": elastic,
        "substeps": int(result.substeps[1:].sum()),
        "iterations": int(result.iterations.sum()), "factorizations": int(result.factorizations.sum()),
        "wall_s": wall, "law_s": totals["law"], "assembly_s": totals["assembly"],
        "factorize_s": totals["factorize"], "solve_s": totals["solve"], "line_search_s": totals["line_search"],
        "relax_s": totals["relax"],
        "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "strain": [float(e) for e in result.strain], "P11_all_MPa": [float(p) for p in result.P[:, 0, 0]],
        "P11_MPa": [float(p) for p in result.P[:, 0, 0][[s for s in (10, 20, 30) if s <= steps]]],
        "free_P12_P22_MPa": [float(free[0, 1]), float(free[1, 1])],
        "F22_end": float(result.loading_frame(result.F)[-1, 1, 1]),
    }


def in_subprocess(*args: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "case", *args], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def show(r: dict, extra: str = "") -> None:
    per_it = r["wall_s"] / max(r["iterations"], 1)
    print(f"{r['size_ratio']:>5.0f} {r['layers']:>4d} {r['dof']:>8d} {r['linear']:>15s} {r['lateral']:>6s} "
          f"{r['steps']:>5d} {r['substeps']:>5d} {r['iterations']:>6d} {r['factorizations']:>6d} {r['wall_s']:>8.1f} "
          f"{r['law_s']:>7.1f} {r['assembly_s']:>7.1f} {r['factorize_s']:>7.1f} {r['solve_s']:>7.1f} "
          f"{r['line_search_s']:>7.1f} {r['relax_s']:>7.1f} {per_it:>7.2f} {r['peak_rss_MB']:>8.0f}  P11 "
          f"{[round(p, 4) for p in r['P11_MPa']]}  F'22 {r['F22_end']:.4f}{extra}", flush=True)


HEADER = (f"{'L~':>5} {'N_l':>4} {'DOF':>8} {'linear':>15s} {'lat.':>6s} {'steps':>5} {'dt':>5} {'iters':>6} "
          f"{'facts':>6} {'wall s':>8} {'law s':>7} {'asm s':>7} {'fact s':>7} {'solv s':>7} {'ls s':>7} {'relax s':>7} "
          f"{'s/iter':>7} {'peak MB':>8}")


def reference(path: Path, common: list[str]) -> dict:
    """P11 of the plla test from 480 and 960 uniform time steps, Richardson-extrapolated."""
    if path.is_file():
        return json.loads(path.read_text())
    runs = {}
    for n in (480, 960):
        runs[n] = in_subprocess("200", "15", "--steps", str(n), "--strain", "0.3", *common,
                                "--set", 'solver.time_rtol="off"')
        show(runs[n], "  (uniform, for the reference)")
    every = {480: 16, 960: 32}
    P = {n: runs[n]["P11_all_MPa"][::every[n]] for n in runs}
    data = {"strain": runs[960]["strain"][::32], "P11_480": P[480], "P11_960": P[960],
            "P11_ref": [2.0 * b - a for a, b in zip(P[480], P[960])]}
    path.write_text(json.dumps(data))
    return data


def error_note(r: dict, ref: dict) -> str:
    """Largest relative P11 error against the reference at strains >= 0.5 %, and where."""
    worst, where = 0.0, 0.0
    for e, p, q in zip(r["strain"], r["P11_all_MPa"], ref["P11_ref"]):
        if e >= 0.005 - 1e-12 and abs(p / q - 1.0) > worst:
            worst, where = abs(p / q - 1.0), e
    return f"  error {100 * worst:.3f} % at {100 * where:.0f} %"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["plla", "accuracy", "scaling", "case"])
    parser.add_argument("numbers", nargs="*", type=float)
    parser.add_argument("--linear", default="auto")
    parser.add_argument("--lateral", default="fixed")
    parser.add_argument("--elastic", action="store_true")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--strain", type=float, default=0.30)
    parser.add_argument("--set", action="append", default=[], help="KEY=VALUE (TOML value)")
    parser.add_argument("--reference", type=Path, default=Path("plla_reference.json"))
    parser.add_argument("--tolerances", default="3e-3,1e-3")
    args = parser.parse_args()
    sets = {k: tomllib.loads(f"v = {v}")["v"] for k, _, v in (s.partition("=") for s in args.set)}
    common = ["--linear", args.linear, "--lateral", args.lateral, *(f"--set={s}" for s in args.set)]
    if args.what == "case":
        size_ratio, layers = args.numbers[0], int(args.numbers[1])
        print(json.dumps(run_case(size_ratio, layers, args.strain, args.steps, args.linear,
                                  args.lateral, args.elastic, sets)))
        return
    print(HEADER, flush=True)
    if args.what == "accuracy":
        ref = reference(args.reference, common)
        for tol in [None, *args.tolerances.split(",")]:
            more = [] if tol is None else ["--set", f"solver.time_rtol={tol}"]
            r = in_subprocess("200", "15", "--steps", "30", "--strain", "0.3", *common, *more)
            show(r, f"  time_rtol {tol or 'default'}" + error_note(r, ref))
    elif args.what == "plla":
        show(in_subprocess("200", "15", "--steps", str(args.steps), "--strain", str(args.strain), *common,
                           *(["--elastic"] if args.elastic else [])))
    else:
        for size_ratio, layers in ((100, 6), (200, 8), (200, 15), (400, 15), (480, 20)):
            show(in_subprocess(str(size_ratio), str(layers), "--steps", "1", "--strain", "0.01",
                               "--elastic", *common))


if __name__ == "__main__":
    main()
