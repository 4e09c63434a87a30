"""Figure: lateral contraction F'22 and secant Poisson ratio against strain, lateral ``free``,
for several shares phi of fused crossings (issue [floppy states], phase 2).

Run:  python benchmarks/fig_fused_poisson.py OUT_FOLDER [SIZE_RATIO LAYERS MAX_STRAIN STEPS]

(defaults 100 5 0.20 40). The ``plla-bonded`` preset (c = 4, compression limit 0.5, trust
region 0.5 D) on a plla RVE of seed 1, uniaxial with lateral ``free``, for phi = 0 (bending
along the fibers only), 0.25, 0.5 and 1, then c = 1 and 16 at phi = 1; one run after another on
one core. Writes ``fused_poisson.csv`` (phi, c, strain, F22, P11 [MPa], Newton iterations,
factorizations) and ``fused_poisson.png`` to OUT_FOLDER and prints each run's totals and wall
seconds. docs/mechanics.md#fused-crossings shows the figure.
"""

import sys
import time
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

import espin
from espin.mechanics.driver import SimulationFailed

out = Path(sys.argv[1])
size, layers, strain, steps = (float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])) \
    if len(sys.argv) > 5 else (100.0, 5, 0.20, 40)
out.mkdir(parents=True, exist_ok=True)
cases = [(0.0, 4.0), (0.25, 4.0), (0.5, 4.0), (1.0, 4.0), (1.0, 1.0), (1.0, 16.0)]
rve = espin.generate("plla-bonded", rve__size_ratio=size, rve__layers=layers)
print("DOF", rve.network.n_dof, flush=True)
rows, curves = [], {}
for phi, c in cases:
    t0 = time.perf_counter()
    try:
        res = espin.simulate(rve, fiber__fused_crossing_fraction=phi, fiber__fused_crossing_stiffness_ratio=c,
                             loading__max_strain=strain, loading__steps=steps)
    except SimulationFailed as failed:
        print(f"phi {phi} c {c}: {failed}", flush=True)
        res = failed.partial
    wall = time.perf_counter() - t0
    curves[(phi, c)] = (res.strain, res.F[:, 1, 1])
    for k in range(len(res.strain)):
        rows.append((phi, c, res.strain[k], res.F[k, 1, 1], res.P[k, 0, 0], res.iterations[k], res.factorizations[k]))
    print(f"phi {phi} c {c}: to strain {res.strain[-1]:.3f}, F22 at 2/5/10 % "
          + " / ".join(f"{np.interp(e, res.strain, res.F[:, 1, 1]):.3f}" for e in (0.02, 0.05, 0.10))
          + f", iterations {int(res.iterations.sum())}, factorizations {int(res.factorizations.sum())}, "
          f"wall {wall:.0f} s", flush=True)
np.savetxt(out / "fused_poisson.csv", np.array(rows), delimiter=",", fmt="%.8g",
           header="phi,c,strain,F22,P11_MPa,iterations,factorizations", comments="")
fig = Figure(figsize=(9.0, 3.8), layout="constrained")
left, right = fig.subplots(1, 2)
for (phi, c), (e, F22) in curves.items():
    label = "phi = 0 (bending only)" if phi == 0 else f"phi = {phi:g}, c = {c:g}"
    style = "-" if c == 4.0 else "--"
    left.plot(100 * e, F22, style, label=label)
    right.plot(100 * e[1:], (1 - F22[1:]) / e[1:], style, label=label)
left.set_xlabel("axial strain [%]")
left.set_ylabel("lateral stretch $F'_{22}$")
right.set_xlabel("axial strain [%]")
right.set_ylabel("secant Poisson ratio $(1 - F'_{22}) / \\varepsilon$")
right.set_yscale("log")
left.legend(fontsize=8)
fig.suptitle(f"plla-bonded, lateral free, L/D {size:g}, {layers} layers, seed 1", fontsize=10)
fig.savefig(out / "fused_poisson.png", dpi=150)
print("wrote", out / "fused_poisson.png", flush=True)
