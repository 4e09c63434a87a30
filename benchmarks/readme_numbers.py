"""The numbers README.md quotes, each produced by the command the README shows.

Run:  python benchmarks/readme_numbers.py [--only NAME,...] [--skip-long]

Runs, in a scratch folder and one after another, every README command whose time or size the
README states, and prints one line per command: what it printed that the README quotes (DOF,
counts, the plan of a long command) and its wall time. Long commands (the fit, the studies,
the design) are not run: their ``--plan-only`` line is the README's number (the plan's time is
this machine's, from a speed calibration). ``--skip-long`` leaves out the FE^2 specimen and
the docs build (about 10 and 2-5 min). Times depend on what else the machine runs: run it on
a quiet machine, or read them as upper bounds.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPECS = ["spec1.csv", "spec2.csv", "spec3.csv"]

# name -> (command, what to pick out of its output: a regex whose match is printed, or None)
COMMANDS: dict[str, tuple[list[str], str | None]] = {
    "example data": (["espin", "example-data", "-o", "."], None),
    "generate": (["espin", "generate", "plla", "-o", "plla_rve"], None),
    "bench_generate": ([sys.executable, str(ROOT / "benchmarks/bench_generate.py")], r"(?m)^.*DOF.*\n.*$"),  # plla: 1st row
    "bench_simulate plla": ([sys.executable, str(ROOT / "benchmarks/bench_simulate.py"), "plla"], r"(?s)DOF.*"),
    "fit": (["espin", "fit", *SPECS, "--params", "eta,b_p,c_p", "--realizations", "3", "-o", "fit", "--plan-only"],
            r"(?s)plan:.*"),
    "design": (["espin", "design", "--target", "E=150", "--target", "sigma_y=4.5", "--var", "eta=0.1:0.3", "--var",
                "kappa=0:4", "--budget", "30", "--set", "rve.size_ratio=100", "--set", "rve.layers=5", "--set",
                "rve.sampling=balanced", "-o", "design", "--plan-only"], r"(?s)plan:.*"),
    "study sweep": (["espin", "study", "sweep", "plla", "--grid", "rve.volume_fraction=0.15,0.19,0.23", "--grid",
                     "rve.max_deviation_deg=5,15", "--realizations", "5", "-o", "sweep", "--plan-only"],
                    r"(?s)plan:.*"),
    "study rve-size": (["espin", "study", "rve-size", "plla", "-o", "rve_size", "--plan-only"], r"(?s)plan:.*"),
    "specimen holed surrogate": (["espin", "specimen", "plla", "--model", "surrogate", "--shape", "holed_strip",
                                  "--workers", "2", "-o", "holed"], r"(?m)^grip force.*$"),
    "specimen dogbone from samples": (["espin", "specimen", "plla", "--model", "surrogate", "--shape", "dogbone",
                                       "--surrogate-from", "holed/surrogate_samples.csv", "--elements-across", "2",
                                       "-o", "dog_sur"],
                                      r"(?m)^grip force.*$"),
    "specimen dogbone FE^2": (["espin", "specimen", "plla", "--shape", "dogbone", "--elements-across", "2",
                               "--workers", "2", "-o", "dogbone"], r"(?m)^\s*(?:quadrature points|grip force).*$"),
    "docs quick build": (["mkdocs", "build", "--strict", "-d", "SCRATCH/site"], None),  # from the clone, as the README
}
LONG = {"specimen dogbone FE^2", "docs quick build"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", help="comma-separated names of the commands to run (the example data always runs)")
    parser.add_argument("--skip-long", action="store_true", help="leave out the FE^2 specimen and the docs build")
    args = parser.parse_args()
    names = list(COMMANDS)
    if args.only:
        wanted = {n.strip() for n in args.only.split(",")}
        unknown = wanted - set(names)
        if unknown:
            parser.error(f"--only: unknown {sorted(unknown)}; choose from {names}")
        names = [n for n in names if n in wanted or n == "example data"]
    if args.skip_long:
        names = [n for n in names if n not in LONG]
    env = {"ESPIN_TUTORIAL_QUICK": "1", "ESPIN_PLAN": "1"}
    folder = Path(tempfile.mkdtemp(prefix="espin_readme_"))
    try:
        for name in names:
            command, pick = COMMANDS[name]
            command = [str(folder) + a.removeprefix("SCRATCH") if a.startswith("SCRATCH") else a for a in command]
            start = time.perf_counter()
            done = subprocess.run(command, cwd=ROOT if name == "docs quick build" else folder, capture_output=True,
                                  text=True, stdin=subprocess.DEVNULL, env={**os.environ, **env})
            seconds = time.perf_counter() - start
            output = done.stdout + done.stderr
            shown = ""
            if pick is not None:
                found = re.findall(pick, output)
                shown = " | ".join(" ".join(f.split()) for f in found)
            status = "ok" if done.returncode == 0 else f"exit {done.returncode}: {output.strip()[-400:]}"
            print(f"{name}: {seconds:.0f} s wall, {status}" + (f"\n    {shown}" if shown else ""), flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
