"""Geometry calibration: targets reached, parameters recovered where identifiable, clear errors.

Search settings are lighter than the defaults (4 seeds, >= 400 visible portions per
evaluation) to keep the file fast; the tolerances below come from the spread measured over
four independent "measured" mats (docs/geometry_calibration.md). KS p-values are descriptive
only (the parameters are fitted to the same sample): the tests assert on the fitted
parameters and on KS distances.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import typer
from scipy import special, stats
from typer.testing import CliRunner

from espin.cli.calibrate_geometry import register
from espin.core.config import load_config
from espin.core.errors import ConfigError, EspinError
from espin.geometry.deposition import deposit
from espin.geometry.orientation import VonMisesOrientation
from espin.geometry.statistics import centred_window, window_tortuosity
from espin.geometry.targets import GeometryTargets, MeasurementError, equivalent_square_side
from espin.imaging.geometry_calibration import (
    MECHANICS_NOTE,
    VirtualMeasurement,
    calibrate_geometry,
    fit_axial_von_mises,
    persistence_ratio,
    truncated_normal_parameters,
)
from espin.geometry.pieces import _point_at, window_runs

FAST = {"seeds": 4, "min_portions": 400, "rendered_check": False}
TRUE_SEGMENT_RATIO, TRUE_DEVIATION_DEG = 5.0, 25.0


@pytest.fixture(scope="module")
def measured_mat():
    """A "measured" sample: the 50 D window of a known mat (seed 7, not a calibration seed)."""
    cfg = load_config("plla", {"rve.size_ratio": 100, "rve.layers": 40, "rve.seed": 7,
                               "rve.max_deviation_deg": TRUE_DEVIATION_DEG})
    mat = deposit(cfg.rve)
    origin, side = centred_window(mat.size, cfg.observation_window_um)
    seen = window_tortuosity(mat.vertices, mat.fiber_offsets, origin, side)
    assert len(seen) > 400  # enough for the tolerances below
    return mat, seen


# --------------------------------------------------------------------------------------------
# targets reached
# --------------------------------------------------------------------------------------------
def _ideal_tracer_pieces(mat, window_um: float, min_chord: float, seed: int = 0):
    """Pieces an ideal SEM tracer would measure: the window portions cut at random arc
    positions (crossings, 1 per 6 um on average); pieces with a shorter chord are dropped.

    Returns (contour_length, chord_length, orientation [rad]) of each piece."""
    rng = np.random.default_rng(seed)
    origin, side = centred_window(mat.size, window_um)
    runs = window_runs(mat.vertices, mat.fiber_offsets, origin, side)
    out = []
    for r in range(len(runs.first)):
        s0, s1 = runs.start[r], runs.end[r]
        ends = np.r_[s0, np.sort(rng.uniform(s0, s1, rng.poisson((s1 - s0) / 6.0))), s1]
        a = _point_at(runs, np.full(len(ends), r), ends)
        chord = b = a[1:] - a[:-1]
        chord = np.hypot(*b.T)
        keep = chord >= min_chord
        out.append(np.column_stack([np.diff(ends), chord, np.mod(np.arctan2(b[:, 1], b[:, 0]), np.pi)])[keep])
    pieces = np.concatenate(out)
    return pieces[:, 0], pieces[:, 1], pieces[:, 2]


@pytest.mark.slow
def test_spec7_half_normal_tortuosity_is_reached():
    targets = GeometryTargets(tortuosity_scale=0.14)
    result = calibrate_geometry(targets, "plla", **FAST)
    assert result.search["sampling"] == "whole portions"  # typed in: no piece lengths
    m = result.match("tortuosity")
    # Table 2 (5 deg turns) is nearly disjoint from the target (KS ~0.95, SPEC 8); the fitted
    # walk reaches the floor set by the shape of the walk's distribution (~0.07-0.08 over the
    # whole valley) plus sampling noise (~0.03 at n ~ 500).
    assert m.ks < 0.12
    target_median = stats.halfnorm(loc=1, scale=0.14).median()
    virtual_median = dict((n, v) for n, _, v in m.summary)["median"]
    assert abs(virtual_median - target_median) < 0.01  # the bulk matches (medians 1.094)
    plla = VirtualMeasurement(result.search["window_um"], result.search["min_chord_um"],
                              tuple(result.search["seeds"]), result.search["layers"])
    seen = plla.measure({"max_deviation_deg": 5.0}, result.search["check_side_um"])
    assert stats.kstest(seen["tortuosity"], stats.halfnorm(1, 0.14).cdf).statistic > 0.8
    assert result.config.rve.segment_ratio == 5.0  # the base's, not searched
    assert result.parameters["fitted"] == ["rve.max_deviation_deg"]
    # The walk's heavier tail leaves the mean off (~1.19 against 1.112): said, not hidden.
    means = dict((n, (t, v)) for n, t, v in m.summary)["mean"]
    assert means[1] - means[0] > 0.02
    assert any("mean tortuosity" in w for w in result.warnings)


def test_round_trip_recovers_the_deviation_at_the_true_segment_length(measured_mat):
    mat, seen = measured_mat
    targets = GeometryTargets(tortuosity=seen.tortuosity, source="known mat")
    result = calibrate_geometry(targets, "plla", fit="deviation", **FAST)
    # Four independent measured mats gave 24.3-25.7 deg: +-2.5 deg is about four sd.
    assert abs(result.config.rve.max_deviation_deg - TRUE_DEVIATION_DEG) < 2.5
    # KS 0.03-0.04 measured; 1.36 / sqrt(n_eff) ~ 0.07 is the 5 % critical value at these n.
    assert result.match("tortuosity").ks < 0.07
    assert result.search["sampling"] == "whole portions"
    # A notebook shows one line and a small table, not the dataclass dump of targets and image.
    shown = repr(result)
    assert shown.startswith("GeometryCalibration(max_deviation_deg ") and "KS tortuosity" in shown
    assert len(shown) < 200 and "<table>" in result._repr_html_()


def test_round_trip_recovers_the_segment_length_at_the_true_deviation(measured_mat):
    mat, seen = measured_mat
    targets = GeometryTargets(tortuosity=seen.tortuosity, source="known mat")
    result = calibrate_geometry(targets, "plla", fit="segment",
                                max_deviation_deg=TRUE_DEVIATION_DEG, **FAST)
    # Four independent measured mats gave 4.71-5.17: +-15 % is about three sd.
    assert abs(result.config.rve.segment_ratio / TRUE_SEGMENT_RATIO - 1.0) < 0.15
    assert result.match("tortuosity").ks < 0.07


@pytest.mark.slow
def test_both_free_only_the_persistence_length_is_identified(measured_mat):
    mat, seen = measured_mat
    targets = GeometryTargets(tortuosity=seen.tortuosity, source="known mat")
    result = calibrate_geometry(targets, "plla", fit="both", segment_ratios=(2.0, 5.0, 8.0), **FAST)
    true_lp = persistence_ratio(TRUE_SEGMENT_RATIO, TRUE_DEVIATION_DEG)
    # Every segment length finds a deviation with the same persistence length (measured
    # 138-172 D for a true 157 D) and a distribution that matches.
    assert len(result.valley) == 3
    for point in result.valley:
        assert abs(point.persistence_ratio / true_lp - 1.0) < 0.2
        assert point.ks < 0.08
    deviations = [p.max_deviation_deg for p in result.valley]
    assert deviations == sorted(deviations) and deviations[-1] - deviations[0] > 10.0
    assert result.match("tortuosity").ks < 0.08


@pytest.mark.slow
def test_measured_folder_sets_window_diameters_and_orientation(measured_mat, tmp_path):
    mat, seen = measured_mat
    # Pieces as an ideal tracer measures them in a 24 um window (the square equivalent of the
    # 30 x 20 um field below), with the tracer's shortest chord 1 um; a few stubs (chord
    # < min_chord_um = 1.5 um) are in the table and must be left out of every sample.
    contour, chord, orientation = _ideal_tracer_pieces(mat, 24.0, 1.0)
    n = len(contour)
    assert n > 400 and 10 < np.sum(chord < 1.5) < n / 4
    # plla's mean diameter, so that segment_ratio 5 is the true 2.25 um segment.
    diameters = np.random.default_rng(3).normal(0.45, 0.09, n)
    folder = tmp_path / "sem"
    folder.mkdir()
    rows = ["diameter_um,orientation_deg,contour_length_um,end_to_end_um,fiber_id,tortuosity"]
    rows += [f"{d},{o},{c},{e},{i}," for i, (d, o, c, e) in enumerate(
        zip(diameters, np.degrees(orientation), contour, chord))]
    (folder / "fibers.csv").write_text("\n".join(rows) + "\n")
    (folder / "measurement.toml").write_text(
        "um_per_px = 0.02\nfield_of_view_um = [30.0, 20.0]\nmin_chord_um = 1.5\n")
    result = calibrate_geometry(folder, "plla", **FAST)
    # The window is the square of equal mean chord to a 30 x 20 um field: 24 um.
    assert result.search["window_um"] == pytest.approx(24.0)
    assert result.config.observation_window_um == pytest.approx(24.0)
    assert result.search["min_chord_um"] == 1.5
    # The empty tortuosity column is skipped (said in the notes); tortuosity is contour /
    # end-to-end, and the stubs are left out of all three samples alike.
    kept = chord >= 1.5
    assert any("tortuosity has no values" in note for note in result.search["notes"])
    assert len(result.targets.tortuosity) == len(result.targets.diameter_um) == kept.sum()
    assert len(result.targets.orientation_deg) == len(result.targets.contour_length_um) == kept.sum()
    np.testing.assert_allclose(result.targets.tortuosity, (contour / chord)[kept].clip(1.0))
    # Pieces with lengths: the virtual mat is measured on pieces of the same lengths.
    assert result.search["sampling"] == "length-matched"
    assert "length-matched" in result.format_table()
    # The true walk (25 deg) is recovered: mats 7-10 gave 25.3 / 24.7 / 24.7 / 25.0 deg.
    # Measured on whole window portions instead, the same pieces give ~14 deg (mats 7, 8):
    # the bias length matching removes.
    assert abs(result.config.rve.max_deviation_deg - TRUE_DEVIATION_DEG) < 2.5
    whole = calibrate_geometry(GeometryTargets(tortuosity=result.targets.tortuosity,
                                               field_of_view_um=(30.0, 20.0), min_chord_um=1.5),
                               "plla", **FAST)
    assert whole.search["sampling"] == "whole portions"
    assert whole.config.rve.max_deviation_deg < TRUE_DEVIATION_DEG - 6.0
    d = result.match("diameter_um")
    assert abs(np.mean(diameters[kept]) - result.config.rve.diameter_um) < 1e-3
    assert d.ks < 0.07
    o = result.match("orientation_deg")
    # An isotropic mat's sample: uniform, or (espin measure's AIC rule takes a uniform sample
    # for von Mises about 14 % of the time) a weak von Mises.
    spec = result.config.rve.orientation
    assert (spec == "uniform" or spec.von_mises.kappa < 0.5) and o.ks < 0.07
    assert result.match("tortuosity").ks < 0.07
    assert set(result.parameters["fitted"]) == {
        "rve.diameter_um", "rve.diameter_sd_um", "rve.diameter_distribution",
        "rve.max_deviation_deg", "rve.orientation"}


# --------------------------------------------------------------------------------------------
# from an SEM image: render_sem -> measure -> calibrate
# --------------------------------------------------------------------------------------------
IMAGE_DEVIATION_DEG = 45.0


@pytest.fixture(scope="module")
def sem_image():
    """An SEM-like image (60 D window, 3 layers) of a mat with 45 deg turns, with its truth."""
    import espin.geometry.rve
    from espin.imaging.synthetic import render_sem

    mat = espin.geometry.rve.generate("plla", rve__size_ratio=100, rve__layers=4, rve__seed=1,
                             rve__max_deviation_deg=IMAGE_DEVIATION_DEG).mat
    return render_sem(mat, side_um=60 * 0.45, seed=1)


@pytest.fixture(scope="module")
def sem_measurement(sem_image):
    """espin measure of that image."""
    from espin.imaging.measurement import measure

    return measure(sem_image.image, um_per_px=sem_image.um_per_px)


@pytest.fixture(scope="module")
def sem_calibration(sem_measurement):
    """The calibration of that measurement with the light settings (FAST), run once for the
    tests that read it (it is deterministic: the same measurement and seeds give the same result)."""
    return calibrate_geometry(sem_measurement, "plla", **FAST)


@pytest.mark.slow
def test_synthetic_image_round_trip_recovers_the_deviation(sem_measurement, sem_image, sem_calibration):
    result = sem_calibration
    # The traced pieces are far shorter than the fibers across the image (median end to end
    # 15 D against 36 D), so their tortuosity is far lower; the calibrated walk says what
    # whole fibers across the window read, as tracing them by hand would.
    true = sem_image.visible.tortuosity
    pieces = sem_measurement.fibers["tortuosity"].to_numpy()
    whole = result.search["whole_portion_tortuosity"]
    assert np.median(true) - np.median(pieces) > 0.05
    assert abs(whole["median"] - np.median(true)) < 0.02
    # The mean of ~50 heavy-tailed portions (45 deg curls) is itself uncertain: standard error
    # 0.07 here (1.303 +- 0.070); the calibrated walk's whole fibers read 1.229.
    assert abs(whole["mean"] - true.mean()) < 2.0 * true.std() / np.sqrt(len(true))
    assert "whole fibers across the window" in result.format_table()
    assert result.search["sampling"] == "length-matched"
    assert result.search["window_um"] == pytest.approx(sem_measurement.field_of_view_um[0])
    # Image of mat 1 (these settings): 40.7 deg with the tracer that ends a trace rather than
    # switch fibers at an ambiguous crossing (mat 2: 35.0); earlier tracers gave 42.5 / 43.5 /
    # 42.7 on mats 1-3, up to 47.6.
    assert abs(result.config.rve.max_deviation_deg - IMAGE_DEVIATION_DEG) < 5.0
    # KS 0.10-0.14 measured against ~60 traced pieces (5 % critical value ~0.18).
    assert result.match("tortuosity").ks < 0.18
    assert result.config.rve.orientation == "uniform"
    # Whole window portions (the former measurement) are much longer than the traced pieces
    # and more tortuous per walk: the same image gave 24-27 deg.
    fibers = sem_measurement.fibers
    whole = calibrate_geometry(
        GeometryTargets(tortuosity=fibers["tortuosity"].to_numpy(),
                        field_of_view_um=sem_measurement.field_of_view_um,
                        min_chord_um=sem_measurement.min_chord_um), "plla", **FAST)
    assert whole.search["sampling"] == "whole portions"
    assert whole.search["whole_portion_tortuosity"] is None  # they are whole portions already
    assert whole.config.rve.max_deviation_deg < IMAGE_DEVIATION_DEG - 10.0


@pytest.mark.slow
def test_calibration_from_an_espin_measure_folder(sem_measurement, sem_calibration, tmp_path):
    folder = tmp_path / "measured"
    sem_measurement.write(folder, figures=False)
    result = calibrate_geometry(folder, "plla", **FAST)
    assert result.search["sampling"] == "length-matched"
    assert result.search["window_um"] == pytest.approx(sem_measurement.field_of_view_um[0], rel=1e-5)
    assert result.search["min_chord_um"] == pytest.approx(sem_measurement.min_chord_um, rel=1e-5)
    assert len(result.targets.tortuosity) == len(sem_measurement.fibers)
    # The same targets as the measurement in memory (fibers.csv keeps 6 digits).
    direct = sem_calibration
    assert result.config.rve.max_deviation_deg == pytest.approx(
        direct.config.rve.max_deviation_deg, abs=0.5)
    # The diameter target is the fully visible fibers' (fibers.csv's visible column); the
    # deeper, partly hidden fibers' diameters are left out.
    visible = sem_measurement.fibers["visible"]
    assert 0 < visible.sum() < len(visible)
    assert result.config.rve.diameter_um == pytest.approx(
        float(sem_measurement.fibers.loc[visible, "diameter_um"].mean()), rel=1e-3)
    assert result.config.rve.diameter_um == pytest.approx(direct.config.rve.diameter_um, rel=1e-3)


@pytest.mark.slow
def test_comparison_shows_the_image_beside_a_rendering_at_its_scale(sem_measurement, sem_calibration, tmp_path):
    """The image an SEMMeasurement analysed is kept, and the folder gets comparison.png: the
    image and a synthetic SEM of the calibrated mat over the same field of view."""
    from PIL import Image

    from espin.imaging.geometry_calibration.comparison import render_like

    result = sem_calibration
    assert result.image.pixels.shape == sem_measurement.image.shape
    rendering = render_like(result.config, result.image.pixels.shape, result.image.um_per_px)
    assert rendering.shape == sem_measurement.image.shape
    assert 0.05 < rendering.mean() < 0.95  # fibers on a background, not an empty square
    files = result.write(tmp_path / "cal")
    assert files["comparison"].name == "comparison.png"
    with Image.open(files["comparison"]) as png:
        assert png.format == "PNG" and png.width > png.height
    # Typed-in targets have no image: no comparison, and none left from another run.
    files["comparison"].write_bytes(b"old")
    typed = calibrate_geometry(GeometryTargets(diameter_mean_um=0.4), "plla", **FAST)
    assert "comparison" not in typed.write(tmp_path / "cal", overwrite=True)
    assert not (tmp_path / "cal" / "comparison.png").exists()


def test_aligned_target_is_corrected_for_the_widening_by_the_walk():
    base = load_config("plla", {"rve.size_ratio": 100})
    targets = GeometryTargets(orientation_mean_deg=30.0, orientation_kappa=3.0)
    result = calibrate_geometry(targets, base, **FAST)
    kappa = result.config.rve.orientation.von_mises.kappa
    assert kappa > 3.0  # the straight plla walk still widens the visible distribution
    target_order = special.i1e(3.0) / special.i0e(3.0)
    m = result.match("orientation_deg")
    summary = {name: (t, v) for name, t, v in m.summary}
    assert summary["order"][0] == pytest.approx(target_order)
    assert abs(summary["order"][1] - target_order) < 0.03  # sampling sd ~0.01 at n ~ 500
    assert abs(summary["director_deg"][1] - 30.0) < 3.0
    assert not result.warnings


def test_alignment_out_of_reach_of_a_tortuous_walk_is_a_warning():
    base = load_config("plla", {"rve.size_ratio": 100, "rve.max_deviation_deg": 40.0})
    targets = GeometryTargets(orientation_mean_deg=0.0, orientation_kappa=3.0)
    result = calibrate_geometry(targets, base, **FAST)
    assert result.config.rve.orientation.von_mises.kappa == 700.0
    assert any("out of reach" in w for w in result.warnings)


# --------------------------------------------------------------------------------------------
# the pieces
# --------------------------------------------------------------------------------------------
def test_truncated_normal_has_the_target_moments():
    mu, sigma = truncated_normal_parameters(0.3, 0.2)
    law = stats.truncnorm((0.1 * mu - mu) / sigma, np.inf, loc=mu, scale=sigma)
    assert law.mean() == pytest.approx(0.3, rel=1e-6) and law.std() == pytest.approx(0.2, rel=1e-6)
    assert mu < 0.3  # the truncation raised the mean: the parent sits lower
    assert truncated_normal_parameters(0.463, 0.05) == (0.463, 0.05)  # truncation negligible
    with pytest.raises(MeasurementError, match="too large"):
        truncated_normal_parameters(0.3, 5.0)


def test_axial_von_mises_fit_and_isotropy_test():
    rng = np.random.default_rng(11)
    theta = np.degrees(VonMisesOrientation(np.radians(150.0), 2.0).sample(rng, 2000))
    mean, kappa, p = fit_axial_von_mises(theta)
    # Sampling sd of kappa at n = 2000 is ~0.07 and of the mean ~1 deg.
    assert abs(kappa - 2.0) < 0.25 and abs((mean - 150.0 + 90.0) % 180.0 - 90.0) < 3.0
    assert p < 1e-10
    uniform = rng.uniform(0.0, 180.0, 2000)
    assert fit_axial_von_mises(uniform)[2] > 0.01


def test_equivalent_square_and_persistence():
    assert equivalent_square_side(10.0, 10.0) == 10.0
    assert equivalent_square_side(30.0, 20.0) == pytest.approx(24.0)
    assert persistence_ratio(5.0, 0.0) == math.inf
    # Small turns: l_p ~ 6 l_s / t^2.
    assert persistence_ratio(1.0, 1.0) == pytest.approx(6.0 / math.radians(1.0) ** 2, rel=1e-4)


# --------------------------------------------------------------------------------------------
# writing, CLI, errors
# --------------------------------------------------------------------------------------------
def _app() -> typer.Typer:
    app = typer.Typer()
    register(app)

    @app.callback()
    def main() -> None:  # a group, so the command keeps its name
        pass

    return app


@pytest.mark.slow
def test_cli_writes_a_config_that_generate_takes(tmp_path):
    out = tmp_path / "calibrated.toml"
    result = CliRunner().invoke(_app(), [
        "calibrate-geometry", "--tortuosity-scale", "0.14", "--diameter-um", "0.5",
        "--diameter-sd-um", "0.1", "--orientation", "uniform", "--seeds", "2", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "espin fit" in result.output and f"espin generate {out}" in result.output
    assert f"espin simulate {out}" in result.output and "KS" in result.output
    config = load_config(out)
    assert config.rve.diameter_um == pytest.approx(0.5, rel=1e-3)
    assert config.rve.max_deviation_deg > 5.0 and config.fiber == load_config("plla").fiber
    report = json.loads(out.with_name("calibrated.calibration.json").read_text())
    assert report["note"] == MECHANICS_NOTE
    assert {m["quantity"] for m in report["matches"]} == {"tortuosity", "orientation_deg", "diameter_um"}
    import espin.geometry.rve

    rve = espin.geometry.rve.generate(out, rve__size_ratio=30, rve__layers=2)
    assert rve.config.rve.max_deviation_deg == config.rve.max_deviation_deg


def test_write_to_a_folder(tmp_path):
    result = calibrate_geometry(GeometryTargets(diameter_mean_um=0.4), "plla", **FAST)
    files = result.write(tmp_path / "cal")
    assert {p.name for p in files.values()} == {"config.toml", "calibration.json", "calibration.txt"}
    assert load_config(files["config"]) == result.config
    assert "espin fit" in files["config"].read_text()


def _csv(tmp_path, text: str):
    path = tmp_path / "fibers.csv"
    path.write_text(text)
    return path


# The table is read by espin.geometry.fibers_csv.read_fibers_csv: its messages name the column, the data
# row and the allowed range.
@pytest.mark.parametrize("text, message", [
    ("a,b\n1,2\n", "needs at least one of the columns diameter_um, orientation_deg, tortuosity"),
    ("tortuosity\n" + "1.1\n" * 9 + "0.9\n", r"column tortuosity, data row 10: 0.9 is not >= 1"),
    ("orientation_deg\n" + "10\n" * 9 + "200\n", r"column orientation_deg, data row 10: 200 is not in \[0, 180\)"),
    ("diameter_um\n" + "0.4\n" * 5, "at least 10"),
    ("diameter_um\n" + "0.4\n" * 9 + "thick\n", "column diameter_um, data row 10: 'thick' is not a number"),
    ("diameter_um,tortuosity\n" + ",\n" * 12, "none of the columns .* holds a value"),
])
def test_bad_measurements_are_clear_errors(tmp_path, text, message):
    with pytest.raises(MeasurementError, match=message):
        calibrate_geometry(_csv(tmp_path, text))


def test_bad_options_are_clear_errors(tmp_path):
    sample = GeometryTargets(tortuosity=np.full(20, 1.1))
    with pytest.raises(MeasurementError, match="no targets"):
        calibrate_geometry(GeometryTargets())
    with pytest.raises(MeasurementError, match="not found"):
        calibrate_geometry(tmp_path / "missing.csv")
    with pytest.raises(MeasurementError, match="both measured"):
        sample.with_typed(tortuosity_scale=0.1)
    with pytest.raises(MeasurementError, match=r"orientation_kappa must be in \[0, 700\]"):
        GeometryTargets(orientation_mean_deg=0.0, orientation_kappa=900.0)
    with pytest.raises(ConfigError, match="fit must be"):
        calibrate_geometry(sample, fit="curl")
    with pytest.raises(ConfigError, match="do not fix it"):
        calibrate_geometry(sample, fit="deviation", max_deviation_deg=10.0)
    with pytest.raises(ConfigError, match="do not give window_um"):
        calibrate_geometry(GeometryTargets(tortuosity=np.full(20, 1.1), field_of_view_um=(20, 20)),
                           window_um=10.0)
    folder = tmp_path / "sem"
    folder.mkdir()
    (folder / "fibers.csv").write_text("tortuosity\n" + "1.1\n" * 10)
    (folder / "measurement.toml").write_text("um_per_px = 0.02\n")
    with pytest.raises(MeasurementError, match="missing key field_of_view_um"):
        calibrate_geometry(folder)
    result = CliRunner().invoke(_app(), ["calibrate-geometry", "--tortuosity-scale", "-1",
                                         "-o", str(tmp_path / "x.toml")])
    assert result.exit_code == 2 and "tortuosity_scale" in result.output
    assert not (tmp_path / "x.toml").exists()
    assert issubclass(MeasurementError, EspinError)


def test_empty_columns_are_skipped_and_stubs_left_out_of_every_sample(tmp_path):
    rows = ["diameter_um,orientation_deg,tortuosity,end_to_end_um"]
    rows += [f",{10 * i % 180},{1.0 + 0.01 * i},{0.5 + 0.1 * i}" for i in range(30)]
    path = _csv(tmp_path, "\n".join(rows) + "\n")
    targets = GeometryTargets.from_csv(path, min_chord_um=1.0)
    assert targets.diameter_um is None  # all empty: skipped, not an error
    assert any("diameter_um has no values" in n for n in targets.notes)
    # Rows with end_to_end < 1 um (i < 5) are left out of tortuosity and orientation alike.
    assert len(targets.tortuosity) == len(targets.orientation_deg) == 25
    np.testing.assert_allclose(targets.contour_length_um,
                               [(1.0 + 0.01 * i) * (0.5 + 0.1 * i) for i in range(5, 30)])


def test_typed_in_fixed_diameter_is_exact_and_matches_with_ks_zero(tmp_path):
    result = calibrate_geometry(GeometryTargets(diameter_mean_um=0.123456), "plla", **FAST)
    assert result.config.rve.diameter_um == 0.123456  # not rounded to 0.1235
    m = result.match("diameter_um")
    assert m.ks == 0.0  # every virtual diameter is the typed-in one (kstest said 1.0)
    from espin.imaging.geometry_calibration.matching import _diameter_target

    target = _diameter_target(GeometryTargets(diameter_mean_um=0.5))
    assert target.ks(np.full(10, 0.5)) == 0.0
    assert target.ks(np.r_[np.full(7, 0.5), [0.6, 0.6, 0.6]]) == pytest.approx(0.3)
    assert target.ks(np.full(4, 0.4)) == 1.0
    assert result.config.rve.diameter_sd_um == 0.0


def test_written_config_leaves_derived_values_to_espin(tmp_path):
    targets = GeometryTargets(diameter_mean_um=0.5, orientation_mean_deg=0.0, orientation_kappa=1.0)
    result = calibrate_geometry(targets, "plla", correct_orientation=False, **FAST)
    path = result.write(tmp_path / "c.toml")["config"]
    import tomllib

    rve = tomllib.loads(path.read_text())["rve"]
    assert "diameter_min_um" not in rve and "seeding" not in rve
    config = load_config(path)
    assert config.rve.diameter_min_um == pytest.approx(0.05)  # 0.1 D of the calibrated D
    assert config.rve.seeding == "lines"  # derived from the von Mises orientation
    assert config == result.config
    # Edited later, the derived values follow.
    edited = load_config(path, {"rve.diameter_um": 0.8, "rve.orientation": "uniform"})
    assert edited.rve.diameter_min_um == pytest.approx(0.08) and edited.rve.seeding == "border"
    # Given explicitly in the base, they are kept.
    base = load_config("plla", {"rve.diameter_min_um": 0.02, "rve.seeding": "border"})
    kept = calibrate_geometry(targets, base, correct_orientation=False, **FAST)
    rve = tomllib.loads(kept.write(tmp_path / "k.toml")["config"].read_text())["rve"]
    assert rve["diameter_min_um"] == 0.02 and rve["seeding"] == "border"


def test_bad_measurement_toml_and_output_paths_are_clear_errors(tmp_path):
    folder = tmp_path / "sem"
    folder.mkdir()
    (folder / "fibers.csv").write_text("tortuosity\n" + "1.1\n" * 10)
    for fov in ('"big"', "[1.0, 2.0, 3.0]", '["a", 2.0]', "[0.0, 2.0]"):
        (folder / "measurement.toml").write_text(f"um_per_px = 0.02\nfield_of_view_um = {fov}\n")
        with pytest.raises(MeasurementError, match="field_of_view_um must be"):
            calibrate_geometry(folder)
    (folder / "measurement.toml").write_text(
        'um_per_px = 0.02\nfield_of_view_um = [10.0, 10.0]\nmin_chord_um = "3"\n')
    with pytest.raises(MeasurementError, match="min_chord_um must be a number"):
        calibrate_geometry(folder)
    with pytest.raises(MeasurementError, match="field_of_view_um must be"):
        GeometryTargets(tortuosity=np.full(20, 1.1), field_of_view_um="big")
    # -o at an existing file that is not .toml: a clear error, not a traceback.
    existing = tmp_path / "notes.txt"
    existing.write_text("keep me")
    result = CliRunner().invoke(_app(), ["calibrate-geometry", "--diameter-um", "0.5",
                                         "--seeds", "1", "-o", str(existing)])
    assert result.exit_code == 2 and "existing file" in result.output
    assert existing.read_text() == "keep me"
    help_text = CliRunner().invoke(_app(), ["calibrate-geometry", "--help"]).output
    assert "folder" in help_text and "calibration.txt" in help_text


def test_orientation_follows_espin_measures_rule():
    # A weakly ordered sample: AIC (espin measure) picks von Mises, though a Rayleigh test at
    # 1 % would not reject isotropy; the calibration follows measure.
    rng = np.random.default_rng(5)
    theta = np.degrees(VonMisesOrientation(0.0, 0.25).sample(rng, 150))
    from espin.imaging.distributions import fit_distributions

    assert fit_distributions(np.empty(0), theta, np.empty(0)).orientation_model == "von_mises"
    assert 0.01 < fit_axial_von_mises(theta)[2]
    result = calibrate_geometry(GeometryTargets(orientation_deg=theta), "plla", **FAST)
    assert "von_mises" in result.parameters["rve.orientation"]
    assert any("AIC" in n and "von Mises" in n for n in result.search["notes"])
    isotropic = np.degrees(rng.uniform(0.0, np.pi, 150))
    assert fit_distributions(np.empty(0), isotropic, np.empty(0)).orientation_model == "uniform"
    assert calibrate_geometry(GeometryTargets(orientation_deg=isotropic), "plla", **FAST).config.rve.orientation == "uniform"


# --------------------------------------------------------------------------------------------
# which walk; through the tracer
# --------------------------------------------------------------------------------------------
def _pieces_and_shape(cfg, window_um: float, min_chord: float) -> GeometryTargets:
    """Targets an ideal tracer reads on a known mat: pieces with their lengths, and the
    long-range shape of its window portions."""
    from espin.geometry.pieces import window_crossings

    mat = deposit(cfg.rve)
    length, chord, theta = _ideal_tracer_pieces(mat, window_um, min_chord)
    origin, side = centred_window(mat.size, window_um)
    shape = window_crossings(window_runs(mat.vertices, mat.fiber_offsets, origin, side), origin, side, min_chord)
    return GeometryTargets(tortuosity=length / chord, contour_length_um=length,
                           orientation_deg=np.degrees(theta), field_of_view_um=(window_um, window_um),
                           min_chord_um=min_chord, n_crossing=shape.n_crossing,
                           u_turn_fraction=shape.u_turn_fraction, straightness=shape.straightness)


@pytest.mark.slow
def test_the_long_range_shape_chooses_the_smooth_walk_of_a_smooth_mat():
    """Pieces and long-range shape of a smooth mat (20 deg, 8 D): the smooth walk is chosen and
    its waviness recovered; without the long-range shape the walks cannot be told apart and
    the paper walk is kept, as documented."""
    cfg = load_config("plla", {"rve.size_ratio": 100, "rve.layers": 30, "rve.seed": 7, "rve.walk": "smooth",
                               "rve.waviness_deg": 20.0, "rve.waviness_length_ratio": 8.0,
                               "rve.segment_ratio": 2.0})
    targets = _pieces_and_shape(cfg, cfg.observation_window_um, 2.0)
    assert targets.n_crossing > 100
    result = calibrate_geometry(targets, "plla", **FAST)
    assert result.config.rve.walk == "smooth"
    assert abs(result.config.rve.waviness_deg - 20.0) < 5.0
    assert any(n.startswith("walk: paper score") for n in result.search["notes"])
    no_shape = GeometryTargets(tortuosity=targets.tortuosity, contour_length_um=targets.contour_length_um,
                               field_of_view_um=targets.field_of_view_um, min_chord_um=2.0)
    kept = calibrate_geometry(no_shape, "plla", **FAST)
    assert kept.config.rve.walk == "paper"
    assert any("no long-range shape" in n for n in kept.search["notes"])


def test_tracer_correction_maps_the_sample_quantile_by_quantile():
    from espin.imaging.geometry_calibration.tracer import TracedRenderings, tracer_corrected

    rng = np.random.default_rng(3)
    true = 1.0 + np.abs(rng.normal(0.0, 0.05, 4000))
    traced = TracedRenderings(1, np.empty(0), np.empty(0), true + 0.01, 0, math.nan, math.nan)
    measured = 1.0 + np.abs(rng.normal(0.0, 0.05, 300)) + 0.01  # read by the same tracer
    corrected, shift = tracer_corrected(GeometryTargets(tortuosity=measured), traced, true)
    assert shift == pytest.approx(-0.01, abs=0.003)
    assert stats.ks_2samp(corrected.tortuosity, true).statistic < 0.1
    assert corrected.tortuosity.min() >= 1.0


@pytest.mark.slow
def test_rendered_check_measures_the_calibrated_mat_like_the_image(sem_measurement):
    result = calibrate_geometry(sem_measurement, "plla", seeds=4, min_portions=400)
    tracer = result.search["tracer"]
    # The tracer's floor makes short straight pieces read more tortuous, and curling fibers
    # read straighter (traced whole only where straighter): on this 45 deg image the two
    # nearly cancel, the median moving by a few thousandths (-0.006 to +0.004 measured).
    assert abs(tracer["tortuosity_bias"]) < 0.02
    assert tracer["first_walk"]["walk"] in ("paper", "smooth")
    assert result.config.targets.source.endswith(f"median shift {tracer['tortuosity_bias']:+.4f})")
    check = tracer["rendered_check"]
    assert check["renderings"] == 3 and check["fibers"] > 20
    assert all(0.0 <= check[k] <= 1.0 for k in ("ks_diameter_um", "ks_orientation_deg", "ks_tortuosity"))
    assert check["target_n_crossing"] == sem_measurement.n_crossing
    assert "rendered check" in result.format_table() and "tracer" in result.format_table()


def test_diameter_family_when_no_truncated_normal_has_the_moments():
    """A skewed sample (coefficient of variation 0.83) that no normal truncated at 0.1 D can
    have: the lognormal is chosen instead of an error."""
    rng = np.random.default_rng(2)
    sample = stats.lognorm(s=0.72, scale=1.0).rvs(400, random_state=rng)
    result = calibrate_geometry(GeometryTargets(diameter_um=sample), "plla", **FAST)
    assert result.config.rve.diameter_distribution == "lognormal"
    assert result.config.rve.diameter_um == pytest.approx(np.mean(sample), rel=1e-3)
    assert any("normal log-likelihood -inf" in n for n in result.search["notes"])


def test_rendering_of_a_field_of_view_larger_than_the_layer():
    from espin.imaging.geometry_calibration.comparison import render_like

    config = load_config("plla", {"rve.size_ratio": 20})  # a 9 um layer
    picture = render_like(config, (200, 300), 0.05)  # a 15 x 10 um image
    assert picture.shape == (200, 300) and picture.std() > 0.05
