"""Benchmark: an ensemble of tensile tests, serial versus parallel workers.

Run:  python benchmarks/bench_ensemble.py [--realizations 10] [--size-ratio 200] [--layers 15]
                                          [--modes serial-1,serial-default,processes,dask]

Defaults: 10 realizations of the plla RVE (seeds 1-10, about 6.5e4 DOF each), uniaxial to 30 %
in 30 steps. Modes:
  serial-1        one task after another in one process, 1 BLAS / MKL thread
  serial-default  one after another, MKL's default threads (all cores) inside each task
  processes       espin's default: one worker process per core, 1 BLAS thread each
  dask            the same through a Dask LocalCluster (one single-threaded worker per core)
Printed per mode: tasks, wall seconds, speed-up over serial-1, sum of task seconds, and the peak
resident memory of the largest worker process (ru_maxrss of the children). Each mode runs in a
fresh Python process; the curves of all modes are compared (max |difference| of stress, MPa).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time


def run_mode(mode: str, realizations: int, size_ratio: float, layers: int) -> dict:
    import resource

    import numpy as np

    from espin.geometry.rve import resolve_config
    from espin.core.parallel import TaskPlace
    from espin.studies.ensemble import plan_tasks, run_ensemble

    base = resolve_config("plla", rve__size_ratio=size_ratio, rve__layers=layers)
    tasks = plan_tasks(base, [{}], list(range(1, realizations + 1)))
    options = {
        "serial-1": {"workers": 1, "blas_threads": 1},
        "serial-default": {"workers": 1, "blas_threads": None},
        "processes": {},
        "dask": {"scheduler": "local"},
    }[mode]
    start = time.perf_counter()
    ensemble = run_ensemble(tasks, place=TaskPlace(**options))
    wall = time.perf_counter() - start
    peak_self = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    peak_children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {
        "mode": mode, "tasks": len(ensemble.records), "failed": len(ensemble.failures),
        "n_dof": int(np.mean([r["n_dof"] for r in ensemble.records])), "wall_s": wall,
        "task_s": float(sum(r["seconds"] for r in ensemble.records)),
        "peak_MB": max(peak_self, peak_children),
        "curves": {r["seed"]: r["stress_MPa"] for r in ensemble.records},
        "failures": [f"seed {f['seed']}: {f['error'].splitlines()[0][:300]}" for f in ensemble.failures],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--realizations", type=int, default=10)
    parser.add_argument("--size-ratio", type=float, default=200)
    parser.add_argument("--layers", type=int, default=15)
    parser.add_argument("--modes", default="serial-1,serial-default,processes,dask")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_mode(args.one, args.realizations, args.size_ratio, args.layers)))
        return
    import numpy as np

    rows = []
    for mode in args.modes.split(","):
        out = subprocess.run([sys.executable, __file__, "--one", mode, "--realizations", str(args.realizations),
                              "--size-ratio", str(args.size_ratio), "--layers", str(args.layers)],
                             check=True, capture_output=True, text=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        row = rows[-1]
        print(f"{row['mode']:>15}: {row['tasks']} tasks ({row['failed']} failed), {row['n_dof']} DOF each, "
              f"wall {row['wall_s']:.1f} s, task sum {row['task_s']:.1f} s, peak {row['peak_MB']:.0f} MB",
              flush=True)
        for failure in row["failures"]:
            print(f"{'':>17}failed {failure}", flush=True)
    reference = next((r for r in rows if r["mode"] == "serial-1"), rows[0])
    for row in rows:
        speedup = reference["wall_s"] / row["wall_s"]
        common = set(row["curves"]) & set(reference["curves"])
        diff = max((float(np.max(np.abs(np.subtract(row["curves"][s], reference["curves"][s])))) for s in common),
                   default=float("nan"))
        print(f"{row['mode']:>15}: speed-up over {reference['mode']} {speedup:.2f}, "
              f"max |stress difference| {diff:.3g} MPa")


if __name__ == "__main__":
    main()
