"""Benchmark: lateral stiffness from fused crossings (issue [floppy states], phase 1).

Run:  python benchmarks/bench_fused_crossings.py SIZE_RATIO LAYERS MAX_STRAIN STEPS LATERAL ['{overrides}']

e.g.  nice -n 10 timeout 240 python benchmarks/bench_fused_crossings.py 60 3 0.10 20 free \
          '{"fiber__bending_modulus_MPa": 3000.0, "fiber__fused_crossing_fraction": 1.0,
            "fiber__fused_crossing_stiffness_ratio": 4.0}'
      (the plla-bonded values add "fiber__compression_limit": 0.5, "solver__max_move_ratio": 0.5)

A plla RVE (seed 1) of L/D = SIZE_RATIO and LAYERS layers, uniaxial to MAX_STRAIN in STEPS
reported steps, lateral ``free`` or ``fixed``, with the given config overrides (JSON, espin's
``section__key`` spelling). Printed as the run goes (so a run stopped by ``timeout`` keeps its
steps): per reported step F'22, the secant Poisson ratio (1 - F'22) / strain, P11 [MPa], Newton
iterations, factorizations, time steps and the cumulative iterations and wall seconds; at the
end the totals and, for lateral fixed, the bilinear fit (E, yield stress, post-yield modulus).
docs/mechanics.md#fused-crossings has the table these runs gave.
"""

import json
import sys
import time

import espin

size, layers, strain, steps = float(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
lateral = sys.argv[5]
extra = json.loads(sys.argv[6]) if len(sys.argv) > 6 else {}
rve = espin.generate("plla", rve__size_ratio=size, rve__layers=layers)
print("DOF", rve.network.n_dof, "elements", rve.network.n_elements, flush=True)
t0 = time.perf_counter()
total = [0, 0]


def on_step(r):
    total[0] += r.iterations
    total[1] += r.factorizations
    F22 = r.F[1, 1]
    nu = (1 - F22) / r.strain if r.strain else float("nan")
    print(f"step {r.index:3d} strain {r.strain:.4f} F22 {F22:.4f} nu_sec {nu:.3f} P11 {r.P[0, 0]:.4f} "
          f"P22 {r.P[1, 1]:.2e} it {r.iterations} fact {r.factorizations} sub {r.substeps} cum_it {total[0]} "
          f"t {time.perf_counter() - t0:.1f}", flush=True)


res = espin.simulate(rve, on_step=on_step, loading__lateral=lateral, loading__max_strain=strain,
                     loading__steps=steps, **extra)
print("DONE iterations", int(res.iterations.sum()), "factorizations", int(res.factorizations.sum()),
      "wall", round(time.perf_counter() - t0, 1), flush=True)
if lateral == "fixed":
    print("PROPS", espin.simulation_properties(res))
