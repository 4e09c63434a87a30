"""README.md runs as written: its commands and Python blocks, in README order, in one folder.

A user follows the README top to bottom in one working directory, so every command here sees
the files of the commands before it, and one Python session runs the Python blocks (the second
uses ``result`` from the first). The package is already installed (CI installs it exactly as
the README says), so the install steps are not repeated. Commands that are heavy at full size
run at small sizes: ``RUNS`` says, for every README command, how this test runs it (as written,
with arguments added, or skipped with a reason), and the test fails when the README gains a
command that ``RUNS`` does not cover, when a run drops or changes a README argument instead of
adding one, when more than three lines are marked ``# long`` or a long line does not say how
long it takes. Each command must exit 0 and leave the files the README promises; at the end,
every output folder still holds its own run (the README order loses no output).

Two more kinds of added arguments keep the run short without skipping a code path the README
shows: ``simulate`` runs whose figures the README does not list draw none (``NO_FIGURES``:
``plla_test`` draws and checks every figure of the same command, tests/test_figures.py each
figure), and the commands that start a pool of worker processes by default run on one worker
(``SERIAL``: at these sizes starting the workers, each importing espin, took longer than the
tests they ran; the ``holed`` surrogate keeps its ``--workers 2``, so the pool path runs here).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
README = ROOT / "README.md"

AS_WRITTEN = "as written"

# Small sizes: a plla RVE with L/D 40 and 3 layers (about 3 s to pull to 30 %).
SMALL = "--set rve.size_ratio=40 --set rve.layers=3"
TINY = "--set rve.size_ratio=30 --set rve.layers=2"
SHORT = "--set loading.max_strain=0.05 --set loading.steps=5"
NO_FIGURES = "--set output.figures=false"
SERIAL = "--workers 1"


@dataclass(frozen=True)
class Skip:
    """A README command this test does not run, and why."""

    reason: str


@dataclass(frozen=True)
class Run:
    """How the test runs a README command, and the files it must leave.

    ``command`` is AS_WRITTEN or the README command with arguments added (checked: a run may
    only drop the install steps and append arguments, the last of a repeated option wins).
    ``outputs``: paths (globs) relative to the working directory; ``folders``: output folders
    whose run.json must name ``subcommand`` (the espin command that wrote them).
    """

    command: str = AS_WRITTEN
    outputs: tuple[str, ...] = ()
    folders: dict[str, str] = field(default_factory=dict)


RVE_FILES = ("rve.h5", "config.toml", "statistics.json", "statistics.txt", "mat.png",
             "statistics.png", "fibers.vtu", "network.vtu")


def _in(folder: str, names: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(f"{folder}/{name}" for name in names)


# Every README command (continuation lines joined, comment removed) -> how the test runs it.
RUNS: dict[str, Run | Skip] = {
    # Two commands: the package is installed already; the plla test at L/D 40, 3 layers.
    "python3 -m venv env && . env/bin/activate && pip install . && espin simulate plla --out plla_test":
        Run(f"espin simulate plla --out plla_test {SMALL}",
            folders={"plla_test": "simulate"}),  # its files: the README paragraph (PLLA_TEST_FILES)
    'pip install ".[test]" && python -m pytest -q':
        Skip("the test suite itself (this test is part of it); CI runs the install and this command"),
    "ESPIN_TUTORIAL_QUICK=1 mkdocs build --strict":
        Skip("tests/docs/test_docs_site.py builds the site the same way (quick tutorials, --strict, offline)"),
    # Use
    "espin generate plla --size-ratio 100 --layers 5 --seed 3 -o small_rve":
        Run(outputs=_in("small_rve", RVE_FILES), folders={"small_rve": "generate"}),
    "espin simulate small_rve/rve.h5 --max-strain 0.1 --steps 10 -o small_test":
        Run(f"espin simulate small_rve/rve.h5 --max-strain 0.1 --steps 10 -o small_test {NO_FIGURES}",
            outputs=("small_test/curve.csv", "small_test/results.h5"), folders={"small_test": "simulate"}),
    "espin simulate plla --set rve.size_ratio=100 --set rve.layers=5 --direction-deg 45 -o small_45deg":
        Run(f"espin simulate plla --set rve.size_ratio=100 --set rve.layers=5 --direction-deg 45 -o small_45deg "
            f"{SMALL} {NO_FIGURES}",
            outputs=("small_45deg/curve.csv",), folders={"small_45deg": "simulate"}),
    "espin simulate plla --test equibiaxial --max-strain 0.05 --set loading.steps=5 -o plla_equibiaxial":
        Run(f"espin simulate plla --test equibiaxial --max-strain 0.05 --set loading.steps=5 -o plla_equibiaxial {SMALL} "
            f"{NO_FIGURES}",
            outputs=("plla_equibiaxial/curve.csv",), folders={"plla_equibiaxial": "simulate"}),
    "espin config plla > my_mat.toml":
        Run(outputs=("my_mat.toml",)),
    "espin simulate my_mat.toml":
        Run(f"espin simulate my_mat.toml {SMALL} {NO_FIGURES}", outputs=("my_mat_test/curve.csv",),
            folders={"my_mat_test": "simulate"}),
    "espin generate --set 'rve.orientation={von_mises={mean_deg=0, kappa=2}}' --set rve.max_deviation_deg=20 -o aligned_rve":
        Run(outputs=_in("aligned_rve", RVE_FILES), folders={"aligned_rve": "generate"}),
    "espin simulate plla-bonded --set rve.size_ratio=100 --set rve.layers=5 --max-strain 0.1 --steps 10 "
    "-o bonded_free":  # 15 s as written
        Run("espin simulate plla-bonded --set rve.size_ratio=100 --set rve.layers=5 --max-strain 0.1 --steps 10 "
            f"-o bonded_free --max-strain 0.02 --steps 2 {SMALL} {NO_FIGURES}",
            outputs=("bonded_free/curve.csv",), folders={"bonded_free": "simulate"}),
    # From SEM images to a virtual mat
    "espin example-data":
        Run(outputs=("mat.tif", "spec1.csv", "spec2.csv", "spec3.csv")),
    "espin measure mat.tif -o measured":
        Run(outputs=_in("measured", ("fibers.csv", "measurement.toml", "histograms.png", "overlay.png",
                                     "orientation_map.png")),
            folders={"measured": "measure"}),
    "espin calibrate-geometry measured -o sem_mat.toml":  # about 80 s as written
        Run("espin calibrate-geometry measured -o sem_mat.toml --seeds 1 --no-rendered-check --walk paper",
            outputs=("sem_mat.toml", "sem_mat.calibration.json")),
    "espin generate sem_mat.toml && espin simulate sem_mat.toml":
        Run(f"espin generate sem_mat.toml {SMALL} && espin simulate sem_mat.toml {SMALL} {NO_FIGURES}",
            outputs=("sem_mat_rve/rve.h5", "sem_mat_test/curve.csv"),
            folders={"sem_mat_rve": "generate", "sem_mat_test": "simulate"}),
    # Properties, calibration, studies
    "espin properties plla_test/curve.csv":
        Run(),
    "espin properties spec1.csv spec2.csv spec3.csv -o avg":
        Run(outputs=_in("avg", ("properties.csv", "average_curve.csv", "properties.png")),
            folders={"avg": "properties"}),
    "espin fit spec1.csv spec2.csv spec3.csv --params eta,b_p,c_p --realizations 3 -o fit":  # long
        Run(f"espin fit spec1.csv spec2.csv spec3.csv --params eta,b_p,c_p --realizations 3 -o fit "
            f"--params eta --realizations 1 --eta-points 2 --eta-tolerance 0.05 --step-strain 0.01 {TINY} {SERIAL}",
            outputs=_in("fit", ("fitted.toml", "fit.csv", "fit.json", "fit.png")), folders={"fit": "fit"}),
    "espin design --target E=150 --target sigma_y=4.5 --var eta=0.1:0.3 --var kappa=0:4 --budget 30 "
    "--set rve.size_ratio=100 --set rve.layers=5 --set rve.sampling=balanced -o design":  # about 30 s as written
        Run("espin design --target E=150 --target sigma_y=4.5 --var eta=0.1:0.3 --var kappa=0:4 --budget 30 "
            f"--set rve.size_ratio=100 --set rve.layers=5 --set rve.sampling=balanced -o design --budget 9 --verify 2 "
            f"{TINY} "
            f"{SHORT} {SERIAL}",
            outputs=_in("design", ("design.toml", "design.json", "evaluations.csv", "convergence.png", "maps.png",
                                   "verification.png", "pareto.png")),
            folders={"design": "design"}),
    "espin study sweep plla --grid rve.volume_fraction=0.15,0.19,0.23 --grid rve.max_deviation_deg=5,15 "
    "--realizations 5 -o sweep":  # long
        Run("espin study sweep plla --grid rve.volume_fraction=0.15,0.19,0.23 --grid rve.max_deviation_deg=5,15 "
            f"--realizations 5 -o sweep --realizations 1 {TINY} {SHORT} {SERIAL}",
            outputs=_in("sweep", ("results.csv", "summary.csv", "sweep_modulus.png")),
            folders={"sweep": "sweep"}),
    "espin study rve-size plla -o rve_size":  # long
        Run("espin study rve-size plla -o rve_size --size-ratios 20,30 --layer-counts 2,3 --layers-for-sizes 2 "
            f"--size-for-layers 30 --realizations 1 {SHORT} {SERIAL}",
            outputs=_in("rve_size", ("results.csv", "summary.csv", "rve_size_modulus.png")),
            folders={"rve_size": "rve-size"}),
    "espin study dof plla -o dof":
        Run(outputs=_in("dof", ("dof.csv", "dof.png", "dof_fit.csv")), folders={"dof": "dof"}),
    "espin specimen plla --model surrogate --shape holed_strip --workers 2 -o holed":
        Run("espin specimen plla --model surrogate --shape holed_strip --workers 2 -o holed --max-strain 0.02 "
            f"--steps 2 --surrogate-reach 1 {TINY}",
            outputs=_in("holed", ("force_displacement.csv", "force.png", "specimen.png", "fields.pvd",
                                  "surrogate_samples.csv")),
            folders={"holed": "specimen"}),
    "espin specimen plla --model surrogate --shape dogbone --surrogate-from holed/surrogate_samples.csv "
    "--elements-across 2 -o dog_sur":
        Run("espin specimen plla --model surrogate --shape dogbone --surrogate-from holed/surrogate_samples.csv "
            f"--elements-across 2 -o dog_sur --max-strain 0.02 --steps 2 {TINY}",
            outputs=_in("dog_sur", ("force_displacement.csv", "force.png", "specimen.png", "surrogate_samples.csv")),
            folders={"dog_sur": "specimen"}),
    "espin specimen plla --shape dogbone --elements-across 2 --workers 2 -o dogbone":
        Run("espin specimen plla --shape dogbone --elements-across 2 --workers 2 -o dogbone --elements-across 1 "
            f"--workers 1 --max-strain 0.01 --steps 1 {TINY}",
            outputs=_in("dogbone", ("force_displacement.csv", "force.png", "specimen.png", "yielded.png",
                                    "fields.pvd", "rve.h5", "rve_points.h5")),
            folders={"dogbone": "specimen"}),
    "python examples/reproduce_paper.py --quick":
        Skip("about a minute; tests/cli/test_cli.py::test_example_reproduce_paper_quick runs the same "
             "main(quick=True) and checks its files"),
}

# Python lines that call espin, as the test runs them: AS_WRITTEN or the line with small
# arguments (or without figures, as NO_FIGURES above). Python blocks run in one interpreter, in
# README order, between the commands.
PYTHON_RUNS: dict[str, str] = {
    'rve = espin.generate("plla", rve__size_ratio=100, rve__layers=5)': AS_WRITTEN,
    "stats = espin.network_statistics(rve.mat, rve.network, rve.config)": AS_WRITTEN,
    'espin.write_rve_folder(rve, "py_rve")': AS_WRITTEN,
    'rve2 = espin.load_rve("py_rve/rve.h5")': AS_WRITTEN,
    'result = espin.simulate(rve, "py_test", loading__max_strain=0.1, loading__steps=10)':
        'result = espin.simulate(rve, "py_test", loading__max_strain=0.1, loading__steps=10, output__figures=False)',
    "props = espin.curve_properties(result.strain, result.stress())": AS_WRITTEN,
    'fitted = espin.fit(["spec1.csv", "spec2.csv"], parameters=("eta",), realizations=1, base=rve.config)':
        'fitted = espin.fit(["spec1.csv", "spec2.csv"], parameters=("eta",), realizations=1, eta_points=2, '
        'eta_tolerance=0.05, step_strain=0.01, '
        'base=espin.load_config("plla", {"rve.size_ratio": 30, "rve.layers": 2}))',
    'm = espin.measure("mat.tif", um_per_px=0.066)': AS_WRITTEN,
    'point = espin.specimen.reopen_point("dogbone", 7)': AS_WRITTEN,
}
PYTHON_OUTPUTS = ("py_rve/rve.h5", "py_test/curve.csv")
PYTHON_FOLDERS = {"py_rve": "generate", "py_test": "simulate"}

INSTALL_STEPS = ("python3 -m venv ", ". env/bin/activate", "pip install ")
MAX_LONG = 3
DURATION = re.compile(r"\b(\d+(\.\d+)?|an?)\s*(s|min|minutes?|h|hours?|days?)\b")


# --- reading the README -------------------------------------------------------------------


@dataclass
class Block:
    lang: str
    lines: list[str]


@dataclass
class Command:
    text: str  # continuation lines joined, comment removed
    comment: str  # the comment, with the comment-only lines after it


def fenced_blocks(text: str) -> list[Block]:
    """The README's fenced blocks in order, with their language ('' for none)."""
    blocks, current = [], None
    for line in text.splitlines():
        fence = re.match(r"^```(\w*)\s*$", line)
        if fence and current is None:
            current = Block(fence.group(1), [])
        elif fence:
            blocks.append(current)
            current = None
        elif current is not None:
            current.lines.append(line)
    assert current is None, "README.md has an unclosed ``` block"
    return blocks


def split_comment(line: str) -> tuple[str, str]:
    """(code, comment) of a shell line: the first # outside quotes that starts a word."""
    quote = None
    for i, char in enumerate(line):
        if quote:
            quote = None if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip(), line[i + 1:].strip()
    return line.rstrip(), ""


def shell_commands(lines: list[str]) -> list[Command]:
    """Commands of a bash block: '\\' continuations joined, comments split off (a comment-only
    line continues the comment of the command before it)."""
    commands: list[Command] = []
    pending = ""
    for line in lines:
        code, comment = split_comment(line)
        if not code and not pending:
            if comment and commands:
                commands[-1].comment += " " + comment
            continue
        if code.endswith("\\"):
            pending += code[:-1].strip() + " "
            continue
        commands.append(Command(" ".join((pending + code).split()), comment))
        pending = ""
    assert not pending, f"a README command ends in a line continuation: {pending!r}"
    return commands


def readme_steps() -> list[tuple[str, object]]:
    """The README's runnable steps in order: ('bash', Command), ('python', code),
    ('error', (command, expected lines)), ('toml', text)."""
    steps: list[tuple[str, object]] = []
    for block in fenced_blocks(README.read_text(encoding="utf-8")):
        if block.lang == "bash":
            steps += [("bash", command) for command in shell_commands(block.lines)]
        elif block.lang == "python":
            steps.append(("python", "\n".join(block.lines)))
        elif block.lang == "toml":
            steps.append(("toml", "\n".join(block.lines)))
        elif block.lines and block.lines[0].startswith("$ "):
            steps.append(("error", (block.lines[0][2:].strip(), [s for s in block.lines[1:] if s.strip()])))
    return steps


def is_long(command: Command) -> bool:
    return re.match(r"long\b", command.comment) is not None


def and_parts(command: str) -> list[str]:
    return [part.strip() for part in command.split("&&")]


def only_adds_arguments(readme: str, run: str) -> bool:
    """``run`` is ``readme`` without its install steps and with arguments added."""
    wanted = [part for part in and_parts(readme) if not part.startswith(INSTALL_STEPS)]
    got = and_parts(run)
    if len(wanted) != len(got):
        return False
    for want, have in zip(wanted, got):
        tokens = iter(shlex.split(have))
        if not all(token in tokens for token in shlex.split(want)):  # a subsequence
            return False
    return True


def python_espin_lines(code: str) -> list[str]:
    return [line.split("#")[0].strip() for line in code.splitlines() if "espin." in line.split("#")[0]]


# --- checks of the README and the table, without running anything ---------------------------


def test_readme_table_covers_every_command():
    """RUNS covers exactly the README's commands, only adds arguments, and runs long lines small."""
    commands = [c for kind, c in readme_steps() if kind == "bash"]
    texts = [c.text for c in commands]
    missing = [t for t in texts if t not in RUNS]
    stale = [t for t in RUNS if t not in texts]
    assert not missing, f"README commands that RUNS (tests/test_readme.py) does not cover: {missing}"
    assert not stale, f"RUNS entries that are no longer README commands: {stale}"
    for text, run in RUNS.items():
        if isinstance(run, Run) and run.command != AS_WRITTEN:
            assert only_adds_arguments(text, run.command), f"the run of {text!r} changes it: {run.command!r}"
    long = [c for c in commands if is_long(c)]
    assert len(long) <= MAX_LONG, f"more than {MAX_LONG} README lines marked '# long': {[c.text for c in long]}"
    for command in long:
        assert DURATION.search(command.comment), f"a '# long' line does not say how long it takes: {command.text!r}"
        run = RUNS[command.text]
        assert isinstance(run, Run) and run.command != AS_WRITTEN, f"a long line must run small: {command.text!r}"


def test_readme_checks_catch_what_they_should():
    """The parsing and the honesty checks on small made-up README text."""
    commands = shell_commands([
        "espin a --x 1 -o out   # long: about 20 min on 2 cores",
        "espin b --grid k=1,2 \\",
        "      --n 5 -o b   # what '#' means",
        "espin c 'a # b'      # first line",
        "                     # second line",
    ])
    assert [c.text for c in commands] == ["espin a --x 1 -o out", "espin b --grid k=1,2 --n 5 -o b", "espin c 'a # b'"]
    assert is_long(commands[0]) and DURATION.search(commands[0].comment)
    assert not is_long(commands[1]) and commands[2].comment == "first line second line"
    assert not DURATION.search("long: many tests")
    assert only_adds_arguments("python3 -m venv env && . env/bin/activate && pip install . && espin s plla --out t",
                               "espin s plla --out t --set rve.layers=3")
    assert only_adds_arguments("espin b --n 5 -o b", "espin b --n 5 -o b --n 1")  # the last --n wins
    assert not only_adds_arguments("espin b --n 5 -o b", "espin b --n 1 -o b")  # changed, not added
    assert not only_adds_arguments("espin g x && espin s x", "espin s x --set a=1")  # a part dropped


def test_readme_python_lines_are_covered():
    lines = [line for kind, code in readme_steps() if kind == "python" for line in python_espin_lines(code)]
    missing = [line for line in lines if line not in PYTHON_RUNS]
    stale = [line for line in PYTHON_RUNS if line not in lines]
    assert not missing, f"README Python lines calling espin that PYTHON_RUNS does not cover: {missing}"
    assert not stale, f"PYTHON_RUNS entries that are no longer README lines: {stale}"
    for line, run in PYTHON_RUNS.items():
        if run != AS_WRITTEN:
            assert run.split("(")[0] == line.split("(")[0], f"the run of {line!r} calls something else: {run!r}"


# --- running the README ---------------------------------------------------------------------

DRIVER = r'''
import contextlib, json, sys, traceback
namespace = {"__name__": "__main__"}
for line in sys.stdin:
    request = json.loads(line)
    with open(request["log"], "w", encoding="utf-8") as log:
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            try:
                exec(compile(request["code"], "<README python block>", "exec"), namespace)
                status = "ok"
            except BaseException:
                traceback.print_exc()
                status = "error"
    print(status, flush=True)
'''


class PythonSession:
    """One Python interpreter that runs the README's Python blocks in order, like a user's."""

    def __init__(self, cwd: Path, env: dict[str, str]):
        self.cwd = cwd
        self.count = 0
        self.process = subprocess.Popen([sys.executable, "-c", DRIVER], cwd=cwd, env=env, text=True,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def run(self, code: str) -> tuple[bool, str]:
        self.count += 1
        log = self.cwd.parent / f"python_block_{self.count}.log"
        self.process.stdin.write(json.dumps({"code": code, "log": str(log)}) + "\n")
        self.process.stdin.flush()
        status = self.process.stdout.readline().strip()
        return status == "ok", log.read_text(encoding="utf-8") if log.exists() else "(no output)"

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait(timeout=60)


def small_python(code: str) -> str:
    for line, run in PYTHON_RUNS.items():
        if run != AS_WRITTEN:
            code = code.replace(line, run)
    return code


def shell(command: str, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", command], cwd=cwd, env=env, text=True, capture_output=True, timeout=600)


def failure(what: str, result: subprocess.CompletedProcess) -> str:
    return f"{what} exited {result.returncode}\n--- stderr ---\n{result.stderr[-4000:]}\n--- stdout ---\n{result.stdout[-2000:]}"


def plla_test_files() -> list[str]:
    """The files the README says plla_test/ holds (its paragraph after the two commands)."""
    text = README.read_text(encoding="utf-8")
    paragraph = text[text.index("`plla_test/` then holds"):]
    paragraph = paragraph[:paragraph.index("\n\n")]
    paragraph = paragraph.replace("`statistics.json`/`.txt`", "`statistics.json` `statistics.txt`")
    names = re.findall(r"`([\w/*]+\.[a-z0-9]+)`", paragraph)
    assert len(names) >= 10, names
    return [f"plla_test/{name}" for name in names]


def missing_files(cwd: Path, paths) -> list[str]:
    return [path for path in paths if not list(cwd.glob(path))]


def snapshot(cwd: Path, *folders: Path) -> dict[str, tuple[int, int]]:
    """(size, mtime) of every file in the folders (or of the files given), by path relative to cwd."""
    files = {}
    for folder in folders:
        for path in [folder] if folder.is_file() else folder.rglob("*"):
            if path.is_file():
                stat = path.stat()
                files[path.relative_to(cwd).as_posix()] = (stat.st_size, stat.st_mtime_ns)
    return files


def run_record(folder: Path) -> dict:
    return json.loads((folder / "run.json").read_text(encoding="utf-8"))


@pytest.mark.slow
def test_readme_runs_in_order(tmp_path):
    """Every README command and Python block, in README order, in one folder: exit 0, the
    promised files, and no folder overwritten by a later command."""
    cwd = tmp_path / "work"
    cwd.mkdir()
    shutil.copytree(ROOT / "examples", cwd / "examples")  # README paths are relative to a clone
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"  # espin, python
    env.setdefault("MPLBACKEND", "Agg")
    session = PythonSession(cwd, env)
    folders: dict[str, tuple[str, str]] = {}  # folder -> (espin command, run_id)
    promised: list[str] = []
    written: dict[str, tuple[int, int]] = {}  # every file a README step wrote -> (size, mtime)
    timings: list[tuple[float, str]] = []

    def claim(owners: dict[str, str], by: str) -> None:
        for name, command in owners.items():
            assert name not in folders, f"{by!r} writes into {name}/, already written by an earlier README step"
            record = run_record(cwd / name)
            assert record["command"] == command and record["status"] == "complete", (by, name, record)
            folders[name] = (command, record["run_id"])
            written.update(snapshot(cwd, cwd / name))

    try:
        for kind, step in readme_steps():
            start = time.perf_counter()
            if kind == "bash":
                run = RUNS[step.text]  # every command is covered (test_readme_table_covers_every_command)
                if isinstance(run, Skip):
                    continue
                command = step.text if run.command == AS_WRITTEN else run.command
                result = shell(command, cwd, env)
                assert result.returncode == 0, failure(f"README: {step.text}\nran: {command}", result)
                outputs = list(run.outputs) + (plla_test_files() if "plla_test" in run.folders else [])
                missing = missing_files(cwd, outputs)
                assert not missing, f"{command!r} did not write {missing}"
                claim(run.folders, command)
                promised += outputs
                written.update(snapshot(cwd, *[path for output in outputs for path in cwd.glob(output)]))
                label = command
            elif kind == "python":
                ok, log = session.run(small_python(step))
                assert ok, f"README Python block failed:\n{step}\n--- output ---\n{log[-4000:]}"
                label = "python block: " + step.splitlines()[0]
                if "py_rve" in step:
                    missing = missing_files(cwd, PYTHON_OUTPUTS)
                    assert not missing, f"the Python block did not write {missing}"
                    claim(PYTHON_FOLDERS, "python block")
                    promised += PYTHON_OUTPUTS
            elif kind == "toml":
                (tmp_path / "loading.toml").write_text(step, encoding="utf-8")
                command = f"espin config {tmp_path / 'loading.toml'}"
                result = shell(command, cwd, env)
                assert result.returncode == 0, failure(f"README TOML block:\n{step}\nran: {command}", result)
                assert "hold_s = 600" in result.stdout, result.stdout
                label = "toml block (espin config)"
            else:  # a shown error: the command fails with exactly the text shown
                command, expected = step
                result = shell(command, cwd, env)
                assert result.returncode != 0, f"README shows {command!r} failing, but it exited 0"
                shown = [line.rstrip() for line in result.stderr.splitlines()]
                for line in expected:
                    assert line.rstrip() in shown, f"README shows {line!r} for {command!r}; stderr:\n{result.stderr}"
                label = command
            timings.append((time.perf_counter() - start, label))
    finally:
        session.close()
        for seconds, label in timings:
            print(f"{seconds:7.1f} s  {label}")

    # A README-order run loses no output: each folder still holds its own run, and every file a
    # step wrote is still there, unchanged.
    for name, (command, run_id) in folders.items():
        record = run_record(cwd / name)
        assert (record["command"], record["run_id"]) == (command, run_id), f"{name}/ was overwritten: {record}"
    missing = missing_files(cwd, promised)
    assert not missing, f"files written by README steps and gone at the end: {missing}"
    now = snapshot(cwd, *[cwd / name for name in folders], *[path for output in promised for path in cwd.glob(output)])
    lost = sorted(set(written) - set(now))
    changed = sorted(path for path in written if path in now and now[path] != written[path])
    assert not lost and not changed, f"later README steps removed {lost} and rewrote {changed}"
