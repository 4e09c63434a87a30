"""Status that tells the truth: run.json says partial or failed when images of a batch or tasks
of a study failed, the failures are printed under --quiet, pooled.toml holds no NaN, and after
an interruption the specimen's CSV and VTK series hold the same steps."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from espin.cli import app
from espin.core.output_folder import read_manifest
from espin.datasets import sem_image

TINY = ["--set", "rve.size_ratio=30", "--set", "rve.layers=2", "--set", "loading.max_strain=0.02",
        "--set", "loading.steps=2"]
FAIL = ["--set", "solver.max_iterations=1", "--set", "solver.max_cuts=0"]


def _run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.slow
@pytest.mark.parametrize("extra, status", [([], "failed"), (["--grid", "solver.max_iterations=1,50"], "partial")])
def test_a_study_with_failed_tasks_says_so_under_quiet(tmp_path, extra, status):
    options = [*TINY, "--set", "solver.max_cuts=0"] + (["--set", "solver.max_iterations=1"] if not extra else [])
    result = _run("study", "sweep", *options, *extra, "--realizations", "1", "-q", "-o", tmp_path / "s")
    assert result.exit_code == 4
    assert "task(s) failed" in result.output and "failed {" in result.output
    assert read_manifest(tmp_path / "s").status == status


@pytest.mark.slow
def test_a_batch_whose_images_failed_is_failed_or_partial_and_pools_no_nan(tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    (images / "a_noise.png").write_bytes(b"not an image")
    (images / "b_text.tif").write_bytes(b"nor this")
    failed = _run("measure", images, "--um-per-px", "0.05", "--no-figures", "-o", tmp_path / "none")
    assert failed.exit_code == 3 and read_manifest(tmp_path / "none").status == "failed"
    sem_image(images / "c_mat.tif")
    partial = _run("measure", images, "--um-per-px", "0.05", "--no-figures", "-o", tmp_path / "one")
    assert partial.exit_code == 0, partial.output
    assert read_manifest(tmp_path / "one").status == "partial"
    pooled = (tmp_path / "one" / "pooled.toml").read_text()
    assert "nan" not in pooled.lower() and "n_measured = 1" in pooled


def test_an_interrupted_specimen_keeps_as_many_vtk_steps_as_csv_rows(tmp_path, monkeypatch):
    """Ctrl-C while a step is written (after its .vtu, before its CSV row)."""
    import espin
    from espin.specimen import result as result_module

    real = result_module._row
    calls = []

    def interrupt_third_row(step):
        calls.append(step)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(step)

    monkeypatch.setattr(result_module, "_row", interrupt_third_row)
    with pytest.raises(KeyboardInterrupt):
        espin.specimen(None, "strip", model="neo_hookean", modulus_MPa=200.0, poisson_ratio=0.3, elements_across=1,
                       steps=4, max_strain=0.02, out=tmp_path / "sp", figures=False)
    rows = (tmp_path / "sp" / "force_displacement.csv").read_text().strip().splitlines()[1:]
    vtk = sorted((tmp_path / "sp" / "vtk").glob("step_*.vtu"))
    assert len(rows) == len(vtk) == 2
    assert (tmp_path / "sp" / "fields.pvd").read_text().count("step_") == 2
    assert json.loads((tmp_path / "sp" / "run.json").read_text())["status"] == "failed"
    assert np.isfinite([float(r.split(",")[4]) for r in rows]).all()
