"""The output policy of ``measure``, ``properties`` and ``calibrate-geometry``: a ``run.json``
manifest in every folder; another run's results refused (exit 2, nothing changed) unless
``--overwrite``, which removes what the command writes and nothing else; a ``.toml`` of
calibrate-geometry refused when it or its report exists; a run refused for a bad input leaves
no folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from espin.cli import app
from espin.core.errors import ConfigError
from espin.core.output_folder import read_manifest


def _run(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


def _files(folder: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _refused(result) -> bool:
    return result.exit_code == 2 and "--overwrite" in result.output and "Traceback" not in result.output


def _check_folder_policy(folder: Path, command: str, first: list, second: list, overwrite: list) -> None:
    """``first`` writes ``folder``; ``second`` is refused leaving it as it was; ``overwrite``
    (plus --overwrite) replaces it, keeping a file that is not the command's."""
    assert (done := _run(*first)).exit_code == 0, done.output
    manifest = read_manifest(folder)
    assert (manifest.command, manifest.status) == (command, "complete") and len(manifest.config_hash) == 64
    before = _files(folder)
    assert _refused(_run(*second))
    assert _files(folder) == before
    (folder / "notes.txt").write_text("mine")
    assert (done := _run(*overwrite, "--overwrite")).exit_code == 0, done.output
    again = read_manifest(folder)
    assert again.status == "complete" and again.run_id != manifest.run_id
    assert (folder / "notes.txt").read_text() == "mine"


# --------------------------------------------------------------------------------------------
# espin measure
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sem(tmp_path_factory):
    """A 160 px synthetic SEM image (PNG) and its pixel size."""
    from PIL import Image

    import espin.geometry.rve
    from espin.imaging.synthetic import render_sem

    mat = espin.geometry.rve.generate("plla", rve__size_ratio=30, rve__layers=2, rve__seed=4,
                                      rve__max_deviation_deg=20.0).mat
    rendered = render_sem(mat, side_um=20 * 0.45, layers=2, seed=4)
    path = tmp_path_factory.mktemp("sem") / "mat.png"
    Image.fromarray(np.round(255 * rendered.image).astype(np.uint8)).save(path)
    return path, rendered.um_per_px


def test_measure_folder_policy(sem, tmp_path):
    image, um_per_px = sem
    folder = tmp_path / "measured"
    args = ["measure", image, "--um-per-px", repr(um_per_px), "-o", folder, "--no-figures", "-q"]
    _check_folder_policy(folder, "measure", args, [*args[:-2], "--max-bend-deg", "30", "-q"], args)
    assert not (folder / "overlay.png").exists()


def test_measure_overwrite_removes_stale_figures(sem, tmp_path):
    image, um_per_px = sem
    folder = tmp_path / "measured"
    folder.mkdir()
    (folder / "overlay.png").write_bytes(b"an earlier run's figure")
    args = ["measure", image, "--um-per-px", repr(um_per_px), "-o", folder, "--no-figures", "-q"]
    assert _refused(_run(*args))  # files of the command, even without a manifest
    assert _run(*args, "--overwrite").exit_code == 0
    assert sorted(p.name for p in folder.iterdir()) == ["fibers.csv", "measurement.toml", "run.json"]


def test_measure_refused_for_a_bad_input_leaves_no_folder(sem, tmp_path):
    image, _ = sem
    bad_option = _run("measure", image, "--um-per-px", "0.05", "--max-bend-deg", "0", "-o", tmp_path / "a")
    assert bad_option.exit_code == 2 and "max_bend_deg" in bad_option.output
    not_an_image = tmp_path / "notes.png"
    not_an_image.write_text("not an image")
    bad_image = _run("measure", not_an_image, "--um-per-px", "0.05", "-o", tmp_path / "b", "-q")
    assert bad_image.exit_code == 3 and "notes.png" in bad_image.output
    missing = _run("measure", tmp_path / "missing.png", "--um-per-px", "0.05", "-o", tmp_path / "c")
    assert missing.exit_code == 3 and "no such file" in missing.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.png"]


def test_measurement_write_in_python(sem, tmp_path):
    from espin.imaging.measurement import measure, measurement_digest

    image, um_per_px = sem
    result = measure(image, um_per_px=um_per_px)
    result.write(tmp_path / "m", figures=False)
    assert read_manifest(tmp_path / "m").config_hash == result.inputs_digest == measurement_digest(
        image, um_per_px=um_per_px, scale_bar_um=None, scale_bar_rows=None, crop_rows=None,
        crop_bottom_px=None, width_px=None, max_bend_deg=35.0, min_length_diameters=3.0)
    with pytest.raises(ConfigError, match="overwrite=True"):
        result.write(tmp_path / "m", figures=False)
    result.write(tmp_path / "m", figures=False, overwrite=True)


# --------------------------------------------------------------------------------------------
# espin properties
# --------------------------------------------------------------------------------------------
def _specimens(folder: Path, moduli=(190.0, 210.0)) -> list[Path]:
    """Bilinear specimens (yield at 6 MPa, hardening 5 MPa) with the given moduli."""
    strain = np.linspace(0.0, 0.2, 81)
    paths = []
    for k, modulus in enumerate(moduli):
        stress = np.minimum(modulus * strain, 6.0) + 5.0 * np.maximum(strain - 6.0 / modulus, 0.0)
        paths.append(folder / f"s{k}.csv")
        np.savetxt(paths[-1], np.c_[strain, stress], delimiter=",", header="strain,stress_MPa", comments="")
    return paths


def test_properties_folder_policy(tmp_path):
    curves = _specimens(tmp_path)
    folder = tmp_path / "props"
    _check_folder_policy(folder, "properties", ["properties", *curves, "-o", folder],
                         ["properties", curves[0], "-o", folder], ["properties", curves[0], "-o", folder])
    # one curve now: the earlier run's average is gone, not left beside the new results
    assert not (folder / "average_curve.csv").exists() and (folder / "properties.png").exists()


def test_properties_refused_for_a_bad_input_leaves_no_folder(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("strain,stress\n0,0\n0.01,oops\n")
    assert _run("properties", bad, "-o", tmp_path / "a").exit_code == 3
    (curve,) = _specimens(tmp_path, moduli=(200.0,))
    unfittable = _run("properties", curve, "--strain-range", "0.5:", "-o", tmp_path / "b")  # after the claim
    assert unfittable.exit_code == 3 and "s0.csv" in unfittable.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "s0.csv"]


# --------------------------------------------------------------------------------------------
# espin calibrate-geometry
# --------------------------------------------------------------------------------------------
CALIBRATE = ["calibrate-geometry", "--diameter-um", "0.5", "--seeds", "1", "-q"]


def test_calibrate_geometry_folder_policy(tmp_path):
    folder = tmp_path / "cal"
    _check_folder_policy(folder, "calibrate-geometry", [*CALIBRATE, "-o", folder],
                         [*CALIBRATE, "--diameter-sd-um", "0.1", "-o", folder], [*CALIBRATE, "-o", folder])
    assert {p.name for p in folder.iterdir()} == {"run.json", "config.toml", "calibration.json",
                                                  "calibration.txt", "notes.txt"}


@pytest.mark.slow
def test_calibrate_geometry_toml_file_is_not_overwritten(tmp_path, monkeypatch):
    out = tmp_path / "mat.toml"
    report = tmp_path / "mat.calibration.json"
    assert (done := _run(*CALIBRATE, "-o", out)).exit_code == 0, done.output
    before = _files(tmp_path)
    again = _run(*CALIBRATE, "-o", out)
    assert _refused(again) and "mat.toml and" in again.output
    assert _files(tmp_path) == before
    out.unlink()  # the report alone is refused too
    only_report = _run(*CALIBRATE, "-o", out)
    assert _refused(only_report) and "mat.calibration.json already exists" in only_report.output
    assert report.read_bytes() == before[report]
    assert _run(*CALIBRATE, "-o", out, "--overwrite").exit_code == 0
    assert out.exists() and report.read_bytes() != before[report]  # a new search record
    # the default -o calibrated.toml in the current folder is refused the same way
    monkeypatch.chdir(tmp_path)
    Path("calibrated.toml").write_text("mine")
    assert _refused(_run(*CALIBRATE)) and Path("calibrated.toml").read_text() == "mine"
    assert not Path("calibrated.calibration.json").exists()


def test_calibrate_geometry_refused_for_a_bad_input_leaves_no_folder(tmp_path):
    typed = _run("calibrate-geometry", "--diameter-um", "-1", "-o", tmp_path / "a")
    assert typed.exit_code == 2 and "diameter" in typed.output
    option = _run(*CALIBRATE, "--fit", "curl", "-o", tmp_path / "b")  # checked after the claim
    assert option.exit_code == 2 and "fit must be" in option.output
    assert list(tmp_path.iterdir()) == []


def test_calibration_write_in_python(tmp_path):
    from espin.geometry.targets import GeometryTargets
    from espin.imaging.geometry_calibration import calibrate_geometry

    result = calibrate_geometry(GeometryTargets(diameter_mean_um=0.5), "plla", seeds=1)
    for path in (tmp_path / "cal", tmp_path / "cal.toml"):
        result.write(path)
        with pytest.raises(ConfigError, match="overwrite=True"):
            result.write(path)
        assert result.write(path, overwrite=True)["config"].exists()
    assert read_manifest(tmp_path / "cal").command == "calibrate-geometry"
