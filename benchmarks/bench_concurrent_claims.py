"""Stress test of output-folder claims: several processes start ``espin study sweep`` or
``espin specimen`` on one new folder at the same instant.

Run:  python benchmarks/bench_concurrent_claims.py                 # 20 rounds of 2 and of 4, both commands
      python benchmarks/bench_concurrent_claims.py --rounds 5 --processes 2

Each round forks the processes from one parent that has imported espin (so they reach the claim
within milliseconds of each other), releases them together and runs the command's CLI in each.
A round passes when exactly one process exits 0, every other exits 2 naming the reason (the
folder is being written by another run; or, for one that reached the folder after the winner
had finished, that it holds another run's results), and the folder holds the winner's whole result:
``run.json`` complete, the result files (a tiny sweep's results.csv row, a specimen's CSV rows)
and no temporary file.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

TINY = ["--set", "rve.size_ratio=30", "--set", "rve.layers=2", "--set", "loading.max_strain=0.02",
        "--set", "loading.steps=2"]
COMMANDS = {
    "sweep": lambda out: ["study", "sweep", *TINY, "--realizations", "1", "-q", "-o", str(out)],
    "specimen": lambda out: ["specimen", "--shape", "strip", "--model", "neo_hookean", "--modulus", "200", "--poisson",
                             "0.3", "--elements-across", "2", "--steps", "3", "--max-strain", "0.02", "-q", "-o",
                             str(out)],
}
REASONS = ("is being written by another", "already holds the results of another", "holds another study")
"""What a refused process may say: the folder is claimed now, or (a process that reached it after the
winner had finished) holds the winner's results, or (a different study) the winner's plan."""


def run_round(argvs: list[list[str]], logs: Path) -> tuple[list[int], list[str]]:
    """Fork a process per command line ``argvs`` and start them at once: their exit codes and
    outputs (logs in ``logs``)."""
    from espin.cli import app

    n = len(argvs)
    go_read, go_write = os.pipe()
    pids = []
    for k in range(n):
        pid = os.fork()
        if pid == 0:  # a child: wait for the start, run the command, exit with its code
            os.close(go_write)
            log = os.open(logs / f"{k}.log", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(log, 1)
            os.dup2(log, 2)
            os.read(go_read, 1)
            try:
                app(argvs[k], prog_name="espin", standalone_mode=True)
                code = 0
            except SystemExit as done:
                code = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
            except BaseException:  # noqa: BLE001 - a traceback is a failed round
                import traceback

                traceback.print_exc()
                code = 1
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        pids.append(pid)
    os.close(go_read)
    os.write(go_write, b"x" * n)  # all at once
    os.close(go_write)
    codes = []
    for pid in pids:
        _, status = os.waitpid(pid, 0)
        codes.append(os.waitstatus_to_exitcode(status))
    return codes, [(logs / f"{k}.log").read_text("utf-8", "replace") for k in range(n)]


def folder_problems(command: str, folder: Path) -> list[str]:
    """What is missing from the winner's result."""
    problems = []
    try:
        manifest = json.loads((folder / "run.json").read_text())
        if manifest["status"] != "complete":
            problems.append(f"run.json says {manifest['status']}")
    except (OSError, ValueError, KeyError) as err:
        problems.append(f"run.json unreadable ({err})")
    if command == "sweep":
        rows = (folder / "results.csv").read_text().strip().splitlines() if (folder / "results.csv").is_file() else []
        if len(rows) != 2:
            problems.append(f"results.csv has {max(len(rows) - 1, 0)} task rows, expected 1")
    else:
        csv = folder / "force_displacement.csv"
        rows = csv.read_text().strip().splitlines() if csv.is_file() else []
        if len(rows) != 5:
            problems.append(f"force_displacement.csv has {max(len(rows) - 1, 0)} rows, expected 4")
        if len(list((folder / "vtk").glob("step_*.vtu"))) != 4:
            problems.append("not 4 vtk steps")
    leftovers = [p.name for p in folder.rglob("*.tmp")]
    if leftovers:
        problems.append(f"temporary files left: {', '.join(leftovers[:3])}")
    return problems


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--processes", type=int, nargs="+", default=[2, 4])
    ap.add_argument("--commands", nargs="+", default=list(COMMANDS), choices=list(COMMANDS))
    args = ap.parse_args()
    import logging

    logging.getLogger("espin").setLevel(logging.WARNING)
    import espin.cli  # noqa: F401 - imported once, before the forks

    root = Path(tempfile.mkdtemp(prefix="espin_claims_"))
    start = time.monotonic()
    failures = 0
    for command in args.commands:
        for n in args.processes:
            outcomes, reasons = Counter(), Counter()
            for r in range(args.rounds):
                folder = root / f"{command}_{n}_{r}" / "out"
                folder.parent.mkdir(parents=True)
                codes, outputs = run_round([COMMANDS[command](folder)] * n, folder.parent)
                problems = []
                winners = [k for k, c in enumerate(codes) if c == 0]
                if len(winners) != 1:
                    problems.append(f"{len(winners)} processes proceeded (exit codes {codes})")
                for k, (code, text) in enumerate(zip(codes, outputs)):
                    if code != 0 and (code != 2 or not any(r in text for r in REASONS) or "Traceback" in text):
                        problems.append(f"process {k}: exit {code}: {text.strip().splitlines()[-1:] or ''}")
                problems += folder_problems(command, folder)
                outcomes["ok" if not problems else "FAILED"] += 1
                reasons.update(next((r for r in REASONS if r in text), "none") for c, text in zip(codes, outputs) if c)
                if problems:
                    failures += 1
                    print(f"  {command} x{n} round {r}: " + "; ".join(problems), flush=True)
            print(f"{command}, {n} processes at once, {args.rounds} rounds: {outcomes['ok']} passed, "
                  f"{outcomes['FAILED']} failed; refusals: "
                  + ", ".join(f"{v} '{k}'" for k, v in reasons.most_common()), flush=True)
    print(f"{failures} failed rounds in {time.monotonic() - start:.0f} s ({root})")
    import shutil

    shutil.rmtree(root, ignore_errors=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
