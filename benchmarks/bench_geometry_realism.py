"""Does a calibrated virtual mat look like the SEM image it was calibrated to?

For each real SEM image: ``espin measure`` it, ``espin calibrate-geometry`` on the measurement
(defaults: walk chosen automatically, through the tracer), render mats of the calibrated config
as synthetic SEM images at the image's pixel size and field of view (as comparison.png; seeds
1..N), measure the renderings the same way, and compare, pooled: Kolmogorov-Smirnov distances
of the per-fiber diameter, orientation and tortuosity samples (renderings against image), the
U-turn fraction and straightness of fibers traced edge to edge (with the image's binomial
interval: few fibers cross an image), and the largest whole-fiber tortuosity of the mats.

Run: python benchmarks/bench_geometry_realism.py [--renderings 8]
(needs ../shared/data/sem beside the repository; about a minute per image).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from scipy import stats

import espin
from espin.geometry.deposition import deposit
from espin.imaging.geometry_calibration import calibrate_geometry
from espin.imaging.geometry_calibration.tracer import measure_renderings

SEM = Path(__file__).resolve().parents[2] / "shared" / "data" / "sem"
IMAGES = {
    # name: (file, measure options); the PLGA data bar starts at row 880 and its ticks span 30 um.
    "PLGA-1500_1": ("PLGA-1500_1.tif", {"scale_bar_um": 30.0, "scale_bar_rows": "880:960",
                                         "crop_rows": "0:880"}),
    # No scale bar: 0.05 um/px is the pixel size assumed in docs/sem.md.
    "nanofiber": ("nanofiber_fiji_diameterj.tif", {"um_per_px": 0.05}),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--renderings", type=int, default=8, help="rendered mats per image")
    args = parser.parse_args()
    for name, (file, options) in IMAGES.items():
        path = SEM / file
        if not path.is_file():
            print(f"{name}: {path} not found, skipped")
            continue
        started = time.perf_counter()
        image = espin.measure(path, **options)
        result = calibrate_geometry(image, "plla")
        calibrated = time.perf_counter() - started
        rve = result.config.rve
        walk = {k: getattr(rve, k) for k in ("walk", "max_deviation_deg", "waviness_deg",
                                               "waviness_length_ratio", "segment_ratio")
                if getattr(rve, k) is not None}
        print(f"\n{name}: {len(image.fibers)} traced fibers, {image.n_crossing} edge to edge, "
              f"U-turn fraction {image.u_turn_fraction:.3f}, straightness {image.straightness:.4f}")
        print(f"  calibrated in {calibrated:.0f} s: {walk}, diameters {rve.diameter_distribution} "
              f"{rve.diameter_um:.4g} +- {rve.diameter_sd_um:.4g} um, orientation {rve.orientation}")
        print(f"  tracer correction: median shift {result.search['tracer']['tortuosity_bias']:+.4f}")
        traced = measure_renderings(result.config, result.image, args.renderings)
        check = traced.check(result.targets)
        n = check["target_n_crossing"]
        k = round(check["target_u_turn_fraction"] * n)
        low, high = stats.binomtest(k, n).proportion_ci(0.95) if n else (math.nan, math.nan)
        print(f"  {args.renderings} renderings measured like the image: {check['fibers']} traced fibers; "
              f"KS diameter {check['ks_diameter_um']:.3f}, orientation {check['ks_orientation_deg']:.3f}, "
              f"tortuosity {check['ks_tortuosity']:.3f} (image sample n {len(image.fibers)}: 5 % critical "
              f"value about {1.36 * math.sqrt(1 / len(image.fibers) + 1 / check['fibers']):.3f})")
        print(f"  edge to edge: renderings {check['n_crossing']} fibers, U-turn fraction "
              f"{check['u_turn_fraction']:.3f}, straightness {check['straightness']:.4f}; image {k} of {n} "
              f"(95 % interval {low:.2f}-{high:.2f}), straightness {check['target_straightness']:.4f}")
        whole = [float(np.max(deposit(result.config.rve.model_copy(update={"seed": seed})).tortuosity))
                 for seed in range(1, args.renderings + 1)]
        print(f"  whole-fiber tortuosity of the calibrated mats (seeds 1-{args.renderings}): max "
              f"{max(whole):.3f}")
        print(f"  {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
