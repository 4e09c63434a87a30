"""The command line and the examples (small variants), run as a user would."""

from __future__ import annotations

import json
import runpy
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from espin.cli import app
from espin.geometry.rve_file import load_rve

runner = CliRunner()
EXAMPLES = Path(__file__).parents[2] / "examples"


@pytest.mark.slow
def test_generate_writes_the_folder(tmp_path):
    out = tmp_path / "rve"
    result = runner.invoke(app, ["generate", "plla", "--size-ratio", "30", "--layers", "2",
                                 "--seed", "4", "-o", str(out), "--set", "rve.max_deviation_deg=10"])
    assert result.exit_code == 0, result.output
    names = {p.name for p in out.iterdir()}
    assert names == {"run.json", "rve.h5", "config.toml", "statistics.json", "statistics.txt", "mat.png",
                     "statistics.png", "fibers.vtu", "network.vtu"}
    assert (out / "mat.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rve = load_rve(out / "rve.h5")
    assert (rve.config.rve.layers, rve.config.rve.seed, rve.config.rve.max_deviation_deg) == (2, 4, 10)
    summary = json.loads((out / "statistics.json").read_text())
    assert summary["n_dof"] == rve.network.n_dof
    # The written config regenerates the same RVE.
    again = tmp_path / "again"
    result = runner.invoke(app, ["generate", str(out / "config.toml"), "-o", str(again),
                                 "--no-figures", "--no-vtk", "-q"])
    assert result.exit_code == 0, result.output
    assert np.array_equal(load_rve(again / "rve.h5").mat.vertices, rve.mat.vertices)
    assert not (again / "mat.png").exists()


def test_bad_input_is_a_clear_error(tmp_path):
    result = runner.invoke(app, ["generate", "--set", "rve.layerz=3", "-o", str(tmp_path / "x")])
    assert result.exit_code == 2 and "rve.layerz: unknown key" in result.output
    result = runner.invoke(app, ["generate", "--volume-fraction", "1.2", "-o", str(tmp_path / "x")])
    assert result.exit_code == 2 and "rve.volume_fraction" in result.output
    assert "less than 1" in result.output
    assert not (tmp_path / "x").exists()  # nothing started


def test_config_command_prints_resolved_toml():
    result = runner.invoke(app, ["config", "plla", "--set", "rve.orientation={von_mises={kappa=3}}"])
    assert result.exit_code == 0
    data = tomllib.loads(result.output)
    # An aligned mat gets the stationary seeding by default (SPEC 1), even from the plla preset.
    assert data["rve"]["seeding"] == "lines" and data["rve"]["orientation"]["von_mises"]["kappa"] == 3


def test_example_generate_plla(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["generate_plla.py", "--size-ratio", "40", "--layers", "3"])
    runpy.run_path(str(EXAMPLES / "generate_plla.py"), run_name="__main__")
    summary = json.loads((tmp_path / "plla_rve" / "statistics.json").read_text())
    # At least the target; at most one longest fiber (sqrt 2 L) more: pi sqrt(2) D / (4 L).
    assert 0.19 <= summary["volume_fraction_min"]
    assert summary["volume_fraction_max"] <= 0.19 + np.pi * np.sqrt(2) / (4 * 40)
    assert summary["fiber_tortuosity_mean"] < 1.02  # Table 2 fibers are nearly straight


@pytest.mark.slow
def test_simulate_from_preset_and_from_saved_rve(tmp_path):
    out = tmp_path / "test"
    args = ["simulate", "plla", "--set", "rve.size_ratio=30", "--set", "rve.layers=2",
            "--max-strain", "0.04", "--steps", "4", "-o", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    for name in ("curve.csv", "results.h5", "deformation.pvd", "curve.png", "deformed.png", "rve.h5"):
        assert (out / name).stat().st_size > 0, name
    assert len(list((out / "vtk").glob("step_*.vtu"))) == 5
    curve = np.genfromtxt(out / "curve.csv", delimiter=",", names=True)
    assert len(curve) == 5 and curve["stress_MPa"][-1] > curve["stress_MPa"][1] > 0
    # The same RVE, loaded from its file, pulled at another rate.
    again = tmp_path / "again"
    result = runner.invoke(app, ["simulate", str(out / "rve.h5"), "--max-strain", "0.04", "--steps", "4",
                                 "--strain-rate-per-s", "0.05", "-o", str(again), "-q"])
    assert result.exit_code == 0, result.output
    fast = np.genfromtxt(again / "curve.csv", delimiter=",", names=True)
    assert fast["stress_MPa"][-1] > curve["stress_MPa"][-1]  # rate dependence
    assert not (again / "rve.h5").exists()


def test_simulate_rejects_bad_input_before_work(tmp_path):
    result = runner.invoke(app, ["simulate", "--lateral", "sideways", "-o", str(tmp_path / "x")])
    assert result.exit_code == 2 and "loading.lateral" in result.output
    result = runner.invoke(app, ["simulate", "--test", "path", "--set", "loading.path_csv='missing.csv'",
                                 "-o", str(tmp_path / "x")])
    assert result.exit_code == 2 and "loading.path_csv" in result.output
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_example_tensile_plla(tmp_path, monkeypatch):
    """The paper's tensile test, small: linear start, yield near 3 %, hardening after."""
    monkeypatch.chdir(tmp_path)
    module = runpy.run_path(str(EXAMPLES / "tensile_plla.py"))
    result = module["main"](size_ratio=40, layers=3, max_strain=0.08, steps=8, out="small_test")
    stress = result.stress()
    slopes = np.diff(stress) / np.diff(result.strain)
    assert slopes[0] == pytest.approx(slopes[1], rel=0.1)  # linear up to 2 %
    assert slopes[-1] < 0.2 * slopes[0]  # post-yield hardening is much softer
    assert np.all(slopes > 0)  # but still hardening
    assert result.yielded_fraction[2] < 0.1 < result.yielded_fraction[-1]
    assert (tmp_path / "small_test" / "curve.csv").exists()


@pytest.mark.slow
def test_example_reproduce_paper_quick(tmp_path, monkeypatch):
    """The paper-reproduction example, reduced: every step runs and gives sane numbers."""
    monkeypatch.chdir(tmp_path)
    module = runpy.run_path(str(EXAMPLES / "reproduce_paper.py"))
    out = module["main"]("paper", quick=True, workers=1)
    props = out["properties"]
    assert props.has_yield and 0.01 < props.yield_strain < 0.06  # paper: yield near 3 %
    assert props.modulus_MPa > 10 * props.post_yield_modulus_MPa > 0
    summary = out["rve_size"].summary
    assert len(summary) == 3 and (summary["n"] == 2).all()
    assert (out["dof"]["ratio"] > 1).all()
    for name in ("rve/rve.h5", "tensile/curve.csv", "rve_size/summary.csv", "rve_size/rve_size_modulus.png",
                 "dof/dof.png", "dof/dof.csv"):
        assert (tmp_path / "paper" / name).is_file(), name


@pytest.mark.slow
def test_image_to_mechanics_end_to_end(tmp_path):
    """espin measure -> calibrate-geometry -> generate -> simulate, as a user runs it."""
    from PIL import Image

    import espin.geometry.rve
    from espin.imaging.synthetic import render_sem

    mat = espin.geometry.rve.generate("plla", rve__size_ratio=60, rve__layers=3, rve__seed=4,
                             rve__max_deviation_deg=20.0).mat
    sem = render_sem(mat, side_um=40 * 0.45, layers=2, seed=4)
    image = tmp_path / "mat.png"
    Image.fromarray(np.round(255 * sem.image).astype(np.uint8)).save(image)

    steps = [
        ["measure", str(image), "--um-per-px", f"{sem.um_per_px!r}", "-o", str(tmp_path / "measured"), "-q"],
        # Without the rendered check, which is half the calibration's work here (124 evaluations
        # against 245) and checked on its own in tests/imaging/test_geometry_calibration.py.
        ["calibrate-geometry", str(tmp_path / "measured"), "--seeds", "2", "--no-rendered-check", "-o",
         str(tmp_path / "mat.toml")],
        ["generate", str(tmp_path / "mat.toml"), "--size-ratio", "30", "--layers", "2", "--no-figures",
         "--no-vtk", "-o", str(tmp_path / "rve"), "-q"],
        ["simulate", str(tmp_path / "rve" / "rve.h5"), "--max-strain", "0.04", "--steps", "4",
         "-o", str(tmp_path / "test"), "-q"],
    ]
    for args in steps:
        result = runner.invoke(app, args)
        assert result.exit_code == 0, (args[0], result.output)
        if args[0] == "calibrate-geometry":
            assert "espin fit" in result.output  # the mechanics must be fitted again
    measured = tomllib.loads((tmp_path / "measured" / "measurement.toml").read_text())
    calibrated = tomllib.loads((tmp_path / "mat.toml").read_text())
    # the generator gets the measured diameter and a wavy walk (the image's mat had 20 deg
    # turns; over its 40 D the smooth walk can look the same, and may be chosen)
    assert calibrated["rve"]["diameter_um"] == pytest.approx(measured["diameter"]["mean_um"], rel=0.05)
    assert calibrated["rve"].get("max_deviation_deg", 0.0) > 5.0 or \
        calibrated["rve"].get("waviness_deg", 0.0) > 2.0
    curve = np.genfromtxt(tmp_path / "test" / "curve.csv", delimiter=",", names=True)
    assert curve["stress_MPa"][-1] > 0


@pytest.mark.slow
def test_exit_codes_tell_usage_input_and_solver_failures_apart(tmp_path):
    """docs/command_line.md: 2 usage, 3 bad input data, 4 solver failure."""
    usage = runner.invoke(app, ["simulate", "--steps", "0", "-o", str(tmp_path / "u")])
    assert usage.exit_code == 2 and "loading.steps" in usage.output
    not_rve = tmp_path / "not_rve.h5"
    not_rve.write_bytes(b"not an HDF5 file")
    bad_file = runner.invoke(app, ["simulate", str(not_rve), "-o", str(tmp_path / "b")])
    assert bad_file.exit_code == 3 and "not_rve.h5" in bad_file.output
    out = tmp_path / "s"
    solver = runner.invoke(app, ["simulate", "--set", "rve.size_ratio=30", "--set", "rve.layers=2",
                                 "--max-strain", "0.02", "--steps", "2", "--set", "solver.max_iterations=1",
                                 "--set", "solver.max_cuts=0", "-q", "-o", str(out)])
    assert solver.exit_code == 4
    message = solver.output.strip().splitlines()
    assert len(message) == 1 and "did not converge" in message[0] and "Try " in message[0]
    assert "the initial state is kept" in message[0] and "solver.log" in message[0]
    log = (out / "solver.log").read_text().splitlines()
    assert len(log) - log.index("    k  residual") - 1 == 4  # Newton, then the first continuation stage
    assert (out / "curve.csv").exists()  # the converged steps (here the initial state) are kept
