"""Benchmark: is the size and memory estimate made before any work within 2x of the measurement?

Run:  python benchmarks/bench_memory.py [--cases small,plla,...] [--out DIR]

Each case runs ``espin simulate`` (default loading program, figures and VTK written) in a
fresh process; printed per case: the estimated and the generated fibers, segments, cross-links
and DOF, the estimated and the measured peak resident memory (ru_maxrss of the child), their
ratio and the wall seconds. The estimate is :func:`espin.geometry.size_estimate.estimate_size`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = {
    "small": {"rve.size_ratio": 100, "rve.layers": 5},
    "medium": {"rve.size_ratio": 140, "rve.layers": 8},
    "wavy": {"rve.size_ratio": 140, "rve.layers": 8, "rve.max_deviation_deg": 30, "rve.segment_ratio": 2},
    "polydisperse": {"rve.size_ratio": 140, "rve.layers": 8, "rve.diameter_sd_um": 0.3},
    "plla": {},
    "dense": {"rve.size_ratio": 200, "rve.layers": 15, "rve.volume_fraction": 0.3},
}

CHILD = """
import json, resource, sys
import espin
from espin.geometry.rve import resolve_config
from espin.geometry.size_estimate import estimate_size
overrides = json.loads(sys.argv[1])
config = resolve_config("plla", **{k.replace(".", "__"): v for k, v in overrides.items()})
size = estimate_size(config)
rve = espin.generate(config)
espin.simulate(rve, sys.argv[2], overwrite=True)
print(json.dumps({"estimate": size.__dict__, "fibers": rve.mat.n_fibers, "segments": rve.mat.n_segments,
                  "crosslinks": rve.crosslinks.n, "dof": rve.network.n_dof,
                  "peak_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated: " + ", ".join(CASES))
    parser.add_argument("--out", type=Path, default=None, help="folder for the runs' results (default: temporary)")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_memory_"))
    print(f"{'case':13s} {'fibers est/gen':>15s} {'segments':>17s} {'cross-links':>17s} {'DOF':>17s} "
          f"{'est MiB':>8s} {'peak MiB':>8s} {'ratio':>6s} {'s':>6s}")
    for name in args.cases.split(","):
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(CASES[name]), str(out / name)],
                              capture_output=True, text=True, check=True)
        seconds = time.perf_counter() - start
        data = json.loads(done.stdout.strip().splitlines()[-1])
        est = data["estimate"]
        pairs = [f"{est[k]:>7,.0f}/{data[k]:<7,d}" for k in ("fibers", "segments", "crosslinks", "dof")]
        estimated, measured = est["memory_bytes"] / 2**20, data["peak_kib"] / 1024
        print(f"{name:13s} {pairs[0]:>15s} {pairs[1]:>17s} {pairs[2]:>17s} {pairs[3]:>17s} "
              f"{estimated:8.0f} {measured:8.0f} {estimated / measured:6.2f} {seconds:6.0f}", flush=True)


if __name__ == "__main__":
    main()
