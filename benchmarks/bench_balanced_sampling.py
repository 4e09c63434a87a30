"""Benchmark: how representative one RVE's orientations are, random against balanced sampling.

Run:  python benchmarks/bench_balanced_sampling.py [--seeds 200] [--size-ratio 200] [--layers 15]
      python benchmarks/bench_balanced_sampling.py --fidelity [--seeds 1000] [--size-ratio 60] [--layers 5] [--chord-strata 3 ...]
      python benchmarks/bench_balanced_sampling.py --count-model [--seeds 6000] [--layers 5]

Deposits `--seeds` mats of the plla geometry (seeds 0 ..) for each variant and prints the
relative standard deviation over seeds of the mat's length-weighted <cos^2> and <cos^4> (the
drivers of yield stress and modulus along x, docs/geometry.md), the mean <cos^4>, the fiber
count's RSD and the deposition seconds per mat. Deterministic but for the seconds.

Variants (the ablation of balanced sampling, espin.geometry.balanced):
  random                  the paper's sampling
  sobol                   balanced draws, no herding (every fiber keeps its walk as drawn)
  sobol, straight         the same on straight fibers (max_deviation_deg = 0): the draws' floor
  balanced, 4 variants    turns of 2 blocks (biased: issue 35)
  balanced, 16 variants   turns of 4 blocks (espin's before issue 35: biased)
  balanced, chord ...     border seeding's chord quantile taken exactly ("quantile"), to its
                          quarter or third (random within), or at random (deposition._CHORD_STRATA)
  balanced                espin's: herding between the walk and its mirror image, chord to its third
and random / balanced with `lines` seeding.

`--fidelity`: whether balanced sampling keeps what random sampling gives (issue 35): for the
paper walk at 5 and 15 deg, the smooth walk and straight fibers, `--seeds` mats per arm, the
mean over seeds of the mat's mean fiber tortuosity - 1 (contour over chord of whole fibers),
its fiber count and its merged node candidates (network.n_merged), with standard errors and
the difference in standard errors (z); `--chord-strata K ...` runs a balanced arm for each
number K of strata of the chord quantile (default espin's).

`--count-model`: why balanced mats hold a third of a fiber fewer (docs/geometry.md). Fiber
volumes 0.1 + 1.8 u^2 (mean 0.7) with u independent or from a scrambled one-dimensional Sobol'
sequence fill 1 and `--layers` layers of target 20 together (each to a random open layer, the
crossing one kept), `--seeds` times: the mean fiber count, the layers' total overshoot and the
prefix's excess volume (sum of the kept volumes minus count x 0.7; zero on average for
independent volumes by Wald's identity).
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
def ablation(blocks: int | None = None, herding: bool = True, strata: int | None = None):
    """Patch the number of turn blocks or of chord strata, or switch herding off (variant 0 always)."""
    saved_blocks, saved_herd, saved_strata = deposition._TURN_BLOCKS, balanced.BalancedSampler.herd, deposition._CHORD_STRATA
    if blocks is not None:
        deposition._TURN_BLOCKS = blocks
    if strata is not None:
        deposition._CHORD_STRATA = strata
    if not herding:
        def first_variant(self, contents):
            self._offered = None
            return np.zeros(contents.shape[1], dtype=np.int64)
        balanced.BalancedSampler.herd = first_variant
    try:
        yield
    finally:
        deposition._TURN_BLOCKS, balanced.BalancedSampler.herd, deposition._CHORD_STRATA = saved_blocks, saved_herd, saved_strata


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


def fidelity_row(overrides: dict) -> list[float]:
    from espin.geometry.crosslinks import find_crosslinks
    from espin.geometry.network import build_network

    config = load_config("plla", overrides)
    mat = deposition.deposit(config.rve)
    first, last = mat.fiber_offsets[:-1], mat.fiber_offsets[1:] - 1
    chord = np.hypot(*(mat.vertices[last] - mat.vertices[first]).T)
    network = build_network(mat, find_crosslinks(mat), config.rve.merge_tolerance_um)
    return [float(np.mean(mat.contour_length / chord)) - 1.0, mat.n_fibers, network.n_merged]


def fidelity(seeds: int, base: dict, strata: list[int]) -> None:
    cases = {"paper walk, 5 deg": {"rve.max_deviation_deg": 5.0}, "paper walk, 15 deg": {"rve.max_deviation_deg": 15.0},
             "smooth walk": {"rve.walk": "smooth"}, "straight": {"rve.max_deviation_deg": 0.0}}
    print(f"{'case':<20} {'strata':>7} {'quantity':<16} {'random':>22} {'balanced':>22} {'z':>6}")
    for name, case in cases.items():
        arms = {}
        for arm in ["random", *strata]:
            sampling = "random" if arm == "random" else "balanced"
            with ablation(strata=None if arm == "random" else arm):
                rows = [fidelity_row(base | case | {"rve.sampling": sampling, "rve.seed": seed}) for seed in range(seeds)]
            r = np.array(rows)
            arms[arm] = (r.mean(axis=0), r.std(axis=0, ddof=1) / np.sqrt(seeds))
        for arm in strata:
            for k, quantity in enumerate(("tortuosity - 1", "fibers", "merged")):
                (mr, sr), (mb, sb) = (arms["random"][0][k], arms["random"][1][k]), (arms[arm][0][k], arms[arm][1][k])
                z = (mb - mr) / np.hypot(sr, sb) if np.hypot(sr, sb) > 0 else 0.0
                print(f"{name:<20} {arm:>7} {quantity:<16} {mr:12.6g} +- {sr:7.2g} {mb:12.6g} +- {sb:7.2g} {z:6.1f}",
                      flush=True)


def count_model(reps: int, layers: int) -> None:
    from scipy.stats import qmc

    print(f"{'layers':>6} {'volumes':<12} {'fibers':>18} {'overshoot':>18} {'prefix excess':>18}")
    for n_layers in sorted({1, layers}):
        for mode in ("independent", "sobol"):
            rows = []
            for rep in range(reps):
                rng = np.random.default_rng(rep)
                u = rng.random(4096) if mode == "independent" else qmc.Sobol(1, seed=rng).random_base2(12)[:, 0]
                x = 0.1 + 1.8 * u**2
                volume, open_layers, n = np.zeros(n_layers), list(range(n_layers)), 0
                for xi in x:
                    k = open_layers[rng.integers(len(open_layers))]
                    volume[k] += xi
                    n += 1
                    if volume[k] >= 20.0:
                        open_layers.remove(k)
                        if not open_layers:
                            break
                rows.append([n, volume.sum() - 20.0 * n_layers, x[:n].sum() - 0.7 * n])
            r = np.array(rows)
            m, se = r.mean(axis=0), r.std(axis=0, ddof=1) / np.sqrt(reps)
            print(f"{n_layers:>6} {mode:<12} " + " ".join(f"{a:9.3f} +- {b:6.3f}" for a, b in zip(m, se)), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, help="mats per variant (default 200; --fidelity 1000)")
    parser.add_argument("--size-ratio", type=float, help="L / D (default 200; --fidelity 60)")
    parser.add_argument("--layers", type=int, help="layers (default 15; --fidelity 5)")
    parser.add_argument("--fidelity", action="store_true", help="balanced against random: shapes, counts, merges")
    parser.add_argument("--count-model", action="store_true", help="the fiber count's model (docs/geometry.md)")
    parser.add_argument("--chord-strata", type=int, nargs="+", default=[deposition._CHORD_STRATA],
                        help="--fidelity: balanced arms with these chord strata (default espin's)")
    args = parser.parse_args()
    if args.count_model:
        count_model(args.seeds or 6000, args.layers or 5)
        return
    defaults = (1000, 60.0, 5) if args.fidelity else (200, 200.0, 15)
    for name, default in zip(("seeds", "size_ratio", "layers"), defaults):
        if getattr(args, name) is None:
            setattr(args, name, default)
    base = {"rve.size_ratio": args.size_ratio, "rve.layers": args.layers}
    if args.fidelity:
        print(f"plla geometry, L/D {args.size_ratio:g}, {args.layers} layers, {args.seeds} mats per arm")
        fidelity(args.seeds, base, args.chord_strata)
        return
    bal = base | {"rve.sampling": "balanced"}
    print(f"plla geometry, L/D {args.size_ratio:g}, {args.layers} layers, {args.seeds} seeds")
    print(f"{'variant':<26} {'cos2 RSD%':>9} {'cos4 RSD%':>9} {'<cos4>':>10} {'SE':>8} {'fibers%':>9} {'s / mat':>9}")
    run("random", args.seeds, base)
    run("sobol", args.seeds, bal, herding=False)
    run("sobol, straight", args.seeds, bal | {"rve.max_deviation_deg": 0.0}, herding=False)
    run("balanced, 4 variants", args.seeds, bal, blocks=2)
    run("balanced, 16 variants", args.seeds, bal, blocks=4)
    run("balanced, chord quantile", args.seeds, bal, strata=2**20)
    run("balanced, chord to 1/4", args.seeds, bal, strata=4)
    run("balanced, chord to 1/3", args.seeds, bal, strata=3)
    run("balanced, chord random", args.seeds, bal, strata=1)
    run("balanced", args.seeds, bal)
    run("random, lines", args.seeds, base | {"rve.seeding": "lines"})
    run("balanced, lines", args.seeds, bal | {"rve.seeding": "lines"})


if __name__ == "__main__":
    main()
