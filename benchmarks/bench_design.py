"""Benchmark: inverse design (espin.design) on problems with a known answer.

Run:  python benchmarks/bench_design.py [--quick] [--work DIR] [--seeds 0,1,2] [--only recovery,...]

Measured (every tensile test on the representative small RVE: rve.size_ratio 100, 5 layers,
balanced sampling; workers=2 on this 2-core machine):

* ``recovery``: a known design (eta, kappa of the von Mises orientation, waviness_deg of the
  smooth walk, diameter_cv) is simulated on seeds 900-904 the search never uses; only the mean
  of its E, sigma_y, H at 0 deg and E at 90 deg (5 % tolerance each) is given to espin design
  with a budget of 60 tensile tests. Compared against two baselines with the same budget,
  implemented here: ``random`` (budget / directions designs drawn uniformly in the unit cube of
  :class:`espin.design.variables.DesignSpace`) and ``lhs`` (the same number by
  scipy.stats.qmc.LatinHypercube), each evaluated on the search seed, the design with the least
  observed objective (``DesignTargets.objective``) verified on the same 5 fresh seeds as espin
  design's (rve.seed + 100000 ...). Optimizer seeds 0, 1, 2 per method (medians reported).
* ``anisotropy``: E_0 / E_90 = 3 at E_0 = 250 MPa (variables eta, kappa; mean direction 0).
* ``curve``: a whole stress-strain curve with a toe (recruitment: smooth walk, waviness 38 deg
  correlated over 5 D, sparse mat) simulated at a known design on seeds 900-904 is the target;
  success is R^2 >= 0.98 of the verified mean curve against the target curve over the whole
  strain range, toe included.
* ``unreachable``: E = 1500 MPa with eta <= 0.3: must be reported as not reached, naming the
  volume fraction's upper bound.

Per (benchmark, method, seed): tensile tests used by the search (deterministic, within the
budget) and for the checks (``verify_tests``: the verification seeds; for espin design also the
best design's replicates, which it runs outside the budget), wall seconds, the verified relative error of every target (mean of the fresh
seeds), the largest one, success. Each run lives in its own folder under the work directory
(default benchmarks/runs/design/, gitignored; espin design resumes its finished tests there,
the baselines and truths resume through the ensemble's task files), and each finished run
appends one row to benchmarks/data/design/results.csv (results_quick.csv for --quick), which
a rerun skips. The summary table is printed at the end and written to summary.txt beside it.

``--quick``: tiny RVEs (size ratio 40, 3 layers), 2 variables, small budgets, one optimizer
seed, 2 verification seeds: checks the script in about 2 minutes; its numbers mean nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "benchmarks" / "data" / "design"
FIELDS = ["benchmark", "method", "seed", "size_ratio", "layers", "variables", "directions", "dof", "budget", "tests",
          "verify_tests", "seconds", "max_error_pct", "success", "reached", "r_squared", "errors", "best", "truth",
          "message", "resumed", "git"]

FULL = {
    "rve": {"rve__size_ratio": 100, "rve__layers": 5, "rve__sampling": "balanced"},
    "loading": {"loading__max_strain": 0.1, "loading__steps": 10},
    "truth_seeds": [900, 901, 902, 903, 904], "verify": 5, "seeds": [0, 1, 2],
    "recovery": {"variables": ["eta=0.1:0.3", "kappa=0:8", "waviness_deg=0:30", "diameter_cv=0:0.4"],
                 "truth": {"rve.volume_fraction": 0.2, "rve.orientation.von_mises.kappa": 1.5,
                           "rve.waviness_deg": 15.0, "diameter_cv": 0.2},
                 "base": {"rve__walk": "smooth"}, "budget": 60},
    "anisotropy": {"variables": ["eta=0.1:0.3", "kappa=0:4"], "targets": ["E=250", "E@0/E@90=3"],
                   "base": {}, "budget": 40},
    "curve": {"variables": ["eta=0.08:0.2", "waviness_deg=25:45"],
              "truth": {"rve.volume_fraction": 0.12, "rve.waviness_deg": 38.0},
              "base": {"rve__walk": "smooth", "rve__waviness_length_ratio": 5.0,
                       "loading__max_strain": 0.2, "loading__steps": 20},
              "range": (0.02, 0.2), "points": 12, "budget": 30},
    "unreachable": {"variables": ["eta=0.1:0.3"], "targets": ["E=1500"], "base": {}, "budget": 20},
}
QUICK = {
    "rve": {"rve__size_ratio": 40, "rve__layers": 3, "rve__sampling": "balanced"},
    "loading": {"loading__max_strain": 0.1, "loading__steps": 10},
    "truth_seeds": [900, 901], "verify": 2, "seeds": [0],
    "recovery": {"variables": ["eta=0.1:0.3", "kappa=0:8"],
                 "truth": {"rve.volume_fraction": 0.2, "rve.orientation.von_mises.kappa": 1.5},
                 "base": {"rve__walk": "smooth"}, "budget": 20},
    "anisotropy": {"variables": ["eta=0.1:0.3", "kappa=0:4"], "targets": ["E=250", "E@0/E@90=3"],
                   "base": {}, "budget": 18},
    "curve": {"variables": ["eta=0.15:0.25", "waviness_deg=25:45"],
              "truth": {"rve.volume_fraction": 0.2, "rve.waviness_deg": 35.0},
              "base": {"rve__walk": "smooth", "rve__waviness_length_ratio": 5.0,
                       "loading__max_strain": 0.2, "loading__steps": 20},
              "range": (0.02, 0.2), "points": 8, "budget": 10},
    "unreachable": {"variables": ["eta=0.1:0.3"], "targets": ["E=1500"], "base": {}, "budget": 10},
}


def git_state() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
        dirty = subprocess.run(["git", "status", "--porcelain", "src/espin/design"], cwd=ROOT, capture_output=True,
                               text=True).stdout
        return head.strip() + ("+dirty-design" if dirty.strip() else "")
    except OSError:
        return ""


def base_config(mode: dict, bench: str):
    from espin.geometry.rve import resolve_config

    return resolve_config("plla", **(mode["rve"] | mode["loading"] | mode[bench]["base"]))


def dof_of(folder: Path) -> float:
    """Mean DOF of the tests in a run folder (from the ensemble's results.csv files)."""
    values = []
    for table in folder.rglob("results.csv"):
        with open(table, newline="") as f:
            values += [float(r["n_dof"]) for r in csv.DictReader(f) if r.get("n_dof")]
    return float(np.mean(values)) if values else math.nan


def evaluate_points(space, targets, points: list[np.ndarray], seeds: list[int], stage: str, folder: Path, workers: int):
    """Evaluations of unit points on seeds (every direction the targets need), run together."""
    from espin.design.search import Evaluation, _evaluate

    evaluations = [Evaluation(k, stage, np.asarray(u, dtype=float), space.values(u), int(s))
                   for k, (u, s) in enumerate((u, s) for u in points for s in seeds)]
    _evaluate(space, targets, evaluations, folder, {"workers": workers, "blas_threads": 1})
    return evaluations


def truth_outputs(mode: dict, bench: str, targets, work: Path, workers: int):
    """The known design simulated on the truth seeds: its evaluations (cached by the task files)."""
    from espin.design.variables import DesignSpace

    spec = mode[bench]
    space = DesignSpace.build(base_config(mode, bench), spec["variables"])
    unit = np.array([v.unit(spec["truth"][v.key]) for v in space.variables], dtype=float)
    return evaluate_points(space, targets, [unit], mode["truth_seeds"], "truth", work / bench / "truth", workers)


def mean_outputs(targets, evaluations) -> dict:
    with np.errstate(all="ignore"):
        out = {}
        for o in targets.outputs:
            values = np.array([e.outputs.get(o, math.nan) for e in evaluations], dtype=float)
            out[o] = float(np.nanmean(values)) if np.any(np.isfinite(values)) else math.nan
    return out


def verified_errors(targets, verification) -> tuple[dict, float, bool]:
    """Relative error of every target at the verification seeds' mean outputs (a curve: its
    relative RMS deviation), the largest |error| [%], all met."""
    from espin.design.targets import CurveTarget

    means = mean_outputs(targets, verification)
    errors, met = {}, True
    for t in targets.targets:
        achieved = float(t.achieved(means))
        error = achieved if isinstance(t, CurveTarget) else (achieved - t.value) / t.value
        errors[t.label] = round(100 * error, 3)
        met = met and math.isfinite(achieved) and t.meets(achieved)
    finite = [abs(e) for e in errors.values() if math.isfinite(e)]
    worst = max(finite) if len(finite) == len(errors) else math.nan
    return errors, worst, met


def mean_curve(evaluations, direction: float) -> tuple[np.ndarray, np.ndarray]:
    curves = [e.curves[direction] for e in evaluations if direction in e.curves]
    n = min(len(s) for s, _ in curves)
    return np.asarray(curves[0][0][:n], dtype=float), np.mean([np.asarray(y[:n], dtype=float) for _, y in curves], axis=0)


def r_squared(strain: np.ndarray, stress: np.ndarray, target_strain: np.ndarray, target_stress: np.ndarray) -> float:
    """R^2 of a curve against the target curve at the target's strains (whole range, toe included)."""
    keep = target_strain <= strain.max() + 1e-12
    model = np.interp(target_strain[keep], strain, stress)
    ref = target_stress[keep]
    return float(1.0 - np.sum((model - ref) ** 2) / np.sum((ref - ref.mean()) ** 2))


def run_espin(mode, bench, targets, seed, folder: Path, workers: int) -> dict:
    import espin.design as design

    spec = mode[bench]
    overrides = mode["rve"] | mode["loading"] | spec["base"]
    result = design(targets, spec["variables"], base="plla", budget=spec["budget"], batch=2, seed=seed,
                    verify=mode["verify"], folder=folder, workers=workers, **overrides)
    errors, worst, met = verified_errors(result.run.targets, result.run.verification)
    checks = getattr(result.run, "checks", len(result.run.verification) * len(result.run.targets.directions))
    return {"tests": result.tests, "verify_tests": checks,
            "errors": errors, "max_error_pct": worst, "success": met, "reached": result.reached,
            "best": result.values, "message": result.message, "verification": result.run.verification,
            "targets": result.run.targets}


def run_baseline(mode, bench, targets, method: str, seed: int, folder: Path, workers: int) -> dict:
    from scipy.stats import qmc

    from espin.design.search import VERIFY_SEED_OFFSET
    from espin.design.targets import parse_targets
    from espin.design.variables import DesignSpace

    spec = mode[bench]
    targets = parse_targets(targets)
    base = base_config(mode, bench)
    space = DesignSpace.build(base, spec["variables"])
    n_dir = len(targets.directions)
    n = spec["budget"] // n_dir
    if method == "random":
        unit = np.random.default_rng([seed, 2026]).random((n, space.dimension))
    else:
        unit = qmc.LatinHypercube(space.dimension, seed=seed).random(n)
    search = evaluate_points(space, targets, list(unit), [base.rve.seed], "search", folder / "search", workers)
    props = {o: np.array([e.outputs.get(o, math.nan) for e in search]) for o in targets.outputs}
    objective = targets.objective(props)
    objective = np.where(np.isfinite(objective), objective, np.inf)
    best = search[int(np.argmin(objective))]
    seeds = [base.rve.seed + VERIFY_SEED_OFFSET + k for k in range(mode["verify"])]
    verification = evaluate_points(space, targets, [best.unit], seeds, "verify", folder / "verify", workers)
    errors, worst, met = verified_errors(targets, verification)
    return {"tests": n * n_dir, "verify_tests": len(seeds) * n_dir, "errors": errors, "max_error_pct": worst,
            "success": met, "reached": met, "best": best.values,
            "message": f"least observed objective {objective.min():.3g} of {n} designs", "verification": verification,
            "targets": targets}


def read_archive(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def append_row(path: Path, row: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not path.exists()
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, FIELDS)
        if new:
            writer.writeheader()
        writer.writerow({k: row.get(k, "") for k in FIELDS})


def build_targets(mode: dict, bench: str, work: Path, workers: int):
    """Targets of a benchmark (recovery and curve: from the known design on the truth seeds)
    and a description of the truth."""
    from espin.design.targets import CurveTarget, DesignTargets, parse_targets

    spec = mode[bench]
    if bench == "recovery":
        probe = parse_targets(["E=1", "sigma_y=1", "H=1", "E@90=1"])
        evaluations = truth_outputs(mode, bench, probe, work, workers)
        means = mean_outputs(probe, evaluations)
        if not all(math.isfinite(v) for v in means.values()):
            raise RuntimeError(f"recovery truth has missing properties: {means}")
        targets = [f"{sym}@{d:g}={means[(name, d)]:.6g}+-5%" for sym, name, d in
                   (("E", "modulus_MPa", 0.0), ("sigma_y", "yield_stress_MPa", 0.0),
                    ("H", "post_yield_modulus_MPa", 0.0), ("E", "modulus_MPa", 90.0))]
        return parse_targets(targets), {"design": spec["truth"], "targets": targets, "seeds": mode["truth_seeds"]}, None
    if bench == "curve":
        probe = parse_targets(["E=1"])
        evaluations = truth_outputs(mode, bench, probe, work, workers)
        strain, stress = mean_curve(evaluations, 0.0)
        target = CurveTarget.from_curve(strain, stress, points=spec["points"], strain_range=spec["range"],
                                        tolerance=0.05, source="known wavy design")
        slopes = np.diff(stress) / np.diff(strain)
        truth = {"design": spec["truth"], "seeds": mode["truth_seeds"], "strain": strain.round(4).tolist(),
                 "stress_MPa": stress.round(4).tolist(), "initial_slopes_MPa": slopes[:6].round(2).tolist()}
        return DesignTargets((target,)), truth, (strain, stress)
    return parse_targets(spec["targets"]), {"targets": spec["targets"]}, None


def summarize(rows: list[dict]) -> str:
    lines = [f"{'benchmark':<12} {'method':<7} {'seed':>4} {'size':>5} {'lay':>3} {'d':>2} {'DOF':>7} {'tests':>5} "
             f"{'+ver':>4} {'sec':>6} {'maxerr%':>8} {'R2':>6} {'ok':>3}  errors % / message"]
    for r in rows:
        r2 = f"{float(r['r_squared']):.4f}" if r.get("r_squared") not in ("", None, "nan") else ""
        extra = r["errors"] if r["benchmark"] != "unreachable" else r["message"][:150]
        lines.append(f"{r['benchmark']:<12} {r['method']:<7} {r['seed']:>4} {float(r['size_ratio']):>5g} "
                     f"{r['layers']:>3} {r['variables']:>2} {float(r['dof'] or 'nan'):>7.0f} {r['tests']:>5} "
                     f"{r['verify_tests']:>4} {float(r['seconds']):>6.0f} {float(r['max_error_pct']):>8.2f} {r2:>6} "
                     f"{'yes' if r['success'] == 'True' else 'NO':>3}  {extra}")
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["benchmark"], r["method"]), []).append(r)
    lines += ["", "medians over optimizer seeds:",
              f"{'benchmark':<12} {'method':<7} {'runs':>4} {'tests':>6} {'sec':>6} {'maxerr%':>8} {'success':>8}"]
    for (bench, method), group in groups.items():
        med = lambda k: float(np.median([float(r[k]) for r in group]))  # noqa: E731
        ok = sum(r["success"] == "True" for r in group)
        lines.append(f"{bench:<12} {method:<7} {len(group):>4} {med('tests'):>6.0f} {med('seconds'):>6.0f} "
                     f"{med('max_error_pct'):>8.2f} {ok:>4}/{len(group)}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="tiny RVEs and budgets (checks the script)")
    parser.add_argument("--work", type=Path, default=ROOT / "benchmarks" / "runs" / "design",
                        help="folder of the runs (resumed)")
    parser.add_argument("--seeds", default=None, help="optimizer seeds, comma separated (default 0,1,2)")
    parser.add_argument("--only", default="recovery,anisotropy,unreachable,curve", help="benchmarks to run")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--archive", type=Path, default=None,
                        help="CSV of finished rows (default benchmarks/data/design/results.csv; another file reruns "
                             "rows already archived there, e.g. after a change to espin design)")
    args = parser.parse_args()

    mode = QUICK if args.quick else FULL
    work = args.work / ("quick" if args.quick else "full")
    archive = args.archive or DATA / ("results_quick.csv" if args.quick else "results.csv")
    seeds = mode["seeds"] if args.seeds is None else [int(s) for s in args.seeds.split(",")]
    benches = args.only.split(",")
    done = {(r["benchmark"], r["method"], r["seed"]) for r in read_archive(archive)}
    git = git_state()
    # Every benchmark once (seed 0) before the other seeds: a run cut short still covers all of them.
    plan = []
    for seed in seeds:
        for bench in benches:
            methods = ["espin", "random", "lhs"] if bench == "recovery" else ["espin"]
            if bench in ("unreachable", "curve") and seed != seeds[0]:
                continue
            plan += [(bench, method, seed) for method in methods]
    targets_of: dict[str, tuple] = {}
    for bench, method, seed in plan:
        if (bench, method, str(seed)) in done:
            print(f"skip {bench} {method} seed {seed}: in {archive.name}", flush=True)
            continue
        if bench not in targets_of:
            start = time.perf_counter()
            targets_of[bench] = build_targets(mode, bench, work, args.workers)
            print(f"{bench}: targets {[t.label for t in targets_of[bench][0].targets]} "
                  f"({time.perf_counter() - start:.0f} s for the truth); truth {json.dumps(targets_of[bench][1])}",
                  flush=True)
        targets, truth, curve = targets_of[bench]
        folder = work / bench / f"{method}-seed{seed}"
        resumed = folder.exists() and any(folder.rglob("*.json"))
        print(f"{bench} {method} seed {seed}: running in {folder}", flush=True)
        start = time.perf_counter()
        if method == "espin":
            out = run_espin(mode, bench, targets, seed, folder, args.workers)
        else:
            out = run_baseline(mode, bench, targets, method, seed, folder, args.workers)
        seconds = time.perf_counter() - start
        r2 = math.nan
        if curve is not None:
            s, y = mean_curve(out["verification"], 0.0)
            r2 = r_squared(s, y, *curve)
        success = out["success"]
        if bench == "curve":
            success = bool(r2 >= 0.98)
        if bench == "unreachable":
            success = (not out["reached"]) and "rve.volume_fraction = 0.3 (upper bound)" in out["message"]
        spec = mode[bench]
        overrides = mode["rve"] | spec["base"]
        row = {"benchmark": bench, "method": method, "seed": seed, "size_ratio": overrides["rve__size_ratio"],
               "layers": overrides["rve__layers"], "variables": len(spec["variables"]),
               "directions": len(targets.directions), "dof": round(dof_of(folder), 0), "budget": spec["budget"],
               "tests": out["tests"], "verify_tests": out["verify_tests"], "seconds": round(seconds, 1),
               "max_error_pct": round(out["max_error_pct"], 3), "success": success, "reached": out["reached"],
               "r_squared": round(r2, 5) if math.isfinite(r2) else "", "errors": json.dumps(out["errors"]),
               "best": json.dumps({k.removeprefix("rve."): round(v, 4) for k, v in out["best"].items()}),
               "truth": json.dumps(truth), "message": out["message"], "resumed": resumed, "git": git}
        append_row(archive, row)
        print(f"  -> tests {row['tests']} (+{row['verify_tests']} verify), {seconds:.0f} s, max error "
              f"{row['max_error_pct']} %, success {success}, R2 {row['r_squared']}, {out['message']}", flush=True)
    rows = read_archive(archive)
    text = summarize(rows)
    (archive.parent / ("summary_quick.txt" if args.quick else "summary.txt")).write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    sys.exit(main())
