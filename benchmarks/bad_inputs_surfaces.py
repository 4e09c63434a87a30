"""The bad-input matrix of the newest surfaces ([hardening 2]), in the style of bad_inputs.py.

Run:  python benchmarks/bad_inputs_surfaces.py            # every group (about 3 minutes on 2 cores)
      python benchmarks/bad_inputs_surfaces.py --only s,m  # some groups
      python benchmarks/bad_inputs_surfaces.py --json out.json --keep -v

Groups (each case through espin's command line, classified as in bad_inputs.py: clear error,
ok, vague error, refused valid, traceback, hang, silent wrong, data lost):

  s  surrogate samples given to ``espin specimen --model surrogate --surrogate-from``: another
     mat, another strain rate, a larger grip strain, edited stresses, cut, reordered, stripped
     of its header, binary, a folder, missing; the same file for its own mat, and another mat
     allowed knowingly
  m  specimen meshes and sizes: folds, repeated cells, two pieces, coincident but unmerged
     interface nodes, non-finite and huge coordinates, gauge marks off the specimen, empty and
     text files, line cells only, a huge --elements-across, non-finite --thickness
  i  SEM images with inverted contrast (dark fibers on a bright background), 8/16-bit, PNG, RGB,
     with and without --invert, --invert on a normal image
  x  ``espin example-data`` into another run's folder, onto a file, twice, with --overwrite, into
     a folder of the user's own files, into an unwritable folder
  t  status and exit codes: a study whose tasks all fail / some fail (under -q), a batch whose
     images all fail / some fail, another study into a study's folder, an interrupted specimen
  c  processes started at one instant on one new folder (2 and 4 sweeps, 2 and 4 specimens, two
     different sweeps, a sweep and a specimen): exactly one proceeds, the others exit 2 naming
     the reason, the winner's result whole

A case's extra invariants (``after``) are checked whatever its exit code: a run.json status, no
NaN in a summary, as many VTK steps as CSV rows. The shared base (a tiny mat's surrogate samples,
about a minute) is built first.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bad_inputs import BAD, CLASSES, ESPIN, Case, Matrix, Outcome, first_lines, run_case  # noqa: E402

TINY = ["--set", "rve.size_ratio=30", "--set", "rve.layers=2"]
STRIP = ["--shape", "strip", "--elements-across", "1", "--max-strain", "0.05", "--steps", "2"]
ELASTIC = ["--model", "neo_hookean", "--modulus", "200", "--poisson", "0.3", "--steps", "2", "--max-strain", "0.02"]
SURROGATE = ["specimen", "plla", "--model", "surrogate", *TINY, *STRIP, "-q"]
AFTER: dict[int, object] = {}
"""Extra invariants of a case (by id), checked whatever its exit code: a list of problems."""


def status_is(folder: Path, *statuses: str):
    def check(o: Outcome, case: Case) -> list[str]:
        try:
            status = json.loads((folder / "run.json").read_text())["status"]
        except (OSError, ValueError, KeyError):
            return [f"no readable {folder}/run.json"]
        return [] if status in statuses else [f"run.json says {status!r} (expected {' or '.join(statuses)})"]
    return check


def no_nan(path: Path):
    def check(o: Outcome, case: Case) -> list[str]:
        return [f"{path.name} holds nan"] if path.is_file() and "nan" in path.read_text().lower() else []
    return check


def force_of(folder: Path) -> float:
    rows = (folder / "force_displacement.csv").read_text().strip().splitlines()
    return float(rows[-1].split(",")[4])


def add(m: Matrix, case: Case, after=None) -> Case:
    m.add(case)
    if after is not None:
        AFTER[id(case)] = after
    return case


# --- base ---------------------------------------------------------------------------------------
def make_samples(root: Path) -> tuple[Path, float]:
    from typer.testing import CliRunner

    from espin.cli import app

    out = root / "base" / "surrogate"
    res = CliRunner().invoke(app, [*SURROGATE, "-o", str(out)])
    if res.exit_code != 0:
        sys.exit(f"cannot build the base surrogate: {res.output}")
    return out / "surrogate_samples.csv", force_of(out)


# --- (s) surrogate samples ------------------------------------------------------------------------
def group_s(m: Matrix, samples: Path, force: float) -> None:
    g = "s"
    text = samples.read_text()
    lines = text.splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))

    def scaled(factor: float) -> str:
        out = lines[:head + 1]
        for line in lines[head + 1:]:
            v = line.rstrip("\n").split(",")
            cols = (5, 6, 7) if len(v) == 10 else (4, 5, 6)
            for c in cols:
                v[c] = repr(factor * float(v[c]))
            out.append(",".join(v) + "\n")
        return "".join(out)

    def same_force(o: Outcome, case: Case) -> list[str]:
        got = force_of(case.out)
        return [] if abs(got - force) <= 1e-9 * abs(force) else [f"force {got:.6g} N, the samples' mat gives {force:.6g} N"]

    def spec(tag: str, path: Path | str, *extra: str, expect: str = "error", names=("surrogate", ), check=None,
             quick: bool = True) -> None:
        out = m.out(tag)
        add(m, Case(g, tag, [*SURROGATE, "--surrogate-from", str(path), *extra, "-o", str(out)], names=names,
                    expect=expect, out=out, check=check, quick=quick, protect=(samples,)))

    spec("own samples, own mat", samples, expect="ok", check=same_force)
    spec("another fiber law", samples, "--set", "fiber.taut_modulus_MPa=4000", names=("fiber law", "surrogate_from"))
    spec("another seed (another mat)", samples, "--set", "rve.seed=2", names=("another mat",))
    spec("another strain rate", samples, "--set", "loading.strain_rate_per_s=0.01", names=("strain rate",))
    spec("a larger grip strain than built for", samples, "--max-strain", "0.2", names=("grip strain",))
    spec("another mat allowed knowingly", samples, "--set", "fiber.taut_modulus_MPa=4000", "--allow-surrogate-mismatch",
         expect="ok")
    spec("every stress x100", m.f("samples/x100.csv", scaled(100.0)), names=("x100.csv",))
    spec("every stress x1.0001", m.f("samples/x1.0001.csv", scaled(1.0001)), names=("x1.0001.csv",))
    spec("cut after 40 rows", m.f("samples/cut.csv", "".join(lines[:head + 41])), names=("cut.csv",))
    spec("cut mid-line", m.f("samples/cut_mid.csv", text[: len(text) // 2]), names=("cut_mid.csv",))
    body = lines[head + 1:]
    spec("rows reordered", m.f("samples/reordered.csv", "".join(lines[:head + 1] + body[::-1])),
         names=("reordered.csv",))
    spec("two rows swapped", m.f("samples/swapped.csv", "".join(lines[:head + 1] + body[1:2] + body[:1] + body[2:])),
         names=("swapped.csv",))
    spec("no header (an old file)", m.f("samples/old.csv", "".join(lines[head:])), names=("old.csv",))
    spec("header but no checksum", m.f("samples/nosum.csv", "".join(line for line in lines
                                                                    if not line.startswith("# data_sha256"))),
         names=("nosum.csv",))
    spec("binary", m.f("samples/binary.csv", bytes(range(256)) * 10), names=("binary.csv",))
    spec("a folder", m.inp, names=(str(m.inp),))
    spec("missing", m.inp / "samples" / "missing.csv", names=("missing.csv",))
    spec("a specimen.json", samples.parent / "specimen.json", names=("specimen.json",))
    spec("NaN stress", m.f("samples/nan.csv", text.replace(lines[head + 3].split(",")[5], "nan", 1)),
         names=("nan.csv",))


# --- (m) meshes ---------------------------------------------------------------------------------------
def group_m(m: Matrix) -> None:
    import meshio

    from espin.specimen.shapes import strip

    g = "m"
    plate = strip(20.0, 5.0, elements_across=2).mesh
    p, t = plate.p.T.copy(), plate.t.T.copy()

    def mesh(name: str, points: np.ndarray, cells: np.ndarray, kind: str = "quad") -> Path:
        path = m.inp / "meshes" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        meshio.write(path, meshio.Mesh(np.column_stack([points, np.zeros(len(points))]), [(kind, cells)]))
        return path

    def positive_force(o: Outcome, case: Case) -> list[str]:
        got = force_of(case.out)
        return [] if got > 1e-3 else [f"force {got:.3g} N: the pieces carry nothing"]

    def spec(tag: str, shape: str | Path, *extra: str, expect: str = "error", names=("specimen mesh",), check=None):
        out = m.out(tag)
        add(m, Case(g, tag, ["specimen", "--shape", str(shape), *ELASTIC, *extra, "-q", "-o", str(out)],
                    names=names, expect=expect, out=out, check=check, quick=True))

    spec("a valid mesh", mesh("valid.vtu", p, t), expect="ok", check=positive_force)
    folded = p.copy()
    inner = np.flatnonzero((p[:, 0] > p[:, 0].min()) & (p[:, 0] < p[:, 0].max()) & (p[:, 1] > p[:, 1].min())
                           & (p[:, 1] < p[:, 1].max()))[0]
    folded[inner, 0] += 8.0
    spec("a fold", mesh("fold.vtu", folded, t), names=("fold", "overlap"))
    spec("a repeated cell", mesh("twice.vtu", p, np.vstack([t, t[:1]])), names=("repeat",))
    spec("a repeated cell reversed", mesh("twice_rev.vtu", p, np.vstack([t, t[:1, ::-1]])), names=("repeat",))
    spec("two pieces apart", mesh("two.vtu", np.vstack([p, p + [30.0, 0.0]]), np.vstack([t, t + len(p)])),
         names=("pieces",))
    right = p[:, 0] >= p[:, 0].mean()
    copy = np.flatnonzero(right)
    renumber = np.arange(len(p))
    renumber[copy] = len(p) + np.arange(len(copy))
    cells = np.where(np.all(right[t], axis=1)[:, None], renumber[t], t)
    spec("two halves, coincident nodes not merged", mesh("halves.vtu", np.vstack([p, p[copy]]), cells),
         expect="ok", check=positive_force)
    bad = p.copy()
    bad[2, 0] = np.inf
    spec("an inf coordinate", mesh("inf.vtu", bad, t), names=("non-finite",))
    bad = p.copy()
    bad[2, 1] = np.nan
    spec("a NaN coordinate", mesh("nan.vtu", bad, t), names=("non-finite",))
    spec("coordinates in nm (x1e6)", mesh("nm.vtu", p * 1e6, t), names=("beyond",))
    spec("a 1e300 coordinate", mesh("huge.vtu", np.where(np.arange(len(p))[:, None] == 3, 1e300, p), t),
         names=("beyond", "non-finite"))
    three = strip(20.0, 5.0, elements_across=3).mesh
    centre = three.p[:, three.t].mean(axis=1)
    slot = (centre[0] > three.p[0].max() - 20.0 / 12) & (np.abs(centre[1]) < 1.0)  # the middle cell at the right end
    spec("gauge mark off the specimen (a slot at the grip on the centre line)",
         mesh("slot.vtu", three.p.T, three.t.T[~slot]), names=("gauge mark",))
    (m.inp / "meshes" / "empty.vtu").write_bytes(b"")
    spec("an empty .vtu", m.inp / "meshes" / "empty.vtu", names=("empty",))
    (m.inp / "meshes" / "text.msh").write_text("hello\n")
    spec("a text file as .msh", m.inp / "meshes" / "text.msh", names=("text.msh",))
    spec("line cells only", mesh("lines.vtu", p, np.column_stack([np.arange(3), np.arange(1, 4)]), "line"),
         names=("triangle",))
    spec("--elements-across 10000", "strip", "--elements-across", "10000", names=("elements_across", "memory"))
    spec("--elements-across 0", "strip", "--elements-across", "0", names=("elements_across",))
    spec("--thickness inf", "strip", "--thickness", "inf", names=("thickness",))
    spec("--thickness nan", "strip", "--thickness", "nan", names=("thickness",))


# --- (i) images ----------------------------------------------------------------------------------------
def group_i(m: Matrix) -> None:
    import tifffile
    from PIL import Image

    from espin.datasets import sem_image
    from espin.imaging.image import read_image

    g = "i"
    d = m.inp / "polarity"
    d.mkdir(parents=True, exist_ok=True)
    grey = read_image(sem_image(d / "normal.tif"))
    u8 = np.round(255.0 * grey / grey.max()).astype(np.uint8)
    dark = 255 - u8
    tifffile.imwrite(d / "dark.tif", dark)
    tifffile.imwrite(d / "dark16.tif", (dark.astype(np.uint16) * 257))
    Image.fromarray(dark).save(d / "dark.png")
    tifffile.imwrite(d / "dark_rgb.tif", np.stack([dark] * 3, axis=-1))
    tifffile.imwrite(d / "dark_float.tif", (1.0 - grey / grey.max()).astype(np.float32))

    def diameter(o: Outcome, case: Case) -> list[str]:
        import csv

        with open(case.out / "fibers.csv") as fh:
            ds = [float(r["diameter_um"]) for r in csv.DictReader(fh) if r.get("diameter_um")]
        med = float(np.median(ds)) if ds else float("nan")
        return [] if 0.3 < med < 0.7 else [f"median diameter {med:.3g} um, the image has about 0.47 um"]

    def spec(tag: str, image: Path, *extra: str, expect: str = "error", names=("--invert",), check=None):
        out = m.out(tag)
        add(m, Case(g, tag, ["measure", str(image), "--um-per-px", "0.05", "--no-figures", *extra, "-q", "-o",
                             str(out)], names=names, expect=expect, out=out, check=check, quick=True))

    spec("normal image", d / "normal.tif", expect="ok", check=diameter)
    for name in ("dark.tif", "dark16.tif", "dark.png", "dark_rgb.tif", "dark_float.tif"):
        spec(f"inverted {name}", d / name, names=("--invert", name))
    spec("inverted, --invert", d / "dark.tif", "--invert", expect="ok", check=diameter)
    spec("inverted 16-bit, --invert", d / "dark16.tif", "--invert", expect="ok", check=diameter)
    spec("normal, --invert", d / "normal.tif", "--invert", names=("leave out --invert",))


# --- (x) example-data ------------------------------------------------------------------------------------
def group_x(m: Matrix) -> None:
    g = "x"
    sim = m.outs / "x_simulate_run"
    sim.mkdir()
    (sim / "run.json").write_text(json.dumps({"run_id": "a", "command": "simulate", "config_hash": "", "espin_version": "0",
                                              "status": "complete", "started_utc": "t", "outputs": ["curve.csv"]}))
    (sim / "curve.csv").write_text("strain,stress_MPa\n0,0\n0.1,1\n")
    afile = m.f("x_a_file.txt", "mine")
    twice = m.outs / "x_twice"
    mine = m.outs / "x_mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("my notes")
    locked = m.outs / "x_locked"
    locked.mkdir()

    def with_manifest(folder: Path):
        def check(o: Outcome, case: Case) -> list[str]:
            return status_is(folder, "complete")(o, case) + (
                [] if (folder / "mat.tif").is_file() else ["no mat.tif"])
        return check

    def spec(tag, out: Path, *extra, expect="error", names=(), check=None, protect=(), pre=None):
        add(m, Case(g, tag, ["example-data", "-o", str(out), *extra], names=names or (str(out),), expect=expect,
                    check=check, protect=protect, quick=True, pre=pre))

    spec("into another run's folder", sim, names=("another simulate run",), protect=(sim,))
    spec("onto a file", afile, names=("not a folder",), protect=(afile,))
    spec("first time", twice, expect="ok", check=with_manifest(twice))
    spec("second time", twice, names=("--overwrite",))
    spec("second time, --overwrite", twice, "--overwrite", expect="ok", check=with_manifest(twice))
    spec("into a folder of the user's files", mine, expect="ok", check=with_manifest(mine),
         protect=(mine / "notes.txt",))
    spec("into another run's folder, --overwrite keeps its other files", sim, "--overwrite", expect="ok",
         check=with_manifest(sim))
    if os.geteuid() != 0:
        spec("into an unwritable folder", locked, names=("x_locked",), pre=lambda: locked.chmod(0o500))


# --- (t) status ------------------------------------------------------------------------------------------
def group_t(m: Matrix) -> None:
    from espin.datasets import sem_image

    g = "t"
    fail = ["--set", "solver.max_iterations=1", "--set", "solver.max_cuts=0"]
    study = ["study", "sweep", *TINY, "--set", "loading.max_strain=0.02", "--set", "loading.steps=2",
             "--realizations", "1", "-q"]

    def failed_listed(o: Outcome, case: Case) -> list[str]:
        return [] if "failed" in o.output and "task(s) failed" in o.output else ["no failure printed under -q"]

    out = m.out("study_all_fail")
    add(m, Case(g, "study: every task fails, -q", [*study, *fail, "-o", str(out)], names=("failed",), out=out,
                quick=True), after=lambda o, c, out=out: status_is(out, "failed")(o, c) + failed_listed(o, c))
    out = m.out("study_some_fail")
    add(m, Case(g, "study: one of two tasks fails, -q", [*study, "--set", "solver.max_cuts=0", "--grid",
                                                        "solver.max_iterations=1,50", "-o", str(out)],
                names=("failed",), out=out, quick=True),
        after=lambda o, c, out=out: status_is(out, "partial")(o, c) + failed_listed(o, c))
    other = m.out("study_other")
    add(m, Case(g, "study: a first sweep", [*study, "--grid", "fiber.slack_modulus_MPa=3", "-o", str(other)],
                expect="ok", out=other, quick=True))
    add(m, Case(g, "study: another sweep into its folder", [*study, "--grid", "fiber.taut_modulus_MPa=2000",
                                                           "-o", str(other)], names=("another study",),
                protect=(other / "results.csv",), quick=True))
    images = m.inp / "status_images"
    images.mkdir()
    (images / "a.tif").write_bytes(b"not an image")
    (images / "b.png").write_bytes(b"nor this")
    out = m.out("batch_all_fail")
    add(m, Case(g, "batch: every image fails", ["measure", str(images), "--um-per-px", "0.05", "-q", "-o", str(out)],
                names=("images",), quick=True), after=status_is(out, "failed"))
    mixed = m.inp / "status_mixed"
    mixed.mkdir()
    (mixed / "a.tif").write_bytes(b"not an image")
    sem_image(mixed / "c.tif")
    out = m.out("batch_one_ok")
    add(m, Case(g, "batch: one of two images fails", ["measure", str(mixed), "--um-per-px", "0.05", "--no-figures",
                                                     "-q", "-o", str(out)], expect="ok", quick=True),
        after=lambda o, c, out=out: status_is(out, "partial")(o, c) + no_nan(out / "pooled.toml")(o, c))


def concurrent_claims(m: Matrix) -> list[Case]:
    """Processes forked at one instant onto one new folder (bench_concurrent_claims.py): exactly
    one proceeds, the others exit 2 naming the reason, the winner's result whole."""
    from bench_concurrent_claims import COMMANDS, REASONS, folder_problems, run_round

    def sweep_of(key: str):
        return lambda out: ["study", "sweep", *TINY, "--set", "loading.max_strain=0.02", "--set", "loading.steps=2",
                            "--grid", key, "--realizations", "1", "-q", "-o", str(out)]

    rounds = [("2 sweeps", "sweep", [COMMANDS["sweep"]] * 2), ("4 sweeps", "sweep", [COMMANDS["sweep"]] * 4),
              ("2 specimens", "specimen", [COMMANDS["specimen"]] * 2),
              ("4 specimens", "specimen", [COMMANDS["specimen"]] * 4),
              ("2 different sweeps", None, [sweep_of("fiber.slack_modulus_MPa=3"),
                                            sweep_of("fiber.taut_modulus_MPa=2000")]),
              ("a sweep and a specimen", None, [COMMANDS["sweep"], COMMANDS["specimen"]])]
    cases = []
    for name, command, makers in rounds:
        out = m.out("claim")
        out.parent.mkdir(parents=True, exist_ok=True)
        logs = m.outs / f"{out.name}_logs"
        logs.mkdir()
        codes, outputs = run_round([make(out) for make in makers], logs)
        case = Case("c", f"{name} started at once on one new folder", makers[0](out), quick=True)
        problems = []
        winners = [k for k, c in enumerate(codes) if c == 0]
        if len(winners) != 1:
            problems.append(f"{len(winners)} proceeded (exit codes {codes})")
        for code, text in zip(codes, outputs):
            if code != 0 and (code != 2 or not any(r in text for r in REASONS)):
                problems.append(f"exit {code} without the reason: {text.strip().splitlines()[-1:]}")
        if command is not None and len(winners) == 1:
            problems += folder_problems(command, out)
        traced = any("Traceback" in text for text in outputs)
        case.outcome = Outcome(codes[0], "\n".join(outputs), 0.0)
        case.cls, case.why = (("traceback", "a traceback") if traced else ("data lost", "; ".join(problems))
                              if problems else ("clear error", ""))
        cases.append(case)
    return cases


def interrupted_specimens(m: Matrix, n: int) -> list[Case]:
    """``espin specimen`` interrupted (SIGINT) at a random time: the CSV and VTK series hold the same
    steps and run.json says failed."""
    cases = []
    for k in range(n):
        out = m.out(f"interrupt_{k}")
        argv = ["specimen", "--shape", "strip", *ELASTIC[:-4], "--steps", "40", "--max-strain", "0.1",
                "--elements-across", "8", "-o", str(out)]
        proc = subprocess.Popen([str(ESPIN), *argv], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True)
        time.sleep(2.5 + 0.7 * k)
        proc.send_signal(signal.SIGINT)
        text = proc.communicate(timeout=60)[0].decode("utf-8", "replace")
        case = Case("t", f"specimen interrupted after {2.5 + 0.7 * k:.1f} s", argv, quick=True)
        problems = []
        csv = out / "force_displacement.csv"
        rows = len(csv.read_text().strip().splitlines()) - 1 if csv.is_file() else 0
        vtk = len(list((out / "vtk").glob("step_*.vtu"))) if (out / "vtk").is_dir() else 0
        if rows != vtk:
            problems.append(f"{rows} CSV rows, {vtk} VTK steps")
        if "Traceback" in text:
            problems.append("traceback")
        if out.is_dir() and json.loads((out / "run.json").read_text())["status"] == "complete" and rows < 41:
            problems.append("run.json complete after an interruption")
        case.outcome = Outcome(proc.returncode, text, 0.0)
        case.cls, case.why = (("data lost", "; ".join(problems)) if problems else ("clear error", ""))
        cases.append(case)
    return cases


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="smixtc", help="groups to run, e.g. s,m")
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--interrupts", type=int, default=4)
    ap.add_argument("--verbose", "-v", action="store_true")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--mem-gb", type=float, default=4.0,
                    help="address-space limit of this process and its children (RLIMIT_AS): a case that allocates "
                         "without bound fails with MemoryError instead of waking the OOM killer")
    args = ap.parse_args()
    if args.mem_gb > 0:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (int(args.mem_gb * 2**30),) * 2)
    groups = set(args.only.replace(",", ""))
    root = Path(tempfile.mkdtemp(prefix="espin_bad_surfaces_"))
    t0 = time.monotonic()
    os.chdir(root)
    import logging
    logging.getLogger("espin").setLevel(logging.WARNING)
    print(f"espin bad-input matrix of the new surfaces in {root}", flush=True)
    m = Matrix(root, False, 20261204)
    if "s" in groups:
        samples, force = make_samples(root)
        group_s(m, samples, force)
    for key, build in {"m": group_m, "i": group_i, "x": group_x, "t": group_t}.items():
        if key in groups:
            build(m)
    for case in m.cases:
        if args.verbose:
            print(f"[{case.group}] {case.name}", flush=True)
        run_case(case, root)
        after = AFTER.get(id(case))
        if after is not None and case.cls in ("clear error", "ok"):
            problems = after(case.outcome, case)
            if problems:
                case.cls, case.why = "silent wrong", "; ".join(problems)
        if args.verbose:
            print(f"    -> {case.cls} ({case.outcome.seconds:.1f} s) {case.why[:150]}", flush=True)
    cases = list(m.cases)
    if "c" in groups:
        cases += concurrent_claims(m)
    if "t" in groups and args.interrupts:
        cases += interrupted_specimens(m, args.interrupts)
    table: dict[str, Counter] = defaultdict(Counter)
    for c in cases:
        table[c.group][c.cls] += 1
    names = {"s": "surrogate samples (--surrogate-from)", "m": "specimen meshes and sizes",
             "i": "inverted SEM images (measure)", "x": "example-data folders", "t": "status and exit codes",
             "c": "runs claiming one new folder at once"}
    print("\n=== counts per group and class")
    print(f"{'group':<42}" + "".join(f"{c:>14}" for c in CLASSES) + f"{'total':>8}")
    total = Counter()
    for grp in sorted(table):
        row = table[grp]
        total.update(row)
        print(f"{grp} {names[grp]:<40}" + "".join(f"{row.get(c, 0):>14}" for c in CLASSES) + f"{sum(row.values()):>8}")
    print(f"{'all':<42}" + "".join(f"{total.get(c, 0):>14}" for c in CLASSES) + f"{sum(total.values()):>8}")
    for cls in BAD:
        listed = [c for c in cases if c.cls == cls]
        if listed:
            print(f"\n=== {cls}: {len(listed)}")
            for c in listed:
                print(f"  [{c.group}] {c.name}: {c.why}")
                print(f"    $ {c.command[:300]}")
                o = c.outcome
                text = (o.output + ("\n" + o.exc_text if o.exc_text else "")) if o else ""
                if text.strip():
                    print(first_lines(text))
    print(f"\n{sum(total.values())} cases in {time.monotonic() - t0:.0f} s; folder {root}"
          + ("" if args.keep else " (removed)"))
    if args.json:
        args.json.write_text(json.dumps([{"group": c.group, "name": c.name, "class": c.cls, "why": c.why,
                                          "command": c.command} for c in cases], indent=1))
    os.chdir("/")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
