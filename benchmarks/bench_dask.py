"""Benchmark: one plla-size tensile task on a local process worker and on Dask workers.

Run:  python benchmarks/bench_dask.py [--runs 3] [--steps 10] [--size-ratio 200] [--layers 15]

The task generates the plla RVE (about 6.5e4 DOF) and pulls it uniaxially to ``steps`` % in
``steps`` steps. It runs ``runs`` times, one at a time, on each of
  processes     espin's local worker processes (one busy worker, 1 BLAS thread)
  dask-local    a worker of a Dask LocalCluster (``--scheduler local``)
  dask-remote   a worker of a ``dask scheduler`` / ``dask worker`` pair started on localhost
                (the path of ``--scheduler tcp://host:8786``)
  dask-unfixed  a worker of a fresh LocalCluster given the task by ``Client.submit`` directly,
                without espin's task pool and so without its allocator setting: the before
Printed per mode: the task seconds of every run (inside the worker, imports excluded), their
median, the median over the local process worker's, the minor page faults of the task, the
worker's MALLOC_TRIM_THRESHOLD_ and Newton iterations (deterministic: equal across modes).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time


def tensile_task(options: dict) -> dict:
    """Generate the RVE and pull on it; seconds and page faults of this task alone."""
    import os
    import resource

    import numpy as np

    from espin.geometry.rve import generate
    from espin.mechanics.run import simulate

    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    start = time.perf_counter()
    rve = generate("plla", rve__size_ratio=options["size_ratio"], rve__layers=options["layers"])
    result = simulate(rve, loading__max_strain=options["steps"] / 100, loading__steps=options["steps"])
    return {"seconds": time.perf_counter() - start,
            "faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults,
            "dof": int(rve.network.n_dof), "iterations": int(np.sum(result.iterations)),
            "trim": os.environ.get("MALLOC_TRIM_THRESHOLD_")}


def _runs(pool, options: dict, runs: int) -> list[dict]:
    out = []
    for _ in range(runs):
        (outcome,) = list(pool.map(tensile_task, [options]))
        if not outcome.ok:
            raise RuntimeError(outcome.error)
        out.append(outcome.value)
    return out


def _unfixed(options: dict, runs: int) -> list[dict]:
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        return [client.submit(tensile_task, options, pure=False).result() for _ in range(runs)]


def _remote_cluster(port: int) -> list[subprocess.Popen]:
    address = f"tcp://127.0.0.1:{port}"
    scheduler = subprocess.Popen(["dask", "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                  "--no-dashboard"], stderr=subprocess.DEVNULL)
    time.sleep(3)
    worker = subprocess.Popen(["dask", "worker", address, "--nworkers", "1", "--nthreads", "1",
                               "--no-dashboard"], stderr=subprocess.DEVNULL)
    time.sleep(5)
    return [worker, scheduler]


def main() -> None:
    from espin.core.parallel import TaskPool

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--size-ratio", type=float, default=200)
    parser.add_argument("--layers", type=int, default=15)
    parser.add_argument("--port", type=int, default=8799)
    args = parser.parse_args()
    options = {"size_ratio": args.size_ratio, "layers": args.layers, "steps": args.steps}

    results: dict[str, list[dict]] = {}
    with TaskPool(workers=2) as pool:  # two processes, one task at a time: one busy worker
        results["processes"] = _runs(pool, options, args.runs)
    with TaskPool(workers=1, scheduler="local") as pool:
        results["dask-local"] = _runs(pool, options, args.runs)
    results["dask-unfixed"] = _unfixed(options, args.runs)
    processes = _remote_cluster(args.port)
    try:
        with TaskPool(scheduler=f"tcp://127.0.0.1:{args.port}") as pool:
            results["dask-remote"] = _runs(pool, options, args.runs)
    finally:
        for p in processes:
            p.terminate()
            p.wait()

    reference = statistics.median(r["seconds"] for r in results["processes"])
    print(f"plla-size task: L/D {args.size_ratio:g}, {args.layers} layers, "
          f"{results['processes'][0]['dof']} DOF, {args.steps} steps of 1 %; {args.runs} runs per mode")
    print(f"{'mode':12s} {'runs [s]':28s} {'median':>7s} {'/proc':>6s} {'faults':>10s} "
          f"{'trim':>7s} {'iterations':>10s}")
    for mode, runs in results.items():
        seconds = [r["seconds"] for r in runs]
        median = statistics.median(seconds)
        print(f"{mode:12s} {' '.join(f'{s:6.2f}' for s in seconds):28s} {median:7.2f} "
              f"{median / reference:6.3f} {statistics.median(r['faults'] for r in runs):10.0f} "
              f"{str(runs[0]['trim']):>7s} {runs[0]['iterations']:10d}")


if __name__ == "__main__":
    sys.exit(main())
