"""Visible (top) fibers against partly hidden deeper ones, on SEM-like images of virtual mats.

Run: ``python benchmarks/bench_sem_visible.py`` (about a minute). For each rendering
(:func:`espin.imaging.synthetic.render_sem`, 60 D window, 8 px per D), ``espin measure``'s
``visible`` column is checked against the depth of the mat fiber each traced fiber follows
(:meth:`espin.imaging.synthetic.SyntheticSEM.followed`, away from junctions by one fiber
width; visible truth = depth 0). Fibers without a diameter (no width sample) are not counted:
they are in neither diameter population. Prints per rendering and pooled precision and
recall, the counts, the visible population's mean diameter against the true mean diameter of
the top-layer fibers in the window, and the runtime; then the numbers of the two real images.
The tables of docs/sem.md ("Visible and hidden fibers").
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from espin.core.config import load_config
from espin.geometry.deposition import deposit
from espin.imaging.measurement import SEMMeasurement, measure
from espin.imaging.synthetic import SyntheticSEM, render_sem

D = 0.45  # um, plla diameter
SEM = Path(__file__).parents[2] / "shared" / "data" / "sem"
ALIGNED = {"rve.orientation": {"von_mises": {"mean_deg": 30.0, "kappa": 3.0}}}
SMOOTH = {"rve.walk": "smooth", "rve.waviness_deg": 15.0}
LOGNORMAL = {"rve.diameter_sd_um": 0.15, "rve.diameter_distribution": "lognormal"}
NORMAL = {"rve.diameter_sd_um": 0.1}
CASES = [
    # label, mat keys, render_sem options
    ("uniform, paper 20 deg, normal", {"rve.max_deviation_deg": 20.0} | NORMAL, {}),
    ("uniform, smooth 15 deg, lognormal", SMOOTH | LOGNORMAL, {}),
    ("aligned, paper 10 deg, normal", {"rve.max_deviation_deg": 10.0} | ALIGNED | NORMAL, {}),
    ("aligned, smooth 15 deg, lognormal", SMOOTH | ALIGNED | LOGNORMAL, {}),
    ("uniform, paper 20 deg, 2 layers, dimming 0.25", {"rve.max_deviation_deg": 20.0},
     {"layers": 2, "depth_dimming": 0.25}),
    ("uniform, smooth 20 deg, dimming 0.5, depth blur 2 px",
     {"rve.walk": "smooth", "rve.waviness_deg": 20.0} | NORMAL,
     {"depth_dimming": 0.5, "depth_blur_px": 2.0}),
    ("uniform, paper 20 deg, depth blur 0.5 px, noise 0.08",
     {"rve.max_deviation_deg": 20.0} | LOGNORMAL, {"depth_blur_px": 0.5, "noise_sd": 0.08}),
]
SEEDS = (1, 2)


def rendering(mat_keys: dict, options: dict, seed: int, window_d: float = 60.0) -> SyntheticSEM:
    """A rendering of a 4-layer mat of ``plla`` with ``mat_keys`` (1.17 windows wide)."""
    rve = load_config("plla", {"rve.size_ratio": 1.17 * window_d, "rve.layers": 4,
                               "rve.seed": seed} | mat_keys).rve
    return render_sem(deposit(rve), side_um=window_d * D, seed=seed, **options)


def scored(image: SyntheticSEM, m: SEMMeasurement) -> dict[str, float]:
    """Counts, precision and recall of ``visible`` against depth 0, and mean diameters [um]."""
    truth = image.depth(image.followed(m.paths_px, m.junctions_px, m.typical_width_px)) == 0
    counted = np.isfinite(m.fibers["diameter_um"].to_numpy())
    visible = m.fibers["visible"].to_numpy()[counted]
    truth = truth[counted]
    top = image.depth(image.fiber) == 0
    return {"n": int(counted.sum()), "true_top": int(truth.sum()),
            "tp": int((visible & truth).sum()), "fp": int((visible & ~truth).sum()),
            "fn": int((~visible & truth).sum()),
            "visible_mean_um": m.fits.diameter.mean_um,
            "all_mean_um": m.diameter_all.mean_um,
            "true_top_mean_um": float(np.mean(image.diameter_um[top]))}


def main() -> None:
    print("rendering | seed | fibers | true top | visible (TP + FP) | precision | recall | "
          "mean diameter visible / all / true top [um] | rule | time [s]")
    pooled = {"tp": 0, "fp": 0, "fn": 0}
    for label, mat_keys, options in CASES:
        for seed in SEEDS:
            image = rendering(mat_keys, options, seed)
            start = time.perf_counter()
            m = measure(image.image, um_per_px=image.um_per_px)
            elapsed = time.perf_counter() - start
            s = scored(image, m)
            for key in pooled:
                pooled[key] += s[key]
            print(f"{label} | {seed} | {s['n']} | {s['true_top']} | {s['tp'] + s['fp']} | "
                  f"{_ratio(s['tp'], s['tp'] + s['fp'])} | {_ratio(s['tp'], s['tp'] + s['fn'])} | "
                  f"{s['visible_mean_um']:.3f} / {s['all_mean_um']:.3f} / "
                  f"{s['true_top_mean_um']:.3f} | {m.visibility.rule.split(' (')[0]} | "
                  f"{elapsed:.2f}")
    tp, fp, fn = pooled["tp"], pooled["fp"], pooled["fn"]
    print(f"pooled: precision {_ratio(tp, tp + fp)} ({tp} / {tp + fp}), "
          f"recall {_ratio(tp, tp + fn)} ({tp} / {tp + fn})")
    real_images()


def real_images() -> None:
    """Visible and hidden populations of the two real images."""
    if not SEM.is_dir():
        print(f"(no real images in {SEM})")
        return
    for name, options in (("PLGA-1500_1.tif", {"crop_rows": "0:880", "um_per_px": 0.06592}),
                          ("nanofiber_fiji_diameterj.tif", {"um_per_px": 0.05})):
        m = measure(SEM / name, **options)
        v, h = m.fits.diameter, m.diameter_hidden
        print(f"{name}: {v.n} visible, {h.n} hidden; visible {v.mean_um:.3f} +- {v.sd_um:.3f} um "
              f"(median {v.median_um:.3f}), hidden {h.mean_um:.3f} +- {h.sd_um:.3f} um, all "
              f"{m.diameter_all.mean_um:.3f} +- {m.diameter_all.sd_um:.3f} um; {m.visibility.rule}")
        for family in ("normal", "lognormal", "mixture"):
            print(f"  visible {family}: ln L {v.log_likelihood[family]:.2f}, AIC "
                  f"{v.aic[family]:.2f}, BIC {v.bic[family]:.2f}")
        print(f"  chosen (BIC): {v.chosen}; mixture {v.mixture}")


def _ratio(a: int, b: int) -> str:
    return f"{a / b:.3f}" if b else "n/a"


if __name__ == "__main__":
    main()
