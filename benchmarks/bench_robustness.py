"""Benchmark: does the mechanics solve every mat a user may bring? A fixed space-filling sample.

Run:  python benchmarks/bench_robustness.py [--out robustness] [--workers 2] [--cap-s 240]
                                             [--cases 0-40] [--loadings fixed,poisson,...]
      python benchmarks/bench_robustness.py --set rve.merge_tolerance_ratio=0.1 --out merge01
      python benchmarks/bench_robustness.py --report robustness     # the table of a folder

The sample: 40 geometries from a seeded Latin hypercube (scipy.stats.qmc) over
  volume fraction 0.05-0.4, max deviation 0-45 deg, segment ratio 2-20, diameter CV 0-0.7
  (truncated normal, D = 0.45 um), von Mises kappa 0-10 (0: uniform), L/D 60-120, layers 3-8,
with the plla fiber law; a case whose network exceeds 5e4 DOF is regenerated smaller (L/D
times 0.9 until it fits). Case 40 is the config that calibrate-geometry wrote for the PLGA SEM
image (``../shared/data/configs/plga_calibrated.toml``, skipped when absent), at its own size.
Each geometry runs five loadings to 20 % strain in 20 reported steps:
  fixed     uniaxial, lateral fixed            poisson   uniaxial, lateral {poisson_ratio = 0.3}
  biaxial   equibiaxial                        shear     simple shear
  unload    uniaxial fixed to 20 %, back to 10 % (10 + 10 steps)
with the default solver settings (``--set KEY=VALUE``, TOML values, overrides a key in every
task, to compare a variant; it is part of each task's key). A task that runs longer than ``--cap-s`` seconds counts as a
failure. Tasks run on espin's task pool (local processes); each finished task is written to
``OUT/tasks/<key>.json`` at once, so a rerun skips what is done (resumable).

Printed: one row per task (case, its parameters, DOF, loading, converged, factorizations per
reported step with failed attempts included: median and max, wall seconds, microseconds per DOF
and reported step) and a summary: converged fraction (in all and per loading), median
factorizations per reported step (over every reported step of every task), the
slowest cases against the median wall per DOF, and the failures with their messages.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import signal
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

SHARED_CONFIG = Path(__file__).resolve().parents[2] / "shared" / "data" / "configs" / "plga_calibrated.toml"
N_GEOMETRIES = 40
SAMPLE_SEED = 20261201
MAX_DOF = 50_000
STRAIN = 0.2
STEPS = 20
DIAMETER_UM = 0.45
LOADINGS = {
    "fixed": {"loading.test": "uniaxial", "loading.lateral": "fixed"},
    "poisson": {"loading.test": "uniaxial", "loading.lateral": {"poisson_ratio": 0.3}},
    "biaxial": {"loading.test": "equibiaxial"},
    "shear": {"loading.test": "simple_shear"},
    "unload": {"loading.test": "uniaxial", "loading.lateral": "fixed",
               "loading.program": [{"to_strain": STRAIN, "rate_per_s": 5e-3, "steps": STEPS // 2},
                                   {"to_strain": STRAIN / 2, "rate_per_s": 5e-3, "steps": STEPS // 2}]},
}


def geometries() -> list[dict]:
    """The sampled geometries (config overrides) and, if present, the PLGA-calibrated config."""
    from scipy.stats import qmc

    u = qmc.LatinHypercube(d=7, seed=SAMPLE_SEED).random(N_GEOMETRIES)
    cases = []
    for i, (vf, dev, seg, cv, kappa, size, layers) in enumerate(u):
        kappa = round(10.0 * kappa, 3)
        cases.append({
            "source": "plla",
            "rve.volume_fraction": round(0.05 + 0.35 * vf, 4),
            "rve.max_deviation_deg": round(45.0 * dev, 2),
            "rve.segment_ratio": round(2.0 + 18.0 * seg, 3),
            "rve.diameter_um": DIAMETER_UM,
            "rve.diameter_sd_um": round(0.7 * cv * DIAMETER_UM, 4),
            "rve.orientation": {"von_mises": {"mean_deg": 0.0, "kappa": kappa}} if kappa > 0 else "uniform",
            "rve.size_ratio": round(60.0 + 60.0 * size, 1),
            "rve.layers": 3 + min(int(6 * layers), 5),
            "rve.seed": i + 1,
        })
    if SHARED_CONFIG.is_file():
        cases.append({"source": str(SHARED_CONFIG)})
    return cases


def _key(case: dict, loading: str) -> str:
    text = json.dumps([case, loading], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _overrides(values: dict) -> dict:
    return {k.replace(".", "__"): v for k, v in values.items() if k != "source"}


class _WallCap(Exception):
    pass


def _on_alarm(signum, frame):  # noqa: ARG001 - signal handler signature
    raise _WallCap()


def run_task(task: dict) -> dict:
    """Generate the geometry (shrunk below MAX_DOF) and run one loading; never raises."""
    import numpy as np

    from espin.core.config import config_from_dict
    from espin.geometry.rve import generate
    from espin.mechanics.driver import SimulationFailed
    from espin.mechanics.run import simulate

    case, loading, cap = task["case"], task["loading"], task["cap_s"]
    loading_overrides = dict(LOADINGS[loading])
    if "loading.program" not in loading_overrides:
        loading_overrides |= {"loading.max_strain": STRAIN, "loading.steps": STEPS}
    loading_overrides |= {k: v for k, v in task.get("set", {}).items() if not k.startswith("rve.")}
    signal.signal(signal.SIGALRM, _on_alarm)
    signal.setitimer(signal.ITIMER_REAL, cap)
    start = time.perf_counter()
    record = {"key": task["key"], "index": task["index"], "loading": loading}
    try:
        overrides = _overrides(case) | _overrides({k: v for k, v in task.get("set", {}).items()
                                                     if k.startswith("rve.")})
        rve = generate(case["source"], **overrides)
        while case["source"] == "plla" and rve.network.n_dof > MAX_DOF:
            overrides["rve__size_ratio"] = round(0.9 * overrides["rve__size_ratio"], 1)
            rve = generate(case["source"], **overrides)
        record |= {"dof": int(rve.network.n_dof), "size_ratio": rve.config.rve.size_ratio}
        if "loading.program" in loading_overrides:  # a program replaces a config's shorthand loading
            data = rve.config.model_dump(mode="json", exclude_none=True, exclude_unset=True)
            for key in ("max_strain", "strain_rate_per_s", "steps"):
                data.get("loading", {}).pop(key, None)
            rve = replace(rve, config=config_from_dict(data, "(benchmark)"))
        try:
            result = simulate(rve, **_overrides(loading_overrides))
            record |= {"converged": True, "message": ""}
        except SimulationFailed as failure:
            result = failure.partial
            record |= {"converged": False, "message": str(failure).split("; residual history")[0]}
    except _WallCap:
        result = None
        record |= {"converged": False, "message": f"wall cap of {cap:g} s reached"}
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    record["wall_s"] = time.perf_counter() - start
    if result is not None:
        record["factorizations"] = np.asarray(result.factorizations)[1:].tolist()
        record["iterations"] = np.asarray(result.iterations)[1:].tolist()
        record["steps_reached"] = len(result.strain) - 1
    return record


def _row(case: dict, r: dict) -> str:
    fact = r.get("factorizations") or [math.nan]
    steps = max(r.get("steps_reached", 0), 1)
    per_dof = 1e6 * r["wall_s"] / (r.get("dof", math.nan) * steps)
    if case["source"] == "plla":
        geom = (f"vf {case['rve.volume_fraction']:.3f} dev {case['rve.max_deviation_deg']:4.1f} "
                f"seg {case['rve.segment_ratio']:5.2f} cv {case['rve.diameter_sd_um'] / DIAMETER_UM:.2f} "
                f"kappa {(case['rve.orientation'] if isinstance(case['rve.orientation'], str) else case['rve.orientation']['von_mises']['kappa'])!s:>7s} "
                f"L/D {r.get('size_ratio', math.nan):5.1f} Nl {case['rve.layers']}")
    else:
        geom = f"{Path(case['source']).name:62s}"
    return (f"{r['index']:3d} {geom} {r.get('dof', 0):6d} {r['loading']:8s} "
            f"{'yes' if r['converged'] else 'NO ':3s} {statistics.median(fact):6.1f} {max(fact):5.0f} "
            f"{r['wall_s']:7.1f} {per_dof:7.2f}")


def report(folder: Path, cases: list[dict]) -> None:
    records = [json.loads(p.read_text()) for p in sorted((folder / "tasks").glob("*.json"))]
    records.sort(key=lambda r: (r["index"], list(LOADINGS).index(r["loading"])))
    print(f"{'#':>3s} {'geometry':62s} {'DOF':>6s} {'loading':8s} {'ok':3s} {'f/step':>6s} {'max':>5s} "
          f"{'wall s':>7s} {'us/DOF/step':>7s}")
    for r in records:
        print(_row(cases[r["index"]], r))
    if not records:
        return
    ok = [r for r in records if r["converged"]]
    per_step = [f for r in records for f in r.get("factorizations", [])]
    per_dof = {r["key"]: r["wall_s"] / (r.get("dof", 1) * max(r.get("steps_reached", 0), 1)) for r in ok}
    median = statistics.median(per_dof.values()) if per_dof else math.nan
    print(f"\nconverged: {len(ok)} of {len(records)} ({100.0 * len(ok) / len(records):.1f} %); "
          f"factorizations per reported step: median {statistics.median(per_step) if per_step else math.nan:.1f}, "
          f"max {max(per_step) if per_step else math.nan:.0f}; wall per DOF and step: median {1e6 * median:.2f} us")
    print("converged per loading: " + ", ".join(
        f"{name} {sum(r['converged'] for r in records if r['loading'] == name)}/"
        f"{sum(r['loading'] == name for r in records)}" for name in LOADINGS))
    worst = sorted(ok, key=lambda r: per_dof[r["key"]], reverse=True)[:5]
    for r in worst:
        print(f"  slowest: case {r['index']} {r['loading']}: {per_dof[r['key']] / median:.1f} x the median")
    for r in records:
        if not r["converged"]:
            print(f"  FAILED case {r['index']} {r['loading']}: {r['message']}")
    print(f"total task seconds {sum(r['wall_s'] for r in records):.0f}")


def _select(text: str, n: int) -> list[int]:
    if not text:
        return list(range(n))
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), (int(b) if b else int(a)) + 1))  # "26-40": 26 to 40, both included
    return [i for i in out if i < n]


def main() -> int:
    from espin.core.atomic import atomic_write_bytes
    from espin.core.parallel import TaskPool

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("robustness"))
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--cap-s", type=float, default=240.0)
    parser.add_argument("--cases", default="", help="e.g. 0-10,40: cases 0 to 10 and 40 (default: all)")
    parser.add_argument("--loadings", default=",".join(LOADINGS))
    parser.add_argument("--set", action="append", default=[], help="KEY=VALUE for every task (TOML value)")
    parser.add_argument("--report", type=Path, default=None, help="print the table of a folder and stop")
    args = parser.parse_args()
    import tomllib

    variant = {k: tomllib.loads(f"v = {v}")["v"] for k, _, v in (s.partition("=") for s in args.set)}
    cases = geometries()
    if args.report is not None:
        report(args.report, cases)
        return 0
    loadings = args.loadings.split(",")
    tasks = [{"case": cases[i], "loading": name, "index": i, "cap_s": args.cap_s, "set": variant,
              "key": _key(cases[i] | {"set": variant} if variant else cases[i], name)}
             for i in _select(args.cases, len(cases)) for name in loadings]
    folder = args.out / "tasks"
    folder.mkdir(parents=True, exist_ok=True)
    todo = [t for t in tasks if not (folder / f"{t['key']}.json").exists()]
    print(f"{len(tasks)} tasks, {len(tasks) - len(todo)} done before, {len(todo)} to run", flush=True)
    start = time.perf_counter()
    with TaskPool(workers=args.workers) as pool:
        for outcome in pool.map(run_task, todo):
            task = todo[outcome.index]
            record = outcome.value if outcome.ok else {
                "key": task["key"], "index": task["index"], "loading": task["loading"], "converged": False,
                "message": outcome.error, "wall_s": outcome.seconds or 0.0}
            atomic_write_bytes(folder / f"{task['key']}.json", json.dumps(record).encode())
            print(_row(task["case"], record), flush=True)
    print(f"wall {time.perf_counter() - start:.0f} s\n")
    report(args.out, cases)
    return 0


if __name__ == "__main__":
    sys.exit(main())
