"""espin example-data: sample files that the other commands read as they are."""

from __future__ import annotations

import pytest

from typer.testing import CliRunner

from espin.analysis.experiments import read_curve
from espin.analysis.properties import curve_properties
from espin.cli import app
from espin.core.config import load_config
from espin.datasets import SEM_UM_PER_PX
from espin.imaging.databar import detect_data_bar
from espin.imaging.image import read_image
from espin.imaging.metadata import read_pixel_size


@pytest.mark.slow
def test_example_data_is_ready_to_use_and_not_overwritten(tmp_path):
    result = CliRunner().invoke(app, ["example-data", "-o", str(tmp_path)])
    assert result.exit_code == 0, result.output
    # The image carries its scale and a data bar that espin measure finds.
    assert read_pixel_size(tmp_path / "mat.tif").um_per_px == SEM_UM_PER_PX
    grey = read_image(tmp_path / "mat.tif")
    rows, bar = detect_data_bar(grey)
    assert bar is not None and rows[0] == 0 and 0.85 * grey.shape[0] < rows[1] < grey.shape[0]
    # The curves read without options and look like the paper's PLLA specimens.
    moduli = [curve_properties(c.strain, c.stress_MPa).modulus_MPa
              for c in (read_curve(tmp_path / f"spec{k}.csv") for k in (1, 2, 3))]
    assert all(180.0 < m < 240.0 for m in moduli) and len(set(moduli)) == 3
    # The calibrated mat is a config that loads and asks for the wavy polydisperse mat of the image.
    rve = load_config(tmp_path / "calibrated_mat.toml").rve
    assert (rve.walk, rve.diameter_distribution) == ("smooth", "lognormal") and rve.waviness_deg > 5.0
    again = CliRunner().invoke(app, ["example-data", "-o", str(tmp_path)])
    assert again.exit_code == 2 and "--overwrite" in again.output
    assert CliRunner().invoke(app, ["example-data", "-o", str(tmp_path), "--overwrite"]).exit_code == 0


@pytest.mark.slow
def test_example_data_follows_the_output_folder_policy(tmp_path):
    """A run.json; another run's folder refused (exit 2, nothing changed); a file where the folder
    should be refused without a traceback; --overwrite replaces only its own files."""
    from espin.core.output_folder import read_manifest

    assert CliRunner().invoke(app, ["example-data", "-o", str(tmp_path / "a")]).exit_code == 0
    assert (read_manifest(tmp_path / "a").command, read_manifest(tmp_path / "a").status) == ("example-data",
                                                                                              "complete")
    simulated = tmp_path / "sim"
    simulated.mkdir()
    (simulated / "run.json").write_text('{"run_id": "x", "command": "simulate", "config_hash": "", '
                                        '"espin_version": "0", "status": "complete", "started_utc": "t"}')
    refused = CliRunner().invoke(app, ["example-data", "-o", str(simulated)])
    assert refused.exit_code == 2 and "another simulate run" in refused.output
    assert sorted(p.name for p in simulated.iterdir()) == ["run.json"]
    (tmp_path / "file").write_text("mine")
    refused = CliRunner().invoke(app, ["example-data", "-o", str(tmp_path / "file")])
    assert refused.exit_code == 2 and "not a folder" in refused.output and "Traceback" not in refused.output
    assert (tmp_path / "file").read_text() == "mine"
    (tmp_path / "a" / "notes.txt").write_text("mine")
    assert CliRunner().invoke(app, ["example-data", "-o", str(tmp_path / "a"), "--overwrite"]).exit_code == 0
    assert (tmp_path / "a" / "notes.txt").read_text() == "mine"
