"""Benchmark: generate, cross-link and save RVEs; time and peak memory versus size.

Run:  python benchmarks/bench_generate.py            (plla + scaling table)
      python benchmarks/bench_generate.py --quick    (plla only)

Each case runs in a fresh Python process so its peak resident memory is its own. Printed:
fibers, segments, cross-links, DOF, seconds per stage (deposition, cross-links, network,
save) and peak RSS. Targets (issue 2): plla in under 3 s and 1 GB; time and memory about
linear in the number of segments.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def run_case(size_ratio: float, layers: int) -> dict:
    from espin.geometry.crosslinks import find_crosslinks
    from espin.geometry.deposition import deposit
    from espin.geometry.network import build_network
    from espin.geometry.rve import RVE, resolve_config
    from espin.geometry.rve_file import save_rve

    cfg = resolve_config("plla", rve__size_ratio=size_ratio, rve__layers=layers)
    t0 = time.perf_counter()
    mat = deposit(cfg.rve)
    t1 = time.perf_counter()
    x = find_crosslinks(mat)
    t2 = time.perf_counter()
    net = build_network(mat, x, cfg.rve.merge_tolerance_um)
    t3 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        save_rve(RVE(cfg, mat, x, net), Path(tmp) / "rve.h5")
    t4 = time.perf_counter()
    return {
        "size_ratio": size_ratio, "layers": layers, "fibers": mat.n_fibers,
        "segments": mat.n_segments, "crosslinks": x.n, "dof": net.n_dof,
        "deposit_s": t1 - t0, "crosslinks_s": t2 - t1, "network_s": t3 - t2, "save_s": t4 - t3,
        "total_s": t4 - t0,
        "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def in_subprocess(size_ratio: float, layers: int) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--case", str(size_ratio), str(layers)],
        check=True, capture_output=True, text=True,
    )
    return json.loads(out.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", nargs=2, type=float, metavar=("SIZE_RATIO", "LAYERS"))
    parser.add_argument("--quick", action="store_true", help="plla only")
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case[0], int(args.case[1]))))
        return
    cases = [(200, 15)]
    if not args.quick:
        cases += [(s, 15) for s in (100, 400, 800)] + [(200, n) for n in (5, 30)] + [(800, 30)]
    header = (f"{'L~':>5} {'N_l':>4} {'fibers':>7} {'segments':>9} {'xlinks':>8} {'DOF':>8} "
              f"{'deposit':>8} {'xlink':>7} {'network':>8} {'save':>6} {'total s':>8} "
              f"{'peak MB':>8} {'us/seg':>7}")
    print(header)
    for size_ratio, layers in cases:
        r = in_subprocess(size_ratio, layers)
        print(f"{r['size_ratio']:>5.0f} {r['layers']:>4d} {r['fibers']:>7d} {r['segments']:>9d} "
              f"{r['crosslinks']:>8d} {r['dof']:>8d} {r['deposit_s']:>8.3f} "
              f"{r['crosslinks_s']:>7.3f} {r['network_s']:>8.3f} {r['save_s']:>6.3f} "
              f"{r['total_s']:>8.3f} {r['peak_rss_MB']:>8.0f} "
              f"{1e6 * r['total_s'] / r['segments']:>7.2f}")


if __name__ == "__main__":
    main()
