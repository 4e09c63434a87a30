"""RVE-size and sweep studies on tiny RVEs, their files, and the ``espin study`` commands."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import typer
from typer.testing import CliRunner

from espin.cli.study import parse_grid, register
from espin.core.errors import ConfigError
from espin.studies.sweeps import rve_size_study, sweep

TINY = {"loading__max_strain": 0.08, "loading__steps": 8}


@pytest.mark.slow
def test_rve_size_study_series_and_files(tmp_path):
    result = rve_size_study("plla", size_ratios=(25, 35), layer_counts=(2, 3), layers_for_sizes=2,
                            size_for_layers=35, realizations=2, folder=tmp_path, workers=1, **TINY)
    summary = result.summary
    points = set(zip(summary["rve.size_ratio"], summary["rve.layers"]))
    assert points == {(25.0, 2), (35.0, 2), (35.0, 3)}  # the shared point (35, 2) once
    assert (summary["n"] == 2).all()
    table = result.table
    for (size, layers), group in table.groupby(["rve.size_ratio", "rve.layers"]):
        row = summary[(summary["rve.size_ratio"] == size) & (summary["rve.layers"] == layers)].iloc[0]
        assert row["modulus_MPa_mean"] == pytest.approx(group["modulus_MPa"].mean())
        assert row["modulus_MPa_sd"] == pytest.approx(group["modulus_MPa"].std(ddof=1))
        assert row["modulus_MPa_rsd"] == pytest.approx(row["modulus_MPa_sd"] / row["modulus_MPa_mean"])
    for name in ("results.csv", "summary.csv", "study.toml", "rve_size_modulus.png",
                 "rve_size_yield_stress.png", "rve_size_post_yield_modulus.png", "rve_size_curves.png"):
        assert (tmp_path / name).is_file(), name
    assert len(list((tmp_path / "tasks").glob("*.json"))) == 6


@pytest.mark.slow
def test_sweep_grid_table_and_parquet(tmp_path):
    grid = {"rve.volume_fraction": [0.15, 0.25], "rve.orientation.von_mises.kappa": [0.0, 4.0]}
    result = sweep("plla", grid, realizations=1, folder=tmp_path, table_format="parquet", workers=1,
                   rve__size_ratio=30, rve__layers=2, **TINY)
    table = pd.read_parquet(tmp_path / "sweep.parquet")
    assert len(table) == 4 and set(table.columns) >= {"rve.volume_fraction", "rve.orientation.von_mises.kappa",
                                                      "seed", "modulus_MPa", "yield_stress_MPa"}
    # a denser mat is stiffer, at either orientation spread (same seed: common random numbers)
    for _, group in table.groupby("rve.orientation.von_mises.kappa"):
        moduli = group.sort_values("rve.volume_fraction")["modulus_MPa"].to_numpy()
        assert moduli[1] > moduli[0]
    assert (tmp_path / "sweep_modulus.png").is_file()
    assert len(result.summary) == 4


@pytest.mark.slow
def test_sweep_text_values_and_numpy_grid(tmp_path):
    grid = {"rve.seeding": ["lines", "border"], "rve.volume_fraction": np.array([0.15, 0.25])}
    result = sweep("plla", grid, folder=tmp_path, workers=1, rve__size_ratio=30, rve__layers=2, **TINY)
    assert len(result.table) == 4 and (tmp_path / "sweep_modulus.png").is_file()
    assert set(result.table["rve.seeding"]) == {"lines", "border"}


@pytest.mark.slow
def test_rerun_with_a_grown_grid_reuses_tasks_under_the_new_names(tmp_path):
    base = {"rve__size_ratio": 30, "rve__layers": 2, **TINY}
    sweep("plla", {"rve.volume_fraction": [0.15, 0.2]}, folder=tmp_path, workers=1, **base)
    grown = sweep("plla", {"rve.volume_fraction": [0.15, 0.2], "rve.layers": [2, 3]}, folder=tmp_path,
                  workers=1, **{k: v for k, v in base.items() if k != "rve__layers"})
    assert grown.ensemble.skipped == 2  # layers = 2 was the base value: the same configs
    assert grown.table["rve.layers"].notna().all()
    assert sorted(grown.summary["rve.layers"]) == [2, 2, 3, 3]


def test_rve_size_refuses_size_overrides():
    with pytest.raises(ConfigError, match="rve.layers"):
        rve_size_study("plla", rve__layers=3)


def test_sweep_bad_grid_named_before_work(tmp_path):
    with pytest.raises(ConfigError, match="rve.layers"):
        sweep("plla", {"rve.layers": [2, 0]}, folder=tmp_path, workers=1)
    with pytest.raises(ConfigError, match="rve.seed"):
        sweep("plla", {"rve.seed": [1, 2]}, folder=tmp_path, workers=1)
    assert not (tmp_path / "tasks").exists()


def test_parse_grid():
    grid = parse_grid(["rve.volume_fraction=0.1:0.3:3", "rve.orientation.von_mises.kappa=0,2,8",
                       "rve.seeding=lines,border"])
    assert np.allclose(grid["rve.volume_fraction"], [0.1, 0.2, 0.3])
    assert grid["rve.orientation.von_mises.kappa"] == [0, 2, 8]
    assert grid["rve.seeding"] == ["lines", "border"]
    for bad in (["rve.layers"], ["rve.layers=1:2:x"], ["rve.layers=1,2", "rve.layers=3"]):
        with pytest.raises(ConfigError, match="--grid"):
            parse_grid(bad)


@pytest.mark.slow
def test_study_sweep_command_resumes(tmp_path):
    app = typer.Typer()
    register(app)
    app.command("noop")(lambda: None)  # a second command, so "study" stays a group
    args = ["study", "sweep", "plla", "--grid", "fiber.flow_resistance_MPa=4,6", "--workers", "1",
            "--out", str(tmp_path), "--set", "rve.size_ratio=30", "--set", "rve.layers=2",
            "--set", "loading.max_strain=0.08", "--set", "loading.steps=8"]
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    assert len((tmp_path / "results.csv").read_text().splitlines()) == 3
    second = CliRunner().invoke(app, args)
    assert second.exit_code == 0 and "2 task(s) were already finished" in second.output
