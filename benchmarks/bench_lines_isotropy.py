"""Benchmark: is a straight-fiber `lines` mat as stiff at 45 deg as along its axes?

Run:  python benchmarks/bench_lines_isotropy.py [--seeds 10] [--size-ratio 200] [--layers 15]

For each seed, a `lines` mat of straight fibers (max deviation 0) with an isotropic
orientation distribution is pulled to 0.5 % in one step (elastic fiber law, lateral fixed)
along 0, 45 and 90 deg; printed: the small-strain modulus P'11 / strain at each direction,
mean and standard error over the seeds, and the ratios to 45 deg. An isotropic mat has ratios
1 within the scatter of the orientation sampling.
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--size-ratio", type=float, default=200.0)
    parser.add_argument("--layers", type=int, default=15)
    args = parser.parse_args()

    from espin.geometry.rve import generate
    from espin.mechanics.run import simulate

    strain = 0.005
    moduli: dict[int, list[float]] = {0: [], 45: [], 90: []}
    for seed in range(args.seeds):
        rve = generate("plla", rve__seeding="lines", rve__max_deviation_deg=0.0, rve__size_ratio=args.size_ratio,
                       rve__layers=args.layers, rve__seed=seed)
        for direction in moduli:
            result = simulate(rve, loading__direction_deg=float(direction), loading__max_strain=strain,
                              loading__steps=1, fiber__flow_rate_per_s=0.0, solver__time_rtol="off")
            moduli[direction].append(result.stress()[1] / strain)
    mean = {d: float(np.mean(v)) for d, v in moduli.items()}
    print(f"{args.seeds} seeds, L/D {args.size_ratio:g}, {args.layers} layers, straight fibers, lines seeding")
    for d, values in moduli.items():
        print(f"  {d:3d} deg: E = {mean[d]:7.1f} +- {np.std(values, ddof=1) / np.sqrt(len(values)):5.1f} MPa")
    print(f"  E0/E45 = {mean[0] / mean[45]:.3f}, E90/E45 = {mean[90] / mean[45]:.3f}, "
          f"(E0 + E90) / 2 / E45 = {(mean[0] + mean[90]) / 2 / mean[45]:.3f}")


if __name__ == "__main__":
    main()
