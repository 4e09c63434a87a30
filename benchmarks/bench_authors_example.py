"""Benchmark: the authors' worked example, equilibrated against affine (docs/mechanics.md).

Run:  python benchmarks/bench_authors_example.py [--authors ../shared/data/authors] [--time-rtol 1e-5]

On the network of the paper's first author (``mesh_malla_i_s.txt``) with their law and rate
(E_t 2900 MPa, E_b 2.9 MPa, a_p 1e-8 /s, b_p 4.5 MPa, c_p 0, dF11/dt 1e-2 /s), runs affine and
equilibrated kinematics with their lateral target (tau22 = 0.01 MPa) and with F22 = 1, and
prints the Kirchhoff tau11 at F11 = 1.01, 1.05, 1.10, 1.1995 (and its difference from their
curve), F22, Newton iterations and wall time.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from espin.core.config import config_from_dict
from espin.core.errors import SolverError
from espin.mechanics.run import simulate

AT = (0.01, 0.05, 0.10, 0.1995)
LAW = {"taut_modulus_MPa": 2900.0, "slack_modulus_MPa": 2.9, "flow_rate_per_s": 1e-8, "flow_resistance_MPa": 4.5,
       "hardening_exponent": 0.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--authors", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data" / "authors")
    parser.add_argument("--time-rtol", type=float, default=1e-5)
    args = parser.parse_args()
    theirs = np.loadtxt(args.authors / "curve_malla_c_every50.txt")
    program = [{"to_strain": b, "rate_per_s": 1e-2, "steps": max(1, round((b - a) / 0.01))}
               for a, b in zip((0.0, *AT), AT)]
    cases = {"affine, tau22 = 0.01": ("affine", {"stress_MPa": 0.01}), "affine, fixed": ("affine", "fixed"),
             "equilibrium, fixed": ("equilibrium", "fixed"),
             "equilibrium, tau22 = 0.01": ("equilibrium", {"stress_MPa": 0.01})}
    for name, (kinematics, lateral) in cases.items():
        config = config_from_dict({"fiber": LAW, "loading": {"lateral": lateral, "program": program},
                                   "solver": {"kinematics": kinematics, "time_rtol": args.time_rtol},
                                   "output": {"stress_measure": "kirchhoff", "figures": False, "vtk": False}})
        t0 = time.perf_counter()
        try:
            result = simulate(args.authors / "mesh_malla_i_s.txt", config=config)
        except SolverError as err:
            print(f"{name}: failed: {err}")
            continue
        line = [f"{name:<26} {time.perf_counter() - t0:7.1f} s, {int(result.iterations.sum()):,} iterations"]
        for strain in AT:
            k = int(np.argmin(np.abs(result.strain - strain)))
            row = theirs[np.argmin(np.abs(theirs[:, 0] - 1.0 - strain))]
            tau = result.kirchhoff[k, 0, 0]
            line.append(f"F11 {1 + strain:.4f}: tau11 {tau:.4f} ({tau / row[4] - 1:+.2%}) F22 {result.F[k, 1, 1]:.4f}")
        print(" | ".join(line), flush=True)


if __name__ == "__main__":
    main()
