"""Grading a generated mat against the measured targets of its config ([targets])."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats as sps

from espin.core.config import apply_overrides, load_config
from espin.geometry.pieces import sample_pieces, window_runs
from espin.geometry.rve import generate
from espin.geometry.rve_folder import PIECE_SEED, rve_statistics, trace_window, write_rve_folder
from espin.geometry.statistics import (
    LENGTH_MATCHED,
    NO_TARGETS,
    WHOLE_PORTIONS,
    diameter_target,
    network_statistics,
    observation_window,
)

SMALL = {"rve__size_ratio": 60, "rve__layers": 3}


@pytest.fixture(scope="module")
def plla():
    return generate("plla", **SMALL)


@pytest.fixture(scope="module")
def wavy():
    """A small wavy mat with a diameter distribution: pieces are not straight."""
    return generate("plla", **SMALL, rve__max_deviation_deg=30.0, rve__diameter_sd_um=0.1)


def _without_targets(rve):
    return rve.config.model_copy(update={"targets": None})


def test_plla_is_graded_against_the_paper_targets_as_before(plla):
    st = rve_statistics(plla)
    g = st.grading
    assert "Fig. 10" in g.targets.source
    assert g.tortuosity.target.label == "halfnorm(loc=1, scale=0.14)"
    assert g.tortuosity_sampling == WHOLE_PORTIONS
    np.testing.assert_array_equal(g.tortuosity.mat, st.window.tortuosity)
    # The KS statistics of this mat before [targets] existed (hard-wired paper targets).
    assert g.tortuosity.ks == pytest.approx(0.9474470054521774, rel=1e-12)
    assert g.diameter.ks == pytest.approx(0.5395248085288082, rel=1e-12)
    assert st.ks_window_orientation == pytest.approx(0.12610319370737078, rel=1e-12)
    # A fixed diameter against the normal: 0.5 + |F(D) - 1/2|.
    f = sps.norm(0.463, 0.131).cdf(0.45)
    assert g.diameter.ks == pytest.approx(0.5 + abs(f - 0.5))
    assert g.orientation is None and g.n_crossing is None
    s = st.summary()
    assert s["ks_window_tortuosity"] == g.tortuosity.ks and s["ks_diameter"] == g.diameter.ks
    assert s["target_tortuosity_mean"] == pytest.approx(1 + 0.14 * math.sqrt(2 / math.pi))
    assert (s["target_diameter_mean_um"], s["target_diameter_sd_um"]) == pytest.approx((0.463, 0.131))
    table = st.format_table()
    for fragment in ("Fig. 10", "halfnorm(loc=1, scale=0.14)", "normal(0.463, 0.131) um",
                     "mat_tortuosity_mean", "ks_diameter"):
        assert fragment in table
    # Without the pieces (which need no tracing here) the grading is the same.
    assert network_statistics(plla.mat, plla.network, plla.config).grading.tortuosity.ks == g.tortuosity.ks


def test_no_targets_grade_no_diameter_or_tortuosity(plla):
    st = network_statistics(plla.mat, plla.network, _without_targets(plla))
    g = st.grading
    assert (g.targets, g.tortuosity, g.diameter, g.orientation) == (None, None, None, None)
    s = st.summary()
    for key in ("targets_source", "ks_window_tortuosity", "ks_diameter", "target_tortuosity_mean",
                "target_diameter_mean_um", "mat_tortuosity_mean", "ks_measured_orientation"):
        assert s[key] is None, key
    # The orientation is still compared with the config's own distribution.
    assert s["ks_window_orientation"] == pytest.approx(0.12610319370737078, rel=1e-12)
    table = st.format_table()
    assert NO_TARGETS in table and "ks_diameter" not in table
    assert trace_window(plla.mat, _without_targets(plla)) is None


def test_samples_equal_to_the_mat_give_ks_zero(wavy):
    whole = network_statistics(wavy.mat, wavy.network, _without_targets(wavy)).window
    assert np.ptp(wavy.mat.fiber_diameter) > 0 and np.ptp(whole.tortuosity) > 0
    config = apply_overrides(_without_targets(wavy), {
        "targets.diameter_um": wavy.mat.fiber_diameter.tolist(),
        "targets.tortuosity": whole.tortuosity.tolist(),
        "targets.orientation_deg": np.degrees(whole.orientation).tolist(),
    })
    g = network_statistics(wavy.mat, wavy.network, config).grading
    assert g.diameter.ks == 0.0 and g.tortuosity.ks == 0.0
    assert g.diameter.target.label == f"sample of {wavy.mat.n_fibers:,} values"
    # Degrees and back may move an axis by a rounding error: at most one step of the ECDF.
    assert g.orientation.ks <= 1.0 / len(whole) + 1e-12
    # Against another sample the two-sample statistic is the largest ECDF gap.
    shifted = apply_overrides(config, {"targets.diameter_um": (wavy.mat.fiber_diameter + 10).tolist()})
    assert network_statistics(wavy.mat, wavy.network, shifted).grading.diameter.ks == 1.0


def test_lognormal_and_fixed_diameter_targets():
    t = load_config("plla", {
        "targets.diameter_mean_um": 2.3, "targets.diameter_sd_um": 0.6,
        "targets.diameter_distribution": "lognormal"}).targets
    law = diameter_target(t).law
    assert (law.mean(), law.std()) == pytest.approx((2.3, 0.6))
    fixed = diameter_target(t.model_copy(update={"diameter_sd_um": 0.0}))
    assert fixed.label == "fixed 2.3 um" and fixed.ks([2.3, 2.3]) == 0.0 and fixed.ks([2.0, 2.3]) == 0.5


def test_contour_lengths_grade_length_matched_pieces(wavy):
    lengths = [2.0, 3.0, 4.0, 6.0] * 25
    config = apply_overrides(_without_targets(wavy), {
        "targets.tortuosity": [1.01, 1.05, 1.1, 1.2] * 25, "targets.contour_length_um": lengths,
        "targets.min_chord_um": 1.0, "targets.source": "pieces"})
    traced = trace_window(wavy.mat, config)
    st = network_statistics(wavy.mat, wavy.network, config, traced)
    g = st.grading
    assert g.tortuosity_sampling == LENGTH_MATCHED
    # The pieces are those of the SEM tracer's sampling, with the fixed seed: deterministic.
    origin, side, min_chord = observation_window(config, wavy.mat.size)
    assert min_chord == 1.0 and st.window.min_chord == 1.0
    runs = window_runs(wavy.mat.vertices, wavy.mat.fiber_offsets, origin, side)
    expected, axes, _ = sample_pieces(runs, np.asarray(lengths), 1.0, np.random.default_rng(PIECE_SEED))
    np.testing.assert_array_equal(g.tortuosity.mat, expected)
    np.testing.assert_array_equal(traced.piece_orientation, axes)
    assert g.tortuosity.ks == pytest.approx(sps.ks_2samp(expected, config.targets.tortuosity).statistic)
    assert len(expected) > 50 and np.all(expected >= 1.0)
    again = network_statistics(wavy.mat, wavy.network, config, trace_window(wavy.mat, config))
    assert again.grading.tortuosity.ks == g.tortuosity.ks
    assert "length-matched pieces" in st.format_table()
    # Without the traced pieces they are reported as not measured, not graded on whole portions.
    missing = network_statistics(wavy.mat, wavy.network, config).grading
    assert len(missing.tortuosity.mat) == 0 and math.isnan(missing.tortuosity.ks)
    assert rve_statistics(replace(wavy, config=config)).grading.tortuosity.ks == g.tortuosity.ks


def test_crossing_targets_show_the_mats_u_turns_and_straightness(plla):
    config = apply_overrides(plla.config, {"targets.u_turn_fraction": 0.1,
                                           "targets.straightness": 0.8})
    st = network_statistics(plla.mat, plla.network, config, trace_window(plla.mat, config))
    g = st.grading
    # Nearly straight fibers (5 deg turns): they cross the window and hardly ever turn back.
    assert g.n_crossing > 20
    assert g.u_turn_fraction < 0.1 and 0.99 < g.straightness <= 1.0
    s = st.summary()
    assert (s["target_u_turn_fraction"], s["target_straightness"]) == (0.1, 0.8)
    assert s["mat_u_turn_fraction"] == g.u_turn_fraction and s["mat_n_crossing"] == g.n_crossing
    table = st.format_table()
    assert "target_u_turn_fraction" in table and "mat_straightness" in table


@pytest.mark.slow
def test_the_rve_folder_writes_the_grading(plla, tmp_path):
    config = apply_overrides(plla.config, {"targets.tortuosity": [1.0, 1.1, 1.3],
                                           "targets.contour_length_um": [3.0, 4.0, 5.0],
                                           "targets.source": "three pieces"})
    rve = generate(config)
    written = write_rve_folder(rve, tmp_path / "rve", figures=True, vtk=False)
    summary = json.loads((tmp_path / "rve" / "statistics.json").read_text())
    assert summary["targets_source"] == "three pieces"
    assert summary["tortuosity_sampling"] == LENGTH_MATCHED
    assert summary["ks_window_tortuosity"] == written.statistics.grading.tortuosity.ks
    # The tortuosity sample replaced the paper's half-normal; its diameter target stays.
    assert summary["target_diameter"] == "normal(0.463, 0.131) um"
    assert (tmp_path / "rve" / "statistics.png").stat().st_size > 1000
    assert "three pieces" in (tmp_path / "rve" / "statistics.txt").read_text()
