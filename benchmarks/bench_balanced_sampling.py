"""Benchmark: how representative one RVE's orientations are, random against balanced sampling.

Run:  python benchmarks/bench_balanced_sampling.py [--seeds 200] [--size-ratio 200] [--layers 15]

Deposits `--seeds` mats of the plla geometry (seeds 0 ..) for each variant and prints the
relative standard deviation over seeds of the mat's length-weighted <cos^2> and <cos^4> (the
drivers of yield stress and modulus along x, docs/geometry.md), the mean <cos^4>, the fiber
count's RSD and the deposition seconds per mat. Deterministic but for the seconds.

Variants (the ablation of balanced sampling, espin.geometry.balanced):
  random                  the paper's sampling
  sobol                   balanced draws, no herding (every fiber keeps its walk as drawn)
  sobol, straight         the same on straight fibers (max_deviation_deg = 0): the draws' floor
  balanced, 2 variants    herding between the walk and its mirror image (turns in 1 block)
  balanced, 4 variants    turns of 2 blocks
  balanced                espin's: turns of 4 blocks, 16 variants
and random / balanced with `lines` seeding.
"""

from __future__ import annotations

import argparse
import contextlib
import time

import numpy as np

import espin.geometry.balanced as balanced
import espin.geometry.deposition as deposition
from espin.core.config import load_config


def moments(mat) -> tuple[float, float]:
    d = mat.vertices[mat.segment_start + 1] - mat.vertices[mat.segment_start]
    length = np.hypot(d[:, 0], d[:, 1])
    c = d[:, 0] / length
    return float(np.sum(length * c**2) / length.sum()), float(np.sum(length * c**4) / length.sum())


@contextlib.contextmanager
def ablation(blocks: int | None = None, herding: bool = True):
    """Patch the number of turn blocks, or switch herding off (variant 0 always)."""
    saved_blocks, saved_herd = deposition._TURN_BLOCKS, balanced.BalancedSampler.herd
    if blocks is not None:
        deposition._TURN_BLOCKS = blocks
    if not herding:
        def first_variant(self, contents):
            self._offered = None
            return np.zeros(contents.shape[1], dtype=np.int64)
        balanced.BalancedSampler.herd = first_variant
    try:
        yield
    finally:
        deposition._TURN_BLOCKS, balanced.BalancedSampler.herd = saved_blocks, saved_herd


def run(name: str, seeds: int, overrides: dict, **patch) -> None:
    rows, seconds = [], 0.0
    with ablation(**patch):
        for seed in range(seeds):
            rve = load_config("plla", overrides | {"rve.seed": seed}).rve
            t0 = time.perf_counter()
            mat = deposition.deposit(rve)
            seconds += time.perf_counter() - t0
            rows.append([*moments(mat), mat.n_fibers])
    r = np.array(rows)
    rsd = 100.0 * r.std(axis=0, ddof=1) / r.mean(axis=0)
    print(f"{name:<26} {rsd[0]:9.3f} {rsd[1]:9.3f} {r[:, 1].mean():10.5f} {r[:, 1].std(ddof=1) / np.sqrt(seeds):8.5f} "
          f"{rsd[2]:9.2f} {seconds / seeds:9.3f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=200)
    parser.add_argument("--size-ratio", type=float, default=200.0)
    parser.add_argument("--layers", type=int, default=15)
    args = parser.parse_args()
    base = {"rve.size_ratio": args.size_ratio, "rve.layers": args.layers}
    bal = base | {"rve.sampling": "balanced"}
    print(f"plla geometry, L/D {args.size_ratio:g}, {args.layers} layers, {args.seeds} seeds")
    print(f"{'variant':<26} {'cos2 RSD%':>9} {'cos4 RSD%':>9} {'<cos4>':>10} {'SE':>8} {'fibers%':>9} {'s / mat':>9}")
    run("random", args.seeds, base)
    run("sobol", args.seeds, bal, herding=False)
    run("sobol, straight", args.seeds, bal | {"rve.max_deviation_deg": 0.0}, herding=False)
    run("balanced, 2 variants", args.seeds, bal, blocks=1)
    run("balanced, 4 variants", args.seeds, bal, blocks=2)
    run("balanced", args.seeds, bal)
    run("random, lines", args.seeds, base | {"rve.seeding": "lines"})
    run("balanced, lines", args.seeds, bal | {"rve.seeding": "lines"})


if __name__ == "__main__":
    main()
