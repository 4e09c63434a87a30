"""Adversarial bad-input matrix over espin's real command line.

Run:  python benchmarks/bad_inputs.py            # the whole matrix (a few minutes on 2 cores)
      python benchmarks/bad_inputs.py --quick    # a subset (about a minute)
      python benchmarks/bad_inputs.py --keep     # keep the temporary folder (printed)
      python benchmarks/bad_inputs.py --only b,c # some groups only
      python benchmarks/bad_inputs.py --json out.json   # every case and its class as JSON

Every case is built in a temporary folder and run through the command line: in-process with
``typer.testing.CliRunner`` on ``espin.cli.app`` (fast), or as a subprocess where a case may
block (FIFOs, devices) and for the kill/restart scenarios. Groups:

  a  config values through --set and TOML files (non-finite, wrong types, out of range, huge
     sizes, absurd physics, empty programs, unknown keys, binary/huge/special files), and the
     options of every command
  b  damaged RVE / results HDF5 files given to ``espin simulate X.h5``
  c  curve CSV files given to ``espin properties``
  d  SEM images given to ``espin measure``
  e  tables referenced by a config (loading.lateral.transverse_csv, loading.path_csv)
  f  output folders (rerun, a file where a folder is expected, unwritable, --overwrite)
  g  fuzzing: random configs through ``config_from_dict`` (in-process), random valid tiny mats
     through ``espin simulate``
  k  kill/restart: SIGKILL ``espin simulate`` / ``espin study sweep`` at a random point, check
     the folder, rerun without and with --overwrite

Each case is classified:

  clear error   exit 2/3/4 with an ``error:`` line naming the key/file at fault, no traceback
                (or exit 0 with the documented warning where the result is legitimate)
  vague error   exit 2/3/4, but the message does not name the key/file, has no ``error:``
                line, uses the wrong exit code, or breaks a documented promise (a refused run
                leaves a folder behind)
  refused valid exit 2/3/4 for an input that is valid (the same values are accepted by
                another route, or the docs allow them)
  traceback     exit 1, or 'Traceback' anywhere in the output
  hang          no answer within the case's time limit
  silent wrong  exit 0 but an invariant is broken (NaN/inf in an output CSV, a curve with one
                point, 0 DOF, a volume fraction far from the target, a value absurd for the
                input, an input refused by the docs accepted)
  data lost     a file the user had is gone or changed without --overwrite, or a killed run
                leaves a mixed folder
  ok            legitimately accepted

Printed: a table of counts per group and class, then every case that is not clear/ok with its
command and the first lines of its output. Nothing under src/ is touched; the script needs
h5py, numpy, tifffile and Pillow (all espin dependencies).
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import hashlib
import io
import json
import math
import os
import random
import shlex
import shutil
import signal
import stat
import struct
import subprocess
import sys
import tempfile
import time
import tomllib
import traceback
import zlib
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

CLASSES = ("clear error", "ok", "vague error", "refused valid", "traceback", "hang", "silent wrong", "data lost")
BAD = ("vague error", "refused valid", "traceback", "hang", "silent wrong", "data lost")
ESPIN = Path(sys.executable).with_name("espin")
TINY = ["--set", "rve.size_ratio=30", "--set", "rve.layers=2"]
SHORT = ["--max-strain", "0.03", "--steps", "2"]


class CaseTimeout(BaseException):
    """Raised by the alarm when an in-process case runs too long (not an Exception, so the
    CliRunner does not swallow it)."""


# ---------------------------------------------------------------------------------------------
# cases and outcomes
# ---------------------------------------------------------------------------------------------
@dataclass
class Outcome:
    code: int | None
    output: str
    seconds: float
    timed_out: bool = False
    exc_text: str = ""


@dataclass
class Case:
    group: str
    name: str
    argv: list[str]
    names: tuple[str, ...] = ()
    """Substrings (any case) of which at least one must be in the error message to be clear."""
    expect: str = "error"
    """"error": a refusal is right (acceptance is checked and reported); "ok": it must
    succeed; "either": both may be right (the invariants decide)."""
    codes: tuple[int, ...] = (2, 3, 4)
    """Exit codes that are right for a refusal."""
    check: Callable[[Outcome, Case], list[str]] | None = None
    """Extra invariants on success: a list of problems."""
    out: Path | None = None
    """The output folder of the case (checked on success; must not appear on a refusal before
    work when it did not exist)."""
    protect: tuple[Path, ...] = ()
    """Files or folders that must be unchanged afterwards (data lost)."""
    subprocess: bool = False
    timeout: float = 90.0
    quick: bool = False
    forbid: tuple[str, ...] = ()
    """Substrings that make a refusal's message wrong (e.g. 'no such file' for a device)."""
    pre: Callable[[], None] | None = None
    """Run before the case (e.g. to create a FIFO)."""
    note: str = ""
    cls: str = ""
    why: str = ""
    outcome: Outcome | None = None

    @property
    def command(self) -> str:
        return "espin " + " ".join(shlex.quote(a) for a in self.argv)


def run_inprocess(argv: list[str], timeout: float) -> Outcome:
    from typer.testing import CliRunner

    from espin.cli import app

    def alarm(signum, frame):
        raise CaseTimeout()

    runner = CliRunner()
    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    start = time.monotonic()
    try:
        res = runner.invoke(app, argv, catch_exceptions=True)
    except CaseTimeout:
        return Outcome(None, "", time.monotonic() - start, timed_out=True)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    seconds = time.monotonic() - start
    exc_text = ""
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        exc_text = "".join(traceback.format_exception(*res.exc_info))
        if isinstance(res.exception, CaseTimeout):
            return Outcome(None, res.output, seconds, timed_out=True)
    return Outcome(res.exit_code, res.output, seconds, exc_text=exc_text)


def run_subprocess(argv: list[str], timeout: float, cwd: Path) -> Outcome:
    start = time.monotonic()
    proc = subprocess.Popen([str(ESPIN), *argv], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            cwd=cwd, start_new_session=True,
                            env={**os.environ, "COLUMNS": "200", "NO_COLOR": "1"})
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        return Outcome(None, out.decode("utf-8", "replace"), time.monotonic() - start, timed_out=True)
    return Outcome(proc.returncode, out.decode("utf-8", "replace"), time.monotonic() - start)


def snapshot(paths: tuple[Path, ...], deep: bool = True) -> dict[str, tuple]:
    """(size, sha256 of small files / mtime of large ones) of every file under ``paths``
    (``deep=False``: size and mtime only)."""
    snap = {}
    for root in paths:
        items = [root] if not root.is_dir() else sorted(p for p in root.rglob("*"))
        if not root.exists() and not root.is_symlink():
            snap[str(root)] = ("missing",)
            continue
        for p in items:
            try:
                st = p.lstat()
            except OSError:
                snap[str(p)] = ("unreadable",)
                continue
            if stat.S_ISREG(st.st_mode):
                if deep and st.st_size <= 4 * 2**20:
                    snap[str(p)] = (st.st_size, hashlib.sha256(p.read_bytes()).hexdigest())
                else:
                    snap[str(p)] = (st.st_size, st.st_mtime_ns)
            else:
                snap[str(p)] = (stat.S_IFMT(st.st_mode),)
    return snap


def error_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if line.startswith("error:")]


def error_text(output: str) -> str:
    """The error message: the ``error:`` line and its continuation lines."""
    lines = output.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("error:"):
            return "\n".join(lines[i:])
    return ""


def classify(case: Case, o: Outcome, lost: list[str], left_folder: bool) -> tuple[str, str]:
    text = o.output + o.exc_text
    if o.timed_out:
        return "hang", f"no answer within {case.timeout:g} s"
    if o.code == 1 or "Traceback" in text or (o.exc_text and o.code != 0):
        first = (o.exc_text.strip().splitlines() or [""])[-1] if o.exc_text else ""
        return "traceback", f"exit {o.code}" + (f": {first}" if first else "")
    if lost:
        return "data lost", "; ".join(lost[:3])
    if o.code == 0:
        problems = generic_problems(case, o)
        if case.check is not None:
            try:
                problems += case.check(o, case)
            except Exception as err:  # noqa: BLE001 - the check itself found unreadable output
                problems.append(f"check failed: {type(err).__name__}: {err}")
        if problems:
            return "silent wrong", "; ".join(problems[:4])
        if case.expect == "error":
            return "silent wrong", "accepted, but the docs say it is refused" + (f" ({case.note})" if case.note else "")
        return "ok", ""
    if o.code in (2, 3, 4):
        msg = error_text(o.output)
        if not msg and o.code == 4 and case.argv[:1] in (["study"], ["fit"]) and "failed" in o.output:
            msg = o.output  # failed tasks are listed, one line each (docs: exit 4 for study and fit)
        if not msg and o.code == 2 and "Usage:" in o.output and "Error" in o.output:
            msg = o.output  # typer's own usage error (a box naming the option), documented as exit 2
        if not msg:
            return "vague error", f"exit {o.code} without an 'error:' line"
        if case.expect == "ok":
            return "refused valid", f"refused (exit {o.code}) although the input is valid" + (f" ({case.note})" if case.note else "")
        low = msg.lower()
        if case.names and not any(n.lower() in low for n in case.names):
            return "vague error", f"the message does not name {' / '.join(case.names)}"
        bad = [f for f in case.forbid if f.lower() in low]
        if bad:
            return "vague error", f"the message says {bad[0]!r}, which is wrong here"
        if o.code not in case.codes:
            return "vague error", f"exit {o.code}, expected {'/'.join(map(str, case.codes))}"
        if left_folder:
            return "vague error", f"refused (exit {o.code}) but left the folder {case.out} behind"
        return "clear error", ""
    return "traceback", f"unexpected exit code {o.code}"


# ---------------------------------------------------------------------------------------------
# invariants of successful runs
# ---------------------------------------------------------------------------------------------
def _floats(row: list[str]) -> list[float]:
    out = []
    for cell in row:
        try:
            out.append(float(cell))
        except ValueError:
            pass
    return out


def csv_problems(path: Path) -> list[str]:
    """NaN/inf cells of a CSV file."""
    try:
        text = path.read_text("utf-8")
    except (OSError, UnicodeDecodeError) as err:
        return [f"{path.name} unreadable ({err})"]
    problems = []
    for i, row in enumerate(csv.reader(io.StringIO(text))):
        for j, cell in enumerate(row):
            c = cell.strip().lower()
            if c in ("nan", "inf", "-inf", "+inf", "infinity", "-infinity"):
                problems.append(f"{path.name} line {i + 1} column {j + 1} is {cell}")
                break
        if len(problems) >= 2:
            break
    return problems


def read_csv_dicts(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def folder_problems(folder: Path, output: str) -> list[str]:
    problems: list[str] = []
    if not folder.is_dir():
        return [f"no output folder {folder}"]
    manifest = None
    rj = folder / "run.json"
    if rj.is_file():
        try:
            manifest = json.loads(rj.read_text("utf-8"))
        except ValueError:
            problems.append("run.json is not JSON")
    else:
        problems.append("no run.json")
    if manifest is not None and manifest.get("status") != "complete":
        problems.append(f"run.json status {manifest.get('status')!r} after exit 0")
    for h5 in sorted(folder.glob("*.h5")):
        try:
            with h5py.File(h5, "r") as f:
                rid = f.attrs.get("run_id")
        except OSError as err:
            problems.append(f"{h5.name} unreadable ({err})")
            continue
        if manifest is not None and rid is not None and str(rid) != manifest.get("run_id"):
            problems.append(f"mixed folder: {h5.name} run_id {rid} != run.json {manifest.get('run_id')}")
    for p in sorted(folder.rglob("*.csv")):
        problems += csv_problems(p)
    curve = folder / "curve.csv"
    if curve.is_file():
        rows = read_csv_dicts(curve)
        if len(rows) < 2:
            problems.append(f"curve.csv has {len(rows)} row(s)")
        else:
            for key in ("recruited_fraction", "yielded_fraction"):
                vals = [float(r[key]) for r in rows if r.get(key)]
                if any(not (0 <= v <= 1) for v in vals):
                    problems.append(f"curve.csv {key} outside [0, 1]")
            strains = [float(r["strain"]) for r in rows]
            if abs(strains[-1]) == 0:
                problems.append("curve.csv ends at zero strain")
        vtk = sorted((folder / "vtk").glob("step_*.vtu")) if (folder / "vtk").is_dir() else []
        if vtk and len(vtk) != len(rows):
            problems.append(f"{len(vtk)} vtk/step_*.vtu for {len(rows)} curve rows (stale files?)")
    stats = folder / "statistics.json"
    if stats.is_file():
        s = json.loads(stats.read_text("utf-8"))
        for k, v in s.items():
            if isinstance(v, float) and not math.isfinite(v) and not k.startswith(("ks_", "target_")):
                problems.append(f"statistics.json {k} = {v}")
                break
        if s.get("n_dof", 1) <= 0:
            problems.append(f"n_dof = {s.get('n_dof')}")
        target, mean = s.get("volume_fraction_target"), s.get("volume_fraction_mean")
        if target and mean is not None:
            err = abs(mean - target) / target
            warned = "volume fraction is" in output
            if err > 1 / 3 and not warned:
                problems.append(f"volume fraction {mean:.3g} against target {target:.3g}, not reported")
            elif err > 0.1 and not warned:
                problems.append(f"volume fraction {mean:.3g} misses the target {target:.3g} by "
                                f"{100 * err:.0f} % without the documented report")
    for toml_file in sorted(folder.glob("*.toml")):
        try:
            data = tomllib.loads(toml_file.read_text("utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
            problems.append(f"{toml_file.name} unreadable ({err})")
            continue
        bad = [k for k, v in walk_items(data) if isinstance(v, float) and not math.isfinite(v)]
        if bad:
            problems.append(f"{toml_file.name}: {bad[0]} = {dict(walk_items(data))[bad[0]]}")
    fibers = folder / "fibers.csv"
    if fibers.is_file():
        rows = read_csv_dicts(fibers)
        if not rows:
            problems.append("fibers.csv has no fiber")
        for r in rows:
            d = r.get("diameter_um")
            if d is not None and not (float(d) > 0):
                problems.append(f"fibers.csv diameter {d}")
                break
    return problems


def walk_items(node, prefix: str = ""):
    """(dotted key, value) of every leaf of nested dicts and lists."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from walk_items(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from walk_items(v, f"{prefix}[{i}]")
    else:
        yield prefix, node


def generic_problems(case: Case, o: Outcome) -> list[str]:
    problems = []
    if case.out is not None and case.argv and case.argv[0] in ("generate", "simulate", "measure", "properties",
                                                               "study", "fit"):
        problems += folder_problems(case.out, o.output)
    if case.argv[:1] == ["config"]:
        problems += config_output_problems(o.output)
    return problems


def config_output_problems(output: str) -> list[str]:
    """`espin config` must print TOML that reads back into the same config."""
    from espin.core.config import config_from_dict, config_to_toml

    try:
        data = tomllib.loads(output)
    except tomllib.TOMLDecodeError as err:
        return [f"espin config printed invalid TOML ({err})"]
    try:
        cfg = config_from_dict(data)
    except Exception as err:  # noqa: BLE001
        return [f"espin config printed a config that does not read back ({str(err).splitlines()[-1]})"]
    if config_to_toml(cfg).strip() != output.strip():
        return ["espin config output does not round-trip"]
    return []


def curve_check(strain_target: float | None = None, tension: bool = True) -> Callable[[Outcome, Case], list[str]]:
    def check(o: Outcome, case: Case) -> list[str]:
        rows = read_csv_dicts(case.out / "curve.csv")
        problems = []
        if strain_target is not None and rows and abs(float(rows[-1]["strain"]) - strain_target) > 1e-9 + 1e-6 * abs(strain_target):
            problems.append(f"final strain {rows[-1]['strain']} != {strain_target}")
        if tension and rows and float(rows[-1]["stress_MPa"]) < -1e-9:
            problems.append(f"tension test ends at a negative stress {rows[-1]['stress_MPa']} MPa")
        return problems
    return check


def props_check(modulus: float | None = None, rtol: float = 0.1, yield_stress: float | None = None) -> Callable:
    def check(o: Outcome, case: Case) -> list[str]:
        rows = read_csv_dicts(case.out / "properties.csv")
        problems = []
        if not rows:
            return ["properties.csv is empty"]
        r = rows[0]
        for k in ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa", "r_squared"):
            v = r.get(k, "")
            if v and not math.isfinite(float(v)):
                problems.append(f"properties.csv {k} = {v}")
        if modulus is not None:
            got = float(r["modulus_MPa"]) if r.get("modulus_MPa") else float("nan")
            if not (abs(got - modulus) <= rtol * abs(modulus)):
                problems.append(f"modulus {got:g} MPa, expected {modulus:g} MPa")
        if yield_stress is not None and r.get("yield_stress_MPa"):
            got = float(r["yield_stress_MPa"])
            if not (abs(got - yield_stress) <= 0.2 * abs(yield_stress)):
                problems.append(f"yield stress {got:g} MPa, expected {yield_stress:g} MPa")
        return problems
    return check


def warned(word: str) -> Callable:
    """Exit 0 is right only with a warning line mentioning ``word``."""
    def check(o: Outcome, case: Case) -> list[str]:
        if not any(line.startswith("warning:") and word.lower() in line.lower() for line in o.output.splitlines()) \
                and word.lower() not in o.output.lower():
            return [f"accepted without the documented warning ({word})"]
        return []
    return check


# ---------------------------------------------------------------------------------------------
# the matrix
# ---------------------------------------------------------------------------------------------
class Matrix:
    def __init__(self, root: Path, quick: bool, seed: int) -> None:
        self.root = root
        self.inp = root / "in"
        self.outs = root / "out"
        self.inp.mkdir(parents=True)
        self.outs.mkdir()
        self.quick = quick
        self.rng = random.Random(seed)
        self.cases: list[Case] = []
        self._n = 0
        self.base_rve = root / "base" / "rve.h5"

    def out(self, tag: str) -> Path:
        self._n += 1
        return self.outs / f"{self._n:04d}_{tag}"

    def add(self, case: Case) -> Case:
        self.cases.append(case)
        return case

    def f(self, name: str, data: bytes | str, encoding: str = "utf-8") -> Path:
        p = self.inp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data if isinstance(data, bytes) else data.encode(encoding))
        return p


def make_base(root: Path) -> None:
    from typer.testing import CliRunner

    from espin.cli import app

    res = CliRunner().invoke(app, ["generate", "plla", "--size-ratio", "30", "--layers", "2", "-o",
                                   str(root / "base"), "-q", "--no-figures", "--no-vtk"])
    if res.exit_code != 0:
        sys.exit(f"cannot make the base RVE: {res.output}")


# --- (a) configs -------------------------------------------------------------------------------
def group_a(m: Matrix) -> None:
    g = "a"
    # non-finite values of numeric keys, through `espin config --set`
    numeric = ["rve.diameter_um", "rve.volume_fraction", "rve.size_ratio", "rve.max_deviation_deg",
               "rve.diameter_sd_um", "fiber.taut_modulus_MPa", "fiber.flow_rate_per_s", "loading.max_strain",
               "loading.direction_deg", "solver.rtol", "output.window_ratio", "rve.orientation.von_mises.kappa",
               "loading.lateral.poisson_ratio", "output.yield_threshold"]
    for i, key in enumerate(numeric):
        for value in ("nan", "inf", "-inf"):
            m.add(Case(g, f"--set {key}={value}", ["config", "--set", f"{key}={value}"], names=(key.split(".")[-1],),
                       codes=(2,), quick=(i < 3 and value == "nan")))
    # wrong types / out of range via --set
    bad_sets = [
        ("rve.layers=true", "layers"), ('rve.layers="3"', "layers"), ("rve.layers=3.0", "layers"),
        ("rve.layers=[3]", "layers"), ("rve.layers={a=1}", "layers"), ("rve.layers=0", "layers"),
        ("rve.layers=1001", "layers"), ("rve.layers=99999999999999999999999", "layers"),
        ('rve.volume_fraction="0.19"', "volume_fraction"), ("rve.volume_fraction=true", "volume_fraction"),
        ("rve.volume_fraction=0", "volume_fraction"), ("rve.volume_fraction=1", "volume_fraction"),
        ("rve.volume_fraction=-0.1", "volume_fraction"),
        ("rve.seed=1.5", "seed"), ("rve.seed=-1", "seed"), (f"rve.seed={2**63}", "seed"), (f"rve.seed={2**64}", "seed"),
        ("rve.seed=1979-05-27", "seed"), ("rve.seed=07:32:00", "seed"),
        ("rve.diameter_um=0", "diameter_um"), ("rve.diameter_um=1001", "diameter_um"),
        ("rve.diameter_sd_um=4.5", "diameter_sd_um"), ("rve.diameter_sd_um=-0.1", "diameter_sd_um"),
        ("rve.diameter_min_um=0.45", "diameter_min_um"), ("rve.diameter_min_um=0", "diameter_min_um"),
        ("rve.size_ratio=4", "size_ratio"), ("rve.size_ratio=0", "size_ratio"),
        ("rve.segment_ratio=0", "segment_ratio"),
        ("rve.max_deviation_deg=90", "max_deviation_deg"), ("rve.max_deviation_deg=-1", "max_deviation_deg"),
        ("rve.merge_tolerance_ratio=0", "merge_tolerance_ratio"), ("rve.merge_tolerance_ratio=0.2", "merge_tolerance_ratio"),
        ('rve.orientation="random"', "orientation"), ("rve.orientation=5", "orientation"),
        ("rve.orientation={von_mises={kappa=-1}}", "kappa"), ("rve.orientation={von_mises={kappa=701}}", "kappa"),
        ("rve.orientation={von_mises={mean_deg=180}}", "mean_deg"),
        ("rve.orientation={von_mises={kappa=1}, histogram={edges_deg=[0,180], weights=[1]}}", "orientation"),
        ("rve.orientation={histogram={edges_deg=[0,90,90,180], weights=[1,1,1]}}", "edges_deg"),
        ("rve.orientation={histogram={edges_deg=[0,180], weights=[0]}}", "weights"),
        ("rve.orientation={histogram={edges_deg=[0,180], weights=[-1]}}", "weights"),
        ("rve.orientation={histogram={edges_deg=[0,200], weights=[1]}}", "edges_deg"),
        ("rve.orientation={histogram={edges_deg=[0,90,180], weights=[1]}}", "weights"),
        ("rve.orientation={histogram={edges_deg=[], weights=[]}}", "edges_deg"),
        ('rve.orientation={histogram={edges_deg=["a","b"], weights=[1]}}', "edges_deg"),
        ("rve.orientation={}", "orientation"),
        ('rve.seeding="spiral"', "seeding"), ("rve.seeding=spiral", "seeding"),
        ("fiber.taut_modulus_MPa=2", "taut_modulus_MPa"), ("fiber.taut_modulus_MPa=1e7", "taut_modulus_MPa"),
        ("fiber.slack_modulus_MPa=0", "slack_modulus_MPa"), ("fiber.flow_rate_per_s=-1", "flow_rate_per_s"),
        ("fiber.hardening_exponent=101", "hardening_exponent"), ("fiber.flow_resistance_MPa=0", "flow_resistance_MPa"),
        ("loading.test=5", "test"), ("loading.test=tension", "test"), ('loading.lateral="clamped"', "lateral"),
        ("loading.lateral={poisson_ratio=51}", "poisson_ratio"), ("loading.lateral={poisson_ratio=true}", "poisson_ratio"),
        ("loading.lateral={poisson_ratio=0.3, transverse_csv='x.csv'}", "lateral"),
        ("loading.lateral=[]", "lateral"),
        ("loading.program=[]", "program"), ('loading.program="abc"', "program"), ("loading.program=[1,2]", "program"),
        ("loading.program=[{}]", "to_strain"), ("loading.program=[{to_strain=0.1, foo=1}]", "foo"),
        ("loading.program=[{hold_s=0}]", "hold_s"), ("loading.program=[{hold_s=1e10}]", "hold_s"),
        ("loading.program=[{to_strain=11}]", "to_strain"), ("loading.program=[{to_strain=-1}]", "to_strain"),
        ("loading.program=[{to_strain=0.1, rate_per_s=0}]", "rate_per_s"),
        ("loading.program=[{to_strain=0.1, steps=0}]", "steps"), ("loading.program=[{to_strain=0.1, steps=100001}]", "steps"),
        ("loading.program=[{to_strain=0.1, hold_s=5}]", "to_strain"),
        ("loading.steps=0", "steps"), ("loading.steps=1.5", "steps"), ("loading.max_strain=10.5", "max_strain"),
        ("loading.max_strain=-1", "max_strain"), ("loading.strain_rate_per_s=0", "strain_rate_per_s"),
        ("loading.strain_rate_per_s=1e4", "strain_rate_per_s"), ("loading.direction_deg=180", "direction_deg"),
        ("loading.direction_deg=-0.1", "direction_deg"),
        ('loading.path_csv="x.csv"', "path_csv"), ('loading.test="path"', "path_csv"),
        ("solver.linear=mkl", "linear"), ("solver.rtol=0", "rtol"), ("solver.rtol=1", "rtol"),
        ("solver.max_iterations=0", "max_iterations"), ("solver.max_cuts=61", "max_cuts"),
        ("solver.time_rtol=on", "time_rtol"), ("solver.time_rtol=0", "time_rtol"),
        ("output.stress_measure=cauchy", "stress_measure"), ("output.figures=1", "figures"),
        ('output.figures="yes"', "figures"), ("output.window_ratio=0", "window_ratio"),
        ("output.yield_threshold=1", "yield_threshold"),
        ("rve.foo=1", "foo"), ("foo.bar=1", "foo"), ("rve=5", "rve"), ("rve.layers.x=1", "layers"),
        ("rve..layers=1", "rve..layers"), (".layers=1", ".layers"), ("=1", "override key"), ("rve.layers", "rve.layers"),
        ("loading.lateral.poisson_ratio.x=1", "lateral"), ("RVE.layers=3", "RVE"), (" rve.layers = 3", None),
    ]
    for i, (item, name) in enumerate(bad_sets):
        if name is None:  # whitespace around the key: a legitimate spelling
            m.add(Case(g, f"--set {item!r}", ["config", "--set", item], expect="either"))
            continue
        m.add(Case(g, f"--set {item}", ["config", "--set", item], names=(name,), codes=(2,), quick=i % 8 == 0))
    # both size_ratio and size_um; segment longer than side
    m.add(Case(g, "size_um on plla (size_ratio is a default)", ["config", "--set", "rve.size_um=10.0"], expect="ok"))
    m.add(Case(g, "size_ratio and size_um", ["config", "--set", "rve.size_um=10.0", "--set", "rve.size_ratio=30"],
               names=("size_um",), codes=(2,)))
    m.add(Case(g, "segment >= side", ["config", "--set", "rve.size_ratio=5", "--set", "rve.segment_ratio=5"],
               names=("segment",), codes=(2,)))
    long_word = "A" * 200_000
    m.add(Case(g, "--set 200k-char bare word", ["config", "--set", f"rve.seeding={long_word}"], names=("seeding",),
               codes=(2,), check=None))
    m.add(Case(g, "--set value with TOML injection", ["config", "--set", "rve.layers=3\nrve = 5"], names=("layers",),
               expect="either", codes=(2,)))
    # the options of generate / simulate
    opt_cases = [
        (["generate", "--seed", "-1"], ("seed",)), (["generate", "--layers", "0"], ("layers",)),
        (["generate", "--size-ratio", "inf"], ("size_ratio",)), (["generate", "--size-ratio", "nan"], ("size_ratio",)),
        (["generate", "--volume-fraction", "1"], ("volume_fraction",)), (["generate", "--seeding", "foo"], ("seeding",)),
        (["generate", "--layers", "abc"], ("layers",)), (["generate", "--seed", str(2**64)], ("seed",)),
        (["simulate", "--steps", "0"], ("steps",)), (["simulate", "--max-strain", "nan"], ("max_strain",)),
        (["simulate", "--direction-deg", "180"], ("direction_deg",)), (["simulate", "--test", "foo"], ("test",)),
        (["simulate", "--lateral", "foo"], ("lateral",)), (["simulate", "--linear", "mumps"], ("linear",)),
        (["simulate", "--strain-rate-per-s", "-1"], ("strain_rate",)),
        (["simulate", "--set", "loading.program=[{to_strain=0.03}]", "--steps", "2"], ("program",)),
        (["simulate", "--set", "loading.program=[{to_strain=0}]"], ("program",)),
        (["simulate", "--set", "loading.program=[{to_strain=0.03}, {to_strain=0.03}]"], ("program[1]",)),
        (["simulate", "--test", "equibiaxial", "--max-strain", "-1"], ("max_strain",)),
        (["simulate", "--lateral", "free", "--test", "equibiaxial"], ("lateral",)),
        (["simulate", "--set", "loading.lateral={poisson_ratio=50}", "--max-strain", "0.05"], ("lateral",)),
        (["simulate", "--set", "rve.layers=2", "/nonexistent/rve.h5"], ("rve.h5",)),
    ]
    for i, (argv, names) in enumerate(opt_cases):
        out = m.out("opt")
        tiny = [] if "/nonexistent/rve.h5" in argv else (
            (["--set", "rve.size_ratio=30"] if "--size-ratio" not in argv else [])
            + (["--set", "rve.layers=2"] if "--layers" not in argv else []))
        full = argv + tiny + ["-o", str(out), "-q"]
        expect = "either" if "--lateral" in argv and "equibiaxial" in argv else "error"
        note = "a uniaxial-only option given to another test" if expect == "either" else ""
        if argv[1:3] == ["--set", "loading.lateral={poisson_ratio=50}"]:
            expect = "error"
            note = "F'22 = 1 - 50 * 0.05 < 0 must be refused"
        m.add(Case(g, " ".join(argv), full, names=names, out=out, expect=expect, note=note,
                   codes=(3,) if "/nonexistent/rve.h5" in argv else (2,), quick=i % 5 == 0,
                   timeout=60))
    # the options of the other commands (refusals before any work)
    curve = m.f("opts/curve.csv", bilinear_csv())
    sem = m.inp / "opts" / "sem.tif"  # made in group d's helper
    write_synthetic_sem(m, sem)
    cal = m.out("calib")
    other = [
        (["properties", str(curve), "--strain-column", "99"], ("strain",)),
        (["properties", str(curve), "--stress-column", "nosuch"], ("nosuch",)),
        (["properties", str(curve), "--delimiter", "ab"], ("delimiter",)),
        (["properties", str(curve), "--decimal", "x"], ("decimal",)),
        (["properties", str(curve), "--skip-rows", "1000000"], ("curve.csv", "skip")),
        (["properties", str(curve), "--skip-rows", "-1"], ("skip-rows",)),
        (["properties", str(curve), "--strain-range", "0.5:0.1"], ("strain-range", "strain_range")),
        (["properties", str(curve), "--strain-range", "a:b"], ("strain-range", "strain_range")),
        (["properties", str(curve), "--strain-range", "nan:"], ("strain-range", "strain_range")),
        (["properties", str(curve), "--strain-range", "0.5:0.5"], ("strain-range", "strain_range")),
        (["properties", str(curve), "--strain-range", "2:3"], ("strain-range", "strain_range", "curve.csv")),
        (["measure", str(sem), "--um-per-px", "0"], ("um-per-px", "um_per_px")),
        (["measure", str(sem), "--um-per-px", "-1"], ("um-per-px", "um_per_px")),
        (["measure", str(sem), "--um-per-px", "nan"], ("um-per-px", "um_per_px")),
        (["measure", str(sem), "--um-per-px", "inf"], ("um-per-px", "um_per_px")),
        (["measure", str(sem), "--um-per-px", "1e300"], ("um-per-px", "um_per_px", "diameter", "fiber")),
        (["measure", str(sem)], ("scale", "um-per-px")),
        (["measure", str(sem), "--um-per-px", "0.05", "--scale-bar-um", "30", "--scale-bar-rows", "0:10"], ("scale",)),
        (["measure", str(sem), "--scale-bar-um", "30"], ("scale-bar-rows", "scale_bar_rows")),
        (["measure", str(sem), "--scale-bar-um", "30", "--scale-bar-rows", "10:5"], ("scale-bar-rows", "scale_bar_rows")),
        (["measure", str(sem), "--scale-bar-um", "30", "--scale-bar-rows", "a:b"], ("scale-bar-rows", "scale_bar_rows")),
        (["measure", str(sem), "--scale-bar-um", "30", "--scale-bar-rows", "250:100000"], ("scale-bar-rows", "scale_bar_rows", "scale bar")),
        (["measure", str(sem), "--scale-bar-um", "-30", "--scale-bar-rows", "250:270"], ("scale-bar-um", "scale_bar_um")),
        (["measure", str(sem), "--scale-bar-um", "30", "--scale-bar-rows", "250:270"], ("scale bar", "scale-bar")),
        (["measure", str(sem), "--um-per-px", "0.05", "--crop-rows", "0:0"], ("crop-rows", "crop_rows")),
        (["measure", str(sem), "--um-per-px", "0.05", "--crop-rows", "100:50"], ("crop-rows", "crop_rows")),
        (["measure", str(sem), "--um-per-px", "0.05", "--crop-rows", "0:100000"], ("crop-rows", "crop_rows")),
        (["measure", str(sem), "--um-per-px", "0.05", "--crop-bottom-px", "-5"], ("crop-bottom", "crop_bottom")),
        (["measure", str(sem), "--um-per-px", "0.05", "--crop-bottom-px", "100000"], ("crop-bottom", "crop_bottom")),
        (["measure", str(sem), "--um-per-px", "0.05", "--width-px", "1"], ("width-px", "width_px")),
        (["measure", str(sem), "--um-per-px", "0.05", "--width-px", "1e9"], ("width-px", "width_px")),
        (["measure", str(sem), "--um-per-px", "0.05", "--width-px", "nan"], ("width-px", "width_px")),
        (["measure", str(sem), "--um-per-px", "0.05", "--max-bend-deg", "0"], ("max-bend", "max_bend")),
        (["measure", str(sem), "--um-per-px", "0.05", "--max-bend-deg", "nan"], ("max-bend", "max_bend")),
        (["measure", str(sem), "--um-per-px", "0.05", "--min-length-diameters", "0"], ("min-length", "min_length")),
        (["measure", str(sem), "--um-per-px", "0.05", "--min-length-diameters", "100"], ("fiber", "min-length", "min_length")),
        (["calibrate-geometry", "--diameter-um", "-1", "--tortuosity-scale", "0.1", "--orientation", "uniform", "-o", str(cal)], ("diameter",)),
        (["calibrate-geometry", "--diameter-um", "nan", "--tortuosity-scale", "0.1", "--orientation", "uniform", "-o", str(cal)], ("diameter",)),
        (["calibrate-geometry", "--diameter-um", "0.45", "--tortuosity-scale", "-1", "--orientation", "uniform", "-o", str(cal)], ("tortuosity",)),
        (["calibrate-geometry", "--diameter-um", "0.45", "--tortuosity-scale", "0.1", "--orientation", "spiral", "-o", str(cal)], ("orientation",)),
        (["calibrate-geometry", "--diameter-um", "0.45", "--tortuosity-scale", "0.1", "--orientation-kappa", "1000", "-o", str(cal)], ("kappa",)),
        (["calibrate-geometry", "--diameter-um", "0.45", "--tortuosity-scale", "0.1", "--orientation", "uniform", "--seeds", "0", "-o", str(cal)], ("seeds",)),
        (["calibrate-geometry", "--diameter-um", "0.45", "--tortuosity-scale", "0.1", "--orientation", "uniform", "--window-um", "0", "-o", str(cal)], ("window",)),
        (["calibrate-geometry", "--diameter-um", "0.45", "--tortuosity-scale", "0.1", "--orientation", "uniform", "--fit", "both2", "-o", str(cal)], ("fit",)),
        (["calibrate-geometry", "--diameter-um", "0.45", "--diameter-sd-um", "5", "--tortuosity-scale", "0.1", "--orientation", "uniform", "-o", str(cal)], ("diameter",)),
        (["calibrate-geometry", str(m.inp / "nosuch_measure"), "-o", str(cal)], ("nosuch_measure",)),
        (["calibrate-geometry", str(m.inp / "opts"), "-o", str(cal)], ("opts", "fibers.csv")),
        (["calibrate-geometry", str(curve), "-o", str(cal)], ("curve.csv",)),
    ]
    fitbase = ["--set", "rve.size_ratio=30", "--set", "rve.layers=2", "--realizations", "1", "--eta-points", "2",
               "--workers", "1"]
    other += [
        (["fit", str(curve), "--params", "foo", *fitbase], ("foo",)),
        (["fit", str(curve), "--params", "", *fitbase], ("params", "parameter")),
        (["fit", str(curve), "--bounds", "eta=0.5:0.1", *fitbase], ("eta", "bounds")),
        (["fit", str(curve), "--bounds", "eta=nan:0.3", *fitbase], ("eta", "bounds")),
        (["fit", str(curve), "--bounds", "foo=0:1", *fitbase], ("foo",)),
        (["fit", str(curve), "--fix", "E_t=-5", *fitbase], ("E_t", "taut")),
        (["fit", str(curve), "--fix", "eta=2", "--params", "b_p", *fitbase], ("eta", "volume_fraction")),
        (["fit", str(curve), "--realizations", "0", "--set", "rve.size_ratio=30", "--workers", "1"], ("realizations",)),
        (["fit", str(curve), "--seeds", "a,b", *fitbase], ("seeds",)),
        (["fit", str(curve), "--seeds", "-1", *fitbase], ("seed",)),
        (["fit", str(curve), "--rate", "0", *fitbase], ("rate",)),
        (["fit", str(curve), "--rate", "nan", *fitbase], ("rate",)),
        (["fit", str(curve), "--curves-at-rate", "x", *fitbase], ("curves-at-rate", "curves_at_rate")),
        (["fit", str(curve), "--rate", "0.005", "--curves-at-rate", f"0.01={m.inp / 'nosuch.csv'}", *fitbase], ("nosuch.csv",)),
        (["fit", str(curve), "--step-strain", "0", *fitbase], ("step-strain", "step_strain")),
        (["fit", str(curve), "--step-strain", "nan", *fitbase], ("step-strain", "step_strain")),
        (["fit", str(curve), "--eta-points", "0", "--set", "rve.size_ratio=30", "--realizations", "1", "--workers", "1"], ("eta-points", "eta_points")),
        (["fit", str(curve), "--eta-tolerance", "-1", *fitbase], ("eta-tolerance", "eta_tolerance")),
        (["fit", str(curve), "--workers", "0", "--set", "rve.size_ratio=30", "--realizations", "1", "--eta-points", "2"], ("workers",)),
        (["fit", str(curve), "--average-grid", "-3", *fitbase], ("average-grid", "average_grid")),
        (["fit", str(curve), "--average-grid", "nan", *fitbase], ("average-grid", "average_grid")),
        (["fit", str(curve), "--base", "nosuch", *fitbase], ("nosuch",)),
        (["fit", str(curve), "--set", "rve.layers=0", "--realizations", "1", "--eta-points", "2", "--workers", "1"], ("layers",)),
        (["fit", str(curve), "--scheduler", "bogus://x", *fitbase], ("scheduler",)),
        (["fit", str(curve), "--scheduler", "tls://127.0.0.1:9", "--tls-ca-file", str(m.inp / "nosuch.pem"), *fitbase], ("nosuch.pem", "tls")),
    ]
    RS = ["study", "rve-size", "plla", "--layer-counts", "2", "--size-for-layers", "30", "--layers-for-sizes", "2", "--realizations", "1", "--workers", "1", "--set", "loading.max_strain=0.03", "--set", "loading.steps=2"]
    sweep = ["study", "sweep", "plla", "--set", "rve.size_ratio=30", "--set", "rve.layers=2", "--set",
             "loading.max_strain=0.03", "--set", "loading.steps=2", "--workers", "1"]
    other += [
        ([*sweep, "--grid", "foo"], ("foo", "grid")),
        ([*sweep, "--grid", "rve.layers="], ("rve.layers", "grid")),
        ([*sweep, "--grid", "rve.volume_fraction=nan:1:3"], ("volume_fraction",)),
        ([*sweep, "--grid", "rve.volume_fraction=0.1:0.2:0"], ("count", "volume_fraction")),
        ([*sweep, "--grid", "rve.volume_fraction=0.1:0.2:-5"], ("count", "volume_fraction")),
        ([*sweep, "--grid", "rve.volume_fraction=0.1:0.2:1000000000"], ("volume_fraction", "count", "grid")),
        ([*sweep, "--grid", "rve.layers=1,2", "--grid", "rve.layers=3"], ("layers",)),
        ([*sweep, "--grid", "rve.nosuch=1,2"], ("nosuch",)),
        ([*sweep, "--grid", "rve.layers=0,1"], ("layers",)),
        ([*sweep, "--grid", "rve.layers=1.5,2"], ("layers",)),
        ([*sweep, "--realizations", "0"], ("realizations",)),
        ([*sweep, "--realizations", "-1"], ("realizations",)),
        ([*sweep, "--seed-start", "-1"], ("seed",)),
        ([*sweep, "--seed-start", str(2**63 - 1), "--realizations", "2"], ("seed",)),
        ([*sweep, "--format", "xlsx"], ("format",)),
        (["study", "sweep", "plla", "--set", "rve.size_ratio=30", "--workers", "0"], ("workers",)),
        (["study", "sweep", "plla", "--set", "rve.size_ratio=30", "--workers", "-3"], ("workers",)),
        ([*sweep, "--blas-threads", "0"], ("blas",)),
        ([*sweep, "--scheduler", "bogus"], ("scheduler",)),
        ([*sweep, "--scheduler", "tls://127.0.0.1:9", "--tls-ca-file", str(m.inp / "nosuch.pem")], ("nosuch.pem", "tls")),
        (["study", "rve-size", "plla", "--size-ratios", "abc"], ("size-ratios", "size_ratios")),
        (["study", "rve-size", "plla", "--size-ratios", "0"], ("size",)),
        (["study", "rve-size", "plla", "--size-ratios", "nan"], ("size",)),
        (["study", "rve-size", "plla", "--layer-counts", "0"], ("layer",)),
        (["study", "rve-size", "plla", "--layer-counts", "2.5"], ("layer",)),
        (["study", "rve-size", "plla", "--layers-for-sizes", "0"], ("layers",)),
        ([*RS, "--size-ratios", "1e9"], ("size", "memory", "large")),
        (["study", "dof", "plla", "--size-ratios", "-5"], ("size",)),
        (["study", "dof", "plla", "--layers", "0"], ("layers",)),
        (["study", "dof", "plla", "--size-ratios", "1e9", "--layers", "2"], ("size", "memory", "large")),
        (["study", "dof", "plla", "--size-ratios", ""], ("size",)),
    ]
    for i, (argv, names) in enumerate(other):
        has_out = "-o" in argv or "--out" in argv
        out = m.out(argv[0].replace("-", "_") + (("_" + argv[1]) if argv[0] == "study" else ""))
        full = argv + ([] if has_out else ["-o", str(out)])
        codes = ((2, 3) if argv[0] in ("measure", "calibrate-geometry", "properties", "fit")
                 else (2, 4) if "1e9" in argv else (2,))
        label = " ".join(Path(a).name if a.startswith(str(m.root)) else a for a in argv)
        c = m.add(Case(g, label, full, names=names, out=None if has_out else out, codes=codes, timeout=40, quick=i % 6 == 0,
                       expect="either" if "--um-per-px" in argv and "1e300" in argv else "error"))
        c.name = c.name[:90]
    # TOML files as the config
    cfgs = {
        "empty.toml": (b"", "either", ()),
        "binary.toml": (bytes(random.Random(1).randrange(256) for _ in range(4096)), "error", ("binary.toml",)),
        "utf16.toml": ("[rve]\nlayers = 2\n".encode("utf-16"), "error", ("utf16.toml",)),
        "bom.toml": (b"\xef\xbb\xbf[rve]\nlayers = 2\n", "either", ("bom.toml",)),
        "latin1.toml": ("# r\xe9sum\xe9\n[rve]\nlayers = 2\n".encode("latin-1"), "error", ("latin1.toml",)),
        "nul.toml": (b"[rve]\x00\nlayers = 2\n", "error", ("nul.toml",)),
        "huge.toml": (b"# " + b"x" * (2 * 2**20) + b"\n", "error", ("huge.toml",)),
        "longline.toml": (b"[rve]\nseeding = \"" + b"a" * (2**20 - 100) + b"\"\n", "error", ("seeding",)),
        "deep.toml": (("x = " + "[" * 5000 + "]" * 5000 + "\n").encode(), "error", ("deep.toml",)),
        "deeptable.toml": (("x = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n").encode(), "error", ("deeptable.toml",)),
        "unknown_section.toml": (b"[foo]\nbar = 1\n", "error", ("foo",)),
        "unknown_key.toml": (b"[rve]\nlayerz = 2\n", "error", ("layerz",)),
        "scalar_section.toml": (b"rve = 5\n", "error", ("rve",)),
        "array_tables.toml": (b"[[rve]]\nlayers = 2\n", "error", ("rve",)),
        "dup_key.toml": (b"[rve]\nlayers = 2\nlayers = 3\n", "error", ("dup_key.toml",)),
        "datetime.toml": (b"[rve]\nseed = 1979-05-27T07:32:00Z\n", "error", ("seed",)),
        "bad_toml.toml": (b"[rve\nlayers = \n", "error", ("bad_toml.toml",)),
        "nan.toml": (b"[rve]\nvolume_fraction = nan\n", "error", ("volume_fraction",)),
        "float_overflow.toml": (b"[rve]\nvolume_fraction = 1e400\n", "error", ("volume_fraction",)),
        "bigint.toml": (b"[rve]\nlayers = 123456789012345678901234567890\n", "error", ("layers",)),
        "hist_40k.toml": (("[rve.orientation.histogram]\nedges_deg = [" + ", ".join(f"{180 * k / 40000:.5f}" for k in range(40001))
                           + "]\nweights = [" + ", ".join("1" for _ in range(40000)) + "]\n").encode(), "either", ("edges_deg",)),
        "program_1e4.toml": (("[loading]\nprogram = [" + ", ".join(f"{{to_strain = {0.03 if k % 2 == 0 else 0.01}, steps = 1}}" for k in range(10000))
                              + "]\n").encode(), "either", ("program",)),
        "crlf.toml": (b"[rve]\r\nlayers = 2\r\n", "either", ()),
        "cr_only.toml": (b"[rve]\rlayers = 2\r", "error", ("cr_only.toml",)),
    }
    for i, (name, (data, expect, names)) in enumerate(cfgs.items()):
        p = m.f(f"cfg/{name}", data)
        m.add(Case(g, f"config file {name}", ["config", str(p)], names=names, expect=expect, codes=(2,), quick=i % 5 == 0,
                   protect=(p,), timeout=60))
    # the resolved config that `espin config plla` prints (README: espin config plla > my_mat.toml) with --set
    from espin.core.config import config_to_toml, load_config

    resolved = m.f("cfg/resolved_plla.toml", config_to_toml(load_config("plla")))

    def seeding_is(value: str) -> Callable:
        def check(o: Outcome, case: Case) -> list[str]:
            got = tomllib.loads(o.output)["rve"]["seeding"]
            return [] if got == value else [(f"rve.seeding = {got!r}, but `espin config plla` with the same --set gives {value!r} "
                                            "(the resolved file pins the derived default)")]
        return check

    def diameter_min_is(value: float) -> Callable:
        def check(o: Outcome, case: Case) -> list[str]:
            got = tomllib.loads(o.output)["rve"]["diameter_min_um"]
            return [] if abs(got - value) < 1e-12 else [(f"rve.diameter_min_um = {got:g}, but the preset with the same --set gives "
                                                        f"{value:g} (0.1 D: the resolved file pins the old D's default)")]
        return check

    out = m.out("resolved")
    m.add(Case(g, "resolved plla.toml + --set loading.program (README workflow)",
               ["simulate", str(resolved), *TINY, "--set", "loading.program=[{to_strain=0.03, steps=2}]", "-o", str(out), "-q"],
               out=out, expect="ok", check=curve_check(0.03), quick=True,
               note="the same --set on the preset is accepted; the resolved file carries max_strain/steps/strain_rate_per_s"))
    m.add(Case(g, "resolved plla.toml + --set rve.orientation (seeding)",
               ["config", str(resolved), "--set", "rve.orientation={von_mises={kappa=2.0}}"], expect="ok", check=seeding_is("lines")))
    m.add(Case(g, "resolved plla.toml + --set rve.diameter_um=0.9 (diameter_min_um)",
               ["config", str(resolved), "--set", "rve.diameter_um=0.9"], expect="ok", check=diameter_min_is(0.09)))
    m.add(Case(g, "resolved plla.toml + --set rve.diameter_um=0.04", ["config", str(resolved), "--set", "rve.diameter_um=0.04"],
               expect="ok", note="the preset accepts it; diameter_min_um = 0.045 is pinned in the resolved file"))
    m.add(Case(g, "resolved plla.toml + --set rve.size_um=10", ["config", str(resolved), "--set", "rve.size_um=10.0"],
               expect="ok", note="size_ratio is pinned in the resolved file"))
    # special paths as the config
    d = m.inp / "cfg" / "adir.toml"
    d.mkdir()
    fifo = m.inp / "cfg" / "fifo.toml"
    os.mkfifo(fifo)
    (m.inp / "cfg" / "zero.toml").symlink_to("/dev/zero")
    (m.inp / "cfg" / "loop.toml").symlink_to(m.inp / "cfg" / "loop.toml")
    (m.inp / "cfg" / "dangling.toml").symlink_to(m.inp / "cfg" / "nowhere.toml")
    unreadable = m.f("cfg/unreadable.toml", "[rve]\nlayers = 2\n")
    unreadable.chmod(0)
    special = [
        (str(d), ("adir.toml",)), (str(fifo), ("fifo.toml",)), ("/dev/zero", ("/dev/zero",)),
        (str(m.inp / "cfg" / "zero.toml"), ("zero.toml",)), (str(m.inp / "cfg" / "loop.toml"), ("loop.toml",)),
        (str(m.inp / "cfg" / "dangling.toml"), ("dangling.toml",)), ("nosuch.toml", ("nosuch.toml",)),
        ("nosuch", ("nosuch",)), ("PLLA", ("PLLA",)), ("plla.toml", ("plla.toml",)), ("", ("''", "preset", "source", "config file .")),
        (str(m.base_rve), ("rve.h5",)),
        (str(m.inp / "cfg" / ("x" * 300 + ".toml")), ("xxxx",)), ("bad\x00name.toml", ("name",)),
    ]
    m.add(Case(g, "config source unreadable.toml (chmod 0)", ["config", str(unreadable)], names=("unreadable.toml",), codes=(2,),
               expect="either" if os.geteuid() == 0 else "error",
               note="running as root: the mode does not stop reading" if os.geteuid() == 0 else ""))
    for i, (src, names) in enumerate(special):
        m.add(Case(g, f"config source {Path(src).name[:40] or repr(src)}", ["config", src], names=names, codes=(2, 3),
                   subprocess="fifo" in src or "zero" in src, timeout=15, quick=i % 4 == 0))
    # generate with special sources (must refuse before creating the folder)
    for src, names in ((str(fifo), ("fifo.toml",)), (str(m.inp / "cfg" / "binary.toml"), ("binary.toml",)),
                       (str(m.base_rve), ("rve.h5",))):
        out = m.out("gen_src")
        m.add(Case(g, f"generate {Path(src).name}", ["generate", src, "-o", str(out), "-q"], names=names, out=out,
                   codes=(2, 3), subprocess="fifo" in src, timeout=15))
    # absurd physics and huge sizes through generate (tiny where possible)
    physics = [
        ("volume_fraction 1e-9", ["--set", "rve.volume_fraction=1e-9"] + TINY, "error", ("volume_fraction", "fibers")),
        ("volume_fraction 0.01 L/D 30", ["--set", "rve.volume_fraction=0.01"] + TINY, "either", ("volume_fraction", "fibers")),
        ("volume_fraction 0.05 L/D 30", ["--set", "rve.volume_fraction=0.05"] + TINY, "either", ("volume_fraction",)),
        ("volume_fraction 0.999", ["--set", "rve.volume_fraction=0.999"] + TINY, "either", ("volume_fraction",)),
        ("volume_fraction 0.9 1 layer", ["--set", "rve.volume_fraction=0.9", "--set", "rve.size_ratio=25", "--set", "rve.layers=1"], "either", ("volume_fraction",)),
        ("diameter_sd = D", ["--set", "rve.diameter_sd_um=0.45", "--set", "rve.diameter_min_um=0.001"] + TINY, "either", ("diameter",)),
        ("diameter_sd = D, L/D 25, 1 layer", ["--set", "rve.diameter_sd_um=0.45", "--set", "rve.size_ratio=25", "--set", "rve.layers=1"], "either", ("diameter",)),
        ("diameter_sd 100 D", ["--set", "rve.diameter_sd_um=45"] + TINY, "error", ("diameter_sd_um",)),
        ("diameter 1e-300 um", ["--set", "rve.diameter_um=1e-300"] + TINY, "either", ("diameter_um",)),
        ("diameter 1e-12 um", ["--set", "rve.diameter_um=1e-12"] + TINY, "either", ("diameter_um",)),
        ("diameter 1000 um", ["--set", "rve.diameter_um=1000"] + TINY, "either", ("diameter_um",)),
        ("size_um 1e-9 segment_um 1e-10", ["--set", "rve.size_um=1e-9", "--set", "rve.segment_um=1e-10", "--set", "rve.layers=2", "--set", "rve.diameter_um=1e-11"], "either", ("size", "diameter_um")),
        ("size_ratio 1e9", ["--set", "rve.size_ratio=1e9", "--set", "rve.layers=2"], "error", ("memory", "size", "large")),
        ("size_ratio 1e300", ["--set", "rve.size_ratio=1e300", "--set", "rve.layers=2"], "error", ("memory", "size", "large")),
        ("layers 1000 L/D 1e4", ["--set", "rve.size_ratio=1e4", "--set", "rve.layers=1000"], "error", ("memory", "large")),
        ("segment_ratio 1e-6", ["--set", "rve.segment_ratio=1e-6"] + TINY, "error", ("memory", "segment", "large")),
        ("segment_ratio 1e-300", ["--set", "rve.segment_ratio=1e-300"] + TINY, "error", ("memory", "segment", "large")),
        ("merge tolerance 1e-300", ["--set", "rve.merge_tolerance_ratio=1e-300"] + TINY, "either", ("merge",)),
        ("max_deviation 89.999", ["--set", "rve.max_deviation_deg=89.999"] + TINY, "either", ("deviation",)),
        ("kappa 700 border", ["--set", "rve.orientation={von_mises={kappa=700}}", "--set", "rve.seeding=border"] + TINY, "either", ("free node", "cross-link", "orientation")),
        ("kappa 700 lines", ["--set", "rve.orientation={von_mises={kappa=700, mean_deg=179.999999}}"] + TINY, "either", ("cross-link", "orientation")),
        ("histogram one thin bin", ["--set", "rve.orientation={histogram={edges_deg=[0, 1e-9, 180], weights=[1, 0]}}"] + TINY, "either", ("cross-link", "orientation")),
        ("seed 2^63-1", ["--set", f"rve.seed={2**63 - 1}"] + TINY, "ok", ()),
        ("segment just below side", ["--set", "rve.segment_ratio=29.999"] + TINY, "either", ("segment",)),
        ("window_ratio 1e6", ["--set", "output.window_ratio=1e6"] + TINY, "ok", ()),
        ("window_ratio 1e-9", ["--set", "output.window_ratio=1e-9"] + TINY, "either", ("window",)),
    ]
    for i, (name, sets, expect, names) in enumerate(physics):
        out = m.out("phys")
        m.add(Case(g, f"generate {name}", ["generate", "plla", *sets, "-o", str(out), "-q", "--no-figures", "--no-vtk"],
                   names=names, out=out, expect=expect, codes=(2,), timeout=60, quick=i % 4 == 0))
    # absurd fiber laws and solver settings on the tiny RVE
    sims = [
        ("slack modulus 1e-300", ["--set", "fiber.slack_modulus_MPa=1e-300"], "either"),
        ("taut 1e6 slack 1e-6", ["--set", "fiber.taut_modulus_MPa=1e6", "--set", "fiber.slack_modulus_MPa=1e-6"], "either"),
        ("flow rate 1e3, resistance 1e-300", ["--set", "fiber.flow_rate_per_s=1e3", "--set", "fiber.flow_resistance_MPa=1e-300"], "either"),
        ("hardening 100, flow 1e3", ["--set", "fiber.hardening_exponent=100", "--set", "fiber.flow_rate_per_s=1e3"], "either"),
        ("elastic (flow 0)", ["--set", "fiber.flow_rate_per_s=0"], "ok"),
        ("rtol 1e-300", ["--set", "solver.rtol=1e-300", "--set", "solver.atol=1e-300", "--set", "solver.max_cuts=2"], "either"),
        ("atol 0.999 rtol 0.999", ["--set", "solver.rtol=0.999", "--set", "solver.atol=0.999"], "either"),
        ("max_iterations 1, max_cuts 0", ["--set", "solver.max_iterations=1", "--set", "solver.max_cuts=0"], "either"),
        ("time_rtol 1e-300", ["--set", "solver.time_rtol=1e-300", "--set", "fiber.flow_rate_per_s=1"], "either"),
        ("time_rtol off", ["--set", 'solver.time_rtol="off"'], "ok"),
        ("max_strain 10 in 1 step", ["--max-strain", "10", "--steps", "1"], "either"),
        ("max_strain -0.99 uniaxial", ["--max-strain", "-0.99", "--steps", "2"], "either"),
        ("pure shear 5", ["--test", "pure_shear", "--max-strain", "5", "--steps", "2"], "either"),
        ("simple shear -0.99", ["--test", "simple_shear", "--max-strain", "-0.99", "--steps", "2"], "either"),
        ("rate 1e3", ["--strain-rate-per-s", "1e3"], "ok"),
        ("a valid loading.program", ["--set", "loading.program=[{to_strain=0.03, steps=2}]"], "ok"),
        ("a valid loading.program on the preset", ["--set", "loading.program=[{to_strain=0.03, steps=2}]"], "ok"),
        ("hold 1e9 s after load", ["--set", "loading.program=[{to_strain=0.03, steps=2}, {hold_s=1e9, steps=2}]"], "either"),
        ("unload below zero", ["--set", "loading.program=[{to_strain=0.03, steps=2}, {to_strain=-0.03, steps=2}]"], "either"),
        ("direction 179.9999", ["--direction-deg", "179.9999"], "ok"),
        ("poisson -1", ["--set", "loading.lateral={poisson_ratio=-1}"], "either"),
        ("poisson 33 strain 0.03 (F22 0.01)", ["--set", "loading.lateral={poisson_ratio=33}"], "either"),
        ("lateral free", ["--lateral", "free"], "either"),
        ("yield threshold 1e-300", ["--set", "output.yield_threshold=1e-300"], "either"),
        ("stress measure paper", ["--set", "output.stress_measure=paper"], "ok"),
        ("geometry override on an RVE", ["--set", "rve.layers=3"], "error"),
    ]
    for i, (name, sets, expect) in enumerate(sims):
        out = m.out("sim")
        program = any(a.startswith("loading.program") for a in sets)
        extra = [] if program or "--max-strain" in sets else list(SHORT)
        # a program on a saved RVE is refused (its stored config holds the shorthand keys): a
        # separate case; the others run on the preset at the same tiny size
        source = [str(m.base_rve)] if not program or name == "a valid loading.program" else ["plla", *TINY]
        argv = ["simulate", *source, *extra, *sets, "-o", str(out), "-q"]
        tension = not any(s in name for s in ("-0.99", "below zero", "simple shear"))
        target = None if "program" in " ".join(sets) or "--max-strain" in sets else 0.03
        # a value outside the documented ranges may be refused up front (exit 2, naming its key)
        keys = tuple(a.split("=", 1)[0] for a in sets if "=" in a and not a.startswith("-"))
        m.add(Case(g, f"simulate {name}", argv,
                   names=("rve.layers",) if "geometry" in name else ("step", "strain", "converge", *keys),
                   out=out, expect=expect, check=curve_check(target, tension), codes=(2,) if "geometry" in name else (2, 4),
                   timeout=40, quick=i % 5 == 0))


# --- (b) damaged HDF5 ----------------------------------------------------------------------------
def group_b(m: Matrix) -> None:
    g = "b"
    base = m.base_rve
    with h5py.File(base, "r") as f:
        n_nodes = f["network/node_position"].shape[0]
        n_inner = int(f["network"].attrs["n_inner"])
        config_toml = f.attrs["config_toml"]
        if isinstance(config_toml, bytes):
            config_toml = config_toml.decode()

    def variant(name: str, edit: Callable[[h5py.File], None], names: tuple[str, ...], expect: str = "error",
                quick: bool = False, codes: tuple[int, ...] = (3,), check: Callable | None = None, note: str = "") -> None:
        p = m.inp / "h5" / f"{name}.h5"
        p.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(base, p)
        with h5py.File(p, "r+") as f:
            edit(f)
        out = m.out("h5")
        checks = [curve_check(0.03)] + ([check] if check else [])
        m.add(Case(g, name, ["simulate", str(p), *SHORT, "-o", str(out), "-q"], names=names, out=out, expect=expect,
                   protect=(p,), codes=codes, check=lambda o, c: [x for f in checks for x in f(o, c)], quick=quick,
                   timeout=90, note=note))

    def attr(name, value, group="/"):
        def edit(f):
            if value is None:
                del f[group].attrs[name]
            else:
                f[group].attrs[name] = value
        return edit

    def replace(dsname, fn):
        def edit(f):
            data = f[dsname][()]
            new = fn(data)
            del f[dsname]
            if isinstance(new, tuple) and new and new[0] == "raw":
                f.create_dataset(dsname, **new[1])
            else:
                f.create_dataset(dsname, data=new)
        return edit

    def setcfg(fn):
        def edit(f):
            data = tomllib.loads(config_toml)
            fn(data)
            import tomli_w
            f.attrs["config_toml"] = tomli_w.dumps(data)
        return edit

    sv = "schema_version"
    variant("schema_version_float", attr(sv, 1.0), ("schema_version",), quick=True)
    variant("schema_version_str", attr(sv, "1"), ("schema_version",))
    variant("schema_version_array", attr(sv, np.array([1, 1])), ("schema_version",))
    variant("schema_version_0", attr(sv, 0), ("schema_version",))
    variant("schema_version_neg", attr(sv, -1), ("schema_version",))
    variant("schema_version_2", attr(sv, 2), ("schema", "version", "upgrade"))
    variant("schema_version_huge", attr(sv, np.uint64(2**64 - 1)), ("schema", "version"))
    variant("schema_version_bool", attr(sv, True), ("schema_version",))
    variant("schema_version_missing", attr(sv, None), ("schema_version",))
    variant("schema_version_nan", attr(sv, float("nan")), ("schema_version",))
    variant("schema_results", attr("schema", "espin.results"), ("schema",))
    variant("schema_bytes", attr("schema", np.bytes_(b"espin.rve")), ("schema",), expect="either")
    variant("schema_missing", attr("schema", None), ("schema",))
    variant("espin_version_missing_and_v2", lambda f: (attr(sv, 2)(f), attr("espin_version", None)(f)), ("version",))
    variant("config_garbage", attr("config_toml", "[[[not toml"), ("config_toml",), quick=True)
    variant("config_int", attr("config_toml", 5), ("config_toml",))
    variant("config_missing", attr("config_toml", None), ("config_toml",))
    variant("config_invalid", setcfg(lambda d: d["rve"].__setitem__("layers", 0)), ("config_toml", "layers"))
    variant("config_layers_3", setcfg(lambda d: d["rve"].__setitem__("layers", 3)), ("layers",), quick=True)
    variant("config_diameter", setcfg(lambda d: d["rve"].__setitem__("diameter_um", 0.5)), ("diameter",))
    variant("config_size_ratio", setcfg(lambda d: d["rve"].__setitem__("size_ratio", 31.0)), ("size",))
    variant("config_merge_tol", setcfg(lambda d: d["rve"].__setitem__("merge_tolerance_ratio", 0.05)), ("merge",))
    variant("config_seed", setcfg(lambda d: d["rve"].__setitem__("seed", 7)), ("seed",))
    variant("config_volume_fraction", setcfg(lambda d: d["rve"].__setitem__("volume_fraction", 0.9)), ("volume_fraction",),
            expect="either", check=stored_vf_check)
    variant("config_transverse_missing", setcfg(lambda d: d["loading"].__setitem__("lateral", {"transverse_csv": "/nonexistent/t.csv"})),
            ("transverse_csv",), codes=(2, 3))
    variant("config_transverse_devzero", setcfg(lambda d: d["loading"].__setitem__("lateral", {"transverse_csv": "/dev/zero"})),
            ("transverse_csv",), codes=(2, 3))
    variant("config_taut_1e6", setcfg(lambda d: d["fiber"].__setitem__("taut_modulus_MPa", 1e6)), (), expect="ok")
    variant("seed_attr_str", attr("seed", "1"), ("seed",))
    P = "network/node_position"
    variant("node_nan", replace(P, lambda a: np.where(np.arange(a.size).reshape(a.shape) == 3, np.nan, a)), ("node_position",), quick=True)
    variant("node_inf", replace(P, lambda a: np.where(np.arange(a.size).reshape(a.shape) == 3, np.inf, a)), ("node_position",))
    variant("node_negative", replace(P, lambda a: a - 100.0), ("node_position",))
    variant("node_outside", replace(P, lambda a: a * 3), ("node_position",))
    variant("node_3_columns", replace(P, lambda a: np.c_[a, a[:, :1]]), ("node_position",))
    variant("node_1d", replace(P, lambda a: a.ravel()), ("node_position",))
    variant("node_float32", replace(P, lambda a: a.astype(np.float32)), (), expect="either")
    variant("node_int", replace(P, lambda a: a.astype(np.int64)), ("node_position", "element"), expect="either")
    variant("node_strings", replace(P, lambda a: np.array([[b"a", b"b"]] * len(a))), ("node_position",))
    variant("node_complex", replace(P, lambda a: a.astype(np.complex128)), ("node_position",))
    variant("node_moved_inside", replace(P, lambda a: np.where((np.arange(len(a)) == 0)[:, None], a[::-1][0], a)),
            ("element", "node", "contour"), expect="either")
    variant("node_empty", replace(P, lambda a: a[:0]), ("node_position", "element_nodes"))
    variant("node_huge_declared", replace(P, lambda a: ("raw", {"shape": (2**50, 2), "chunks": (1024, 2), "dtype": "f8"})),
            ("node_position",), quick=True)
    E = "network/element_nodes"
    variant("elements_out_of_range", replace(E, lambda a: np.where(a == a.max(), n_nodes, a)), ("element_nodes",), quick=True)
    variant("elements_negative", replace(E, lambda a: np.where(a == a.max(), -1, a)), ("element_nodes",))
    variant("elements_float", replace(E, lambda a: a.astype(float)), ("element_nodes",))
    variant("elements_same_node", replace(E, lambda a: np.r_[a[:1, [0, 0]], a[1:]]), ("element_nodes",))
    variant("elements_duplicated", replace(E, lambda a: np.r_[a[:1], a[:1], a[2:]]), ("element",), expect="either")
    variant("elements_huge_declared", replace(E, lambda a: ("raw", {"shape": (2**50, 2), "chunks": (1024, 2), "dtype": "i8"})),
            ("element_nodes",))
    variant("elements_uint64_max", replace(E, lambda a: a.astype(np.uint64) + np.uint64(2**64 - 100)), ("element_nodes",))
    L = "network/element_contour_length"
    variant("contour_zero", replace(L, lambda a: np.where(np.arange(len(a)) == 0, 0.0, a)), ("element_contour_length",))
    variant("contour_negative", replace(L, lambda a: -a), ("element_contour_length",))
    variant("contour_nan", replace(L, lambda a: np.where(np.arange(len(a)) == 0, np.nan, a)), ("element_contour_length",))
    variant("contour_short", replace(L, lambda a: a * 0.5), ("element_contour_length",))
    variant("contour_1e300", replace(L, lambda a: a * 1e300), ("element_contour_length",), expect="either")
    variant("contour_wrong_length", replace(L, lambda a: a[:-1]), ("element_contour_length",))
    D = "network/element_diameter"
    variant("diameter_mismatch", replace(D, lambda a: a * 2), ("element_diameter",))
    variant("all_diameters_1e-300", lambda f: (replace(D, lambda a: a * 0 + 1e-300)(f),
                                               replace("mat/fiber_diameter", lambda a: a * 0 + 1e-300)(f)),
            ("diameter",))
    variant("element_layer_mismatch", replace("network/element_layer", lambda a: 1 - a), ("element_layer",))
    variant("element_fiber_out_of_range", replace("network/element_fiber", lambda a: a + 10_000), ("element_fiber",))
    variant("n_inner_too_big", attr("n_inner", n_nodes + 1, "network"), ("n_inner",))
    variant("n_inner_zero", attr("n_inner", 0, "network"), ("n_inner", "DOF", "free"), quick=True,
            note="n_inner = 0: 0 DOF, every node moves affinely, Newton does nothing (iterations 0); a generated mat "
                 "without a free node is refused, and border nodes are not checked to lie on the border")
    variant("n_inner_minus_1", attr("n_inner", n_inner - 1, "network"), ("n_inner",), expect="either")
    variant("n_inner_float", attr("n_inner", float(n_inner), "network"), ("n_inner",))
    variant("n_inner_negative", attr("n_inner", -1, "network"), ("n_inner",))
    variant("n_merged_missing", attr("n_merged", None, "network"), ("n_merged",))
    variant("merge_tol_nan", attr("merge_tolerance_um", float("nan"), "network"), ("merge_tolerance",))
    variant("size_zero", attr("size_um", 0.0, "mat"), ("size_um",))
    variant("size_str", attr("size_um", "13.5", "mat"), ("size_um",))
    variant("n_layers_mismatch", attr("n_layers", 5, "mat"), ("n_layers", "layers"))
    variant("offsets_unsorted", replace("mat/fiber_offsets", lambda a: a[::-1]), ("fiber_offsets",))
    variant("offsets_not_zero", replace("mat/fiber_offsets", lambda a: a + 1), ("fiber_offsets",))
    variant("offsets_empty", replace("mat/fiber_offsets", lambda a: a[:0]), ("fiber_offsets",))
    variant("vertices_nan", replace("mat/vertices", lambda a: a * np.nan), ("vertices",))
    variant("fiber_layer_out", replace("mat/fiber_layer", lambda a: a + 2), ("fiber_layer",))
    variant("crosslinks_empty", lambda f: [replace(f"crosslinks/{k}", lambda a: a[:0])(f) for k in
                                           ("point", "segment", "fiber", "layer", "arc")], ("crosslinks",), expect="either")
    variant("crosslink_arc_negative", replace("crosslinks/arc", lambda a: -a - 1), ("arc",))
    variant("crosslink_fiber_mismatch", replace("crosslinks/fiber", lambda a: a[:, ::-1]), ("crosslinks/fiber",), expect="either")
    variant("network_is_dataset", lambda f: (f.__delitem__("network"), f.create_dataset("network", data=[1])), ("network",))
    variant("dataset_is_group", lambda f: (f.__delitem__(E), f.create_group(E)), ("element_nodes",))
    variant("network_missing", lambda f: f.__delitem__("network"), ("network",))
    variant("external_link_missing", lambda f: (f.__delitem__("network"), f.__setitem__(
        "network", h5py.ExternalLink("/nonexistent/x.h5", "/network"))), ("network",))
    variant("external_link_self", lambda f: (f.__delitem__("network"), f.__setitem__(
        "network", h5py.ExternalLink(str(base), "/network"))), ("network",), expect="either")
    variant("soft_link_loop", lambda f: (f.__delitem__("network"), f.__setitem__("network", h5py.SoftLink("/network"))),
            ("network",))
    variant("external_storage_devzero", replace(L, lambda a: ("raw", {"shape": a.shape, "dtype": "f8",
                                                                          "external": [("/dev/zero", 0, a.nbytes)]})),
            ("element_contour_length",))
    variant("compressed_corrupt", lambda f: corrupt_chunk(f, L), ("element_contour_length", "damaged", "rve"))
    # whole-file damage
    raw_cases = {
        "truncated_half": base.read_bytes()[: base.stat().st_size // 2],
        "truncated_1k": base.read_bytes()[:1024],
        "empty": b"",
        "random_bytes": bytes(random.Random(2).randrange(256) for _ in range(8192)),
        "text": b"this is not hdf5\n",
        "toml_named_h5": b"[rve]\nlayers = 2\n",
        "bitflip_middle": flip(base.read_bytes(), base.stat().st_size // 2),
    }
    for i, (name, data) in enumerate(raw_cases.items()):
        p = m.f(f"h5/{name}.h5", data)
        out = m.out("h5")
        m.add(Case(g, name, ["simulate", str(p), *SHORT, "-o", str(out), "-q"], names=(p.name,), out=out, protect=(p,),
                   codes=(3,), quick=i == 0, expect="either" if name == "bitflip_middle" else "error",
                   check=curve_check(0.03)))
    # results.h5 as the source; special paths
    sim = m.outs / "b_results_src"
    p_dir = m.inp / "h5" / "adir.h5"
    p_dir.mkdir()
    fifo = m.inp / "h5" / "fifo.h5"
    os.mkfifo(fifo)
    (m.inp / "h5" / "zero.h5").symlink_to("/dev/zero")
    m.add(Case(g, "results.h5 as the RVE", ["simulate", str(sim / "results.h5"), *SHORT, "-o", str(m.out("h5")), "-q"],
               names=("results.h5",), codes=(3,), pre=lambda: make_results(m, sim)))
    for p, sub in ((p_dir, False), (fifo, True), (m.inp / "h5" / "zero.h5", True), (m.inp / "h5" / "nosuch.h5", False)):
        out = m.out("h5")
        m.add(Case(g, f"special {p.name}", ["simulate", str(p), *SHORT, "-o", str(out), "-q"], names=(p.name,), out=out,
                   codes=(3,), subprocess=sub, timeout=15))
    # an uppercase suffix: read as TOML
    up = m.inp / "h5" / "RVE.H5"
    shutil.copy(base, up)
    out = m.out("h5")
    m.add(Case(g, "RVE file with suffix .H5", ["simulate", str(up), *SHORT, "-o", str(out), "-q"], names=("RVE.H5",),
               out=out, codes=(2, 3), expect="either", check=curve_check(0.03), note="the suffix test is case-sensitive"))


def stored_vf_check(o: Outcome, case: Case) -> list[str]:
    """The results' config.toml must not claim a volume fraction the mat does not have."""
    claimed = tomllib.loads((case.out / "config.toml").read_text("utf-8"))["rve"]["volume_fraction"]
    src = Path(case.argv[1])
    with h5py.File(src, "r") as f:
        v = f["mat/vertices"][()]
        off = f["mat/fiber_offsets"][()]
        d = f["mat/fiber_diameter"][()]
        size = float(f["mat"].attrs["size_um"])
        thick = float(f["mat"].attrs["thickness_um"])
        layers = int(f["mat"].attrs["n_layers"])
    seg = np.linalg.norm(np.diff(v, axis=0), axis=1)
    fiber_of_seg = np.searchsorted(off, np.arange(len(v) - 1), side="right") - 1
    inside = np.isin(np.arange(len(v) - 1), off[1:] - 1, invert=True)
    volume = float(np.sum((seg * np.pi * d[fiber_of_seg] ** 2 / 4)[inside]))
    actual = volume / (size * size * thick * layers)
    if abs(actual - claimed) > 0.5 * actual:
        return [(f"the results' config.toml says rve.volume_fraction = {claimed:g}, the mat's is {actual:.3g}: "
                "the stored config's volume fraction is not checked against the arrays and is copied on")]
    return []


def corrupt_chunk(f: h5py.File, name: str) -> None:
    data = f[name][()]
    del f[name]
    ds = f.create_dataset(name, data=np.tile(data, 1), chunks=(len(data),), compression="gzip")
    info = ds.id.get_chunk_info(0)
    f.flush()
    fname = f.filename
    f.close()
    with open(fname, "r+b") as fh:
        fh.seek(info.byte_offset + 4)
        fh.write(b"\xde\xad\xbe\xef" * 4)


def flip(data: bytes, at: int) -> bytes:
    b = bytearray(data)
    for k in range(64):
        b[at + k] ^= 0xFF
    return bytes(b)


def make_results(m: Matrix, folder: Path) -> None:
    if (folder / "results.h5").exists():
        return
    from typer.testing import CliRunner

    from espin.cli import app

    CliRunner().invoke(app, ["simulate", str(m.base_rve), *SHORT, "-o", str(folder), "-q"])


# --- (c) curve CSV files ---------------------------------------------------------------------------
def bilinear_csv(n: int = 301, percent: bool = False, sep: str = ",", decimal: str = ".", header: str = "strain,stress_MPa") -> str:
    e = np.linspace(0, 0.3, n)
    s = np.where(e < 0.03, 200 * e, 6 + 5 * (e - 0.03))
    if percent:
        e = e * 100
    lines = [header.replace(",", sep)] if header else []
    for a, b in zip(e, s):
        lines.append(f"{a:.6g}{sep}{b:.6g}".replace(".", decimal) if decimal != "." else f"{a:.6g}{sep}{b:.6g}")
    return "\n".join(lines) + "\n"


def group_c(m: Matrix) -> None:
    g = "c"
    good = bilinear_csv()
    files: list[tuple[str, bytes | str, str, tuple, list[str], Callable | None]] = [
        # name, content, expect, names, extra options, check
        ("good.csv", good, "ok", (), [], props_check(200.0, 0.05, 6.0)),
        ("percent.csv", bilinear_csv(percent=True), "ok", (), [], warned("percent")),
        ("percent_flag.csv", bilinear_csv(percent=True), "ok", (), ["--percent-strain"], props_check(200.0, 0.05, 6.0)),
        ("percent_flag_on_fraction.csv", good, "either", ("percent",), ["--percent-strain"], warned("percent")),
        ("all_zero_stress.csv", "strain,stress_MPa\n" + "".join(f"{k / 100},0\n" for k in range(30)), "error", ("all_zero_stress.csv",), [], None),
        ("negative_stress.csv", "strain,stress_MPa\n" + "".join(f"{k / 100},{-k}\n" for k in range(30)), "error", ("negative_stress.csv",), [], None),
        ("nan_row.csv", good.replace("\n0.15,", "\nnan,", 1).replace("0.15,", "nan,"), "error", ("nan_row.csv",), [], None),
        ("nan_stress.csv", good.replace(",6.6\n", ",nan\n"), "error", ("nan_stress.csv",), [], None),
        ("inf_stress.csv", good.replace(",6.6\n", ",inf\n"), "error", ("inf_stress.csv",), [], None),
        ("empty_cell.csv", good.replace(",6.6\n", ",\n"), "error", ("empty_cell.csv",), [], None),
        ("one_point.csv", "strain,stress_MPa\n0.01,2\n", "error", ("one_point.csv",), [], None),
        ("two_points.csv", "strain,stress_MPa\n0,0\n0.01,2\n", "ok", (), [], props_check(200.0, 1e-6)),
        ("same_strain.csv", "strain,stress_MPa\n" + "".join(f"0.01,{k}\n" for k in range(10)), "error", ("same_strain.csv",), [], None),
        ("decreasing.csv", "strain,stress_MPa\n" + "".join(f"{(30 - k) / 100},{30 - k}\n" for k in range(30)), "error", ("decreasing.csv",), [], None),
        ("negative_strain_only.csv", "strain,stress_MPa\n" + "".join(f"{-k / 100},{k}\n" for k in range(30)), "error", ("negative_strain_only.csv",), [], None),
        ("huge_line.csv", "strain,stress_MPa\n0,0\n" + "1" * (10 * 2**20) + ",5\n", "error", ("huge_line.csv",), [], None),
        ("decimal_comma_semicolon.csv", bilinear_csv(sep=";", decimal=","), "ok", (), [], props_check(200.0, 0.05, 6.0)),
        ("decimal_comma_tab.csv", bilinear_csv(sep="\t", decimal=","), "ok", (), [], props_check(200.0, 0.05, 6.0)),
        ("decimal_comma_comma.csv", "strain,stress\n" + "".join(f"0,{k:02d},{2 * k},5\n" for k in range(1, 30)), "either", ("decimal_comma_comma.csv",), [], props_check()),
        ("latin1.csv", bilinear_csv(header="strain,stress_MPa,température").replace("\n", ",1\n").replace("température,1", "température").encode("latin-1"), "ok", (), [], props_check(200.0, 0.05)),
        ("utf16_bom.csv", good.encode("utf-16"), "ok", (), [], props_check(200.0, 0.05)),
        ("utf16_nobom.csv", good.encode("utf-16-le"), "error", ("utf16_nobom.csv",), [], None),
        ("utf8_bom.csv", b"\xef\xbb\xbf" + good.encode(), "ok", (), [], props_check(200.0, 0.05)),
        ("binary.csv", bytes(random.Random(3).randrange(256) for _ in range(8192)), "error", ("binary.csv",), [], None),
        ("empty.csv", b"", "error", ("empty.csv",), [], None),
        ("header_only.csv", "strain,stress_MPa\n", "error", ("header_only.csv",), [], None),
        ("comments_only.csv", "# nothing\n# here\n", "error", ("comments_only.csv",), [], None),
        ("crlf.csv", good.replace("\n", "\r\n"), "ok", (), [], props_check(200.0, 0.05)),
        ("cr_only.csv", good.replace("\n", "\r"), "ok", (), [], props_check(200.0, 0.05)),
        ("too_many_points.csv", "strain,stress_MPa\n" + "".join(f"{k * 1e-6:.7f},{k * 2e-4:.5f}\n" for k in range(250_002)), "error", ("too_many_points.csv",), [], None),
        ("extreme_scale.csv", "strain,stress_MPa\n" + "".join(f"{k * 1e-302:.3e},{k * 1e300:.3e}\n" for k in range(30)), "either", ("extreme_scale.csv",), [], props_check()),
        ("denormal_stress.csv", "strain,stress_MPa\n" + "".join(f"{k / 100},{k * 1e-320:.3e}\n" for k in range(30)), "either", ("denormal_stress.csv",), [], props_check()),
        ("stress_1e308.csv", "strain,stress_MPa\n" + "".join(f"{k / 100},{k * 1e307:.3e}\n" for k in range(30)), "either", ("stress_1e308.csv",), [], props_check()),
        ("strain_1e6.csv", "strain,stress_MPa\n" + "".join(f"{k * 1e5},{k}\n" for k in range(30)), "either", ("strain_1e6.csv", "percent"), [], warned("strain")),
        ("dup_header.csv", "strain,strain,stress_MPa\n" + "".join(f"{k / 100},{k / 50},{k}\n" for k in range(30)), "error", ("strain",), [], props_check()),
        ("dup_stress_header.csv", "strain,stress_MPa,stress_MPa\n" + "".join(f"{k / 100},{k},{2 * k}\n" for k in range(30)), "error", ("stress",), [], props_check()),
        ("wide_header.csv", ",".join(f"c{k}" for k in range(3000)) + "\n" + ",".join("1" for _ in range(3000)) + "\n", "error", ("wide_header.csv",), [], None),
        ("quoted.csv", '"strain","stress_MPa"\n' + "".join(f'"{k / 100}","{k}"\n' for k in range(30)), "either", ("quoted.csv",), [], props_check(100.0, 0.05)),
        ("unbalanced_quote.csv", 'strain,stress_MPa\n0,0\n"0.01,2\n0.02,4\n', "error", ("unbalanced_quote.csv",), [], None),
        ("nul_inside.csv", good[:200] + "\x00" + good[200:], "error", ("nul_inside.csv",), [], None),
        ("control_chars.csv", good[:200] + "\x1b[31m" + good[200:], "error", ("control_chars.csv",), [], None),
        ("text_columns.csv", "strain,stress_MPa\n" + "".join(f"a{k},b{k}\n" for k in range(30)), "error", ("text_columns.csv",), [], None),
        ("fake.xlsx", good, "error", ("fake.xlsx",), [], None),
        ("zip_not_xlsx.xlsx", zip_bytes(), "error", ("zip_not_xlsx.xlsx",), [], None),
        ("single_column.csv", "strain\n" + "".join(f"{k / 100}\n" for k in range(30)), "error", ("single_column.csv", "stress"), [], None),
        ("stress_column_99.csv", good, "error", ("99", "column"), ["--stress-column", "99"], None),
        ("skip_all.csv", good, "error", ("skip_all.csv", "skip"), ["--skip-rows", "400"], None),
        ("range_outside.csv", good, "error", ("range", "strain"), ["--strain-range", "5:6"], None),
    ]
    huge_sparse = m.inp / "curves" / "sparse_100MB.csv"
    for i, (name, data, expect, names, opts, check) in enumerate(files):
        p = m.f(f"curves/{name}", data if isinstance(data, bytes) else data.encode("utf-8"))
        out = m.out("props")
        note = ("a repeated column name: the loading-table reader refuses it ('which one to read is unclear'), "
                "the curve reader takes one of them without a word") if name.startswith("dup_") else ""
        m.add(Case(g, name, ["properties", str(p), *opts, "-o", str(out)], names=names, out=out, expect=expect, codes=(3,) if "--" not in " ".join(opts) else (2, 3),
                   check=check, protect=(p,), quick=i % 6 == 0, timeout=60, note=note))
    huge_sparse.parent.mkdir(parents=True, exist_ok=True)
    with open(huge_sparse, "wb") as fh:
        fh.truncate(100 * 2**20)
    d = m.inp / "curves" / "adir.csv"
    d.mkdir()
    fifo = m.inp / "curves" / "fifo.csv"
    os.mkfifo(fifo)
    (m.inp / "curves" / "link_to_dir.csv").symlink_to(d)
    specials = [(huge_sparse, False), (d, False), (fifo, True), (Path("/dev/zero"), True), (Path("/dev/null"), True),
                (m.inp / "curves" / "link_to_dir.csv", False), (m.inp / "curves" / "nosuch.csv", False),
                (Path("/proc/self/status"), True)]
    for p, sub in specials:
        out = m.out("props")
        m.add(Case(g, f"special {p}", ["properties", str(p), "-o", str(out)], names=(p.name,), out=out, codes=(3,),
                   subprocess=sub, timeout=15))
    # several curves: one bad, disjoint ranges
    goodp = m.inp / "curves" / "good.csv"
    bad = m.inp / "curves" / "nan_stress.csv"
    late = m.f("curves/late.csv", "strain,stress_MPa\n" + "".join(f"{0.5 + k / 100},{k}\n" for k in range(30)))
    for name, paths, expect, names, check in (
        ("good + nan", [goodp, bad], "error", ("nan_stress.csv",), None),
        ("good + disjoint range", [goodp, late], "either", ("late.csv", "range", "common"), props_check()),
        ("good twice", [goodp, goodp], "ok", (), props_check(200.0, 0.05)),
    ):
        out = m.out("props")
        m.add(Case(g, f"curves {name}", ["properties", *map(str, paths), "-o", str(out)], names=names, out=out, expect=expect,
                   codes=(3,), check=check))
    # espin's own curve.csv (from a simulation) must be read
    sim = m.outs / "b_results_src"
    out = m.out("props")
    m.add(Case(g, "espin curve.csv", ["properties", str(sim / "curve.csv"), "-o", str(out)], out=out, expect="ok",
               check=props_check(), pre=lambda: make_results(m, sim)))


def zip_bytes() -> bytes:
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("hello.txt", "not a workbook")
    return buf.getvalue()


# --- (d) SEM images ------------------------------------------------------------------------------
def write_synthetic_sem(m: Matrix, path: Path) -> np.ndarray:
    import tifffile

    from espin.geometry.rve_file import load_rve
    from espin.imaging.synthetic import render_sem

    path.parent.mkdir(parents=True, exist_ok=True)
    rve = load_rve(m.base_rve)
    img = np.clip(render_sem(rve.mat, um_per_px=0.05, layers=2).image, 0, 1)
    tifffile.imwrite(path, (img * 255).astype(np.uint8))
    return img


def tiff_header_only(width: int, height: int, bits: int = 8, data: bytes = b"\x00" * 64) -> bytes:
    """A little-endian baseline TIFF declaring ``width`` x ``height`` with only ``data`` behind it."""
    entries = [
        (256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, bits), (259, 3, 1, 1), (262, 3, 1, 1),
        (273, 4, 1, 8), (277, 3, 1, 1), (278, 4, 1, height), (279, 4, 1, len(data)),
    ]
    ifd_offset = 8 + len(data)
    ifd = struct.pack("<H", len(entries))
    for tag, typ, count, value in entries:
        ifd += struct.pack("<HHII", tag, typ, count, value) if typ == 4 else struct.pack("<HHIHH", tag, typ, count, value, 0)
    ifd += struct.pack("<I", 0)
    return b"II*\x00" + struct.pack("<I", ifd_offset) + data + ifd


def png_header_only(width: int, height: int) -> bytes:
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 100)) + chunk(b"IEND", b"")


def group_d(m: Matrix) -> None:
    import tifffile
    from PIL import Image

    g = "d"
    d = m.inp / "sem"
    d.mkdir(parents=True, exist_ok=True)
    good_path = d / "good.tif"
    img = write_synthetic_sem(m, good_path)
    u8 = (img * 255).astype(np.uint8)

    def tif(name: str, data: np.ndarray, **kw) -> Path:
        p = d / name
        tifffile.imwrite(p, data, **kw)
        return p

    def check_diameter(o: Outcome, case: Case) -> list[str]:
        rows = read_csv_dicts(case.out / "fibers.csv")
        ds = [float(r["diameter_um"]) for r in rows if r.get("diameter_um")]
        if ds and not (0.3 < float(np.median(ds)) < 0.7):
            return [f"median fiber diameter {np.median(ds):.3g} um, the image has 0.45 um"]
        return []

    f32 = img.astype(np.float32)
    nan_img = f32.copy()
    nan_img[5, 5] = np.nan
    neg_img = f32.copy()
    neg_img[5, 5] = -1.0
    inf_img = f32.copy()
    inf_img[7, 7] = np.inf
    cases = [
        ("good.tif", good_path, "ok", (), check_diameter),
        ("good.png", None, "ok", (), check_diameter),
        ("good_16bit.tif", tif("good_16bit.tif", (img * 65535).astype(np.uint16)), "ok", (), check_diameter),
        ("good_float.tif", tif("good_float.tif", f32), "ok", (), check_diameter),
        ("good_float_tiny_range.tif", tif("good_float_tiny_range.tif", f32 * np.float32(1e-30)), "ok", (), check_diameter),
        ("rgb.tif", tif("rgb.tif", np.stack([u8] * 3, axis=-1)), "ok", (), check_diameter),
        ("tiny_8x8.png", None, "error", ("tiny_8x8.png",), None),
        ("constant_64.tif", tif("constant_64.tif", np.full((64, 64), 128, np.uint8)), "error", ("constant_64.tif", "fiber"), None),
        ("black_float.tif", tif("black_float.tif", np.zeros((64, 64), np.float32)), "error", ("black_float.tif", "fiber"), None),
        ("noise.tif", tif("noise.tif", np.random.default_rng(1).integers(0, 255, (200, 200)).astype(np.uint8)), "either", ("noise.tif", "fiber"), None),
        ("nan_float.tif", tif("nan_float.tif", nan_img), "error", ("nan_float.tif",), None),
        ("negative_float.tif", tif("negative_float.tif", neg_img), "error", ("negative_float.tif",), None),
        ("inf_float.tif", tif("inf_float.tif", inf_img), "error", ("inf_float.tif",), None),
        ("complex.tif", tif("complex.tif", f32.astype(np.complex64)), "error", ("complex.tif",), None),
        ("five_channels.tif", tif("five_channels.tif", np.stack([u8] * 5, axis=-1), photometric="minisblack", planarconfig="contig"), "error", ("five_channels.tif",), None),
        ("stack_3_pages.tif", tif("stack_3_pages.tif", np.stack([u8] * 3)), "either", ("stack_3_pages.tif",), check_diameter),
        ("huge_declared.tif", None, "error", ("huge_declared.tif",), None),
        ("huge_declared_16bit.tif", None, "error", ("huge_declared_16bit.tif",), None),
        ("declared_9000_truncated.tif", None, "error", ("declared_9000_truncated.tif",), None),
        ("huge_declared.png", None, "error", ("huge_declared.png",), None),
        ("zero_width.tif", None, "error", ("zero_width.tif",), None),
        ("text.tif", None, "error", ("text.tif",), None),
        ("truncated.tif", None, "error", ("truncated.tif",), None),
        ("truncated.png", None, "error", ("truncated.png",), None),
        ("truncated.jpg", None, "error", ("truncated.jpg",), None),
        ("empty.tif", None, "error", ("empty.tif",), None),
        ("tiff_named.png", None, "either", ("tiff_named.png",), check_diameter),
        ("bool.tif", tif("bool.tif", img > 0.5), "either", ("bool.tif",), None),
        ("int32_negative.tif", tif("int32_negative.tif", (u8.astype(np.int32) - 1000)), "either", ("int32_negative.tif", "contrast"), check_diameter),
        ("int32_0_255.tif", tif("int32_0_255.tif", u8.astype(np.int32)), "ok", (), check_diameter),
        ("uint32_0_255.tif", tif("uint32_0_255.tif", u8.astype(np.uint32)), "ok", (), check_diameter),
        ("palette.png", None, "ok", (), check_diameter),
    ]
    Image.fromarray(u8).save(d / "good.png")
    Image.fromarray(u8[:8, :8]).save(d / "tiny_8x8.png")
    (d / "huge_declared.tif").write_bytes(tiff_header_only(60000, 60000))
    (d / "huge_declared_16bit.tif").write_bytes(tiff_header_only(10000, 9000, bits=16))
    (d / "declared_9000_truncated.tif").write_bytes(tiff_header_only(9000, 9000))
    (d / "huge_declared.png").write_bytes(png_header_only(100000, 100000))
    (d / "zero_width.tif").write_bytes(tiff_header_only(0, 100))
    (d / "text.tif").write_text("not an image\n")
    (d / "truncated.tif").write_bytes(good_path.read_bytes()[:200])
    (d / "truncated.png").write_bytes((d / "good.png").read_bytes()[:300])
    Image.fromarray(u8).save(d / "good.jpg", quality=95)
    (d / "truncated.jpg").write_bytes((d / "good.jpg").read_bytes()[:400])
    (d / "empty.tif").write_bytes(b"")
    shutil.copy(good_path, d / "tiff_named.png")
    Image.fromarray(u8).convert("P", palette=Image.Palette.ADAPTIVE).save(d / "palette.png")
    for i, (name, _, expect, names, check) in enumerate(cases):
        p = d / name
        out = m.out("measure")
        m.add(Case(g, name, ["measure", str(p), "--um-per-px", "0.05", "-o", str(out), "-q"], names=names, out=out,
                   expect=expect, codes=(3,), check=check, protect=(p,), quick=i % 5 == 0, timeout=90))
    # special paths
    adir = d / "adir.tif"
    adir.mkdir()
    fifo = d / "fifo.tif"
    os.mkfifo(fifo)
    (d / "zero.tif").symlink_to("/dev/zero")
    for p, sub in ((adir, False), (fifo, True), (d / "zero.tif", True), (d / "nosuch.tif", False)):
        out = m.out("measure")
        m.add(Case(g, f"special {p.name}", ["measure", str(p), "--um-per-px", "0.05", "-o", str(out), "-q"],
                   names=(p.name,), out=out, codes=(3,), subprocess=sub, timeout=15,
                   forbid=("no such file",) if p.name != "nosuch.tif" else ()))
    # calibrate-geometry on damaged measurements
    meas = m.outs / "d_measure_ok"
    def make_meas() -> None:
        if not (meas / "fibers.csv").exists():
            run_inprocess(["measure", str(good_path), "--um-per-px", "0.05", "-o", str(meas), "-q", "--no-figures"], 120)
    for name, edit, names in (
        ("fibers_nan", nanify, ("fibers.csv",)),
        ("fibers_negative", lambda t: negify(t), ("fibers.csv",)),
        ("fibers_empty", lambda t: t.splitlines()[0] + "\n", ("fibers.csv",)),
        ("fibers_binary", lambda t: "\x00\x01\x02" * 100, ("fibers.csv",)),
        ("measurement_garbage", None, ("measurement.toml",)),
    ):
        folder = m.inp / "meas" / name
        out = m.inp / "meas_out" / f"{name}.toml"

        def pre(folder=folder, edit=edit, name=name) -> None:
            make_meas()
            shutil.copytree(meas, folder, dirs_exist_ok=True)
            if edit is None:
                (folder / "measurement.toml").write_text("[[[garbage\n")
            else:
                (folder / "fibers.csv").write_text(edit((meas / "fibers.csv").read_text()))
        m.add(Case(g, f"calibrate-geometry {name}", ["calibrate-geometry", str(folder), "-o", str(out), "--seeds", "1", "-q"],
                   names=names, codes=(2, 3), pre=pre, timeout=120,
                   expect="either" if name == "fibers_nan" else "error",
                   note="pandas reads the text 'nan' as an empty (not measured) cell" if name == "fibers_nan" else ""))
    # special files where measure / calibrate-geometry / fit read a table or hash an input
    sp = m.inp / "meas" / "special"
    sp.mkdir(parents=True)
    os.mkfifo(sp / "fifo.csv")
    (sp / "zero.csv").symlink_to("/dev/zero")
    for name in ("fifo_fibers", "zero_fibers"):
        folder = m.inp / "meas" / name
        folder.mkdir()
        (folder / "fibers.csv").symlink_to(sp / ("fifo.csv" if name.startswith("fifo") else "zero.csv"))
        m.add(Case(g, f"calibrate-geometry {name}", ["calibrate-geometry", str(folder), "-o", str(m.inp / "meas_out" / f"{name}.toml"),
                   "--seeds", "1", "-q"], names=("fibers.csv",), codes=(3,), subprocess=True, timeout=15))
    fitbase = ["--set", "rve.size_ratio=30", "--set", "rve.layers=2", "--realizations", "1", "--eta-points", "2", "--workers", "1"]
    for p in (sp / "fifo.csv", sp / "zero.csv", Path("/dev/zero")):
        out = m.out("fit")
        m.add(Case(g, f"fit {p}", ["fit", str(p), *fitbase, "-o", str(out), "-q"], names=(p.name,), out=out, codes=(3,),
                   subprocess=True, timeout=30))


def nanify(text: str) -> str:
    lines = text.splitlines()
    head = lines[0].split(",")
    j = head.index("diameter_um") if "diameter_um" in head else 1
    cells = lines[1].split(",")
    cells[j] = "nan"
    lines[1] = ",".join(cells)
    return "\n".join(lines) + "\n"


def negify(text: str) -> str:
    lines = text.splitlines()
    head = lines[0].split(",")
    j = head.index("diameter_um") if "diameter_um" in head else 1
    for k in range(1, len(lines)):
        cells = lines[k].split(",")
        cells[j] = "-" + cells[j]
        lines[k] = ",".join(cells)
    return "\n".join(lines) + "\n"


# --- (e) tables referenced by a config -------------------------------------------------------------
def group_e(m: Matrix) -> None:
    g = "e"
    d = m.inp / "tables"
    d.mkdir(parents=True, exist_ok=True)
    tgood = "axial_strain,transverse_strain\n0,0\n0.01,-0.003\n0.02,-0.006\n0.03,-0.009\n0.05,-0.015\n"
    pgood = "time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,1.01,0,0,1\n2,1.02,0,0,1\n3,1.03,0,0,1\n"
    bad_bodies = [
        # name, transverse content, path content, expect, extra names
        ("good", tgood, pgood, "ok"),
        ("empty", "", "", "error"),
        ("header_only", tgood.splitlines()[0] + "\n", pgood.splitlines()[0] + "\n", "error"),
        ("one_row", "\n".join(tgood.splitlines()[:2]) + "\n", "\n".join(pgood.splitlines()[:2]) + "\n", "error"),
        ("nan", tgood.replace("-0.006", "nan"), pgood.replace("1.02", "nan"), "error"),
        ("inf", tgood.replace("-0.006", "inf"), pgood.replace("1.02", "inf"), "error"),
        ("1e300", tgood.replace("-0.006", "1e300"), pgood.replace("1.02", "1e300"), "error"),
        ("decreasing", tgood.replace("0.02,", "0.005,"), pgood.replace("\n2,", "\n0.5,"), "error"),
        ("repeated_first", tgood.replace("0.02,", "0.01,"), pgood.replace("\n2,", "\n1,"), "error"),
        ("missing_column", tgood.replace("transverse_strain", "lateral"), pgood.replace("F21", "Fxx"), "error"),
        ("dup_column", tgood.replace("transverse_strain", "axial_strain"), pgood.replace("F21", "F11"), "error"),
        ("text_cell", tgood.replace("-0.006", "abc"), pgood.replace("1.02", "abc"), "error"),
        ("empty_cell", tgood.replace("-0.006", ""), pgood.replace("1.02", ""), "error"),
        ("short_row", tgood.replace("0.02,-0.006", "0.02"), pgood.replace("2,1.02,0,0,1", "2,1.02"), "error"),
        ("decimal_comma", tgood.replace("0.0", "0,0").replace(",0,0", ";0,0"), pgood.replace("1.0", "1,0"), "error"),
        ("huge_line", tgood + "1" * 100_000 + ",0\n", pgood + "1" * 100_000 + ",1,0,0,1\n", "error"),
        ("binary", None, None, "error"),
        ("utf16_bom", None, None, "ok"),
        ("utf16_nobom", None, None, "error"),
        ("latin1", None, None, "ok"),
        ("quoted", tgood.replace("0.01,", '"0.01",'), pgood.replace("1,1.01", '"1","1.01"'), "ok"),
        ("unbalanced_quote", tgood.replace("0.01,", '"0.01,'), pgood.replace("1,1.01", '"1,1.01'), "error"),
        ("too_many_rows", None, None, "error"),
        ("nul", tgood.replace("0.02", "0.0\x002"), pgood.replace("1.02", "1.0\x002"), "error"),
        ("comments_blank", "# c\n\n" + tgood.replace("\n0.01", "\n\n,\n0.01"), "# c\n\n" + pgood.replace("\n1,", "\n\n,,,,\n1,"), "ok"),
    ]
    for i, (name, tbody, pbody, expect) in enumerate(bad_bodies):
        for kind in ("transverse", "path"):
            body = tbody if kind == "transverse" else pbody
            good_body = tgood if kind == "transverse" else pgood
            if name == "binary":
                data = bytes(random.Random(4).randrange(256) for _ in range(4096))
            elif name == "utf16_bom":
                data = good_body.encode("utf-16")
            elif name == "utf16_nobom":
                data = good_body.encode("utf-16-le")
            elif name == "latin1":
                data = ("# mesur\xe9 \xb5m\n" + good_body).encode("latin-1")
            elif name == "too_many_rows":
                if kind == "transverse":
                    data = ("axial_strain,transverse_strain\n" + "".join(f"{k * 1e-7:.8f},{-k * 3e-8:.9f}\n" for k in range(100_002))).encode()
                else:
                    data = ("time_s,F11,F12,F21,F22\n" + "".join(f"{k},1,0,0,1\n" for k in range(100_002))).encode()
            else:
                data = body.encode("utf-8")
            p = m.f(f"tables/{kind}_{name}.csv", data)
            out = m.out(f"tab_{kind}")
            key = "loading.lateral.transverse_csv" if kind == "transverse" else "loading.path_csv"
            sets = (["--set", f"loading.lateral={{transverse_csv={json.dumps(str(p))}}}", *SHORT] if kind == "transverse"
                    else ["--set", 'loading.test="path"', "--set", f"loading.path_csv={json.dumps(str(p))}"])
            m.add(Case(g, f"{kind} {name}", ["simulate", str(m.base_rve), *sets, "-o", str(out), "-q"],
                       names=(key,) if expect == "error" else (), out=out, expect=expect, protect=(p,), codes=(3,),
                       check=None if expect == "error" else curve_check(0.03 if kind == "transverse" else None),
                       quick=i % 6 == 0, timeout=60))
    # path tables with bad physics
    phys = [
        ("path_det_zero", "time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,0,0,0,1\n", "error", (2, 3, 4)),
        ("path_det_negative", "time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,-1,0,0,1\n", "error", (2, 3)),
        ("path_jump_F11_10", "time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,10,0,0,1\n", "either", (4,)),
        ("path_not_from_identity", "time_s,F11,F12,F21,F22\n0,1.05,0,0,1\n1,1.06,0,0,1\n", "either", (2, 3)),
        ("path_time_from_1e9", "time_s,F11,F12,F21,F22\n1e9,1,0,0,1\n1000000001,1.01,0,0,1\n", "either", (3,)),
        ("path_tiny_time", "time_s,F11,F12,F21,F22\n0,1,0,0,1\n1e-300,1.01,0,0,1\n", "either", (3, 4)),
        ("path_rotation_only", "time_s,F11,F12,F21,F22\n0,1,0,0,1\n1,0.8660254,-0.5,0.5,0.8660254\n", "either", (4,)),
        ("transverse_short_range", "axial_strain,transverse_strain\n0,0\n0.01,-0.005\n", "either", (2, 3)),
        ("transverse_below_minus_1", "axial_strain,transverse_strain\n0,0\n0.01,-2\n0.03,-2\n", "error", (2, 3)),
        ("transverse_not_from_0", "axial_strain,transverse_strain\n0.01,-0.1\n0.03,-0.1\n", "either", (2, 3)),
    ]
    for name, body, expect, codes in phys:
        p = m.f(f"tables/{name}.csv", body)
        out = m.out("tab_phys")
        if name.startswith("path"):
            sets = ["--set", 'loading.test="path"', "--set", f"loading.path_csv={json.dumps(str(p))}"]
            key = "loading.path_csv"
        else:
            sets = ["--set", f"loading.lateral={{transverse_csv={json.dumps(str(p))}}}", *SHORT]
            key = "loading"
        note = ""
        check: Callable | None = curve_check(None)
        if name == "transverse_short_range":
            note = "the program goes to 0.03, the table to 0.01"
            check = lambda o, c: ([] if "warning" in o.output.lower() or "extrapol" in o.output.lower() else
                                  [("transverse table ends at 0.01 but the test goes to 0.03: F'22 held "
                                   "constant beyond the table without a word")])
        if name == "transverse_not_from_0":
            check = lambda o, c: ([] if "warning" in o.output.lower() else
                                  [("transverse table starts at 0.01 with -0.1: the undeformed step gets "
                                   "F'22 = 0.9 (a jump at strain 0) without a word")])
        if name == "path_not_from_identity":
            check = lambda o, c: ([] if "warning" in o.output.lower() else
                                  ["path starts at F11 = 1.05, not the identity: the first row jumps at t = 0 without a word"])
        m.add(Case(g, name, ["simulate", str(m.base_rve), *sets, "-o", str(out), "-q"], names=(key, p.name), out=out,
                   expect=expect, codes=codes, check=check, note=note, timeout=60))
    # special paths as tables
    adir = d / "adir.csv"
    adir.mkdir()
    fifo = d / "fifo.csv"
    os.mkfifo(fifo)
    specials = [(adir, False), (fifo, True), (Path("/dev/zero"), True), (Path("/dev/null"), True), (d / "nosuch.csv", False),
                (Path(""), False)]
    for p, sub in specials:
        for kind in ("transverse", "path"):
            out = m.out("tab_special")
            key = "loading.lateral.transverse_csv" if kind == "transverse" else "loading.path_csv"
            sval = json.dumps(str(p)) if str(p) != "." else '""'
            sets = (["--set", f"loading.lateral={{transverse_csv={sval}}}", *SHORT] if kind == "transverse"
                    else ["--set", 'loading.test="path"', "--set", f"loading.path_csv={sval}"])
            m.add(Case(g, f"{kind} special {str(p) or '(empty string)'}", ["simulate", str(m.base_rve), *sets, "-o", str(out), "-q"],
                       names=(key,), out=out, codes=(2, 3), subprocess=sub, timeout=15))
    # relative path in a TOML config kept in another folder
    cdir = m.inp / "tables" / "cfgdir"
    cdir.mkdir()
    (cdir / "lat.csv").write_text(tgood)
    cfg = cdir / "cfg.toml"
    cfg.write_text('[rve]\nsize_ratio = 30.0\nlayers = 2\n[loading]\nmax_strain = 0.03\nsteps = 2\n'
                   'lateral = {transverse_csv = "lat.csv"}\n')
    out = m.out("tab_rel")
    m.add(Case(g, "relative transverse_csv beside the config", ["simulate", str(cfg), "-o", str(out), "-q"], out=out,
               expect="ok", names=("transverse_csv",), check=curve_check(0.03),
               note="the table lies beside the config; the command runs from another folder"))
    # a config whose table changes between validation and the run is out of scope; a table with a
    # BOM-less UTF-16 name in the key is covered above


# --- (f) output folders ------------------------------------------------------------------------
def group_f(m: Matrix) -> None:
    g = "f"
    folder = m.outs / "f_rerun"
    gen = ["generate", "plla", *TINY, "-q", "--no-figures"]
    m.add(Case(g, "generate into a new folder", [*gen, "-o", str(folder)], out=folder, expect="ok", quick=True))
    m.add(Case(g, "generate again into the same folder", [*gen, "-o", str(folder)], names=(str(folder), "f_rerun"),
               codes=(2,), protect=(folder,), quick=True))
    m.add(Case(g, "generate again with --overwrite", [*gen, "-o", str(folder), "--overwrite"], out=folder, expect="ok",
               quick=True))
    # a user's own file in the folder
    ufold = m.outs / "f_userfile"
    ufold.mkdir()
    (ufold / "notes.txt").write_text("my notes\n")
    m.add(Case(g, "folder with an unrelated user file", [*gen, "-o", str(ufold)], out=ufold, expect="ok",
               protect=(ufold / "notes.txt",)))
    m.add(Case(g, "--overwrite keeps unrelated user files", [*gen, "-o", str(ufold), "--overwrite"], out=ufold, expect="ok",
               protect=(ufold / "notes.txt",)))
    # a user's file named like an output, no run.json
    cfold = m.outs / "f_collide"
    cfold.mkdir()
    (cfold / "statistics.json").write_text('{"mine": true}\n')
    m.add(Case(g, "folder holding a user file named like an output", [*gen, "-o", str(cfold)], names=("statistics.json", "f_collide"),
               codes=(2,), protect=(cfold,)))
    mfold = m.outs / "f_measure_collide"
    mfold.mkdir()
    (mfold / "fibers.csv").write_text("my,table\n")
    m.add(Case(g, "measure into a folder holding the user's fibers.csv", ["measure", str(m.inp / "sem" / "good.tif"),
               "--um-per-px", "0.05", "-o", str(mfold), "-q"], names=("fibers.csv", "f_measure_collide"), codes=(2,),
               protect=(mfold,)))
    # a file where a folder is expected
    afile = m.f("f_file_not_folder", "precious\n")
    for cmd in (gen, ["simulate", str(m.base_rve), *SHORT, "-q"], ["properties", str(m.inp / "curves" / "good.csv")],
                ["measure", str(m.inp / "sem" / "good.tif"), "--um-per-px", "0.05", "-q"]):
        m.add(Case(g, f"{cmd[0]} -o an existing file", [*cmd, "-o", str(afile)], names=(afile.name,), codes=(2,),
                   protect=(afile,), quick=cmd[0] == "generate"))
        m.add(Case(g, f"{cmd[0]} -o below a file", [*cmd, "-o", str(afile / "sub")], names=(afile.name,), codes=(2, 3),
                   protect=(afile,)))
    # unwritable folders
    ro = m.outs / "f_readonly"
    ro.mkdir()
    ro.chmod(0o500)
    m.add(Case(g, "generate into a chmod 0o500 folder", [*gen, "-o", str(ro / "x")], names=("f_readonly",), codes=(2, 3),
               expect="either", note="root ignores the mode: running as root, this is accepted" if os.geteuid() == 0 else ""))
    for target in ("/sys/espin_bad_inputs", "/proc/espin_bad_inputs", "/dev/full/x"):
        for cmd in (gen, ["simulate", str(m.base_rve), *SHORT, "-q"], ["properties", str(m.inp / "curves" / "good.csv")]):
            m.add(Case(g, f"{cmd[0]} -o {target}", [*cmd, "-o", target], names=(target,), codes=(2, 3), quick=cmd[0] == "generate"))
    # --overwrite leaves no stale vtk/step files; simulate -o the RVE's own folder
    sfold = m.outs / "f_stale"
    m.add(Case(g, "simulate 4 steps", ["simulate", str(m.base_rve), "--max-strain", "0.03", "--steps", "4", "-o", str(sfold), "-q"],
               out=sfold, expect="ok"))
    m.add(Case(g, "simulate 2 steps again without --overwrite", ["simulate", str(m.base_rve), *SHORT, "-o", str(sfold), "-q"],
               names=("f_stale",), codes=(2,), protect=(sfold,)))
    m.add(Case(g, "simulate 2 steps with --overwrite (stale vtk?)", ["simulate", str(m.base_rve), *SHORT, "-o", str(sfold), "-q", "--overwrite"],
               out=sfold, expect="ok", check=curve_check(0.03)))
    m.add(Case(g, "generate --overwrite into a simulate folder", [*gen, "-o", str(sfold), "--overwrite"], out=sfold, expect="either",
               check=lambda o, c: stale_outputs(c.out, ("curve.csv", "results.h5", "deformation.pvd"))))
    rfold = m.outs / "f_rve_home"
    m.add(Case(g, "generate an RVE folder", [*gen, "-o", str(rfold)], out=rfold, expect="ok"))
    m.add(Case(g, "simulate its rve.h5 into its own folder --overwrite", ["simulate", str(rfold / "rve.h5"), *SHORT, "-o", str(rfold),
               "-q", "--overwrite"], out=rfold, expect="either"))
    # a corrupt run.json
    jfold = m.outs / "f_bad_manifest"
    jfold.mkdir()
    (jfold / "run.json").write_text("{not json")
    m.add(Case(g, "folder with a corrupt run.json", [*gen, "-o", str(jfold)], names=("run.json",), codes=(2,), protect=(jfold,)))
    m.add(Case(g, "folder with a corrupt run.json, --overwrite", [*gen, "-o", str(jfold), "--overwrite"], out=jfold, expect="either",
               names=("run.json",), codes=(2,)))
    jfold2 = m.outs / "f_run_json_dir"
    (jfold2 / "run.json").mkdir(parents=True)
    m.add(Case(g, "run.json is a directory", [*gen, "-o", str(jfold2)], names=("run.json",), codes=(2,)))
    # -o "" and a refused run leaves no folder
    m.add(Case(g, "generate -o '' (empty)", [*gen, "-o", ""], names=("out", "-o", "folder"), codes=(2,), expect="either",
               protect=(m.inp,), note="an empty -o is the current folder"))
    gone = m.outs / "f_refused_leaves_nothing"
    m.add(Case(g, "a refused generate leaves no folder", ["generate", "--set", "rve.volume_fraction=1e-9", *TINY, "-o", str(gone), "-q"],
               names=("volume_fraction", "fibers"), out=gone, codes=(2,)))
    gone2 = m.outs / "f_refused_sim_leaves_nothing"
    m.add(Case(g, "a simulate refused after the claim leaves no folder",
               ["simulate", "plla", "--set", "rve.orientation={von_mises={kappa=700}}", "--set", "rve.max_deviation_deg=0",
                "--set", "rve.seeding=lines", "--set", "rve.size_ratio=25", "--set", "rve.layers=1", *SHORT, "-o", str(gone2), "-q"],
               names=("cross-link", "free", "volume_fraction"), out=gone2, codes=(2,), expect="either"))
    # symlinked output folder
    real = m.outs / "f_real"
    real.mkdir()
    (m.outs / "f_link").symlink_to(real)
    m.add(Case(g, "generate -o a symlink to a folder", [*gen, "-o", str(m.outs / "f_link")], out=m.outs / "f_link", expect="ok"))
    # properties into a simulate folder; study resume
    m.add(Case(g, "properties -o a simulate folder", ["properties", str(m.inp / "curves" / "good.csv"), "-o", str(sfold)],
               names=("f_stale",), codes=(2,), protect=(sfold,)))


def stale_outputs(folder: Path, names: tuple[str, ...]) -> list[str]:
    left = [n for n in names if (folder / n).exists()]
    return [f"--overwrite by generate left {', '.join(left)} of the earlier simulate run beside a new run.json"] if left else []


# --- (g) fuzz ----------------------------------------------------------------------------------------
DOC_KEYS = {
    "rve": ["diameter_um", "diameter_sd_um", "diameter_min_um", "volume_fraction", "size_ratio", "size_um", "segment_ratio",
            "segment_um", "max_deviation_deg", "layers", "orientation", "seeding", "merge_tolerance_ratio", "seed"],
    "fiber": ["taut_modulus_MPa", "slack_modulus_MPa", "flow_rate_per_s", "flow_resistance_MPa", "hardening_exponent"],
    "loading": ["test", "direction_deg", "lateral", "program", "max_strain", "strain_rate_per_s", "steps", "path_csv"],
    "solver": ["linear", "rtol", "atol", "max_iterations", "max_cuts", "time_rtol"],
    "output": ["stress_measure", "yield_threshold", "window_ratio", "figures", "vtk"],
}
WORDS = ["uniform", "border", "lines", "uniaxial", "equibiaxial", "pure_shear", "simple_shear", "path", "fixed", "free",
         "auto", "superlu", "pardiso", "off", "nominal", "paper", "", "nan", "1", "x" * 100, "\x00", "é", "plla"]


def random_value(rng: random.Random, depth: int = 0):
    kind = rng.random()
    if kind < 0.2:
        return rng.choice([0, 1, -1, 2, 3, 5, 15, 100, 1000, 1001, 2**31, 2**63 - 1, 2**63, 2**64, -2**63, 10**30])
    if kind < 0.45:
        return rng.choice([0.0, -0.0, 1e-300, 5e-324, 1e-9, 0.01, 0.19, 0.45, 0.5, 0.999, 1.0, 1.5, 5.0, 30.0, 89.999,
                           90.0, 179.999, 180.0, 700.0, 701.0, 1e3, 1e6, 1e300, 1.7976931348623157e308, -1.0, -1e300,
                           float("nan"), float("inf"), -float("inf"), rng.uniform(-10, 1000)])
    if kind < 0.6:
        return rng.choice(WORDS)
    if kind < 0.67:
        return rng.choice([True, False])
    if kind < 0.72:
        return rng.choice([dt.datetime(1979, 5, 27, 7, 32), dt.date(2000, 1, 1), dt.time(7, 32)])
    if kind < 0.85 and depth < 3:
        return [random_value(rng, depth + 1) for _ in range(rng.choice([0, 1, 2, 3, 5]))]
    if depth < 3:
        keys = rng.choice([["von_mises"], ["histogram"], ["poisson_ratio"], ["transverse_csv"], ["mean_deg", "kappa"],
                           ["edges_deg", "weights"], ["to_strain", "rate_per_s", "steps"], ["hold_s", "steps"], ["x"], []])
        out = {}
        for k in keys:
            if k in ("von_mises", "histogram"):
                out[k] = random_value(rng, depth + 1) if rng.random() < 0.3 else (
                    {"mean_deg": random_value(rng, 3), "kappa": random_value(rng, 3)} if k == "von_mises"
                    else {"edges_deg": [0.0, 90.0, 180.0] if rng.random() < 0.5 else random_value(rng, 2),
                          "weights": [1.0, 2.0] if rng.random() < 0.5 else random_value(rng, 2)})
            else:
                out[k] = random_value(rng, depth + 1)
        return out
    return None


def random_config(rng: random.Random) -> dict:
    data: dict = {}
    for _ in range(rng.randint(1, 6)):
        if rng.random() < 0.05:
            data[rng.choice(["foo", "RVE", "", "rve.layers"])] = random_value(rng)
            continue
        section = rng.choice(list(DOC_KEYS))
        key = rng.choice(DOC_KEYS[section]) if rng.random() < 0.95 else rng.choice(["foo", "Layers", "seed "])
        if rng.random() < 0.03:
            data[section] = random_value(rng)
            continue
        sec = data.setdefault(section, {})
        if not isinstance(sec, dict):
            continue
        if key == "program" and rng.random() < 0.6:
            sec[key] = [rng.choice([{"to_strain": random_value(rng, 3)}, {"hold_s": random_value(rng, 3), "steps": random_value(rng, 3)},
                                    {"to_strain": random_value(rng, 3), "rate_per_s": random_value(rng, 3), "steps": random_value(rng, 3)}])
                        for _ in range(rng.randint(0, 3))]
        elif key == "lateral" and rng.random() < 0.5:
            sec[key] = rng.choice([{"poisson_ratio": random_value(rng, 3)}, {"transverse_csv": random_value(rng, 3)}, "fixed", "free"])
        elif key == "orientation" and rng.random() < 0.5:
            sec[key] = random_value(rng, 1) if rng.random() < 0.2 else rng.choice([
                {"von_mises": {"mean_deg": random_value(rng, 3), "kappa": random_value(rng, 3)}},
                {"histogram": {"edges_deg": [random_value(rng, 3) for _ in range(3)], "weights": [random_value(rng, 3) for _ in range(2)]}}])
        else:
            sec[key] = random_value(rng)
    return data


def mutated_overrides(rng: random.Random) -> dict:
    """1-3 documented keys of the plla config set to plausible or random values (dotted)."""
    plausible = {
        "rve.layers": [1, 2, 3, 5.0, 0], "rve.volume_fraction": [0.05, 0.19, 0.3, 1e-9], "rve.size_ratio": [25.0, 30, 40.0, 4.0],
        "rve.size_um": [10.0, 13.5], "rve.segment_ratio": [2.0, 5, 29.0], "rve.segment_um": [1.0, 2.25],
        "rve.diameter_um": [0.3, 0.45, 1e-300], "rve.diameter_sd_um": [0.0, 0.1, 0.45], "rve.diameter_min_um": [0.01, 0.045],
        "rve.max_deviation_deg": [0.0, 5.0, 45, 89.9], "rve.seeding": ["border", "lines"], "rve.seed": [0, 1, 2**63 - 1],
        "rve.orientation": ["uniform", {"von_mises": {"mean_deg": 30.0, "kappa": 2.0}}, {"von_mises": {}},
                            {"histogram": {"edges_deg": [0.0, 90.0, 180.0], "weights": [1.0, 3.0]}}],
        "rve.orientation.von_mises.kappa": [0.0, 2.0, 700.0], "rve.orientation.von_mises.mean_deg": [0.0, 90.0],
        "rve.merge_tolerance_ratio": [0.001, 0.1], "fiber.taut_modulus_MPa": [3000.0, 1e6, 3.0],
        "fiber.slack_modulus_MPa": [3.0, 1e-6], "fiber.flow_rate_per_s": [0.0, 1e-8, 1e3], "fiber.flow_resistance_MPa": [5.0],
        "fiber.hardening_exponent": [0.0, 0.5, 100.0], "loading.test": ["uniaxial", "equibiaxial", "pure_shear", "simple_shear"],
        "loading.direction_deg": [0.0, 45.0, 179.9], "loading.lateral": ["fixed", "free", {"poisson_ratio": 0.3}],
        "loading.lateral.poisson_ratio": [0.3, -1.0, 50.0],
        "loading.program": [[{"to_strain": 0.03, "steps": 2}], [{"to_strain": 0.05}, {"hold_s": 10.0}, {"to_strain": 0.02}]],
        "loading.max_strain": [0.03, 0.3, -0.5], "loading.strain_rate_per_s": [5e-3, 1e3], "loading.steps": [1, 2, 30],
        "solver.linear": ["auto", "superlu"], "solver.rtol": [1e-6, 0.5], "solver.atol": [1e-8], "solver.max_iterations": [1, 200],
        "solver.max_cuts": [0, 12, 60], "solver.time_rtol": [1e-3, "off"], "output.stress_measure": ["nominal", "paper"],
        "output.yield_threshold": [1e-3], "output.window_ratio": [50.0, 1e6], "output.figures": [True, False], "output.vtk": [False],
    }
    keys = list(plausible)
    out = {}
    for _ in range(rng.randint(1, 3)):
        key = rng.choice(keys)
        out[key] = rng.choice(plausible[key]) if rng.random() < 0.8 else random_value(rng, 1)
    return out


def fuzz_configs(n: int, seed: int) -> tuple[Counter, list[dict]]:
    """Random configs: half random TOML-ish dicts through ``config_from_dict`` (or ``load_config``
    overrides), half plla mutations through three routes that must agree: ``load_config("plla",
    ov)`` (a preset or TOML with --set), ``apply_overrides(plla, ov)`` (a Config in Python) and
    ``apply_overrides(stored, ov)`` where ``stored`` is plla read back from its own TOML, as a
    saved RVE's config is (``espin simulate rve.h5 --set ...``). Counted: anything other than a
    ConfigError or a valid Config, a valid config that does not round-trip, and routes that
    disagree."""
    from espin.core.config import (
        apply_overrides,
        config_from_dict,
        config_to_toml,
        load_config,
    )
    from espin.core.errors import ConfigError

    rng = random.Random(seed)
    counts: Counter = Counter()
    bad: list[dict] = []
    plla = load_config("plla")
    stored = config_from_dict(tomllib.loads(config_to_toml(plla)))

    def note(kind: str, data, error: str, via: str) -> None:
        if sum(1 for b in bad if b["kind"] == kind) < 12:
            bad.append({"kind": kind, "data": repr(data)[:400], "error": error[:300], "via": via})

    def validated(cfg) -> list[str]:
        problems = []
        try:
            back = config_from_dict(tomllib.loads(config_to_toml(cfg)))
            if back != cfg:
                problems.append("config_to_toml does not round-trip")
        except Exception as err:  # noqa: BLE001
            problems.append(f"config_to_toml/readback fails: {type(err).__name__}: {str(err).splitlines()[0][:150]}")
        if any(isinstance(v, float) and not math.isfinite(v) for v in walk(cfg.model_dump())):
            problems.append("a non-finite value was accepted")
        r = cfg.rve
        if not (0 < r.diameter_min_um < r.diameter_um and r.diameter_sd_um <= r.diameter_um and r.side_um > r.segment_length_um):
            problems.append("rve invariants broken")
        return problems

    def attempt(fn):
        try:
            return fn(), None
        except ConfigError as err:
            return None, err
        except Exception as err:  # noqa: BLE001
            return None, err

    for i in range(n):
        if i % 2 == 0:
            data = random_config(rng)
            via_overrides = rng.random() < 0.3
            if via_overrides:
                flat = {}
                for sec, body in data.items():
                    if isinstance(body, dict):
                        for k, v in body.items():
                            flat[f"{sec}.{k}"] = v
                    else:
                        flat[str(sec)] = body
                cfg, err = attempt(lambda flat=flat: load_config("plla", flat))
                via = "load_config('plla', overrides)"
            else:
                cfg, err = attempt(lambda data=data: config_from_dict(data))
                via = "config_from_dict"
            if err is not None:
                if isinstance(err, ConfigError):
                    counts["ConfigError"] += 1
                else:
                    counts["other exception"] += 1
                    note(type(err).__name__, data, "".join(traceback.format_exception_only(type(err), err)).strip(), via)
                continue
            counts["valid"] += 1
            problems = validated(cfg)
            if problems:
                counts["valid but broken"] += 1
                note("valid but broken", data, "; ".join(problems), via)
            continue
        ov = mutated_overrides(rng)
        results = {
            "load_config('plla', ov)": attempt(lambda ov=ov: load_config("plla", ov)),
            "apply_overrides(plla, ov)": attempt(lambda ov=ov: apply_overrides(plla, ov)),
            "apply_overrides(stored plla, ov)": attempt(lambda ov=ov: apply_overrides(stored, ov)),
        }
        for via, (cfg, err) in results.items():
            if err is not None and not isinstance(err, ConfigError):
                counts["other exception"] += 1
                note(type(err).__name__, ov, "".join(traceback.format_exception_only(type(err), err)).strip(), via)
        ok = {via: cfg is not None for via, (cfg, err) in results.items()}
        if len(set(ok.values())) > 1:
            counts["routes disagree"] += 1
            refused = [v for v, good in ok.items() if not good]
            err = next(results[v][1] for v in refused)
            note("routes disagree", ov, f"valid through {', '.join(v for v, g in ok.items() if g)}; refused through "
                 f"{', '.join(refused)}: {str(err).splitlines()[-1].strip()}", "mutation of plla")
        elif all(ok.values()):
            counts["valid"] += 1
            cfgs = [cfg for cfg, _ in results.values()]
            if not (cfgs[0] == cfgs[1] == cfgs[2]):
                counts["routes disagree"] += 1
                note("routes disagree", ov, "the three routes give different configs", "mutation of plla")
            problems = validated(cfgs[0])
            if problems:
                counts["valid but broken"] += 1
                note("valid but broken", ov, "; ".join(problems), "load_config('plla', ov)")
        else:
            counts["ConfigError"] += 1
    return counts, bad


def walk(node):
    if isinstance(node, dict):
        for v in node.values():
            yield from walk(v)
    elif isinstance(node, (list, tuple)):
        for v in node:
            yield from walk(v)
    else:
        yield node


def group_g_mats(m: Matrix, n: int) -> None:
    g = "g"
    rng = m.rng
    tests = [("uniaxial", ["--lateral", "fixed"]), ("uniaxial", ["--lateral", "free"]),
             ("uniaxial", ["--set", "loading.lateral={poisson_ratio=0.3}"]), ("equibiaxial", []), ("pure_shear", []),
             ("simple_shear", [])]
    for i in range(n):
        size = rng.uniform(25, 40)
        layers = rng.randint(1, 3)
        vf = rng.uniform(0.1, 0.4)
        dev = rng.uniform(0, 45)
        seg = rng.uniform(2, 10)
        kappa = rng.choice([0, 0, rng.uniform(0, 10)])
        sd = rng.choice([0, rng.uniform(0, 0.5)]) * 0.45
        test, extra = rng.choice(tests)
        direction = rng.uniform(0, 179.9)
        strain = 0.03 if rng.random() < 0.85 else -0.03
        if test == "uniaxial" and strain < 0 and "free" in extra:
            strain = 0.03
        sets = ["--set", f"rve.size_ratio={size:.3f}", "--set", f"rve.layers={layers}", "--set", f"rve.volume_fraction={vf:.4f}",
                "--set", f"rve.max_deviation_deg={dev:.3f}", "--set", f"rve.segment_ratio={seg:.3f}",
                "--set", f"rve.diameter_sd_um={sd:.4f}", "--set", f"rve.seed={rng.randint(0, 2**40)}"]
        if kappa:
            sets += ["--set", f"rve.orientation={{von_mises={{mean_deg={rng.uniform(0, 179):.2f}, kappa={kappa:.3f}}}}}"]
        out = m.out("fuzzmat")
        argv = ["simulate", "plla", *sets, "--test", test, *extra, "--direction-deg", f"{direction:.2f}", "--max-strain",
                str(strain), "--steps", "2", "-o", str(out), "-q", "--no-figures" if False else "-q"]
        m.add(Case(g, f"random mat {i}: L/D {size:.0f}, {layers} layer(s), vf {vf:.2f}, {test} {' '.join(extra)} {strain:+}",
                   argv, out=out, expect="either", names=("rve.", "step", "strain", "volume_fraction", "cross-link"),
                   codes=(2, 4), check=curve_check(strain, tension=strain > 0 and test != "simple_shear"), quick=i < 4,
                   timeout=120))


# --- (k) kill / restart -------------------------------------------------------------------------------
@dataclass
class KillResult:
    name: str
    command: str
    killed_at: float
    cls: str
    why: str
    details: list[str] = field(default_factory=list)


def folder_consistency(folder: Path) -> tuple[str, list[str]]:
    """(status, problems) of a folder after a kill."""
    problems = []
    if not folder.exists():
        return "absent", []
    rj = folder / "run.json"
    files = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
    if not rj.exists():
        if files:
            problems.append(f"files without run.json: {files[:5]}")
        return "no manifest", problems
    try:
        man = json.loads(rj.read_text())
    except ValueError:
        return "bad manifest", ["run.json is not JSON"]
    status = man.get("status")
    for h5 in sorted(folder.rglob("*.h5")):
        try:
            with h5py.File(h5, "r") as f:
                rid = f.attrs.get("run_id")
        except OSError as err:
            problems.append(f"{h5.relative_to(folder)} unreadable ({str(err)[:80]})")
            continue
        if rid is not None and str(rid) != man.get("run_id"):
            problems.append(f"mixed: {h5.relative_to(folder)} run_id {str(rid)[:8]} != run.json {man.get('run_id', '')[:8]}")
    curve = folder / "curve.csv"
    if curve.exists():
        lines = curve.read_text("utf-8", errors="replace").split("\n")
        body = [ln for ln in lines[1:] if ln != ""]
        ncols = len(lines[0].split(","))
        for k, ln in enumerate(body):
            cells = ln.split(",")
            ok = len(cells) == ncols
            try:
                [float(c) for c in cells]
            except ValueError:
                ok = False
            last = k == len(body) - 1 and not curve.read_text().endswith("\n")
            if not ok and not last:
                problems.append(f"curve.csv line {k + 2} does not parse and is not the last")
    leftovers = [f for f in files if f.split("/")[-1].startswith(".") and f.endswith(".tmp")]
    if status == "complete":
        for need in ("curve.csv", "results.h5") if (folder / "curve.csv").exists() or man.get("command") == "simulate" else ():
            if not (folder / need).exists():
                problems.append(f"complete but no {need}")
    if leftovers and status == "complete":
        problems.append(f"temporary files left: {leftovers[:3]}")
    return str(status), problems


def kill_scenarios(m: Matrix, n: int, seed: int) -> list[KillResult]:
    rng = random.Random(seed)
    results: list[KillResult] = []
    cfg = m.f("kill/cfg.toml", "[rve]\nsize_ratio = 60.0\nlayers = 4\n[loading]\nmax_strain = 0.2\nsteps = 60\n"
                               "[output]\nfigures = false\n")
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1"}
    kinds = ["simulate_config", "simulate_rve", "overwrite_complete", "study"]
    durations: dict[str, float] = {}

    def command(kind: str, folder: Path) -> list[str]:
        if kind in ("simulate_config", "overwrite_complete"):
            return ["simulate", str(cfg), "-o", str(folder), "-q"]
        if kind == "simulate_rve":
            return ["simulate", str(m.base_rve), "--max-strain", "0.2", "--steps", "60", "-o", str(folder), "-q"]
        return ["study", "sweep", str(cfg), "--realizations", "4", "--set", "loading.steps=10", "--set",
                "loading.max_strain=0.1", "--workers", "2", "-o", str(folder), "-q"]

    for i in range(n):
        kind = kinds[i % 4]
        folder = m.outs / f"k{i:02d}_{kind}"
        if kind not in durations:  # a full run, timed: the kill falls within its duration
            scratch = m.outs / f"k_timing_{kind}"
            start = time.monotonic()
            r = subprocess.run([str(ESPIN), *command(kind, scratch)], capture_output=True, env=env, timeout=600, check=False)
            durations[kind] = time.monotonic() - start
            if r.returncode != 0:
                results.append(KillResult(kind, " ".join(command(kind, scratch)), 0, "traceback",
                                          f"the full run failed: {r.stderr[-300:]!r}"))
                continue
        argv = command(kind, folder)
        if kind == "overwrite_complete":
            r = subprocess.run([str(ESPIN), *argv], capture_output=True, env=env, timeout=600, check=False)
            if r.returncode != 0:
                results.append(KillResult(kind, " ".join(argv), 0, "traceback", f"setup run failed: {r.stderr[-300:]!r}"))
                continue
            argv = ["simulate", str(cfg), "--set", "loading.steps=61", "-o", str(folder), "-q", "--overwrite"]
        # mostly after the imports (about 1.5 s), when files are being written; sometimes before
        at = rng.uniform(0.2, 1.5) if rng.random() < 0.2 else rng.uniform(min(1.5, 0.5 * durations[kind]), 0.95 * durations[kind])
        proc = subprocess.Popen([str(ESPIN), *argv], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
        finished = False
        try:
            proc.wait(timeout=at)
            finished = True
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        status, problems = folder_consistency(folder)
        details = [f"killed at {at:.2f} s" if not finished else f"finished before {at:.2f} s (rc {proc.returncode})",
                   f"status after kill: {status}"]
        cls, why = "ok", ""
        if problems:
            cls, why = "data lost", "; ".join(problems[:3])
        if status in ("no manifest",) and problems:
            cls, why = "data lost", "; ".join(problems[:3])
        # the partial curve of a killed simulate is readable by espin properties (or refused clearly)
        if kind != "study" and (folder / "curve.csv").exists():
            po = run_inprocess(["properties", str(folder / "curve.csv"), "-o", str(m.outs / f"k{i:02d}_props")], 60)
            details.append(f"espin properties on the partial curve.csv: exit {po.code}"
                           + (f" ({error_lines(po.output)[0][:150]})" if error_lines(po.output) else ""))
            if po.code == 1 or po.exc_text or po.timed_out:
                cls, why = "traceback", f"espin properties on the killed run's curve.csv: {(po.exc_text.strip().splitlines() or [''])[-1]}"
        # rerun without --overwrite
        plain = [a for a in argv if a != "--overwrite"]
        snap = snapshot((folder,)) if folder.exists() else {}
        r = subprocess.run([str(ESPIN), *plain], capture_output=True, env=env, timeout=600, check=False)
        out = (r.stdout + r.stderr).decode("utf-8", "replace")
        if kind == "study":
            details.append(f"rerun (resume): rc {r.returncode}")
            st, pr = folder_consistency(folder)
            if r.returncode != 0 or "Traceback" in out:
                cls, why = ("traceback" if r.returncode == 1 or "Traceback" in out else cls), f"resume after kill: rc {r.returncode}: {out.strip().splitlines()[-1:] if out.strip() else ''}"
            elif st != "complete" or pr:
                cls, why = "data lost", f"resume left status {st}: {pr[:2]}"
            else:
                tables = sorted(folder.glob("*.csv"))
                details.append(f"tables after resume: {[t.name for t in tables]}")
                for t in tables:
                    cp = csv_problems(t)
                    if cp:
                        details.append(f"{t.name}: {cp[0]}")
        else:
            details.append(f"rerun without --overwrite: rc {r.returncode}")
            after = snapshot((folder,)) if folder.exists() else {}
            if status == "absent" and r.returncode == 0:
                details.append("nothing was written before the kill: the rerun ran")
            elif r.returncode == 1 or "Traceback" in out:
                cls, why = "traceback", f"rerun without --overwrite: {out.strip().splitlines()[-1:]}"
            elif r.returncode == 0:
                cls, why = "data lost", "rerun without --overwrite accepted a folder holding a killed run"
            elif r.returncode != 2 or "error:" not in out:
                cls, why = "vague error", f"rerun without --overwrite: rc {r.returncode}: {out.strip()[:200]}"
            elif after != snap:
                cls, why = "data lost", "the refused rerun changed the folder"
            # rerun with --overwrite
            r2 = subprocess.run([str(ESPIN), *plain, "--overwrite"], capture_output=True, env=env, timeout=600, check=False)
            out2 = (r2.stdout + r2.stderr).decode("utf-8", "replace")
            st2, pr2 = folder_consistency(folder)
            details.append(f"rerun with --overwrite: rc {r2.returncode}, status {st2}")
            if r2.returncode != 0:
                cls, why = ("traceback" if r2.returncode == 1 or "Traceback" in out2 else "vague error"), f"--overwrite rerun failed: {out2.strip()[-300:]}"
            elif st2 != "complete" or pr2:
                cls, why = "data lost", f"after --overwrite: status {st2} {pr2[:2]}"
            else:
                fp = folder_problems(folder, out2)
                if fp:
                    cls, why = "silent wrong", "; ".join(fp[:2])
        results.append(KillResult(f"kill {kind} #{i}", "espin " + " ".join(shlex.quote(a) for a in argv), at, cls, why, details))
    return results


# ---------------------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------------------
def run_case(case: Case, root: Path) -> None:
    if case.pre is not None:
        try:
            case.pre()
        except Exception as err:  # noqa: BLE001
            case.cls, case.why = "traceback", f"case setup failed: {type(err).__name__}: {err}"
            case.outcome = Outcome(None, traceback.format_exc(), 0.0)
            return
    existed = case.out.exists() if case.out is not None else True
    before = snapshot(tuple(case.protect)) | snapshot((root / "in",), deep=False)
    if case.subprocess:
        o = run_subprocess(case.argv, case.timeout, root)
    else:
        o = run_inprocess(case.argv, case.timeout)
    after = snapshot(tuple(case.protect)) | snapshot((root / "in",), deep=False)
    lost = []
    for k, v in before.items():
        if k not in after:
            lost.append(f"{k} removed")
        elif after[k] != v:
            lost.append(f"{k} changed")
    left = (not existed and case.out is not None and o.code in (2, 3) and (case.out.exists() or case.out.is_symlink()))
    case.outcome = o
    case.cls, case.why = classify(case, o, lost, left)


def first_lines(text: str, n: int = 6) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    if len(lines) > n:
        lines = lines[: n - 2] + ["..."] + lines[-2:]
    return "\n".join("      | " + ln[:220] for ln in lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a subset of every group")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder")
    ap.add_argument("--only", default="abcdefgk", help="groups to run, e.g. b,c")
    ap.add_argument("--seed", type=int, default=20261202)
    ap.add_argument("--fuzz", type=int, default=None, help="random configs through config_from_dict (default 3000; quick 300)")
    ap.add_argument("--mats", type=int, default=None, help="random tiny mats through simulate (default 30; quick 4)")
    ap.add_argument("--kills", type=int, default=None, help="kill/restart scenarios (default 10; quick 2)")
    ap.add_argument("--mem-gb", type=float, default=8.0,
                    help="address-space limit of this process and its children (RLIMIT_AS), so that a case that "
                         "allocates without bound fails with MemoryError instead of waking the OOM killer")
    ap.add_argument("--verbose", "-v", action="store_true", help="print each case as it runs")
    ap.add_argument("--json", type=Path, default=None, help="write every case and its class here")
    args = ap.parse_args()
    if args.json is not None:
        args.json = args.json.resolve()
    groups = set(args.only.replace(",", ""))
    if args.mem_gb > 0:
        import resource

        limit = int(args.mem_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    n_fuzz = args.fuzz if args.fuzz is not None else (300 if args.quick else 3000)
    n_mats = args.mats if args.mats is not None else (4 if args.quick else 30)
    n_kills = args.kills if args.kills is not None else (2 if args.quick else 10)

    root = Path(tempfile.mkdtemp(prefix="espin_bad_inputs_"))
    t0 = time.monotonic()
    os.chdir(root)
    print(f"espin bad-input matrix in {root} ({'quick' if args.quick else 'full'})", flush=True)
    import logging
    logging.getLogger("espin").setLevel(logging.WARNING)
    make_base(root)
    m = Matrix(root, args.quick, args.seed)
    builders = {"a": group_a, "b": group_b, "c": group_c, "d": group_d, "e": group_e, "f": group_f}
    # d's helper files are needed by a and f
    if groups & set("af") and "d" not in groups:
        (m.inp / "sem").mkdir(parents=True, exist_ok=True)
        write_synthetic_sem(m, m.inp / "sem" / "good.tif")
    if "f" in groups and "c" not in groups:
        m.f("curves/good.csv", bilinear_csv())
    for key in "abcdef":
        if key in groups:
            builders[key](m)
    if "g" in groups:
        group_g_mats(m, n_mats)
    cases = [c for c in m.cases if c.quick or not args.quick]
    print(f"{len(cases)} command-line cases", flush=True)
    for k, case in enumerate(cases):
        if args.verbose:
            print(f"[{case.group}] {case.name[:100]}", flush=True)
        run_case(case, root)
        if args.verbose:
            print(f"    -> {case.cls} ({case.outcome.seconds:.1f} s) {case.why[:150]}", flush=True)
            continue
        mark = "." if case.cls in ("clear error", "ok") else case.cls[0].upper()
        print(mark, end="" if (k + 1) % 80 else "\n", flush=True)
    print()
    fuzz_counts, fuzz_bad = (Counter(), [])
    if "g" in groups:
        print(f"fuzzing {n_fuzz} random configs through config_from_dict ...", flush=True)
        fuzz_counts, fuzz_bad = fuzz_configs(n_fuzz, args.seed)
    kills: list[KillResult] = []
    if "k" in groups and n_kills:
        print(f"{n_kills} kill/restart scenarios ...", flush=True)
        kills = kill_scenarios(m, n_kills, args.seed)
    elapsed = time.monotonic() - t0

    # ---- report
    table: dict[str, Counter] = defaultdict(Counter)
    for c in cases:
        table[c.group][c.cls] += 1
    for k in kills:
        table["k"][k.cls] += 1
    names = {"a": "config values, options, config files", "b": "damaged HDF5 (simulate X.h5)", "c": "curve CSV (properties)",
             "d": "SEM images (measure)", "e": "tables referenced by a config", "f": "output folders",
             "g": "random valid tiny mats (simulate)", "k": "kill / restart"}
    print("\n=== counts per group and class")
    header = f"{'group':<42}" + "".join(f"{c:>14}" for c in CLASSES) + f"{'total':>8}"
    print(header)
    total = Counter()
    for grp in sorted(table):
        row = table[grp]
        total.update(row)
        print(f"{grp} {names[grp]:<40}" + "".join(f"{row.get(c, 0):>14}" for c in CLASSES) + f"{sum(row.values()):>8}")
    print(f"{'all':<42}" + "".join(f"{total.get(c, 0):>14}" for c in CLASSES) + f"{sum(total.values()):>8}")
    if fuzz_counts:
        print(f"\nfuzz: {n_fuzz} random configs through config_from_dict / load_config overrides: "
              + ", ".join(f"{k} {v}" for k, v in sorted(fuzz_counts.items())))
    for cls in BAD:
        listed = [c for c in cases if c.cls == cls]
        if not listed:
            continue
        print(f"\n=== {cls}: {len(listed)}")
        for c in listed:
            o = c.outcome
            print(f"  [{c.group}] {c.name}: {c.why}")
            print(f"    $ {c.command[:400]}")
            text = (o.output + ("\n" + o.exc_text if o.exc_text else "")) if o else ""
            if text.strip():
                print(first_lines(text))
    if fuzz_bad:
        n_bad = sum(fuzz_counts.get(k, 0) for k in ("other exception", "valid but broken", "routes disagree"))
        print(f"\n=== fuzz: configs that raised something other than ConfigError, were accepted broken, or that "
              f"the routes treat differently: {n_bad} (distinct ones listed)")
        seen = set()
        for b in fuzz_bad:
            key = (b["kind"], b["error"][-90:])
            if key in seen:
                continue
            seen.add(key)
            print(f"  {b['kind']} via {b.get('via', 'config_from_dict')}: {b['error']}")
            print(f"    data: {b['data']}")
    if kills:
        print("\n=== kill / restart")
        for k in kills:
            print(f"  {k.name}: {k.cls}{': ' + k.why if k.why else ''}")
            print(f"    $ {k.command}")
            for d in k.details:
                print(f"      {d}")
    print(f"\n{sum(total.values())} cases + {n_fuzz if fuzz_counts else 0} fuzzed configs in {elapsed:.0f} s; folder {root}"
          + ("" if args.keep else " (removed)"))
    if args.json:
        payload = [{"group": c.group, "name": c.name, "class": c.cls, "why": c.why, "command": c.command,
                    "exit": c.outcome.code if c.outcome else None, "output": (c.outcome.output[:2000] if c.outcome else ""),
                    "exception": (c.outcome.exc_text[-3000:] if c.outcome else "")} for c in cases]
        payload += [{"group": "k", "name": k.name, "class": k.cls, "why": k.why, "command": k.command, "details": k.details}
                    for k in kills]
        payload += [{"group": "g-fuzz", **b} for b in fuzz_bad]
        args.json.write_text(json.dumps(payload, indent=1, default=str))
    os.chdir("/")
    if not args.keep:
        for p in root.rglob("*"):
            try:
                if p.is_dir() and not p.is_symlink():
                    p.chmod(0o755)
                elif p.is_file() and not p.is_symlink():
                    p.chmod(0o644)
            except OSError:
                pass
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
