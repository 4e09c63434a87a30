"""``espin generate`` grades the mat against the measured targets of its config."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from espin.cli import app
from espin.core.config import load_config, write_config

runner = CliRunner()
SOURCE = "PLGA-1500_1.tif, rows 0:880 at 0.066 um/px, traced by espin measure with its defaults"


def test_generate_shows_the_targets_source(tmp_path):
    config = load_config("plla", {
        "rve.size_ratio": 40, "rve.layers": 2, "rve.diameter_um": 2.3,
        "targets.source": SOURCE,
        "targets.diameter_um": [2.1, 2.3, 2.6, 1.9, 2.4],
        "targets.tortuosity": [1.02, 1.1, 1.3], "targets.contour_length_um": [10.0, 20.0, 30.0],
        "targets.window_um": 90.0,
    })
    path = write_config(config, tmp_path / "plga.toml")
    out = tmp_path / "rve"
    result = runner.invoke(app, ["generate", str(path), "-o", str(out), "--no-figures", "--no-vtk",
                                 "--set", "targets.straightness=0.9"])
    assert result.exit_code == 0, result.output
    # The table is not wrapped: a long source stays on its line.
    assert "targets_source" in result.output
    line = next(x for x in result.output.splitlines() if "targets_source" in x)
    assert line.endswith(SOURCE)
    assert "length-matched pieces" in result.output and "mat_straightness" in result.output
    summary = json.loads((out / "statistics.json").read_text())
    assert summary["targets_source"] == SOURCE
    # A fixed 2.3 um against 1.9, 2.1, 2.3, 2.4, 2.6: the ECDFs differ by 2/5 below 2.3.
    assert summary["target_diameter"] == "sample of 5 values"
    assert summary["ks_diameter"] == pytest.approx(0.4)
    assert summary["target_straightness"] == 0.9 and summary["target_window_um"] == 90.0


def test_generate_without_targets_says_so(tmp_path):
    config = load_config(None, {"rve.size_ratio": 40, "rve.layers": 2})
    path = write_config(config, tmp_path / "plain.toml")
    result = runner.invoke(app, ["generate", str(path), "-o", str(tmp_path / "rve"), "--no-figures",
                                 "--no-vtk"])
    assert result.exit_code == 0, result.output
    assert "no measured targets in the config" in result.output
    summary = json.loads((tmp_path / "rve" / "statistics.json").read_text())
    assert summary["ks_diameter"] is None and summary["ks_window_tortuosity"] is None
