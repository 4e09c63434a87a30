"""Visible (top) fibers against partly hidden deeper ones, and the diameter families.

The classification is checked against the truth of renderings of virtual mats: each traced
fiber follows the mat fiber most of its centre line lies on (away from junctions), and it is
visible when that fiber is of the top drawn layer. Criterion (the issue): precision and
recall of ``visible`` at least 0.9, pooled over the renderings. benchmarks/bench_sem_visible.py
runs the larger set of docs/sem.md.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from espin.core.config import load_config
from espin.geometry.deposition import deposit
from espin.geometry.fibers_csv import FIBER_COLUMNS, read_fibers_csv, write_fibers_csv
from espin.geometry.targets import GeometryTargets
from espin.imaging.distributions import fit_diameter_families, fit_normal_mixture
from espin.imaging.measurement import measure
from espin.imaging.synthetic import render_sem
from espin.imaging.visibility import MIN_EDGE_CONTRAST, SINGLE_THRESHOLD, classify

D = 0.45  # um, plla diameter
RENDERINGS = [
    # mat keys, render_sem options, seed: straight-ish and wavy, uniform and aligned,
    # normal and lognormal diameters, 2 and 3 layers, default and weaker dimming
    ({"rve.max_deviation_deg": 20.0, "rve.diameter_sd_um": 0.1}, {}, 1),
    ({"rve.walk": "smooth", "rve.waviness_deg": 15.0, "rve.diameter_sd_um": 0.15,
      "rve.diameter_distribution": "lognormal",
      "rve.orientation": {"von_mises": {"mean_deg": 30.0, "kappa": 3.0}}}, {}, 2),
    ({"rve.max_deviation_deg": 10.0}, {"layers": 2, "depth_dimming": 0.25}, 3),
]


def _scored(mat_keys: dict, options: dict, seed: int) -> tuple[int, int, int, int]:
    """(true positives, false positives, false negatives, fibers) of ``visible`` on one
    rendering of a 45 D window, over the fibers with a diameter."""
    rve = load_config("plla", {"rve.size_ratio": 55, "rve.layers": 4, "rve.seed": seed}
                      | mat_keys).rve
    image = render_sem(deposit(rve), side_um=45 * D, seed=seed, **options)
    m = measure(image.image, um_per_px=image.um_per_px)
    followed = image.followed(m.paths_px, m.junctions_px, m.typical_width_px)
    counted = np.isfinite(m.fibers["diameter_um"].to_numpy())
    truth = (image.depth(followed) == 0)[counted]
    visible = m.fibers["visible"].to_numpy()[counted]
    return (int((visible & truth).sum()), int((visible & ~truth).sum()),
            int((~visible & truth).sum()), len(truth))


@pytest.mark.slow
def test_visible_fibers_are_the_top_layer():
    tp, fp, fn, n = np.sum([_scored(*case) for case in RENDERINGS], axis=0)
    assert tp + fn >= 30 and n - (tp + fn) >= 30  # enough fibers of both kinds to mean something
    assert tp / (tp + fp) >= 0.9
    assert tp / (tp + fn) >= 0.9


def test_one_population_keeps_the_fixed_threshold():
    """All fibers about equally bright: no mixture is split off, the fallback threshold holds."""
    rng = np.random.default_rng(0)
    bright = rng.normal(0.93, 0.04, 40)
    features = {"brightness": bright, "edge_sigma_px": np.ones(40), "occluded": np.zeros(40),
                "both_edges": np.ones(40), "edge_contrast": np.full(40, 0.8)}
    found = classify(features)
    assert found.threshold == SINGLE_THRESHOLD and found.rule.startswith("one population")
    assert found.visible.all()
    # Dimmer fibers (0.6, one layer down) beside them are two populations, split between.
    two = {k: np.r_[v, v[:20]] for k, v in features.items()} | {
        "brightness": np.r_[bright, rng.normal(0.6, 0.04, 20)]}
    found = classify(two)
    assert found.rule.startswith("two populations") and 0.65 < found.threshold < 0.85
    assert found.visible[:40].all() and not found.visible[40:].any()
    # A fiber covered at most of its crossings is hidden however bright.
    covered = features | {"occluded": np.r_[np.ones(3), np.full(2, 0.5), np.zeros(35)]}
    assert classify(covered).visible.sum() == 37  # more than half: 1, not 0.5
    # And one without a free edge (a trace along the rim of a wider fiber).
    rim = features | {"edge_contrast": np.r_[np.full(4, MIN_EDGE_CONTRAST - 0.01), np.full(36, 0.8)]}
    assert classify(rim).visible.sum() == 36


def test_mixture_recovers_two_populations_and_bic_chooses():
    rng = np.random.default_rng(1)
    two = np.r_[rng.normal(1.2, 0.2, 60), rng.normal(3.5, 0.3, 90)]
    mixture = fit_normal_mixture(two)
    assert mixture.weight == pytest.approx(0.4, abs=0.05)
    assert (mixture.mean_1, mixture.mean_2) == pytest.approx((1.2, 3.5), abs=0.1)
    assert (mixture.sd_1, mixture.sd_2) == pytest.approx((0.2, 0.3), abs=0.06)
    assert fit_normal_mixture(two[::-1]) == mixture  # deterministic, order-free
    fits = fit_diameter_families(two)
    assert fits.chosen == "mixture" and fits.bic["mixture"] < fits.bic["normal"] - 50
    # BIC = k ln n - 2 ln L and AIC = 2 k - 2 ln L with k = 2, 2, 5
    for family, k in (("normal", 2), ("lognormal", 2), ("mixture", 5)):
        assert fits.bic[family] == pytest.approx(k * math.log(150) - 2 * fits.log_likelihood[family])
        assert fits.aic[family] == pytest.approx(2 * k - 2 * fits.log_likelihood[family])
    skewed = fit_diameter_families(rng.lognormal(math.log(0.3), 0.5, 200))
    assert skewed.chosen == "lognormal"
    assert skewed.lognormal_sigma == pytest.approx(0.5, abs=0.06)
    # the densities integrate to 1
    grid = np.linspace(-4.0, 10.0, 14001)
    for family in ("normal", "lognormal", "mixture"):
        assert np.trapezoid(fits.pdf(family, grid), grid) == pytest.approx(1.0, abs=0.01)


def test_too_few_diameters_give_nan_fits_not_errors():
    assert fit_diameter_families(np.array([])).n == 0
    one = fit_diameter_families(np.array([0.5, np.nan]))
    assert one.n == 1 and one.mean_um == 0.5 and one.chosen == ""
    few = fit_diameter_families(np.array([0.4, 0.5, 0.6]))
    assert few.mixture is None and few.chosen in ("normal", "lognormal")
    assert math.isnan(few.bic["mixture"])


def test_visible_column_round_trip_and_old_tables(tmp_path):
    n = 15
    table = pd.DataFrame({"fiber": np.arange(n), "diameter_um": np.tile([3.5, 1.2, 3.3], 5),
                          "orientation_deg": np.linspace(0.0, 170.0, n),
                          "tortuosity": np.linspace(1.0, 1.2, n),
                          "contour_length_um": np.full(n, 20.0),
                          "end_to_end_um": 20.0 / np.linspace(1.0, 1.2, n),
                          "start_edge": ["top", "", ""] * 5, "end_edge": ["bottom", "", "left"] * 5,
                          "visible": [True, False, True] * 5})
    path = write_fibers_csv(table, tmp_path / "fibers.csv")
    back = read_fibers_csv(path)
    assert list(back.columns) == list(FIBER_COLUMNS)
    assert back["visible"].dtype == bool and back["visible"].tolist() == [True, False, True] * 5
    targets = GeometryTargets.from_table(back)
    np.testing.assert_array_equal(targets.diameter_um, [3.5, 3.3] * 5)  # the visible fibers'
    assert len(targets.tortuosity) == n  # orientation and tortuosity: all fibers
    # a table written before the column existed: every diameter counts
    old = tmp_path / "old.csv"
    table.drop(columns="visible").to_csv(old, index=False)
    assert "visible" not in read_fibers_csv(old).columns
    np.testing.assert_array_equal(GeometryTargets.from_csv(old).diameter_um, [3.5, 1.2, 3.3] * 5)
    bad = tmp_path / "bad.csv"
    bad.write_text("diameter_um,visible\n0.4,maybe\n")
    from espin.core.errors import SEMError

    with pytest.raises(SEMError, match="column visible, data row 1: 'maybe' is not True or False"):
        read_fibers_csv(bad)
    # a DataFrame read by pandas itself: the words, and a blank cell refused (np.bool_ would read
    # "False" and NaN as True and let hidden fibers into the target)
    raw = pd.read_csv(path)
    raw["visible"] = raw["visible"].map({True: "True", False: "False"})
    np.testing.assert_array_equal(GeometryTargets.from_table(raw).diameter_um, [3.5, 3.3] * 5)
    raw.loc[1, "visible"] = np.nan
    from espin.geometry.targets import MeasurementError

    with pytest.raises(MeasurementError, match="visible must hold True or False, got nan"):
        GeometryTargets.from_table(raw)
