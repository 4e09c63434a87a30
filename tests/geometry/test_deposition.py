"""Virtual deposition (SPEC 1): inputs obeyed, orientation statistics, homogeneity."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from espin.core.config import load_config
from espin.geometry.deposition import deposit
from espin.geometry.orientation import orientation_distribution

VON_MISES = {"von_mises": {"mean_deg": 30.0, "kappa": 2.0}}


def _mat(**overrides):
    base = {"rve.size_ratio": 60, "rve.layers": 4}
    cfg = load_config("plla", base | {f"rve.{k}": v for k, v in overrides.items()})
    return cfg, deposit(cfg.rve)


@pytest.mark.parametrize("seeding", ["border", "lines"])
def test_geometry_obeys_inputs(seeding):
    cfg, mat = _mat(seeding=seeding, max_deviation_deg=12.0, seed=3)
    L, ls = cfg.rve.side_um, cfg.rve.segment_length_um
    v = mat.vertices
    assert v.min() >= 0.0 and v.max() <= L
    for ends in (mat.fiber_offsets[:-1], mat.fiber_offsets[1:] - 1):  # both ends on the border
        p = v[ends]
        assert np.abs(np.minimum.reduce([p[:, 0], p[:, 1], L - p[:, 0], L - p[:, 1]])).max() < 1e-9
    last = np.zeros(mat.n_segments, bool)
    last[np.cumsum(np.diff(mat.fiber_offsets) - 1) - 1] = True
    assert np.allclose(mat.segment_length[~last], ls, rtol=1e-12)
    assert mat.segment_length[last].max() <= ls * (1 + 1e-12)
    d = v[mat.segment_start + 1] - v[mat.segment_start]
    angle = np.arctan2(d[:, 1], d[:, 0])
    same = mat.segment_fiber[1:] == mat.segment_fiber[:-1]
    turn = np.angle(np.exp(1j * (angle[1:] - angle[:-1])))[same]
    assert np.abs(turn).max() <= np.radians(12.0) + 1e-9
    # The turns are uniform on [-theta_max, theta_max] (trimmed segments keep their direction).
    assert stats.kstest(turn, stats.uniform(-np.radians(12), np.radians(24)).cdf).pvalue > 1e-3


@pytest.mark.parametrize("seeding", ["border", "lines"])
@pytest.mark.parametrize("sd", [0.0, 0.13])
def test_volume_fraction_reached_by_the_crossing_fiber(seeding, sd):
    cfg, mat = _mat(seeding=seeding, diameter_sd_um=sd)
    eta = mat.layer_volume_fraction()
    volume = np.pi * mat.fiber_diameter**2 / 4 * mat.contour_length / (mat.size**2 * mat.thickness)
    for k in range(mat.n_layers):
        in_layer = mat.fiber_layer == k
        assert eta[k] >= cfg.rve.volume_fraction
        # Without the last fiber of the layer the target was not yet reached.
        assert eta[k] - volume[in_layer][-1] < cfg.rve.volume_fraction


def test_diameters_truncated_normal():
    cfg, mat = _mat(diameter_sd_um=0.131, diameter_um=0.463, diameter_min_um=0.2, layers=6)
    d = mat.fiber_diameter
    assert d.min() >= 0.2
    law = stats.truncnorm((0.2 - 0.463) / 0.131, np.inf, loc=0.463, scale=0.131)
    assert stats.kstest(d, law.cdf).pvalue > 1e-3
    _, fixed = _mat()
    assert np.all(fixed.fiber_diameter == 0.45)


def test_diameters_lognormal():
    """Lognormal diameters of the given mean and sd, truncated below at diameter_min_um, and
    the volume fraction counts each fiber's own diameter."""
    from espin.geometry.deposition import lognormal_diameters

    cfg, mat = _mat(diameter_sd_um=0.2, diameter_um=0.45, diameter_min_um=0.1, layers=80,
                    diameter_distribution="lognormal")
    d = mat.fiber_diameter
    law = lognormal_diameters(0.45, 0.2)
    assert law.mean() == pytest.approx(0.45) and law.std() == pytest.approx(0.2)
    low = law.cdf(0.1)
    assert d.min() >= 0.1
    assert stats.kstest(d, lambda x: (law.cdf(x) - low) / (1 - low)).pvalue > 1e-3
    assert stats.kstest(d, stats.truncnorm((0.1 - 0.45) / 0.2, np.inf, loc=0.45, scale=0.2).cdf).pvalue < 1e-3
    eta = mat.layer_volume_fraction()
    assert np.all(eta >= cfg.rve.volume_fraction)


@pytest.mark.parametrize("seeding", ["border", "lines"])
@pytest.mark.parametrize(
    "orientation",
    ["uniform", VON_MISES, {"histogram": {"edges_deg": [0, 45, 90, 180], "weights": [1, 3, 1]}}],
)
def test_first_axis_follows_the_distribution(seeding, orientation):
    """Every fiber's first segment is drawn from the distribution (``border``), or from it
    weighted by the square's width across the axis (``lines``, SPEC 1), over several seeds."""
    axes = []
    for seed in range(4):
        cfg, mat = _mat(seeding=seeding, orientation=orientation, seed=seed, max_deviation_deg=20.0)
        d = mat.vertices[mat.fiber_offsets[:-1] + 1] - mat.vertices[mat.fiber_offsets[:-1]]
        axes.append(np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi))
    dist = orientation_distribution(cfg.rve.orientation)
    target = dist.cdf if seeding == "border" else _width_weighted_cdf(dist)
    assert stats.kstest(np.concatenate(axes), target).pvalue > 1e-3
    # A wrong target is rejected by the same test.
    wrong = load_config(None, {"rve.orientation": {"von_mises": {"mean_deg": 120.0, "kappa": 2.0}}})
    wrong = orientation_distribution(wrong.rve.orientation)
    assert stats.kstest(np.concatenate(axes), wrong.cdf).pvalue < 1e-3


def _width_weighted_cdf(dist):
    """CDF of p(theta) (|cos theta| + |sin theta|), normalized, on a fine grid."""
    grid = np.linspace(0.0, np.pi, 20001)
    density = dist.pdf(grid) * (np.abs(np.cos(grid)) + np.abs(np.sin(grid)))
    cumulative = np.concatenate([[0.0], np.cumsum((density[1:] + density[:-1]) / 2 * np.diff(grid))])
    return lambda theta: np.interp(theta, grid, cumulative / cumulative[-1])


def _weighted_mean_and_se(values, weights):
    mean = np.sum(weights * values) / weights.sum()
    return mean, np.sqrt(np.sum(weights**2 * (values - mean) ** 2)) / weights.sum()


def test_lines_give_each_direction_its_length():
    """Chords of 200,000 lines: the length-weighted <cos^4> of a uniform distribution is 3/8
    (drawing axes from p alone gives 0.384, 11 standard errors off), and the length per
    10-deg bin of a von Mises one is its probability."""
    from espin.geometry.deposition import _exit_distance, _line_starts

    side, rng = 90.0, np.random.default_rng(0)
    for orientation in ("uniform", VON_MISES):
        dist = orientation_distribution(load_config(None, {"rve.orientation": orientation}).rve.orientation)
        start, theta = _line_starts(rng, 200_000, side, dist)
        chord = _exit_distance(start, np.c_[np.cos(theta), np.sin(theta)], side)
        axis = np.mod(theta, np.pi)
        if orientation == "uniform":
            mean, se = _weighted_mean_and_se(np.cos(axis) ** 4, chord)
            assert abs(mean - 3 / 8) < 3 * se and se < 1e-3
        else:
            edges = np.radians(np.arange(0, 181, 10))
            share = np.histogram(axis, edges, weights=chord)[0] / chord.sum()
            assert np.allclose(share, np.diff(dist.cdf(edges)), atol=0.004)


def test_pooled_straight_lines_mats_are_isotropic_in_length():
    """About 15,000 straight fibers (16 mats): length-weighted <cos^4> = 3/8 within 3
    standard errors (SPEC 1); with von Mises axes the length-weighted histogram is p."""
    fibers = []
    for orientation in ("uniform", VON_MISES):
        chords, axes = [], []
        for seed in range(16):
            cfg = load_config("plla", {"rve.seeding": "lines", "rve.max_deviation_deg": 0.0, "rve.seed": seed,
                                       "rve.orientation": orientation})
            mat = deposit(cfg.rve)
            chords.append(mat.contour_length)
            axes.append(mat.orientation)
        chord, axis = np.concatenate(chords), np.concatenate(axes)
        fibers.append(chord.size)
        if orientation == "uniform":
            mean, se = _weighted_mean_and_se(np.cos(axis) ** 4, chord)
            assert abs(mean - 3 / 8) < 3 * se
        else:
            dist = orientation_distribution(cfg.rve.orientation)
            edges = np.radians(np.arange(0, 181, 20))
            share = np.histogram(axis, edges, weights=chord)[0] / chord.sum()
            assert np.allclose(share, np.diff(dist.cdf(edges)), atol=0.015)
    assert min(fibers) > 13_000


def test_chord_orientation_of_isotropic_mats_is_uniform():
    """What an SEM sees (end-to-end axes) is uniform for both seedings of a uniform mat."""
    for seeding in ("border", "lines"):
        chords = np.concatenate([_mat(seeding=seeding, seed=s)[1].orientation for s in range(4)])
        assert stats.kstest(chords, stats.uniform(0, np.pi).cdf).pvalue > 1e-3


def _box_density(mat, boxes, step=0.2):
    """Fiber length per unit area in square boxes (x0, y0, side), by points along fibers."""
    s = mat.segment_start
    p, q = mat.vertices[s], mat.vertices[s + 1]
    n = np.maximum(np.ceil(mat.segment_length / step).astype(int), 1)
    seg = np.repeat(np.arange(len(s)), n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / n[seg]
    pts = p[seg] + frac[:, None] * (q[seg] - p[seg])
    w = mat.segment_length[seg] / n[seg]
    out = []
    for x0, y0, side in boxes:
        inside = (pts[:, 0] >= x0) & (pts[:, 0] < x0 + side) & (pts[:, 1] >= y0) & (pts[:, 1] < y0 + side)
        out.append(w[inside].sum() / side**2)
    return np.array(out)


def _corner_over_centre(seeding, orientation="uniform"):
    ratios = []
    for seed in range(4):
        cfg = load_config(None, {"rve.size_ratio": 100, "rve.layers": 40, "rve.seed": seed,
                                 "rve.seeding": seeding, "rve.orientation": orientation})
        mat = deposit(cfg.rve)
        L = mat.size
        b = L / 5
        d = _box_density(mat, [(L / 2 - b / 2, L / 2 - b / 2, b), (0, 0, b), (L - b, 0, b),
                               (0, L - b, b), (L - b, L - b, b)])
        ratios.append(d[1:].mean() / d[0])
    return float(np.mean(ratios))


def test_lines_seeding_is_homogeneous_and_border_is_not():
    """Corner boxes hold as much fiber as the centre with `lines`; ~1.4x with `border`.

    Band: over 4 seeds x 40 layers the mean ratio scatters by about 0.05 (measured).
    """
    assert abs(_corner_over_centre("lines") - 1.0) < 0.15
    assert abs(_corner_over_centre("lines", VON_MISES) - 1.0) < 0.15
    assert _corner_over_centre("border") > 1.25


def test_same_seed_same_mat_and_layers_independent():
    _, a = _mat(seed=5)
    _, b = _mat(seed=5)
    _, c = _mat(seed=6)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.fiber_offsets, b.fiber_offsets)
    assert not np.array_equal(a.vertices[:50], c.vertices[:50])
    _, fewer = _mat(seed=5, layers=2)  # layers draw from their own streams
    n = fewer.fiber_offsets[-1]
    assert np.array_equal(fewer.vertices, a.vertices[:n])


def test_straight_fibers_when_no_deviation():
    _, mat = _mat(max_deviation_deg=0.0, seeding="lines")
    assert np.allclose(mat.tortuosity, 1.0, atol=1e-12)


def test_smooth_walk_deviation_is_stationary_and_smooth():
    """The smooth walk's deviation from the mean axis has rms waviness_deg at every segment and
    the correlation a^k (1 + k (1 - a^2) / (1 + a^2)), a = exp(-l_s / l_c), across the chunks
    in which the walk is drawn."""
    from espin.geometry.deposition import _SmoothDeviation

    rms, length, segment = np.radians(12.0), 20.0, 2.5
    model = _SmoothDeviation(rms, length, segment)
    rng = np.random.default_rng(7)
    n = 40_000
    start = np.full((n, 2), 50.0)  # inside: no first deviation is redrawn
    state = model.start(rng, start, np.zeros(n), 100.0)
    first, state = model.directions(rng, state, 6, True)
    second, _ = model.directions(rng, state, 6, False)
    phi = np.hstack([first, second])  # mean axis 0: the angles are the deviations
    se = rms / np.sqrt(2 * n)  # standard error of an sd over n normal values
    assert np.all(np.abs(phi.std(axis=0) - rms) < 4 * se)
    a = np.exp(-segment / length)
    for lag in (1, 5, 11):
        r = np.corrcoef(phi[:, 0], phi[:, lag])[0, 1]
        assert abs(r - a**lag * (1 + lag * (1 - a**2) / (1 + a**2))) < 4 / np.sqrt(n)
    # Smooth: the turn between consecutive segments is much smaller than a random walk's
    # (an AR(1) deviation of the same rms and length turns by rms sqrt(2 (1 - a)) per segment).
    turn = np.diff(phi, axis=1).std()
    assert turn < 0.35 * rms * np.sqrt(2 * (1 - a))
    assert stats.normaltest(phi[:, 8]).pvalue > 1e-3


@pytest.mark.parametrize("seeding", ["border", "lines"])
def test_smooth_fibers_keep_their_direction_across_the_mat(seeding):
    """Wavy at short range like the paper walk at 40 deg, but no fiber curls: the paper walk
    with the same local waviness gives fibers that loop (tortuosity > 3)."""
    _, smooth = _mat(walk="smooth", waviness_deg=25.0, waviness_length_ratio=8.0,
                     seeding=seeding, size_ratio=150)
    _, paper = _mat(max_deviation_deg=40.0, seeding=seeding, size_ratio=150)
    assert smooth.tortuosity.max() < 1.6
    assert paper.tortuosity.max() > 3.0
    d = smooth.vertices[smooth.segment_start + 1] - smooth.vertices[smooth.segment_start]
    assert np.all(np.hypot(*d.T) > 0)  # every first segment points into the square


def test_walk_keys_belong_to_their_walk():
    from espin.core.errors import ConfigError

    cfg = load_config("plla", {"rve.walk": "smooth"})  # the preset's max_deviation_deg goes
    assert (cfg.rve.max_deviation_deg, cfg.rve.waviness_deg, cfg.rve.waviness_length_ratio) == \
        (None, 10.0, 20.0)
    assert load_config("plla").rve.waviness_deg is None
    with pytest.raises(ConfigError, match="max_deviation_deg does not apply to rve.walk = 'smooth'"):
        load_config("plla", {"rve.walk": "smooth", "rve.max_deviation_deg": 5})
    with pytest.raises(ConfigError, match="waviness_deg does not apply to rve.walk = 'paper'"):
        load_config("plla", {"rve.waviness_deg": 5})
    with pytest.raises(ConfigError, match="waviness_deg"):
        load_config("plla", {"rve.walk": "smooth", "rve.waviness_deg": 50})


def test_smooth_walk_without_waviness_is_straight():
    _, mat = _mat(walk="smooth", waviness_deg=0.0, seeding="lines")
    assert np.allclose(mat.tortuosity, 1.0, atol=1e-12)
