"""The specimen checks of docs/specimen.md: FE^2 and the surrogate on the holed strip and the dogbone.

``python benchmarks/bench_specimen.py PART [--across N] [--workers W]`` with PART one of

* ``fe2``: FE^2 of the holed strip (lateral fixed, clamped grips) to 20 % grip strain in 20
  steps, ``--across`` elements across the net section, ``--workers`` processes; ``--size-ratio``
  and ``--layers`` choose the RVE (default L/D 60 x 3; the balanced RVE is 100 x 5), ``--steps``
  and ``--strain`` shorten the program for a quick check; ``--tag`` names the archive (e.g.
  ``old`` for the same run on an older checkout);
* ``points``: ``--points`` RVE points of one network (``--size-ratio``, ``--layers``) evaluated
  twice in this process, from rest to F = diag(1.01, 0.99) (F11, F12, F21 +- 0.004) and again at the same time
  with F changed by up to 3e-4: process CPU time and RVE iterations of each trial (run it with
  the old code's PYTHONPATH for the ratio; ``--tag`` saves P and A for a comparison);
* ``compare NAME OTHER``: the forces of two archived runs, step by step (relative difference),
  and their counts and rates;
* ``surrogate``: the surrogate route (built once and archived as ``surrogate_samples.csv``, then
  the holed strip at 2, 4, 6 and 8 across, and the dogbone (2 across) with fixed and free sides);
* ``dogbone``: the ISO 527-2 5A dogbone (2 across) by FE^2 with lateral fixed, and the single RVE
  (lateral fixed / free) to compare its gauge section with;
* ``free``: FE^2 with free sides, a small strip to 5 % and the holed strip (run it under
  ``timeout``: the holed strip does not get far; free_edge_*.log in the archive);
* ``dask``: a tiny FE^2 run in this process and on a Dask LocalCluster (the same forces);
* ``report``: the comparisons from the archived runs (mesh convergence, surrogate vs FE^2,
  speed-up from 1 to 2 workers, the dogbone).

Every run prints elements, quadrature points (RVEs), DOF, wall seconds, macro iterations, time
steps, RVE solves and their rate per wall and per CPU second (user + system of the run and its
workers: compare these on a loaded machine), and the peak memory, and archives its force-displacement table
and counts in benchmarks/data/specimen/ (``NAME.csv`` and ``NAME.json``). The RVE: plla, L/D 60,
3 layers, seed 1 (the default of ``espin.specimen``); thickness 0.1 mm.
"""

from __future__ import annotations

import argparse
import json
import logging
import resource
import time
from pathlib import Path

import numpy as np

import espin
from espin.specimen.shapes import dogbone, holed_strip

DATA = Path(__file__).parent / "data" / "specimen"
STRAIN, STEPS = 0.2, 20


def _peak_mb() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 1024.0


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its finished workers."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _archive(name: str, result, extra: dict) -> None:
    DATA.mkdir(parents=True, exist_ok=True)
    result.to_dataframe().to_csv(DATA / f"{name}.csv", index=False)
    counts = {k: v for k, v in result.counts.items()}
    counts.update(extra, elements=result.specimen.n_elements, points=result.membrane.n_points,
                  dofs=result.membrane.n_dofs, peak_memory_mb=round(_peak_mb(), 1), cpu_s=round(_cpu_s(), 1))
    (DATA / f"{name}.json").write_text(json.dumps(counts, indent=1, default=str))
    solves = counts.get("rve_solves", 0)
    rate = (f", {solves / counts['seconds']:.0f} RVE solves/s ({counts['cpu_s']:.0f} s of CPU, "
            f"{solves / counts['cpu_s']:.0f} per CPU s)" if solves else "")
    print(f"{name}: {counts['elements']} elements, {counts['points']} points, {counts['dofs']} DOF, "
          f"{counts['seconds']:.1f} s, {counts['macro_iterations']} macro iterations, {counts['time_steps']} time "
          f"steps, {solves} RVE solves{rate}, {counts.get('rve_iterations', 0)} RVE iterations, "
          f"peak {counts['peak_memory_mb']:.0f} MB; force at the end: "
          f"{result.force_N[-1]:.5g} N", flush=True)


def fe2(across: int, workers: int, size_ratio: int, layers: int, strain: float, steps: int, tag: str) -> None:
    start = time.perf_counter()
    rve = espin.generate("plla", rve__size_ratio=size_ratio, rve__layers=layers)
    result = espin.specimen(rve, holed_strip(elements_across=across), max_strain=strain, steps=steps,
                            workers=workers)
    name = f"fe2_holed_{across}_w{workers}"
    if (size_ratio, layers) != (60, 3):
        name += f"_rve{size_ratio}x{layers}"
    if (strain, steps) != (STRAIN, STEPS):
        name += f"_{steps}steps"
    _archive(name + (f"_{tag}" if tag else ""), result,
             {"wall_s": time.perf_counter() - start, "rve_dofs": 2 * rve.network.n_inner})


def points(n: int, size_ratio: int, layers: int, tag: str) -> None:
    """The RVE solves of ``n`` points of one network, two trials, timed by process CPU time."""
    from espin.specimen.rve_points import RVEPoints, rve_tolerance

    rve = espin.generate("plla", rve__size_ratio=size_ratio, rve__layers=layers)
    config = rve_tolerance(rve.config, 1e-6)
    rve_points = RVEPoints(rve.network, config, n)
    rng = np.random.default_rng(0)
    F1 = np.array([[[1.01 + rng.uniform(-0.004, 0.004), rng.uniform(-0.004, 0.004)],
                    [rng.uniform(-0.004, 0.004), 0.99]] for _ in range(n)])
    F2 = F1 + rng.uniform(-3e-4, 3e-4, F1.shape)
    time_s = 0.01 / config.loading.strain_rate_per_s
    out = {}
    for label, F in (("first", F1), ("second", F2)):
        iterations, cpu = rve_points.rve_iterations, time.process_time()
        out[f"P_{label}"], out[f"A_{label}"] = rve_points.evaluate(F, time_s)
        print(f"{label} trial, {n} points, L/D {size_ratio} x {layers}: {time.process_time() - cpu:.2f} s CPU, "
              f"{rve_points.rve_iterations - iterations} RVE iterations", flush=True)
    if tag:
        DATA.mkdir(parents=True, exist_ok=True)
        np.savez(DATA / f"points_{n}_rve{size_ratio}x{layers}_{tag}.npz", **out)


def compare(name: str, other: str) -> None:
    """Forces of two archived runs step by step, and their counts."""
    a, b = _table(name), _table(other)
    if a is None or b is None:
        raise SystemExit(f"no archived run {name if a is None else other} in {DATA}")
    steps = min(len(a), len(b))
    fa, fb = a["force_N"][1:steps].to_numpy(), b["force_N"][1:steps].to_numpy()
    print(f"{name} vs {other}: {steps - 1} steps, largest relative force difference "
          f"{np.max(np.abs(fa - fb) / np.abs(fb)):.2e}")
    for label in (name, other):
        info = json.loads((DATA / f"{label}.json").read_text())
        print(f"  {label}: {info['seconds']:.1f} s, {info['macro_iterations']} macro iterations, {info['time_steps']} "
              f"time steps, {info['rve_solves']} RVE solves, {info.get('rve_iterations')} RVE iterations, "
              f"{info['rve_solves'] / info['seconds']:.0f} RVE solves/s")


def surrogate(workers: int, reuse: bool) -> None:
    from espin.core.parallel import TaskPool
    from espin.specimen.solver import SpecimenFailed
    from espin.specimen.surrogate import SAMPLE_COLUMNS, build_surrogate

    rve = espin.generate("plla", rve__size_ratio=60, rve__layers=3)
    samples = DATA / "surrogate_samples.csv"
    timing = DATA / "surrogate_build.json"
    if reuse and samples.is_file() and timing.is_file():
        build = json.loads(timing.read_text())["seconds"]
    else:
        start = time.perf_counter()
        with TaskPool(workers=workers) as pool:
            built = build_surrogate(rve.network, rve.config, STRAIN, pool=pool)
        build = time.perf_counter() - start
        print(f"surrogate: {len(built.paths)} RVE paths x {len(built.speeds)} speeds, {len(built.E)} samples, built "
              f"in {build:.1f} s ({workers} workers)", flush=True)
        DATA.mkdir(parents=True, exist_ok=True)
        np.savetxt(samples, built.table(), delimiter=",", header=",".join(SAMPLE_COLUMNS), comments="",
                   fmt="%.12g")
        timing.write_text(json.dumps({"seconds": build, "workers": workers, "paths": len(built.paths),
                                      "speeds": list(built.speeds), "samples": len(built.E)}, indent=1))
    runs = [(f"surrogate_holed_{across}", holed_strip(elements_across=across), "fixed") for across in (2, 4, 6, 8)]
    runs += [(f"surrogate_dogbone_{lateral}", dogbone(elements_across=2), lateral) for lateral in ("fixed", "free")]
    for name, geometry, lateral in runs:
        try:
            result = espin.specimen(rve, geometry, model="surrogate", max_strain=STRAIN, steps=STEPS,
                                    lateral=lateral, surrogate_from=samples)
        except SpecimenFailed as failure:
            print(f"{name}: failed after {len(failure.steps) - 1} steps: {failure}", flush=True)
            for stale in (DATA / f"{name}.csv", DATA / f"{name}.json"):
                stale.unlink(missing_ok=True)
            continue
        _archive(name, result, {"surrogate_build_s": build})


def dogbone_runs(workers: int) -> None:
    rve = espin.generate("plla", rve__size_ratio=60, rve__layers=3)
    for lateral in ("fixed", "free"):
        single = espin.simulate(rve, loading__max_strain=0.3, loading__steps=30, loading__lateral=lateral)
        DATA.mkdir(parents=True, exist_ok=True)
        np.savetxt(DATA / f"single_rve_{lateral}.csv", np.c_[single.strain, single.P[:, 0, 0]], delimiter=",",
                   header="strain,P11_MPa", comments="", fmt="%.8g")
    result = espin.specimen(rve, dogbone(elements_across=2), max_strain=STRAIN, steps=STEPS, lateral="fixed",
                            workers=workers)
    _archive("fe2_dogbone_fixed", result, {})


def free_sides() -> None:
    """FE^2 with free sides (clamped grips): a 20 x 5 mm strip (4 elements, 16 RVEs) to 5 % in 5
    steps, then the holed strip (2 across) to 20 %, one worker, with the solver's log (cuts)."""
    from espin.specimen.shapes import strip

    logging.disable(logging.NOTSET)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    for name in ("skfem", "espin.mechanics", "espin.geometry"):
        logging.getLogger(name).setLevel(logging.ERROR)
    start = time.perf_counter()

    def show(step) -> None:
        print(f"step {step.index}: grip strain {step.grip_strain:.3g}, force {step.force_N:.4g} N, {step.iterations} "
              f"iterations, {step.cuts} cuts, {step.substeps} time steps, {time.perf_counter() - start:.0f} s",
              flush=True)

    result = espin.specimen("plla", strip(20.0, 5.0, elements_across=1), max_strain=0.05, steps=5, lateral="free",
                            on_step=show)
    F22 = result.steps[-1].F[:, 1, 1]
    print(f"strip: {result.counts['rve_solves']} RVE solves, {result.counts['rve_iterations']} RVE iterations, "
          f"F22 {F22.min():.3f} to {F22.max():.3f} at 5 %", flush=True)
    start = time.perf_counter()
    espin.specimen("plla", holed_strip(elements_across=2), max_strain=STRAIN, steps=STEPS, lateral="free",
                   on_step=show)


def dask_check() -> None:
    """The same tiny FE^2 run in this process and on a Dask LocalCluster of 2 workers."""
    from espin.specimen.shapes import strip

    options = dict(max_strain=0.02, steps=2, rve__size_ratio=30, rve__layers=2)
    runs = {}
    for label, pool in (("serial", {"workers": 1}), ("dask", {"scheduler": "local", "workers": 2})):
        start = time.perf_counter()
        runs[label] = espin.specimen("plla", strip(20.0, 5.0, elements_across=1), **pool, **options).force_N
        print(f"{label}: forces {runs[label]} N in {time.perf_counter() - start:.1f} s", flush=True)
    print("identical:", bool(np.array_equal(runs["serial"], runs["dask"])))


def _table(name: str):
    import pandas as pd

    path = DATA / f"{name}.csv"
    return pd.read_csv(path) if path.is_file() else None


def report() -> None:
    print("holed strip, force [N] at grip strain 5 / 10 / 20 %:")
    runs = {}
    for name in ("fe2_holed_2_w2", "fe2_holed_4_w2", "fe2_holed_6_w2", "surrogate_holed_2", "surrogate_holed_4",
                 "surrogate_holed_6", "surrogate_holed_8"):
        table = _table(name)
        if table is None:
            continue
        runs[name] = table
        at = [np.interp(e, table["grip_strain"], table["force_N"]) for e in (0.05, 0.1, 0.2)]
        info = json.loads((DATA / f"{name}.json").read_text())
        rate = ""
        if info.get("rve_solves"):
            evaluations = info["rve_solves"] / info["points"]
            iterations = info["macro_iterations"]
            rate = (f", {iterations} macro iterations, {info['seconds'] / iterations:.2f} s each, "
                    f"{evaluations:.0f} evaluations of all points, {info['seconds'] / evaluations:.2f} s each, "
                    f"{info['rve_solves'] / info['seconds']:.0f} RVE solves/s")
        print(f"  {name}: {at[0]:.4f} / {at[1]:.4f} / {at[2]:.4f} ({info['elements']} elements, "
              f"{info['seconds']:.1f} s{rate})")
    for across in (2, 4, 6):
        fe, sur = runs.get(f"fe2_holed_{across}_w2"), runs.get(f"surrogate_holed_{across}")
        if fe is not None and sur is not None:
            error = (sur["force_N"][1:] - fe["force_N"][1:]) / fe["force_N"][1:]
            print(f"  surrogate vs FE^2 at {across} across: largest |error| {100 * np.abs(error).max():.2f} % at grip "
                  f"strain {fe['grip_strain'][1 + int(np.argmax(np.abs(error)))]:.3g}")
    one, two = DATA / "fe2_holed_2_w1.json", DATA / "fe2_holed_2_w2.json"
    if one.is_file() and two.is_file():
        a, b = json.loads(one.read_text()), json.loads(two.read_text())
        print(f"  1 -> 2 workers (2 across): {a['seconds']:.0f} s -> {b['seconds']:.0f} s, speed-up "
              f"{a['seconds'] / b['seconds']:.2f}")
    for lateral in ("fixed", "free"):
        single = DATA / f"single_rve_{lateral}.csv"
        for name in (f"fe2_dogbone_{lateral}", f"surrogate_dogbone_{lateral}"):
            table = _table(name)
            if table is None or not single.is_file():
                continue
            rve = np.loadtxt(single, delimiter=",", skiprows=1)
            strain = table["gauge_strain"][1:]
            expected = np.interp(strain, rve[:, 0], rve[:, 1])
            error = (table["gauge_stress_MPa"][1:] - expected) / expected
            print(f"  {name}: gauge stress vs single RVE ({lateral}) at gauge strain "
                  + ", ".join(f"{100 * s:.3g} %: {100 * e:+.1f} %" for s, e in list(zip(strain, error))[::4]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("part", choices=("fe2", "points", "surrogate", "dogbone", "dask", "free", "report", "compare"))
    parser.add_argument("names", nargs="*", help="compare: two archived runs")
    parser.add_argument("--across", type=int, default=2)
    parser.add_argument("--size-ratio", type=int, default=60)
    parser.add_argument("--layers", type=int, default=3)
    parser.add_argument("--strain", type=float, default=STRAIN)
    parser.add_argument("--steps", type=int, default=STEPS)
    parser.add_argument("--tag", default="")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--points", type=int, default=96, help="points: how many")
    parser.add_argument("--reuse", action="store_true", help="surrogate: the archived samples, not built again")
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    if args.part == "fe2":
        fe2(args.across, args.workers, args.size_ratio, args.layers, args.strain, args.steps, args.tag)
    elif args.part == "points":
        points(args.points, args.size_ratio, args.layers, args.tag)
    elif args.part == "compare":
        compare(*args.names)
    elif args.part == "surrogate":
        surrogate(args.workers, args.reuse)
    elif args.part == "dogbone":
        dogbone_runs(args.workers)
    elif args.part == "dask":
        dask_check()
    elif args.part == "free":
        free_sides()
    else:
        report()


if __name__ == "__main__":
    main()
