"""Benchmark: the cost model's predicted time of a tensile test against the measured time.

Run:  python benchmarks/bench_cost_model.py [--only NAME,...] [--json rows.jsonl]

Each case runs in a fresh Python process, one after another: the speed calibration
(:func:`espin.mechanics.cost.calibrate`, timed), the prediction
(:func:`espin.mechanics.cost.predict_test`), then the test as a study's worker runs it (generate
the RVE, simulate without an output folder, one BLAS thread; the linear solver's library is
loaded before, as in a worker past its first test: a plan adds that start once,
``espin.mechanics.cost.START_S``). Printed per case: DOF (estimated
and actual), time steps and Newton iterations (predicted and actual), predicted and measured
seconds, their ratio, the calibration's time and the machine's slowness it found, and the
slowness of a second calibration after the test (when the two differ much, other jobs changed
the machine's speed during the test and the row is noisy). The criterion is a ratio within
[0.5, 2] on every row.

Cases: ``plla`` (Table 2 mat, uniaxial to 30 % in 30 steps) at L/D 60 / 100 / 200 with 3 / 5 /
15 layers, a wavy mat (``rve.walk = "smooth"``, ``rve.waviness_deg = 12``), an aligned mat
(von Mises, kappa 2, with the README's ``rve.max_deviation_deg = 20``), an equibiaxial test and a fit-like program (300 uniform steps to 30 %,
``solver.time_rtol = "off"``); the constants of the model were fitted to those. Two cases were
not: ``plla`` at L/D 150 with 10 layers, a shorter test (10 % in 10 steps), an aligned mat
with the plla's turns (von Mises kappa 5, ``rve.max_deviation_deg`` 5), and two mats of the
README's sweep (turns of 15 deg; volume fraction 0.23 with them), at smaller sizes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

SMALL = {"rve.size_ratio": 100.0, "rve.layers": 5}
CASES = {
    "plla L/D 60, 3 layers": {"rve.size_ratio": 60.0, "rve.layers": 3},
    "plla L/D 60, 15 layers": {"rve.size_ratio": 60.0, "rve.layers": 15},
    "plla L/D 100, 5 layers": SMALL,
    "plla L/D 100, 15 layers": {"rve.size_ratio": 100.0, "rve.layers": 15},
    "plla L/D 200, 5 layers": {"rve.size_ratio": 200.0, "rve.layers": 5},
    "wavy (smooth walk, 12 deg), L/D 100, 5 layers": {**SMALL, "rve.walk": "smooth", "rve.waviness_deg": 12.0},
    "aligned (von Mises kappa 2, turns 20 deg), L/D 100, 5 layers": {
        **SMALL, "rve.orientation": {"von_mises": {"mean_deg": 0.0, "kappa": 2.0}}, "rve.max_deviation_deg": 20.0},
    "equibiaxial, L/D 100, 5 layers": {**SMALL, "loading.test": "equibiaxial"},
    "fit-like: 300 uniform steps, L/D 100, 5 layers": {**SMALL, "loading.steps": 300, "solver.time_rtol": "off"},
    "plla (L/D 200, 15 layers)": {},
    # not used to fit the constants
    "held out: plla L/D 150, 10 layers": {"rve.size_ratio": 150.0, "rve.layers": 10},
    "held out: to 10 % in 10 steps, L/D 100, 5 layers": {**SMALL, "loading.max_strain": 0.1, "loading.steps": 10},
    "held out: aligned (kappa 5, turns 5 deg), L/D 100, 5 layers": {
        **SMALL, "rve.orientation": {"von_mises": {"mean_deg": 0.0, "kappa": 5.0}}},
    "held out: turns 15 deg, L/D 100, 5 layers": {**SMALL, "rve.max_deviation_deg": 15.0},
    "held out: volume fraction 0.23, turns 15 deg, L/D 100, 15 layers": {
        "rve.size_ratio": 100.0, "rve.layers": 15, "rve.volume_fraction": 0.23, "rve.max_deviation_deg": 15.0},
}


def run_case(overrides: dict) -> dict:
    """Calibrate, predict, then generate and simulate (in this process)."""
    from threadpoolctl import threadpool_limits

    from espin.geometry.rve import generate, resolve_config
    from espin.mechanics.cost import calibrate, predict_test
    from espin.mechanics.linear_solvers import make_linear_solver
    from espin.mechanics.run import simulate

    kwargs = {k.replace(".", "__"): v for k, v in overrides.items()}
    config = resolve_config("plla", **kwargs)
    make_linear_solver(config.solver.linear).release()  # its library loaded, as in a worker past its first test
    calibration = calibrate()
    cost = predict_test(config, calibration)
    start, cpu = time.perf_counter(), time.process_time()
    with threadpool_limits(limits=1):
        rve = generate(config)
        result = simulate(rve)
    measured, cpu = time.perf_counter() - start, time.process_time() - cpu
    after = calibrate(refresh=True)  # the machine's load may have changed during the test
    return {"dof_estimate": cost.dof, "dof": int(rve.network.n_dof), "steps": cost.steps,
            "substeps_predicted": cost.substeps, "substeps": int(result.substeps[1:].sum()),
            "iterations_predicted": cost.iterations, "iterations": int(result.iterations.sum()),
            "predicted_s": cost.seconds, "measured_s": measured, "ratio": cost.seconds / measured,
            "calibration_s": calibration.seconds, "slowness": calibration.slowness,
            "slowness_after": after.slowness, "cpu_s": cpu, "elements": int(rve.network.n_elements),
            "segments": int(rve.mat.n_segments) if hasattr(rve.mat, "n_segments") else None,
            "calibration_per_iteration_s": [calibration.seconds_per_iteration, after.seconds_per_iteration],
            "calibration_cpu_per_iteration_s": [calibration.cpu_seconds_per_iteration,
                                                after.cpu_seconds_per_iteration]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="comma-separated case numbers (0-based) to run")
    parser.add_argument("--json", help="append the rows to this JSON-lines file")
    parser.add_argument("--case", help=argparse.SUPPRESS)  # internal: one case, JSON out
    args = parser.parse_args()
    if args.case is not None:
        print(json.dumps(run_case(json.loads(args.case))))
        return
    names = list(CASES)
    chosen = names if not args.only else [names[int(i)] for i in args.only.split(",")]
    print("| case | DOF (est.) | time steps pred. / run | iterations pred. / run | predicted s | measured s "
          "| ratio | calibration s | slowness before / after |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in chosen:
        out = subprocess.run([sys.executable, __file__, "--case", json.dumps(CASES[name])], check=True,
                             capture_output=True, text=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"| {name} | {r['dof']:,} ({r['dof_estimate']:,.0f}) | {r['substeps_predicted']:.0f} / {r['substeps']} "
              f"| {r['iterations_predicted']:.0f} / {r['iterations']} | {r['predicted_s']:.1f} | {r['measured_s']:.1f} "
              f"| **{r['ratio']:.2f}** | {r['calibration_s']:.2f} | {r['slowness']:.2f} / {r['slowness_after']:.2f} |",
              flush=True)
        if args.json:
            with open(args.json, "a") as f:
                f.write(json.dumps({"case": name, **r}) + "\n")


if __name__ == "__main__":
    main()
