"""Benchmark: the paper's Appendix A at paper scale, with random and balanced sampling.

Run:  python benchmarks/bench_rve_size.py [--out rve_size_bench] [--realizations 10] [--update-archive]
                                          [--variants border-random,border-balanced,lines-random,lines-balanced]
                                          [--sizes 50,100,150,200,250,300] [--layers 5,10,15,20]
      python benchmarks/bench_rve_size.py --report-only     # print what is on disk

For each variant (seeding x sampling of the plla mat), `espin study rve-size` on L/D = sizes at 5
layers and N_l = layers at L/D 200, the same seeds at every size: mean, sd and RSD of the
elastic modulus, yield stress and post-yield modulus, with the mean DOF and task seconds of each
size, and the smallest size at which all three RSDs fall below 2 % (the paper's criterion).

It runs in the background and resumes: each variant's folder keeps every finished realization
(keyed by its whole config), so a killed run continues where it stopped. The points run from
the cheapest up across all variants (a first pass on the small sizes of every variant, then the
large ones), so an interrupted run already compares the variants. A full run on 2 cores is
about 4 hours (about 49 plla-sized tensile tests per variant).

The rows of finished points are kept in the archive `benchmarks/data/rve_size/<variant>.csv`
(`--archive`; written with `--update-archive`): points with all their realizations there are
not run again, and the report merges the archive with the folder, so the study can be carried
on from a fresh clone.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

VARIANTS = {
    "border-random": {"rve__seeding": "border", "rve__sampling": "random"},
    "border-balanced": {"rve__seeding": "border", "rve__sampling": "balanced"},
    "lines-random": {"rve__seeding": "lines", "rve__sampling": "random"},
    "lines-balanced": {"rve__seeding": "lines", "rve__sampling": "balanced"},
}
PROPERTIES = ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa")
LAYERS_FOR_SIZES, SIZE_FOR_LAYERS = 5, 200.0


def _numbers(text: str, kind: type) -> list:
    return [kind(v) for v in text.split(",") if v.strip()]


ARCHIVE = Path(__file__).parent / "data" / "rve_size"


def results(out: Path, archive: Path, name: str) -> pd.DataFrame:
    """Finished realizations of a variant: its folder's task files (every pass's; the folder's
    results.csv holds only the last pass) and the archive's rows, one row per (L/D, layers,
    seed), the folder's first."""
    rows = []
    for task in sorted((out / name / "tasks").glob("*.json")):
        record = json.loads(task.read_text())
        rows.append(record.pop("parameters") | {k: v for k, v in record.items() if k not in ("strain", "stress_MPa")})
    tables = [pd.DataFrame(rows)] if rows else []
    if (archive / f"{name}.csv").exists():
        tables.append(pd.read_csv(archive / f"{name}.csv"))
    if not tables:
        return pd.DataFrame(columns=["rve.size_ratio", "rve.layers", "seed"])
    return pd.concat(tables).drop_duplicates(["rve.size_ratio", "rve.layers", "seed"])


def run(out: Path, archive: Path, variants: list[str], sizes: list[float], layers: list[int],
        realizations: int) -> None:
    from espin.studies.sweeps import rve_size_study

    # Passes of increasing cost (cost ~ (L/D)^2 N_l): every variant's cheap points first.
    points = [(s, LAYERS_FOR_SIZES) for s in sizes] + [(SIZE_FOR_LAYERS, n) for n in layers]
    cost = sorted({s * s * n for s, n in points})
    passes = [c for c in (100.0**2 * 5, 200.0**2 * 10, np.inf) if c >= cost[0]]
    for limit in passes:
        for name in variants:
            done = results(out, archive, name).groupby(["rve.size_ratio", "rve.layers"]).size()

            def missing(size: float, n_layers: int) -> bool:
                return size * size * n_layers <= limit and done.get((size, n_layers), 0) < realizations

            todo_sizes = [s for s in sizes if missing(s, LAYERS_FOR_SIZES)]
            todo_layers = [n for n in layers if missing(SIZE_FOR_LAYERS, n)]
            if not todo_sizes and not todo_layers:
                continue
            t0 = time.perf_counter()
            rve_size_study("plla", size_ratios=todo_sizes, layer_counts=todo_layers,
                           layers_for_sizes=LAYERS_FOR_SIZES, size_for_layers=SIZE_FOR_LAYERS,
                           realizations=realizations, folder=out / name, **VARIANTS[name])
            print(f"{name}: pass <= {limit:.3g} done in {time.perf_counter() - t0:.0f} s", flush=True)


def report(out: Path, archive: Path, variants: list[str], update_archive: bool) -> pd.DataFrame:
    rows = []
    for name in variants:
        table = results(out, archive, name)
        if table.empty:
            continue
        if update_archive:
            archive.mkdir(parents=True, exist_ok=True)
            table.sort_values(["rve.size_ratio", "rve.layers", "seed"]).to_csv(archive / f"{name}.csv", index=False)
        for (size, n_layers), group in table.groupby(["rve.size_ratio", "rve.layers"]):
            row = {"variant": name, "L/D": size, "layers": n_layers, "n": len(group),
                   "dof": group["n_dof"].mean(), "seconds": group["seconds"].mean()}
            for p in PROPERTIES:
                values = group[p].dropna()
                row[f"{p}_mean"] = values.mean()
                row[f"{p}_rsd_%"] = 100.0 * values.std(ddof=1) / values.mean() if len(values) > 1 else np.nan
            rows.append(row)
    summary = pd.DataFrame(rows)
    if summary.empty:
        print("nothing on disk yet")
        return summary
    with pd.option_context("display.width", 200, "display.max_columns", 30, "display.float_format", "{:.4g}".format):
        print(summary.to_string(index=False))
    print("\nsmallest size with all three RSDs < 2 % (n >= 10):")
    for name, group in summary.groupby("variant", sort=False):
        ok = group[(group["n"] >= 10) & (group[[f"{p}_rsd_%" for p in PROPERTIES]].max(axis=1) < 2.0)]
        if ok.empty:
            print(f"  {name}: no size run so far (with 10 realizations) has all three below 2 %")
            continue
        best = ok.sort_values("dof").iloc[0]
        print(f"  {name}: L/D {best['L/D']:g}, {best['layers']:d} layers: {best['dof']:.0f} DOF, "
              f"{best['seconds']:.0f} s per tensile test")
    summary.to_csv(out / "rve_size_variants.csv", index=False)
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("rve_size_bench"))
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--sizes", default="50,100,150,200,250,300")
    parser.add_argument("--layers", default="5,10,15,20")
    parser.add_argument("--realizations", type=int, default=10)
    parser.add_argument("--report-only", action="store_true")
    parser.add_argument("--archive", type=Path, default=ARCHIVE)
    parser.add_argument("--update-archive", action="store_true",
                        help="write the merged rows of each variant to the archive")
    args = parser.parse_args()
    variants = [v for v in args.variants.split(",") if v]
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        parser.error(f"--variants: unknown {unknown}; choose from {list(VARIANTS)}")
    if not args.report_only:
        run(args.out, args.archive, variants, _numbers(args.sizes, float), _numbers(args.layers, int),
            args.realizations)
    report(args.out, args.archive, variants, args.update_archive)


if __name__ == "__main__":
    main()
