"""Reproduce the paper's workflow on its PLLA mat: geometry, tensile curve, properties, RVE size, DOF.

Steps (the paper's sections in brackets):
1. the Table 2/3 RVE (3.1.1, 4.1): generate it, its geometry statistics against the SEM
   measurements of Fig. 10/12 (diameter, orientation, tortuosity);
2. its uniaxial tensile curve to 30 % (Fig. 11/13) and the curve's properties: elastic modulus,
   yield stress and post-yield modulus from a bilinear fit;
3. the RVE-size study (Appendix A, Figs. A.15-A.18): mean, sd and RSD of the properties versus
   L/D and N_l over several realizations;
4. the DOF study (4.3, Fig. 14): DOF of this model versus a beam finite-element model.

Run:  python examples/reproduce_paper.py [--out paper] [--workers N] [--quick]

The full run is the paper's size (the plla RVE, 10 realizations per RVE size: about 70 tensile
tests, more than an hour on 2 cores; rerunning resumes the RVE-size study where it stopped).
``--quick`` runs small RVEs and 2 realizations (about a minute): the same steps and files,
numbers that are not the paper's.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import espin
from espin.analysis.properties import simulation_properties
from espin.core.atomic import atomic_write
from espin.studies.dof import dof_fit_table, dof_study, plot_dof_study
from espin.studies.sweeps import rve_size_study

FULL = {"size": 200, "layers": 15, "sizes": (50, 100, 150, 200), "layer_counts": (5, 10, 15, 20),
        "layers_for_sizes": 5, "size_for_layers": 200, "realizations": 10,
        "dof_sizes": (50, 100, 150, 200, 250, 300), "dof_layers": 15}
QUICK = {"size": 60, "layers": 5, "sizes": (30, 45), "layer_counts": (2, 3),
         "layers_for_sizes": 2, "size_for_layers": 45, "realizations": 2,
         "dof_sizes": (30, 45, 60), "dof_layers": 3}
QUICK_LOADING = {"loading__max_strain": 0.15, "loading__steps": 15}


def main(out: str = "paper", quick: bool = False, workers: int | None = None) -> dict:
    plan = QUICK if quick else FULL
    loading = QUICK_LOADING if quick else {}
    folder = Path(out)

    print("1. the Table 2/3 RVE and its geometry against the SEM measurements")
    rve = espin.generate("plla", rve__size_ratio=plan["size"], rve__layers=plan["layers"])
    rve_files = espin.write_rve_folder(rve, folder / "rve")
    stats = rve_files.statistics
    print(stats.format_table())

    print("\n2. the tensile curve and its properties")
    result = espin.simulate(rve, folder / "tensile", **loading)
    props = simulation_properties(result)
    print(f"   E = {props.modulus_MPa:.1f} MPa, yield stress = {props.yield_stress_MPa:.2f} MPa at "
          f"{100 * props.yield_strain:.2f} % strain, post-yield modulus = {props.post_yield_modulus_MPa:.2f} MPa "
          f"({props.note or 'bilinear fit R^2 = %.4f' % props.r_squared})")

    print("\n3. RVE size (Appendix A)")
    size_study = rve_size_study(
        "plla", size_ratios=plan["sizes"], layer_counts=plan["layer_counts"],
        layers_for_sizes=plan["layers_for_sizes"], size_for_layers=plan["size_for_layers"],
        realizations=plan["realizations"], folder=folder / "rve_size", workers=workers, **loading)
    columns = ["rve.size_ratio", "rve.layers", "n"] + [f"{p}_{s}" for p in ("modulus_MPa", "yield_stress_MPa",
                                                                             "post_yield_modulus_MPa")
                                                      for s in ("mean", "rsd")]
    print(size_study.summary[columns].to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    for failure in size_study.ensemble.failures:
        print(f"   failed: {failure['parameters']} seed {failure['seed']}: {failure['error']}")

    print("\n4. DOF of this model and of a beam model (Fig. 14)")
    dof = dof_study(plan["dof_sizes"], plan["dof_layers"])
    plot_dof_study(dof, folder / "dof" / "dof.png")
    atomic_write(folder / "dof" / "dof.csv", lambda tmp: dof.to_csv(tmp, index=False))
    print(dof.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    fits = dof_fit_table(dof)
    print(fits.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    print(f"   (quadratic fits DOF = c0 + c1 L + c2 L^2, L = L/D, N_l = {plan['dof_layers']})")
    print(f"\nwrote {folder}/")
    return {"statistics": stats, "result": result, "properties": props, "rve_size": size_study, "dof": dof}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="paper")
    parser.add_argument("--quick", action="store_true", help="small RVEs, 2 realizations (about a minute)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    args = parser.parse_args()
    main(args.out, args.quick, args.workers)
