"""Tortuosity from SEM-like images against the truth, across waviness: how far and why.

For mats of ``plla`` with a growing largest turn (``rve.max_deviation_deg``), rendered as in
docs/sem.md (top 3 of 4 layers, 60 D window, 8 px per D), this prints per image:

* the true mean and median tortuosity of the visible fiber portions (the ground truth of
  :func:`espin.imaging.synthetic.render_sem`), and the spread of the true mean from image to image;
* the error of the mean over the traced pieces (``espin measure``);
* the error of the whole-fiber mean and median that ``calibrate_geometry`` infers;
* how much of each true portion its longest traced piece covers, by depth of its layer
  (0 = top): the tracer's continuity, which sets how far the pieces fall short.

Run: ``python benchmarks/bench_sem_tortuosity.py`` (about 2 min; ``--quick``: two
seeds and three turns).
"""

from __future__ import annotations

import logging
import sys
import time

import numpy as np
from scipy.spatial import cKDTree

import espin.geometry.rve
from espin.imaging.geometry_calibration import calibrate_geometry
from espin.imaging.geometry_calibration.virtual import window_runs
from espin.imaging.measurement import measure
from espin.imaging.synthetic import render_sem

D = 0.45  # plla mean diameter [um]
WINDOW, PX_PER_D = 60, 8
NEAR_PX = 3.0  # a true centre-line point within this of a traced path is covered by it


def best_piece_coverage(image, mat, paths_px: list[np.ndarray]) -> dict[int, float]:
    """Mean fraction of a true portion's length covered by its longest traced piece, by depth.

    A true centre-line point (every pixel of arc) is covered by the traced path nearest to it
    if that one is within NEAR_PX.
    """
    runs = window_runs(mat.vertices, mat.fiber_offsets, image.origin, image.side)
    top = image.origin[1] + image.side
    points = np.concatenate(paths_px)
    owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(paths_px)])
    tree = cKDTree(points)
    depth_of = {int(layer): k for k, layer in enumerate(image.layers)}
    cover: dict[int, list[float]] = {}
    for r, fiber in enumerate(runs.fiber):
        depth = depth_of.get(int(mat.fiber_layer[fiber]))
        xy = runs.points[runs.first[r]:runs.last[r] + 1]
        if depth is None or np.hypot(*(xy[-1] - xy[0])) < 3 * D:
            continue
        arc = runs.arc[runs.first[r]:runs.last[r] + 1] - runs.arc[runs.first[r]]
        s = np.arange(0.0, arc[-1], image.um_per_px)
        px = np.column_stack([(top - np.interp(s, arc, xy[:, 1])) / image.um_per_px - 0.5,
                              (np.interp(s, arc, xy[:, 0]) - image.origin[0]) / image.um_per_px
                              - 0.5])
        distance, nearest = tree.query(px)
        hit = owner[nearest[distance <= NEAR_PX]]
        cover.setdefault(depth, []).append(np.bincount(hit).max() / len(px) if len(hit) else 0.0)
    return {depth: float(np.mean(values)) for depth, values in sorted(cover.items())}


def main(quick: bool) -> None:
    logging.disable(logging.WARNING)  # the calibration warns about the orientation model
    turns = (20.0, 30.0, 45.0) if quick else (0.0, 10.0, 20.0, 25.0, 30.0, 35.0, 45.0)
    seeds = (1, 2) if quick else (1, 2, 3, 4)
    print("max dev [deg] | seed | portions / pieces | true mean / median | pieces mean - true "
          "| inferred mean - true | inferred median - true | fitted max dev [deg] | longest "
          "piece covers, depth 0 / 1 / 2 | time [s]")
    for turn in turns:
        true_means = []
        for seed in seeds:
            start = time.perf_counter()
            mat = espin.geometry.rve.generate("plla", rve__size_ratio=100, rve__layers=4, rve__seed=seed,
                                     rve__max_deviation_deg=turn).mat
            image = render_sem(mat, side_um=WINDOW * D, um_per_px=D / PX_PER_D, seed=seed)
            m = measure(image.image, um_per_px=image.um_per_px)
            result = calibrate_geometry(m, "plla")
            whole = result.search["whole_portion_tortuosity"]
            truth = image.visible.tortuosity
            true_means.append(truth.mean())
            cover = best_piece_coverage(image, mat, m.paths_px)
            print(f"{turn:.0f} | {seed} | {len(truth)} / {len(m.fibers)} | {truth.mean():.3f} / "
                  f"{np.median(truth):.3f} | {m.fibers['tortuosity'].mean() - truth.mean():+.3f} | "
                  f"{whole['mean'] - truth.mean():+.3f} | "
                  f"{whole['median'] - np.median(truth):+.3f} | "
                  f"{result.config.rve.max_deviation_deg:.1f} | "
                  f"{' / '.join(f'{cover.get(k, np.nan):.2f}' for k in range(3))} | "
                  f"{time.perf_counter() - start:.1f}", flush=True)
        print(f"{turn:.0f} | sd of the true mean over the {len(seeds)} images: "
              f"{np.std(true_means, ddof=1):.3f}", flush=True)


if __name__ == "__main__":
    main("--quick" in sys.argv[1:])
