"""Tracing through crossings: how often a trace switches fibers, and how long traces run.

Virtual mats of ``plla`` (4 layers; uniform and aligned, von Mises kappa 3; straight and
wavy), rendered as in docs/sem.md (60 D window, 8 px per D; 2 or 3 layers drawn), segmented
and traced as ``espin measure`` does (:func:`espin.imaging.segment.segment_fibers`,
:func:`espin.imaging.trace.trace_fibers` with the default bend limit), and checked against the
ground truth by :func:`espin.imaging.trace_check.check_traces`. Printed per image and pooled:
traces, true crossings passed by traces (by crossing angle: 10-30, 30-60, 60-90 deg; the
crossings below 10 deg are counted apart), switches (a trace entering a crossing on one
fiber and leaving on another), switch rate (switches / crossings passed), jumps (changes of
fiber away from a crossing of the two: through fused fibers or a segmented blob), the median
fraction of a visible fiber's length covered by its longest trace, and the run time of the
segmentation and tracing. ``--list`` prints every switch with its place.

Run: ``python benchmarks/bench_sem_tracing.py`` (about 1 min: 5 cases x 6 seeds; ``--quick``:
one seed).
"""

from __future__ import annotations

import sys
import time

import numpy as np

import espin.geometry.rve
from espin.imaging.segment import segment_fibers
from espin.imaging.synthetic import render_sem
from espin.imaging.trace import trace_fibers
from espin.imaging.trace_check import check_traces

D = 0.45  # plla mean diameter [um]
WINDOW, PX_PER_D = 60, 8
BINS = (0.0, 10.0, 30.0, 60.0, 90.0)
ALIGNED = {"rve__orientation": {"von_mises": {"mean_deg": 30.0, "kappa": 3.0}}}
CASES = [  # label, generate() overrides, layers drawn
    ("uniform straight, 3 layers", {"rve__max_deviation_deg": 0.0}, 3),
    ("uniform wavy 20 deg, 3 layers", {"rve__max_deviation_deg": 20.0}, 3),
    ("uniform wavy 20 deg, 2 layers", {"rve__max_deviation_deg": 20.0}, 2),
    ("aligned kappa 3 straight, 3 layers", {"rve__max_deviation_deg": 0.0, **ALIGNED}, 3),
    ("aligned kappa 3 wavy 20 deg, 2 layers", {"rve__max_deviation_deg": 20.0, **ALIGNED}, 2),
]


def run_case(overrides: dict, layers: int, seed: int):
    """Render one mat, trace it, check the traces: (TraceCheck, seconds of tracing)."""
    mat = espin.geometry.rve.generate("plla", rve__size_ratio=70, rve__layers=4, rve__seed=seed,
                                      **overrides).mat
    image = render_sem(mat, side_um=WINDOW * D, um_per_px=D / PX_PER_D, layers=layers,
                       seed=seed)
    start = time.perf_counter()
    seg = segment_fibers(image.image)
    traced = trace_fibers(seg.mask, seg.width_px)
    seconds = time.perf_counter() - start
    return check_traces(traced.paths, image, mat, seg.width_px), seconds


def main(seeds: tuple[int, ...], listing: bool) -> None:
    print("case | seed | traces | crossings passed <10 / 10-30 / 30-60 / 60-90 deg | switches "
          "| switch rate | jumps off crossings | median coverage | time [s]")
    passed, switches, coverage = np.zeros(4, int), np.zeros(4, int), []
    traces, jumps, seconds = 0, 0, 0.0
    for label, overrides, layers in CASES:
        for seed in seeds:
            check, s = run_case(overrides, layers, seed)
            p = check.passed_by_angle(BINS)
            n_sw = check.switches_by_angle(BINS)
            passed += p
            switches += n_sw
            jumps += check.n_jumps
            coverage.append(check.coverage)
            traces += check.n_traces
            seconds += s
            print(f"{label} | {seed} | {check.n_traces} | {' / '.join(map(str, p))} | "
                  f"{check.n_switches} | {check.switch_rate:.3f} | {check.n_jumps} | "
                  f"{check.median_coverage:.3f} | {s:.2f}", flush=True)
            if listing and check.n_switches:
                print("\n".join(check.describe().splitlines()[3:]))
    n, m = passed[1:].sum(), switches[1:].sum()
    print(f"pooled: {traces} traces; crossings passed at 10-90 deg {n} (10-30: {passed[1]}, "
          f"30-60: {passed[2]}, 60-90: {passed[3]}; below 10: {passed[0]}); switches at "
          f"10-90 deg {m} (10-30: {switches[1]}, 30-60: {switches[2]}, 60-90: {switches[3]}; "
          f"below 10: {switches[0]}); switch rate 10-90 deg {m / n:.4f}, all angles "
          f"{switches.sum() / passed.sum():.4f}; jumps off crossings {jumps}; median coverage "
          f"{np.median(np.concatenate(coverage)):.3f}; tracing {seconds:.1f} s")


if __name__ == "__main__":
    main((1,) if "--quick" in sys.argv[1:] else (1, 2, 3, 4, 5, 6), "--list" in sys.argv[1:])
