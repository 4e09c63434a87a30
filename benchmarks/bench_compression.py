"""Benchmark: compression-dominated states, with and without the opt-in fiber bending.

Run:  python benchmarks/bench_compression.py [--parts poisson,free,fixed] [--cap-s 600]
                                             [--bending 0,3000,30000,300000]

Parts (plla fiber law, seed 1, solver defaults unless said):
  poisson  uniaxial to 10 % in 10 steps, L/D 100, 5 layers: lateral fixed and
           {poisson_ratio = 0.5}, each bending modulus; the issue's case.
  free     uniaxial, lateral free, to 30 % in 30 steps, L/D 100, 5 layers, each bending
           modulus: P'11 and F'22 at 5, 10, 30 % (or where it stopped).
  fixed    uniaxial, lateral fixed, to 30 % in 30 steps at the plla size (L/D 200, 15 layers),
           each bending modulus: the effect of bending on P'11 at 5, 10, 30 %.
Each run is a child process stopped after --cap-s seconds (then marked "cap").
Printed per run: DOF, Newton iterations, factorizations, sub-steps, wall seconds, P'11 [MPa]
and F'22 at the reported strains, and how it ended.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import time

STRAINS = (0.05, 0.10, 0.30)


def _run(kwargs: dict, queue: mp.Queue) -> None:
    import numpy as np

    import espin
    from espin.core.errors import EspinError

    t0 = time.perf_counter()
    rows = []

    def on_step(record) -> None:
        rows.append((record.strain, record.P[0, 0], record.F[1, 1], record.iterations,
                     record.factorizations, record.substeps))

    status = "converged"
    try:
        espin.simulate("plla", on_step=on_step, **kwargs)
    except EspinError as err:
        status = "failed: " + str(err).split(":")[0]
    wall = time.perf_counter() - t0
    rve = espin.generate("plla", **{k: v for k, v in kwargs.items() if k.startswith("rve__")})
    queue.put({"rows": rows, "wall": wall, "status": status, "dof": int(rve.network.n_dof),
               "iterations": int(np.sum([r[3] for r in rows])),
               "factorizations": int(np.sum([r[4] for r in rows]))})


def run_case(kwargs: dict, cap_s: float) -> dict:
    """One simulation in a child process, at most ``cap_s`` seconds."""
    queue: mp.Queue = mp.Queue()
    process = mp.Process(target=_run, args=(kwargs, queue))
    t0 = time.perf_counter()
    process.start()
    process.join(cap_s)
    if process.is_alive():
        process.terminate()
        process.join()
        return {"status": f"cap ({cap_s:g} s)", "wall": time.perf_counter() - t0, "rows": []}
    return queue.get() if not queue.empty() else {"status": "crashed", "wall": time.perf_counter() - t0, "rows": []}


def _at(rows: list, strain: float) -> str:
    for s, P11, F22, *_ in rows:
        if abs(s - strain) < 1e-9:
            return f"{P11:7.4f} {F22:6.4f}"
    return "      -      -"


def report(name: str, bending: float, result: dict) -> None:
    rows = result["rows"]
    last = rows[-1][0] if rows else 0.0
    print(f"{name:8s} E_bend {bending:8g}  DOF {result.get('dof', '-'):>6}  its {result.get('iterations', '-'):>6}  "
          f"fact {result.get('factorizations', '-'):>6}  wall {result['wall']:7.1f} s  "
          + "  ".join(f"{e:.0%}: {_at(rows, e)}" for e in STRAINS)
          + f"  reached {last:.3f}  {result['status']}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", default="poisson,free,fixed")
    parser.add_argument("--bending", default="0,3000,30000,300000")
    parser.add_argument("--cap-s", type=float, default=600.0)
    parser.add_argument("--json", help="also write every result to this file")
    args = parser.parse_args()
    moduli = [float(v) for v in args.bending.split(",")]
    small = dict(rve__size_ratio=100, rve__layers=5)
    cases = []
    for part in args.parts.split(","):
        for E in moduli:
            bend = dict(fiber__bending_modulus_MPa=E)
            if part == "poisson":
                for name, lateral in (("fixed", "fixed"), ("nu=0.5", {"poisson_ratio": 0.5})):
                    cases.append((name, E, dict(**small, **bend, loading__lateral=lateral, loading__max_strain=0.1,
                                                loading__steps=10)))
            elif part == "free":
                cases.append(("free", E, dict(**small, **bend, loading__lateral="free", loading__max_strain=0.3,
                                              loading__steps=30)))
            elif part == "fixed":
                cases.append(("plla", E, dict(**bend, loading__lateral="fixed", loading__max_strain=0.3,
                                              loading__steps=30)))
            else:
                sys.exit(f"unknown part {part!r}")
    print("columns: P'11 [MPa] and F'22 at each strain", flush=True)
    results = []
    for name, E, kwargs in cases:
        result = run_case(kwargs, args.cap_s)
        report(name, E, result)
        results.append({"case": name, "bending_modulus_MPa": E, "kwargs": kwargs, **result})
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
