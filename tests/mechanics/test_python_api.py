"""The Python objects at a prompt or in Jupyter: one-line reprs with the key numbers, HTML
tables, curves as DataFrames, and load_results on a results folder."""

from __future__ import annotations

import re

import numpy as np
import pytest

import espin.geometry.rve
from espin.analysis.calibration.result import FitResult
from espin.core.config import load_config
from espin.core.errors import RVEFileError
from espin.imaging.measurement import measure
from espin.imaging.synthetic import render_sem
from espin.mechanics.results_file import load_results
from espin.mechanics.run import simulate

STEPS = 3
CURVE_COLUMNS = ["step", "time_s", "strain",
                 *(f"{p}{i}{j}{u}" for p, u in (("F", ""), ("P", "_MPa"), ("paper", "_MPa"), ("kirchhoff", "_MPa"),
                                                ("cauchy", "_MPa"))
                   for i in (1, 2) for j in (1, 2)),
                 "stress_MPa", "recruited_fraction", "yielded_fraction", "iterations", "factorizations",
                 "substeps", "residual_uN"]


@pytest.fixture(scope="module")
def run(small_rve, tmp_path_factory):
    """A short tensile test of the session's small RVE, and its results folder."""
    folder = tmp_path_factory.mktemp("run")
    result = simulate(small_rve, folder, loading__max_strain=0.02, loading__steps=STEPS)
    return result, folder


def assert_short(text: str, *numbers: object) -> None:
    """One line under 200 characters that shows each number."""
    assert "\n" not in text and len(text) < 200, text
    for number in numbers:
        assert re.search(rf"(?<![\d.]){re.escape(str(number))}(?![\d])", text), (number, text)


def assert_html(html: str, *numbers: object) -> None:
    assert html.startswith("<table") and html.endswith("</table>")
    for number in numbers:
        assert str(number) in html, (number, html)


def test_rve_repr_shows_its_size_and_network(small_rve):
    rve, network = small_rve, small_rve.network
    text = repr(rve)
    assert text.startswith("RVE(")
    assert_short(text, "L/D 40", f"{rve.mat.n_layers} layers", f"{rve.mat.n_fibers} fibers",
                 f"{rve.crosslinks.n} cross-links", f"{network.n_nodes} nodes", f"{network.n_dof} DOF",
                 f"seed {rve.config.rve.seed}", rve.config.rve.sampling)
    assert f"side {rve.config.rve.side_um:.4g} um" in text
    assert_html(rve._repr_html_(), rve.mat.n_fibers, network.n_dof, network.n_elements)


def test_simulation_result_repr_and_dataframe(run):
    result, _ = run
    stress = result.stress()
    text = repr(result)
    assert text.startswith("SimulationResult(uniaxial, ")
    assert_short(text, f"{STEPS} steps", "max strain 0.02", f"peak {np.max(np.abs(stress)):.4g} MPa",
                 f"last {stress[-1]:.4g} MPa", f"{len(result.final.stress)} elements")
    assert_html(result._repr_html_(), f"{stress[-1]:.4g} MPa", "uniaxial")
    table = result.to_dataframe()
    assert list(table.columns) == CURVE_COLUMNS
    assert len(table) == STEPS + 1 == len(result.time)
    assert np.array_equal(table["stress_MPa"], stress)
    assert np.array_equal(table["strain"], result.strain)
    assert np.array_equal(table["P12_MPa"], result.P[:, 0, 1])
    assert np.array_equal(table["iterations"], result.iterations)


def test_results_file_dataframe_matches_curve_csv(run):
    import pandas as pd

    result, folder = run
    back = load_results(folder / "results.h5")
    table = back.to_dataframe()
    assert list(table.columns) == CURVE_COLUMNS and len(table) == STEPS + 1
    assert np.array_equal(table["stress_MPa"], back.steps["stress_MPa"])
    assert np.array_equal(table["stress_MPa"], result.stress())
    pd.testing.assert_frame_equal(table, pd.read_csv(folder / "curve.csv"), check_dtype=False, rtol=1e-15)
    text = repr(back)
    assert text.startswith("ResultsFile(uniaxial, ")
    assert_short(text, f"{STEPS} steps", "max strain 0.02", f"last {result.stress()[-1]:.4g} MPa",
                 f"seed {back.seed}", "complete")
    assert_html(back._repr_html_(), "complete", back.provenance["run_id"])


def test_load_results_reads_a_results_folder(run, tmp_path):
    _, folder = run
    from_folder, from_file = load_results(folder), load_results(folder / "results.h5")
    assert from_folder.config == from_file.config and from_folder.status == from_file.status == "complete"
    for group in ("steps", "final"):
        a, b = getattr(from_folder, group), getattr(from_file, group)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), group
    (tmp_path / "curve.csv").write_text("step\n0\n", encoding="utf-8")
    with pytest.raises(RVEFileError, match=rf"^{re.escape(str(tmp_path))}: is a folder without results\.h5; "
                                           r"expected .*espin simulate"):
        load_results(tmp_path)


def test_fit_result_repr_html_and_evaluations():
    keys = ("rve.volume_fraction", "fiber.flow_resistance_MPa")
    values = {keys[0]: 0.1912, keys[1]: 23.45}
    sd = {keys[0]: 0.0123, keys[1]: 1.5}
    history = tuple({"evaluation": k + 1, "stage": "fiber", keys[0]: 0.19, "fiber.flow_resistance_MPa": v,
                     "sse_MPa2": s, "failed_simulations": 0}
                    for k, (v, s) in enumerate([(20.0, 3.0), (23.45, 1.2)]))
    fit = FitResult(parameters=keys, values=values, uncertainties=sd, gauss_newton_sd=sd, realization_sd=None,
                    eta_profile_sd=None, eta_resolution=0.004, at_bound={k: None for k in keys}, warnings=(),
                    correlation=np.eye(2), bounds={keys[0]: (0.1, 0.3), keys[1]: (5.0, 50.0)}, fixed={},
                    r_squared=0.9876, rmse_MPa=0.123, config=load_config(None), curves=(), seeds=(1,),
                    eta_profile=None, failed_etas=(), history=history, simulations=8, failed_simulations=0,
                    elapsed_s=12.0, pool="serial", load_steps=())
    text = repr(fit)
    assert_short(text, "eta 0.1912 +- 0.0123", "b_p 23.45 +- 1.5 MPa", "RMS 0.123 MPa", "R^2 0.9876",
                 "8 simulations")
    assert_html(fit._repr_html_(), "fiber.flow_resistance_MPa", "0.123 MPa", "8 (0 failed)")
    table = fit.to_dataframe()
    assert len(table) == len(history)
    assert list(table.columns) == ["evaluation", "stage", *keys, "sse_MPa2", "failed_simulations"]
    assert np.array_equal(table["sse_MPa2"], [3.0, 1.2])


def test_sem_measurement_repr_and_html():
    mat = espin.geometry.rve.generate("plla", rve__size_ratio=40, rve__layers=2, rve__seed=4,
                                      rve__max_deviation_deg=20.0).mat
    image = render_sem(mat, side_um=30 * 0.45, layers=2, seed=4)
    result = measure(image.image, um_per_px=image.um_per_px)
    d = result.fits.diameter
    text = repr(result)
    assert text.startswith("SEMMeasurement(array, ")
    assert_short(text, f"{result.um_per_px:.4g} um/px", f"{len(result.fibers)} fibers",
                 f"diameter {d.mean_um:.3g} +- {d.sd_um:.2g} um")
    assert_html(result._repr_html_(), "µm/px", "fibers traced")
    assert " um" not in result._repr_html_()  # the unit typeset in the notebook's table
