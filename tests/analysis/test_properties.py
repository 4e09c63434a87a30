"""Properties from a stress-strain curve: the bilinear fit on curves with known answers."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from espin.analysis.properties import (
    CurveError,
    CurveProperties,
    bilinear_stress,
    curve_properties,
    simulation_properties,
    summarize_properties,
)
from espin.core.errors import EspinError

# A PLLA-like curve (paper Fig. 13): E = 200 MPa, yield at 3 % and 6 MPa, then H = 5 MPa to 30 %.
E, YIELD_STRAIN, H = 200.0, 0.03, 5.0
YIELD_STRESS = E * YIELD_STRAIN
STRAIN = np.linspace(0.0, 0.30, 301)


def bilinear(strain):
    return np.where(strain < YIELD_STRAIN, E * strain, YIELD_STRESS + H * (strain - YIELD_STRAIN))


def test_exact_bilinear_curve_is_recovered():
    props = curve_properties(STRAIN, bilinear(STRAIN))
    assert props.has_yield and props.note == ""
    assert props.modulus_MPa == pytest.approx(E, rel=1e-9)
    assert props.post_yield_modulus_MPa == pytest.approx(H, rel=1e-6)
    assert props.yield_strain == pytest.approx(YIELD_STRAIN, rel=1e-6)
    assert props.yield_stress_MPa == pytest.approx(YIELD_STRESS, rel=1e-6)
    assert props.r_squared == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(bilinear_stress(props, STRAIN), bilinear(STRAIN), atol=1e-6)


def test_coarse_curve_with_the_knee_between_samples():
    # 1 % steps (like a simulation) and a yield at 3.5 %, between two samples.
    strain = np.linspace(0.0, 0.30, 31)
    stress = np.where(strain < 0.035, E * strain, 7.0 + H * (strain - 0.035))
    props = curve_properties(strain, stress)
    assert props.has_yield
    assert props.modulus_MPa == pytest.approx(E, rel=1e-9)
    assert props.yield_strain == pytest.approx(0.035, rel=1e-6)
    assert props.post_yield_modulus_MPa == pytest.approx(H, rel=1e-6)


def test_noisy_bilinear_curve_within_statistical_tolerance():
    # Gaussian noise of sd 0.05 MPa (0.8 % of the yield stress; a load cell's noise on a mat).
    # Tolerances are 4 standard errors: the elastic line rests on the 16 points below half the
    # knee (15 intervals of 0.001), so SE(E) = sd sqrt(12 / 16) / 0.015 = 2.9 MPa (1.4 %); the
    # post-yield line on ~270 points over 0.27, SE(H) = sd sqrt(12 / 270) / 0.27 = 0.04 MPa.
    # Over 300 seeds the scatter was 2.8 MPa, 0.043 MPa, 0.007 MPa and 4.3e-4 in yield strain.
    rng = np.random.default_rng(7)
    stress = bilinear(STRAIN) + rng.normal(0.0, 0.05, STRAIN.size)
    props = curve_properties(STRAIN, stress)
    assert props.has_yield
    assert abs(props.modulus_MPa - E) < 4 * 2.9
    assert abs(props.post_yield_modulus_MPa - H) < 4 * 0.043
    assert abs(props.yield_stress_MPa - YIELD_STRESS) < 4 * 0.007
    assert abs(props.yield_strain - YIELD_STRAIN) < 4 * 4.3e-4
    assert props.r_squared > 0.99


def smooth_knee(strain, width):
    """Bilinear curve whose corner is rounded over about +-2 width (softplus); its asymptotes
    are exactly the lines E e and sigma_y + H (e - e_y)."""
    return E * strain - (E - H) * width * np.logaddexp(0.0, (strain - YIELD_STRAIN) / width)


@pytest.mark.parametrize("width", [0.001, 0.003])
def test_smooth_knee_gives_the_asymptotic_lines(width):
    # The curve leaves the elastic line by (E - H) w log 2 at the yield strain and meets its
    # asymptotes within about 5 w, so the fit (on straight windows away from the knee) is biased
    # by a fraction of w / e_y: tolerances 1 % of E and yield, 5 % of H (the hinge's post-yield
    # line still sees the end of the rounding).
    props = curve_properties(STRAIN, smooth_knee(STRAIN, width))
    assert props.has_yield
    assert props.modulus_MPa == pytest.approx(E, rel=0.01)
    assert props.yield_stress_MPa == pytest.approx(YIELD_STRESS, rel=0.01)
    assert props.yield_strain == pytest.approx(YIELD_STRAIN, rel=0.01)
    assert props.post_yield_modulus_MPa == pytest.approx(H, rel=0.05)


def test_rounded_tanh_knee_initial_slope_and_yield():
    # s = 6 tanh(200 e / 6) + 5 e: initial slope 205 MPa, asymptote 6 + 5 e, which meets the
    # initial tangent at e = 0.03 (sigma 6.15 MPa). The knee is broad (tanh(1) = 0.76 there), so
    # even the points below half the knee bend: the elastic window underestimates the initial
    # slope (by about 10 %), but far less than the hinge's secant line (about 25 % low).
    stress = 6.0 * np.tanh(E * STRAIN / 6.0) + H * STRAIN
    props = curve_properties(STRAIN, stress)
    assert props.has_yield
    assert 0.85 * 205.0 < props.modulus_MPa <= 205.0
    assert props.yield_strain == pytest.approx(0.03, rel=0.15)
    assert props.yield_stress_MPa == pytest.approx(6.15, rel=0.05)
    assert H < props.post_yield_modulus_MPa < 1.5 * H


def test_strain_offset_is_compensated():
    # The same curve recorded with its strain origin 0.5 % early (slack in the grips).
    shifted = curve_properties(STRAIN + 0.005, bilinear(STRAIN))
    assert shifted.has_yield
    assert shifted.strain_offset == pytest.approx(0.005, rel=1e-6)
    assert shifted.yield_strain == pytest.approx(YIELD_STRAIN, rel=1e-6)
    assert shifted.modulus_MPa == pytest.approx(E, rel=1e-9)
    assert shifted.yield_stress_MPa == pytest.approx(YIELD_STRESS, rel=1e-6)


def test_toe_region_is_left_out_with_strain_range():
    # A concave toe: slack taken up over the first 1 % before the linear part starts.
    toe = 0.01
    stress = np.where(STRAIN < toe, 0.5 * E * STRAIN**2 / toe, bilinear(STRAIN - toe / 2))
    props = curve_properties(STRAIN, stress, strain_range=(toe, None))
    assert props.has_yield
    assert props.modulus_MPa == pytest.approx(E, rel=1e-6)
    assert props.strain_offset == pytest.approx(toe / 2, rel=1e-6)
    assert props.yield_strain == pytest.approx(YIELD_STRAIN, rel=1e-6)


@pytest.mark.parametrize("noise", [0.0, 0.5])
def test_linear_curve_has_no_yield(noise):
    rng = np.random.default_rng(3)
    stress = 1.0 + E * STRAIN + rng.normal(0.0, noise, STRAIN.size)
    props = curve_properties(STRAIN, stress)
    assert not props.has_yield
    assert math.isnan(props.yield_stress_MPa) and math.isnan(props.yield_strain)
    assert math.isnan(props.post_yield_modulus_MPa)
    assert "no clear yield" in props.note
    assert props.modulus_MPa == pytest.approx(E, rel=0.01)  # one line through all points


def test_nearly_equal_slopes_have_no_yield():
    stress = np.where(STRAIN < 0.1, E * STRAIN, 0.1 * E + 0.8 * E * (STRAIN - 0.1))
    props = curve_properties(STRAIN, stress)
    assert not props.has_yield and "80%" in props.note


def test_breakpoint_at_the_end_of_the_data_has_no_yield():
    strain = np.linspace(0.0, 0.03, 31)
    stress = np.where(strain < 0.029, E * strain, E * 0.029 + H * (strain - 0.029))
    props = curve_properties(strain, stress)
    assert not props.has_yield and "end of the data" in props.note


def test_stiffening_curve_has_no_yield():
    props = curve_properties(STRAIN, 10.0 * STRAIN + 500.0 * STRAIN**2)
    assert not props.has_yield and props.note


def test_too_few_points():
    props = curve_properties([0.0, 0.01, 0.02], [0.0, 2.0, 4.0])
    assert not props.has_yield and "too few" in props.note
    assert props.modulus_MPa == pytest.approx(200.0)


@pytest.mark.parametrize(
    ("strain", "stress", "message"),
    [
        ([0.0, 0.01, np.nan], [0.0, 1.0, 2.0], "not finite"),
        ([0.0, 0.02, 0.01], [0.0, 1.0, 2.0], "strain decreases at point 2"),
        ([0.0, 0.01], [0.0, 1.0, 2.0], "one length"),
        ([0.0], [0.0], "two distinct strains"),
    ],
)
def test_bad_curves_raise(strain, stress, message):
    with pytest.raises(CurveError, match=message) as info:
        curve_properties(strain, stress)
    assert isinstance(info.value, EspinError)


@pytest.mark.parametrize("stress", [np.zeros(301), np.full(301, 5.0), 5.0 + 1e-12 * np.sin(100 * STRAIN)])
def test_constant_stress_has_no_slope_and_no_yield(stress):
    # A flat curve (a wrong column, or no load carried): modulus 0, no yield, no zero crossing.
    props = curve_properties(STRAIN, stress)
    assert not props.has_yield and "stress is constant" in props.note
    assert props.modulus_MPa == 0.0
    assert math.isnan(props.strain_offset) and math.isnan(props.r_squared)
    assert math.isnan(props.yield_stress_MPa) and math.isnan(props.post_yield_modulus_MPa)
    assert np.isnan(bilinear_stress(props, STRAIN)).all()  # no line to draw
    two = curve_properties([0.0, 0.01], [3.0, 3.0])
    assert two.modulus_MPa == 0.0 and "constant (3 MPa at all 2 points)" in two.note


def test_flat_line_with_noise_has_no_strain_offset():
    # Zero slope up to rounding: its zero crossing (1e14 and more) would be noise.
    stress = np.where(np.arange(STRAIN.size) == 150, 1.0, 0.0)
    props = curve_properties(STRAIN, stress)
    assert not props.has_yield and abs(props.modulus_MPa) < 1e-12
    assert math.isnan(props.strain_offset)


def test_two_points_are_one_line():
    props = curve_properties([0.0, 0.01], [1.0, 3.0])
    assert not props.has_yield and "only 2 points" in props.note
    assert props.modulus_MPa == pytest.approx(200.0)
    assert props.strain_offset == pytest.approx(-0.005)


def test_repeated_first_strains_keep_a_determined_elastic_line():
    # Three readings at zero strain (load settling), then a coarse bilinear curve: the elastic
    # window must reach the next strain, not fit a line through one strain (a LinAlgError before).
    strain = np.r_[0.0, 0.0, 0.0, np.arange(1, 11) * 0.01]
    stress = np.where(strain < 0.015, E * strain, E * 0.015 + H * (strain - 0.015))
    stress[1:3] += (0.2, -0.2)
    props = curve_properties(strain, stress)
    assert props.has_yield, props.note
    assert props.modulus_MPa == pytest.approx(E, rel=1e-9)
    assert props.yield_stress_MPa == pytest.approx(E * 0.015, rel=1e-6)


@pytest.mark.parametrize("scale", [1e-300, 2.0**-1000, 1e300])
def test_tiny_and_huge_stresses_scale_the_results(scale):
    reference = curve_properties(STRAIN, bilinear(STRAIN))
    props = curve_properties(STRAIN, scale * bilinear(STRAIN))
    assert props.has_yield
    assert props.modulus_MPa == pytest.approx(scale * reference.modulus_MPa, rel=1e-12)
    assert props.yield_stress_MPa == pytest.approx(scale * reference.yield_stress_MPa, rel=1e-12)
    assert props.post_yield_modulus_MPa == pytest.approx(scale * reference.post_yield_modulus_MPa, rel=1e-12)
    assert props.yield_strain == pytest.approx(reference.yield_strain, rel=1e-12)


@pytest.mark.parametrize(
    ("strain_range", "message"),
    [
        ((0.2, 0.1), r"strain_range must be \(min, max\) strains with min < max.*got \(0.2, 0.1\)"),
        ((0.1, 0.1), "min < max"),
        ((math.nan, None), "finite numbers"),
        (("a", None), "got \\('a', None\\)"),
        ((0.1,), "got \\(0.1,\\)"),
        ((0.5, None), r"two distinct strains within strain_range \(0.5, None\) to fit, got 0"),
    ],
)
def test_bad_strain_range_raises(strain_range, message):
    with pytest.raises(CurveError, match=message):
        curve_properties(STRAIN, bilinear(STRAIN), strain_range=strain_range)


def test_non_numeric_curve_raises():
    with pytest.raises(CurveError, match="arrays of numbers"):
        curve_properties(["0", "x"], [0.0, 1.0])
    with pytest.raises(CurveError, match="two distinct strains to fit, got 1"):
        curve_properties([0.01] * 5, [0.0, 1.0, 2.0, 3.0, 4.0])


def test_options_are_checked():
    with pytest.raises(CurveError, match="elastic_fraction"):
        curve_properties(STRAIN, bilinear(STRAIN), elastic_fraction=0.0)
    with pytest.raises(CurveError, match="max_slope_ratio"):
        curve_properties(STRAIN, bilinear(STRAIN), max_slope_ratio=1.5)


def test_as_dict_and_summary():
    rng = np.random.default_rng(11)
    specimens = [curve_properties(STRAIN, bilinear(STRAIN) + rng.normal(0.0, 0.05, STRAIN.size))
                 for _ in range(3)]
    linear = curve_properties(STRAIN, E * STRAIN)
    row = specimens[0].as_dict()
    assert set(row) == {f for f in CurveProperties.__dataclass_fields__}
    summary = summarize_properties([*specimens, linear])
    moduli = [p.modulus_MPa for p in specimens] + [linear.modulus_MPa]
    assert summary["modulus_MPa"]["mean"] == pytest.approx(np.mean(moduli))
    assert summary["modulus_MPa"]["sd"] == pytest.approx(np.std(moduli, ddof=1))
    assert summary["yield_stress_MPa"]["n"] == 3  # the linear curve has no yield


@pytest.fixture(scope="module")
def plla_result():
    import espin

    return espin.simulate("plla", rve__size_ratio=60, rve__layers=5)


@pytest.mark.slow
def test_simulated_plla_curve(plla_result):
    props = simulation_properties(plla_result)
    assert props.has_yield, props.note
    # The paper's mats: linear to about 3 %, then yield (SPEC 7).
    assert 0.01 < props.yield_strain < 0.06
    assert props.modulus_MPa > props.post_yield_modulus_MPa > 0.0
    assert props.modulus_MPa > 10 * props.post_yield_modulus_MPa
    assert props.r_squared > 0.95
    # The curve is concave, so the lines' intersection lies above it, below its final stress.
    stress = plla_result.stress()
    on_curve = np.interp(props.yield_strain + props.strain_offset, plla_result.strain, stress)
    assert on_curve <= props.yield_stress_MPa < stress[-1]


# --------------------------------------------------------------------------------------------
# The ``properties`` command
# --------------------------------------------------------------------------------------------
def cli():
    import typer

    from espin.cli.properties import register

    app = typer.Typer()
    register(app)
    app.callback()(lambda: None)  # keep "properties" as a subcommand, as in espin's app
    return app


def invoke(*args):
    from typer.testing import CliRunner

    return CliRunner().invoke(cli(), ["properties", *map(str, args)])


def test_command_reads_espin_curve_csv(plla_result, tmp_path):
    from espin.mechanics.results_file import write_results

    curve = write_results(plla_result, tmp_path)["curve_csv"]
    result = invoke(curve, "--out", tmp_path / "props")
    assert result.exit_code == 0, result.output
    expected = simulation_properties(plla_result)
    assert f"{expected.modulus_MPa:.4g}" in result.output
    assert f"{expected.yield_stress_MPa:.4g}" in result.output
    table = pd.read_csv(tmp_path / "props" / "properties.csv")
    assert table["modulus_MPa"].iloc[0] == pytest.approx(expected.modulus_MPa, rel=1e-9)
    assert (tmp_path / "props" / "properties.png").exists()
    assert not (tmp_path / "props" / "average_curve.csv").exists()  # one curve: no average


def test_command_averages_specimens(tmp_path):
    # Three specimens in percent strain with a European-style header, moduli 190 / 200 / 210.
    strain_pct = np.linspace(0.0, 30.0, 151)
    moduli = (190.0, 200.0, 210.0)
    for k, modulus in enumerate(moduli):
        stress = np.minimum(modulus * strain_pct / 100, 6.0) + H * np.maximum(strain_pct / 100 - 6.0 / modulus, 0)
        np.savetxt(tmp_path / f"s{k}.csv", np.c_[strain_pct, stress], delimiter=";",
                   header="Strain [%];Stress [MPa]", comments="")
    files = [tmp_path / f"s{k}.csv" for k in range(3)]
    result = invoke(*files, "--percent-strain", "--stress-column", "Stress [MPa]", "-o", tmp_path / "out")
    assert result.exit_code == 0, result.output
    assert "200 ± 10" in result.output  # mean ± sample sd of the three moduli
    table = pd.read_csv(tmp_path / "out" / "properties.csv").set_index("curve")
    assert table.loc["mean", "modulus_MPa"] == pytest.approx(200.0, rel=1e-6)
    assert table.loc["sd", "modulus_MPa"] == pytest.approx(10.0, rel=1e-5)
    assert table.loc["mean", "yield_stress_MPa"] == pytest.approx(6.0, rel=1e-6)
    average = pd.read_csv(tmp_path / "out" / "average_curve.csv")
    assert list(average.columns) == ["strain", "mean_MPa", "sd_MPa", "n"] and (average["n"] == 3).all()


def test_command_reports_bad_files(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("strain,stress\n0,0\n0.01,oops\n")
    result = invoke(bad)
    assert result.exit_code == 3  # bad input data (docs/command_line.md)
    assert "bad.csv, line 3" in result.output and "oops" in result.output
    result = invoke(bad, "--stress-column", "load")
    assert result.exit_code == 3 and "no stress column named 'load'" in result.output


def toe_specimen(path, toe=0.01):
    """A specimen in percent strain with a concave toe over the first ``toe`` of strain."""
    stress = np.where(STRAIN < toe, 0.5 * E * STRAIN**2 / toe, bilinear(STRAIN - toe / 2))
    np.savetxt(path, np.c_[100 * STRAIN, stress], delimiter=",", header="Strain,Stress", comments="")
    return stress


def test_command_strain_range_leaves_out_a_toe(tmp_path):
    stress = toe_specimen(tmp_path / "toe.csv")
    expected = curve_properties(STRAIN, stress, strain_range=(0.01, None))
    assert expected.modulus_MPa == pytest.approx(E, rel=1e-6)
    whole = curve_properties(STRAIN, stress)
    assert abs(whole.modulus_MPa - E) > 0.05 * E  # without the option the toe biases E
    # Percent strain: the range is in the file's units (1 % -> 0.01).
    result = invoke(tmp_path / "toe.csv", "--percent-strain", "--strain-range", "1:", "-o", tmp_path / "out")
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "out" / "properties.csv")
    assert table["modulus_MPa"].iloc[0] == pytest.approx(expected.modulus_MPa, rel=1e-9)  # %.10g
    assert table["strain_offset"].iloc[0] == pytest.approx(0.005, rel=1e-6)
    # The same range in fractions without --percent-strain, closed on both ends.
    np.savetxt(tmp_path / "frac.csv", np.c_[STRAIN, stress], delimiter=",", header="strain,stress", comments="")
    result = invoke(tmp_path / "frac.csv", "--strain-range", "0.01:0.25", "-o", tmp_path / "frac")
    assert result.exit_code == 0, result.output
    closed = curve_properties(STRAIN, stress, strain_range=(0.01, 0.25))
    table = pd.read_csv(tmp_path / "frac" / "properties.csv")
    assert table["yield_stress_MPa"].iloc[0] == pytest.approx(closed.yield_stress_MPa, rel=1e-9)


@pytest.mark.parametrize("text", ["0.2:0.1", "1:2:3", "a:", "nan:"])
def test_command_bad_strain_range(tmp_path, text):
    toe_specimen(tmp_path / "toe.csv")
    result = invoke(tmp_path / "toe.csv", "--strain-range", text)
    assert result.exit_code == 2
    assert "--strain-range: LO:HI" in result.output and repr(text) in result.output


def test_command_names_the_curve_that_cannot_be_fitted(tmp_path):
    toe_specimen(tmp_path / "toe.csv")
    result = invoke(tmp_path / "toe.csv", "--percent-strain", "--strain-range", "50:")  # ends at 30 %
    assert result.exit_code == 3
    assert "toe.csv: a curve needs at least two distinct strains within strain_range" in result.output
