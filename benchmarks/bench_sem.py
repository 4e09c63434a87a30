"""Accuracy and timing of ``espin measure`` on SEM-like images of virtual mats and real images.

Run: ``python benchmarks/bench_sem.py`` (about 30 s). Prints the tables of docs/sem.md.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import espin.geometry.rve
from espin.imaging.image import read_image
from espin.imaging.measurement import measure
from espin.imaging.synthetic import render_sem

D = 0.45
SEM = Path(__file__).parents[2] / "shared" / "data" / "sem"


def synthetic_accuracy() -> None:
    cases = [
        ("wavy uniform, max dev 20", {"rve__max_deviation_deg": 20.0}, 60, 8),
        ("wavy uniform, max dev 25", {"rve__max_deviation_deg": 25.0}, 60, 8),
        ("wavy uniform, max dev 45", {"rve__max_deviation_deg": 45.0}, 60, 8),
        ("aligned kappa 10, mean 30", {"rve__max_deviation_deg": 10.0, "rve__orientation":
                                       {"von_mises": {"mean_deg": 30.0, "kappa": 10.0}}}, 80, 7),
        ("aligned kappa 20, mean 150", {"rve__max_deviation_deg": 10.0, "rve__orientation":
                                        {"von_mises": {"mean_deg": 150.0, "kappa": 20.0}}}, 80, 7),
    ]
    print("case | seed | fibers traced / true portions | diameter error | tortuosity "
          "measured / true | median end-to-end traced / true [D] | direction error [deg] | "
          "coherency | time [s]")
    for label, overrides, window, px in cases:
        for seed in (1, 2, 3):
            mat = espin.geometry.rve.generate("plla", rve__size_ratio=100, rve__layers=4, rve__seed=seed,
                                     **overrides).mat
            image = render_sem(mat, side_um=window * D, um_per_px=D / px, seed=seed)
            start = time.perf_counter()
            m = measure(image.image, um_per_px=image.um_per_px)
            elapsed = time.perf_counter() - start
            v = image.visible
            true_dir = np.degrees(np.angle(np.sum(v.contour_length * np.exp(2j * v.orientation))) / 2)
            turn = (m.dominant_direction_deg - true_dir + 90) % 180 - 90
            d_err = m.diameter_all.mean_um / np.mean(image.diameter_um) - 1  # all fibers
            chords = (np.median(m.fibers["end_to_end_um"]) / D, np.median(v.chord_length) / D)
            print(f"{label} | {seed} | {len(m.fibers)} / {len(v)} | {100 * d_err:+.1f} % | "
                  f"{m.fibers['tortuosity'].mean():.4f} / {v.tortuosity.mean():.4f} | "
                  f"{chords[0]:.0f} / {chords[1]:.0f} | {turn:+.1f} | {m.coherency:.2f} | "
                  f"{elapsed:.2f}")


def real_images() -> None:
    if not SEM.is_dir():
        print(f"(no real images in {SEM})")
        return
    from skimage.transform import rescale

    plga, nano = SEM / "PLGA-1500_1.tif", SEM / "nanofiber_fiji_diameterj.tif"
    runs = []
    start = time.perf_counter()
    base = measure(plga, scale_bar_um=30.0, scale_bar_rows="880:960")
    runs.append(("PLGA, scale bar", base, time.perf_counter() - start))
    grey = read_image(plga)[:880]
    runs.append(("PLGA cropped", measure(grey[16:-16, 32:-32], um_per_px=base.um_per_px), 0))
    runs.append(("PLGA x0.8", measure(rescale(grey, 0.8, anti_aliasing=True),
                                      um_per_px=base.um_per_px / 0.8), 0))
    start = time.perf_counter()
    runs.append(("nanofiber, 0.05 um/px", measure(nano, um_per_px=0.05),
                 time.perf_counter() - start))
    grey = read_image(nano)
    runs.append(("nanofiber cropped", measure(grey[16:-16, 32:-32], um_per_px=0.05), 0))
    runs.append(("nanofiber x0.8", measure(rescale(grey, 0.8, anti_aliasing=True),
                                           um_per_px=0.05 / 0.8), 0))
    print("\nimage | um/px | fibers | diameter mean +- sd, all fibers [um] | median local width [um] | "
          "tortuosity mean | half-normal scale | dominant [deg] | coherency | orientation fit | time [s]")
    for label, m, elapsed in runs:
        f = m.fits
        print(f"{label} | {m.um_per_px:.5f} | {len(m.fibers)} | {m.diameter_all.mean_um:.3f} +- "
              f"{m.diameter_all.sd_um:.3f} | {np.median(m.widths_um):.3f} | "
              f"{m.fibers['tortuosity'].mean():.4f} | {f.tortuosity_scale:.4f} | "
              f"{m.dominant_direction_deg:.1f} | {m.coherency:.3f} | {f.orientation_model} | "
              f"{elapsed:.2f}")


if __name__ == "__main__":
    synthetic_accuracy()
    real_images()
