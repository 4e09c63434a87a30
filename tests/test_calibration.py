"""Calibration (paper 4.2): parameter recovery on synthetic curves, eta search, two rates, errors.

Small RVEs (L = 50 D, 4 layers, 12 load steps to 15 %): a curve takes ~0.1-0.2 s. The synthetic
"measured" curves come from the same seeds as the fit (so the exact answer is reachable), with
noise added: the tests check that the fit finds the true values within the uncertainty it
reports, not that it matches a frozen number.
"""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

import espin.run
from espin.calibration import fit, parameter_key, synthetic_curve
from espin.config import load_config
from espin.errors import ConfigError, SolverError
from espin.rve import generate, resolve_config

STRAIN = np.linspace(0.005, 0.15, 30)
STEPS = 12
SEEDS = (1, 2)


@pytest.fixture(scope="module")
def base():
    """A small plla RVE whose flow parameters differ from the truth (the fit's start)."""
    return resolve_config("plla", rve__size_ratio=50, rve__layers=4)


@pytest.fixture(scope="module")
def flow_fit(base):
    """b_p and c_p fitted to a noisy synthetic curve made with b_p = 4, c_p = 0.8."""
    truth = resolve_config(base, fiber__flow_resistance_MPa=4.0, fiber__hardening_exponent=0.8)
    data = synthetic_curve(truth, STRAIN, seeds=SEEDS, steps=STEPS, noise_sd_MPa=0.05, rng=0)
    return fit(data, base=base, parameters=("b_p", "c_p"), seeds=SEEDS, steps=STEPS)


def test_recovers_flow_parameters_within_their_uncertainty(flow_fit):
    true = {"fiber.flow_resistance_MPa": 4.0, "fiber.hardening_exponent": 0.8}
    for key, value in true.items():
        error = abs(flow_fit.values[key] - value)
        # The data come from the fit's own realizations, so only the noise moves the optimum:
        # within 3 Gauss-Newton sd, or the fit misjudged its precision or missed the optimum.
        assert error < 3 * flow_fit.gauss_newton_sd[key], (key, flow_fit.values[key])
        assert flow_fit.gauss_newton_sd[key] < 0.1 * value  # 0.05 MPa noise pins both well
        # The total adds the realizations' share: sd over RVEs / sqrt(2).
        total = math.hypot(flow_fit.gauss_newton_sd[key], flow_fit.realization_sd[key] / math.sqrt(2))
        assert flow_fit.uncertainties[key] == pytest.approx(total)
    assert flow_fit.r_squared > 0.999  # noise 0.05 MPa on a 0-6 MPa curve
    # b_p and c_p trade off (both raise the post-yield stress): a negative correlation.
    assert flow_fit.correlation[0, 1] < -0.5
    assert set(flow_fit.realization_sd) == set(flow_fit.parameters)
    assert all(sd > 0 for sd in flow_fit.realization_sd.values())


def test_scaling_moduli_and_flow_resistance_scales_every_stress(small_rve):
    """Why E_t, E_b and b_p cannot all be fitted with eta: together they are a stress scale."""
    plla = load_config("plla").fiber
    run = {"loading__max_strain": 0.08, "loading__steps": 8}
    k = 1.7
    one = espin.run.simulate(small_rve, **run)
    scaled = espin.run.simulate(
        small_rve, fiber__taut_modulus_MPa=k * plla.taut_modulus_MPa,
        fiber__slack_modulus_MPa=k * plla.slack_modulus_MPa,
        fiber__flow_resistance_MPa=k * plla.flow_resistance_MPa, **run,
    )
    # Exact up to the solver tolerance (rtol 1e-6 on forces).
    np.testing.assert_allclose(scaled.stress(), k * one.stress(), rtol=1e-5, atol=1e-9)


def test_eta_bracket_finds_the_network_of_the_data(base):
    """eta alone: a grid then a bracket search; data from eta = 0.22 with 0.05 MPa noise."""
    truth = resolve_config(base, rve__volume_fraction=0.22)
    data = synthetic_curve(truth, STRAIN, seeds=SEEDS, steps=STEPS, noise_sd_MPa=0.05, rng=1)
    result = fit(data, base=base, parameters=("eta",), bounds={"eta": (0.12, 0.3)}, seeds=SEEDS,
                 steps=STEPS, eta_points=4, eta_tolerance=0.002)
    # A layer gains a whole fiber at a time: eta moves in steps of about pi D / (4 L) per layer,
    # and the network (so the curve) is the same over such a step, so SSE(eta) is a staircase
    # at that scale and the bracket search ends on a local step. It must land within one
    # step of 0.22 and match the curve closely (R^2 > 0.99; eta = 0.12 or 0.30 give < 0).
    resolution = math.pi / (4 * base.rve.size_ratio)
    assert abs(result.values["rve.volume_fraction"] - 0.22) < resolution
    assert result.r_squared > 0.99
    profile = result.eta_profile
    assert profile.shape[0] >= 4 + 3  # the grid and the bracket search
    assert profile[:, 1].min() == pytest.approx(result.rmse_MPa**2 * STRAIN.size)  # the best kept
    assert profile[0, 1] > 100 * profile[:, 1].min()  # eta = 0.12 is far off
    assert 0 < result.gauss_newton_sd["rve.volume_fraction"] < resolution


def test_two_rates_identify_flow_rate(base):
    """a_p and b_p from curves at two strain rates (one rate fixes only b_p asinh(rate / a_p))."""
    truth = resolve_config(base, fiber__flow_rate_per_s=1e-8, fiber__flow_resistance_MPa=4.0)
    start = resolve_config(base, fiber__flow_rate_per_s=1e-6, fiber__flow_resistance_MPa=6.0)
    rates = (5e-4, 5e-2)
    curves = {r: synthetic_curve(truth, STRAIN, seeds=(1,), strain_rate_per_s=r, steps=STEPS,
                                 noise_sd_MPa=0.02, rng=int(1e4 * r)) for r in rates}
    result = fit(curves, base=start, parameters=("a_p", "b_p"), seeds=(1,), steps=STEPS)
    a_p, b_p = result.values["fiber.flow_rate_per_s"], result.values["fiber.flow_resistance_MPa"]
    assert abs(math.log(a_p / 1e-8)) < 3 * result.uncertainties["fiber.flow_rate_per_s"] / a_p
    assert abs(b_p - 4.0) < 3 * result.uncertainties["fiber.flow_resistance_MPa"]
    assert abs(math.log(a_p / 1e-8)) < math.log(3)  # from a start 100x off
    assert result.realization_sd is None  # one realization: no spread to report


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"parameters": ("b_q",)}, "unknown fit parameter 'b_q'"),
        ({"parameters": ("b_p",), "bounds": {"b_p": (-1.0, 10.0)}}, "fiber.flow_resistance_MPa"),
        ({"parameters": ("eta",), "bounds": {"eta": (0.1, 1.2)}}, "allowed range > 0 and < 1"),
        ({"parameters": ("a_p", "b_p")}, "fiber.flow_rate_per_s (a_p): from one strain rate"),
        ({"parameters": ("b_p",), "bounds": {"c_p": (0.0, 1.0)}}, "fiber.hardening_exponent, which is not fitted"),
        ({"parameters": ("b_p",), "fixed": {"flow_resistance_MPa": 3.0}}, "both fitted and fixed"),
        ({"parameters": ("E_t", "E_b"), "bounds": {"E_t": (10.0, 1e4), "E_b": (1.0, 20.0)}}, "must stay >"),
        ({"parameters": ("c_p",), "fixed": {"b_p": -2.0}}, "fiber.flow_resistance_MPa"),
        ({"parameters": ("c_p",), "seeds": (1, 1)}, "seeds"),
    ],
)
def test_bad_input_fails_before_any_simulation(monkeypatch, kwargs, message):
    def no_simulation(*args, **kw):
        raise AssertionError("a simulation started")

    monkeypatch.setattr(espin.run, "simulate", no_simulation)
    with pytest.raises(ConfigError) as info:
        fit((STRAIN, 40 * STRAIN), base="plla", **kwargs)
    assert message in str(info.value)


def test_parameter_names():
    assert parameter_key("eta") == parameter_key("volume_fraction") == "rve.volume_fraction"
    assert parameter_key("b_p") == parameter_key("flow_resistance_MPa") == "fiber.flow_resistance_MPa"
    assert parameter_key("fiber.taut_modulus_MPa") == parameter_key("E_t") == "fiber.taut_modulus_MPa"


def test_a_failing_model_is_an_error_naming_the_parameters(monkeypatch, base):
    import espin.calibration

    def failing(task):
        return np.full(task.strain.shape, np.nan), "step 2 did not converge"

    monkeypatch.setattr(espin.calibration, "_simulate_task", failing)
    with pytest.raises(SolverError, match="fiber.hardening_exponent = 0.5.*step 2 did not converge"):
        fit((STRAIN, 40 * STRAIN), base=base, parameters=("c_p",), seeds=(1,), steps=STEPS)


def test_written_files_reproduce_the_fit(flow_fit, tmp_path):
    written = flow_fit.write(tmp_path)
    assert {p.name for p in written.values()} == {"fitted.toml", "fit.csv", "fit.json", "fit.png"}
    assert (tmp_path / "fit.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    config = load_config(tmp_path / "fitted.toml")
    assert config.fiber.flow_resistance_MPa == flow_fit.values["fiber.flow_resistance_MPa"]
    assert config.loading.max_strain == pytest.approx(STRAIN[-1])
    # Running the fitted config gives the first realization's model curve.
    rerun = espin.run.simulate(generate(config))
    first = np.interp(STRAIN, rerun.strain, rerun.stress())
    report = json.loads((tmp_path / "fit.json").read_text())
    assert report["r_squared"] == pytest.approx(flow_fit.r_squared)
    assert [p["key"] for p in report["parameters"]] == list(flow_fit.parameters)
    table = np.genfromtxt(tmp_path / "fit.csv", delimiter=",", names=True)
    np.testing.assert_allclose(table["model_MPa"], flow_fit.curves[0].model_MPa)
    # The model is the mean of the two realizations; the first lies within their spread.
    assert np.all(np.abs(first - table["model_MPa"]) <= table["model_sd_MPa"] + 1e-9)


def test_cli_fit(tmp_path):
    from espin.cli_fit import register

    app = typer.Typer()
    register(app)
    app.command("noop")(lambda: None)  # a second command keeps "fit" a sub-command
    base = resolve_config("plla", rve__size_ratio=40, rve__layers=3)
    truth = resolve_config(base, fiber__hardening_exponent=0.8)
    files = []
    for k, seed in enumerate((1, 2)):
        c = synthetic_curve(truth, STRAIN[::2], seeds=(seed,), steps=10)
        path = tmp_path / f"specimen{k}.csv"
        path.write_text("strain_percent;stress_MPa\n" + "".join(
            f"{100 * e:.6f};{s:.6f}\n" for e, s in zip(c.strain, c.stress_MPa)))
        files.append(str(path))
    out = tmp_path / "fit"
    runner = CliRunner()
    result = runner.invoke(app, ["fit", *files, "--params", "c_p", "--bounds", "c_p=0:2",
                                 "--seeds", "1,2", "--steps", "10", "--workers", "1",
                                 "--set", "rve.size_ratio=40", "--set", "rve.layers=3",
                                 "--percent-strain", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "fiber.hardening_exponent" in result.output and "R^2" in result.output
    assert f"espin simulate {out}/fitted.toml" in result.output
    fitted = tomllib.loads((out / "fitted.toml").read_text())
    # Two specimens = the two realizations of the fit: the mean curve is matched exactly.
    assert fitted["fiber"]["hardening_exponent"] == pytest.approx(0.8, abs=0.02)
    bad = runner.invoke(app, ["fit", *files, "--params", "a_p", "-o", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "a_p" in bad.output
    assert not (tmp_path / "bad").exists()
