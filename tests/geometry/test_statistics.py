"""Statistics of mats and networks: window tortuosity, counts, densities, KS, figures."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats as sps

from espin.core.config import Config, OutputConfig, RVEConfig, TargetsConfig, VonMises, VonMisesParams
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network
from espin.geometry.statistics import (
    DEFAULT_MIN_CHORD_FRACTION,
    centred_window,
    diameter_target,
    ks_statistic,
    network_statistics,
    tortuosity_target,
    window_tortuosity,
)

PAPER = TargetsConfig(diameter_mean_um=0.463, diameter_sd_um=0.131, tortuosity_halfnorm_scale=0.14)
"""The paper's PLLA SEM statistics (Fig. 10), as the plla preset gives them."""

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def csr(*fibers):
    """Vertices and offsets of polylines given as lists of (x, y)."""
    vertices = np.concatenate([np.asarray(f, dtype=float).reshape(-1, 2) for f in fibers])
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in fibers])])
    return vertices, offsets


# --------------------------------------------------------------------------------------------
# window_tortuosity
# --------------------------------------------------------------------------------------------
def test_straight_fibers_crossing_the_window():
    v, o = csr(
        [(0, 3), (3, 3), (10, 3)],  # horizontal, a vertex inside the window
        [(0, 0), (1, 1), (4, 4), (10, 10)],  # the diagonal, corner to corner
        [(4, 10), (4, 0)],  # vertical, one segment through the window, pointing down
    )
    vis = window_tortuosity(v, o, origin=(2, 2), side=4, min_chord=0)
    assert len(vis) == 3
    np.testing.assert_array_equal(vis.fiber, [0, 1, 2])
    np.testing.assert_allclose(vis.chord_length, [4, 4 * math.sqrt(2), 4])
    np.testing.assert_allclose(vis.contour_length, vis.chord_length)
    np.testing.assert_allclose(vis.tortuosity, 1.0)
    np.testing.assert_allclose(vis.orientation, [0, math.pi / 4, math.pi / 2])
    np.testing.assert_allclose(vis.start, [(2, 3), (2, 2), (4, 6)])
    np.testing.assert_allclose(vis.end, [(6, 3), (6, 6), (4, 2)])


def test_zigzag_inside_the_window_has_the_exact_ratio():
    v, o = csr(
        [(3, 3), (4, 4), (5, 3), (6, 4), (7, 3)],  # four 45-degree zigzag segments
        [(5, 4), (3, 5)],  # leftwards: axis pi - atan(1/2), in [0, pi)
    )
    vis = window_tortuosity(v, o, origin=(0, 0), side=10, min_chord=0)
    assert len(vis) == 2
    np.testing.assert_allclose(vis.contour_length, [4 * math.sqrt(2), math.sqrt(5)])
    np.testing.assert_allclose(vis.chord_length, [4, math.sqrt(5)])
    np.testing.assert_allclose(vis.tortuosity, [math.sqrt(2), 1.0])
    np.testing.assert_allclose(vis.orientation, [0.0, math.pi - math.atan(0.5)])


def test_fiber_leaving_and_reentering_gives_two_portions():
    v, o = csr(
        [(1, 1), (1, 6), (3, 6), (3, 1)],  # out through the top, back in two units right
        [(1, 1), (2, 5), (3, 1)],  # a single vertex outside: out and in on adjacent segments
    )
    vis = window_tortuosity(v, o, origin=(0, 0), side=4, min_chord=0)
    assert len(vis) == 4
    np.testing.assert_array_equal(vis.fiber, [0, 0, 1, 1])
    np.testing.assert_allclose(vis.contour_length[:2], [3, 3])
    np.testing.assert_allclose(vis.tortuosity[:2], 1.0)
    np.testing.assert_allclose(vis.orientation[:2], math.pi / 2)
    # Second fiber: (1,1) -> (1.75, 4) and (2.25, 4) -> (3, 1), each of length sqrt(9.5625).
    np.testing.assert_allclose(vis.start[2:], [(1, 1), (2.25, 4)])
    np.testing.assert_allclose(vis.end[2:], [(1.75, 4), (3, 1)])
    np.testing.assert_allclose(vis.contour_length[2:], math.sqrt(0.75**2 + 9))


def test_fibers_outside_or_touching_a_corner_give_nothing():
    v, o = csr(
        [(5, 5), (8, 9)],  # fully outside
        [(3, 5), (5, 3)],  # touches the corner (4, 4) at a single point
        [(-1, 5), (5, 5)],  # parallel to the top edge, above it
        [(2.0, 2.0)],  # a single vertex: no segment
    )
    vis = window_tortuosity(v, o, origin=(0, 0), side=4, min_chord=0)
    assert len(vis) == 0
    assert vis.start.shape == (0, 2) and vis.fiber.dtype == np.int64


def test_min_chord_drops_stubs_and_has_a_documented_default():
    v, o = csr(
        [(0, 9.2), (0.8, 10.8)],  # clips the top-left corner: chord ~0.89 < 1
        [(0, 8.9), (1.1, 11.1)],  # chord ~1.23 > 1
        [(0, 5), (5, 12)],  # leaves through the top at x = 25/7: chord ~6.1
    )
    side = 10.0
    default = window_tortuosity(v, o, origin=(0, 0), side=side)
    assert default.min_chord == pytest.approx(DEFAULT_MIN_CHORD_FRACTION * side) == 1.0
    np.testing.assert_array_equal(default.fiber, [1, 2])
    strict = window_tortuosity(v, o, origin=(0, 0), side=side, min_chord=2.0)
    np.testing.assert_array_equal(strict.fiber, [2])
    everything = window_tortuosity(v, o, origin=(0, 0), side=side, min_chord=0.0)
    assert len(everything) == 3
    with pytest.raises(ValueError):
        window_tortuosity(v, o, origin=(0, 0), side=0.0)


def test_visible_contour_matches_brute_force_sampling():
    rng = np.random.default_rng(3)
    fibers = []
    for _ in range(30):
        steps = rng.normal(size=(rng.integers(2, 12), 2)) * 2.0
        fibers.append(rng.uniform(0, 10, 2) + np.cumsum(steps, axis=0))
    v, o = csr(*fibers)
    origin, side = np.array([2.0, 3.0]), 5.0
    vis = window_tortuosity(v, o, origin, side, min_chord=0.0)
    # Brute force: midpoints of 2000 sub-pieces per segment inside the window.
    total = 0.0
    for f in fibers:
        for p, q in zip(f[:-1], f[1:]):
            t = (np.arange(2000) + 0.5) / 2000
            mid = p + t[:, None] * (q - p)
            inside = np.all((mid >= origin) & (mid <= origin + side), axis=1)
            total += inside.mean() * np.hypot(*(q - p))
    assert vis.contour_length.sum() == pytest.approx(total, rel=2e-3)
    assert np.all(vis.tortuosity >= 1.0)
    assert np.all((vis.orientation >= 0) & (vis.orientation < np.pi))
    for pts in (vis.start, vis.end):
        assert np.all((pts >= origin - 1e-12) & (pts <= origin + side + 1e-12))


def test_centred_window_is_clipped_to_the_rve():
    origin, side = centred_window(100.0, 20.0)
    np.testing.assert_allclose(origin, [40, 40])
    assert side == 20.0
    origin, side = centred_window(10.0, 20.0)
    np.testing.assert_allclose(origin, [0, 0])
    assert side == 10.0


# --------------------------------------------------------------------------------------------
# network_statistics on a hand-built mat
# --------------------------------------------------------------------------------------------
def tiny_mat_and_network():
    """Three straight fibers in a 10 um square: two cross-links, one within, one between.

    f0 (layer 0): y = 5; f1 (layer 0): x = 5; f2 (layer 1): y = 2.
    Inner nodes: n0 = (5, 5) joins f0, f1; n1 = (5, 2) joins f1, f2.
    """
    v, o = csr(
        [(0, 5), (4, 5), (10, 5)],
        [(5, 0), (5, 6), (5, 10)],
        [(0, 2), (10, 2)],
    )
    mat = FiberMat(v, o, np.array([0, 0, 1]), np.array([0.5, 0.5, 0.5]), 10.0, 0.5, 2)
    nodes = np.array([(5, 5), (5, 2), (0, 5), (10, 5), (5, 0), (5, 10), (0, 2), (10, 2)], float)
    elements = np.array([(2, 0), (0, 3), (4, 1), (1, 0), (0, 5), (6, 1), (1, 7)])
    network = Network(
        node_position=nodes,
        n_inner=2,
        element_nodes=elements,
        element_contour_length=np.array([5, 5, 2, 3, 5, 5, 5], float),
        element_diameter=np.full(7, 0.5),
        element_layer=np.array([0, 0, 0, 0, 0, 1, 1]),
        element_fiber=np.array([0, 0, 1, 1, 1, 2, 2]),
        size=10.0,
        thickness=0.5,
        n_layers=2,
        n_merged=0,
        merge_tolerance=5e-4,
    )
    config = Config(
        rve=RVEConfig(size_um=10.0, diameter_um=0.5, segment_ratio=2.0, layers=2),
        output=OutputConfig(window_ratio=8.0),  # a 4 um window, centred: [3, 7]^2
    )
    return mat, network, config


def test_counts_and_crosslink_densities_of_a_tiny_network():
    mat, network, config = tiny_mat_and_network()
    st = network_statistics(mat, network, config)
    assert (st.n_fibers, st.n_segments, st.n_elements) == (3, 5, 7)
    assert (st.n_inner_nodes, st.n_border_nodes, st.n_merged, st.n_dof) == (2, 6, 0, 4)
    assert (st.n_crosslinks_within_layer, st.n_crosslinks_between_layers) == (1, 1)
    assert st.total_fiber_length_um == pytest.approx(30.0)
    # Two cross-links, each on two fibers: 4 incidences over 30 um of fiber.
    assert st.crosslink_density_per_um == pytest.approx(4 / 30)
    # Two cross-links over two layers of 100 um^2.
    assert st.crosslink_density_per_um2 == pytest.approx(2 / 200)
    # Volume fraction: pi 0.25 / 4 * length / (100 * 0.5).
    np.testing.assert_allclose(st.layer_volume_fraction, np.pi * 0.0625 * np.array([20, 10]) / 50)
    assert st.mean_volume_fraction == pytest.approx(np.pi * 0.0625 * 15 / 50)
    # Integral geometry with L_A = 0.2 and 0.1 um^-1: within 100 (0.04 + 0.01) / pi,
    # between 100 * 2 * 0.02 / pi.
    np.testing.assert_allclose(st.layer_length_density_per_um, [0.2, 0.1])
    assert st.expected_crosslinks_within == pytest.approx(5 / np.pi)
    assert st.expected_crosslinks_between == pytest.approx(4 / np.pi)
    assert st.crosslink_ratio == pytest.approx(2 / (9 / np.pi))
    # Without self-pairs: layer 0 has two 10 um fibers, (20^2 - 2 * 10^2) / (100 pi);
    # layer 1 has one fiber, which cannot cross itself.
    assert st.expected_crosslinks_within_distinct == pytest.approx(2 / np.pi)
    assert st.crosslink_ratio_distinct == pytest.approx(2 / (6 / np.pi))
    assert st.nominal_length_density_per_um == pytest.approx(4 * 0.19 / (np.pi * 0.5))
    # Samples.
    np.testing.assert_allclose(st.fiber_orientation, [0, np.pi / 2, 0])
    np.testing.assert_allclose(st.fiber_tortuosity, 1.0)
    np.testing.assert_allclose(st.element_length_um, [5, 5, 2, 3, 5, 5, 5])
    np.testing.assert_allclose(st.element_tortuosity, 1.0)
    # Window [3, 7]^2 sees f0 and f1 crossing it (chord 4); f2 (y = 2) is outside.
    np.testing.assert_allclose(st.window.origin, [3, 3])
    np.testing.assert_array_equal(st.window.fiber, [0, 1])
    np.testing.assert_allclose(st.window.chord_length, 4.0)


def test_equal_layers_reduce_to_the_spec_formula():
    # Three layers of equal length density L_A: L^2 (N_l L_A^2 / pi + (N_l - 1) 2 L_A^2 / pi).
    _, _, config = tiny_mat_and_network()
    v, o = csr(*[[(0, 1 + k), (10, 1 + k)] for k in range(3)])
    mat3 = FiberMat(v, o, np.arange(3), np.full(3, 0.5), 10.0, 0.5, 3)
    st = network_statistics(mat3, _trivial_network(mat3), config)
    la = 10.0 / 100.0
    expected = 100 * (3 * la**2 / np.pi + 2 * 2 * la**2 / np.pi)
    assert st.expected_crosslinks == pytest.approx(expected)


def _trivial_network(mat: FiberMat) -> Network:
    """One element per fiber between its two ends; no cross-links."""
    first = mat.vertices[mat.fiber_offsets[:-1]]
    last = mat.vertices[mat.fiber_offsets[1:] - 1]
    n = mat.n_fibers
    return Network(
        node_position=np.concatenate([first, last]),
        n_inner=0,
        element_nodes=np.stack([np.arange(n), np.arange(n) + n], axis=1),
        element_contour_length=mat.contour_length,
        element_diameter=mat.fiber_diameter,
        element_layer=mat.fiber_layer,
        element_fiber=np.arange(n),
        size=mat.size,
        thickness=mat.thickness,
        n_layers=mat.n_layers,
        n_merged=0,
        merge_tolerance=1e-3 * mat.thickness,
    )


def straight_line_mat(theta: np.ndarray, diameter: np.ndarray, size: float, rng) -> FiberMat:
    """Straight fibers through random interior points along the axes theta, border to border."""
    centre = rng.uniform(0.2 * size, 0.8 * size, (len(theta), 2))
    u = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    with np.errstate(divide="ignore"):
        # Distance along +u and -u to the square's border.
        fwd = np.min(np.where(u > 0, (size - centre) / u, np.where(u < 0, -centre / u, np.inf)), 1)
        bwd = np.min(np.where(u < 0, (size - centre) / -u, np.where(u > 0, centre / u, np.inf)), 1)
    a = centre - bwd[:, None] * u
    b = centre + fwd[:, None] * u
    vertices = np.stack([a, b], axis=1).reshape(-1, 2)
    offsets = np.arange(0, 2 * len(theta) + 1, 2)
    return FiberMat(vertices, offsets, np.zeros(len(theta), np.int64), diameter, size, 0.45, 1)


def test_ks_statistics_separate_right_and_wrong_targets():
    rng = np.random.default_rng(7)
    n = 800
    config = Config(rve=RVEConfig(size_um=90.0, layers=1), targets=PAPER)
    aligned = Config(
        rve=RVEConfig(size_um=90.0, layers=1,
                      orientation=VonMises(von_mises=VonMisesParams(mean_deg=0, kappa=4))),
        targets=PAPER,
    )
    diam = np.clip(diameter_target(PAPER).law.rvs(n, random_state=rng), 0.05, None)
    mat = straight_line_mat(rng.uniform(0, np.pi, n), diam, 90.0, rng)
    net = _trivial_network(mat)
    right = network_statistics(mat, net, config)
    wrong = network_statistics(mat, net, aligned)
    # Samples from the target: KS > 0.1 at n = 800 has probability ~1e-7.
    assert right.ks_fiber_orientation < 0.1
    assert right.ks_window_orientation < 0.1
    assert right.grading.diameter.ks < 0.1
    assert wrong.ks_fiber_orientation > 0.25
    # Straight fibers against the measured half-normal: every tortuosity is 1, F(1) = 0.
    assert right.grading.tortuosity.ks == pytest.approx(1.0)
    # A fixed diameter: the statistic is 0.5 + |F(D) - 1/2| (no meaningful p-value).
    fixed = straight_line_mat(rng.uniform(0, np.pi, n), np.full(n, 0.45), 90.0, rng)
    st = network_statistics(fixed, _trivial_network(fixed), config)
    f = sps.norm(0.463, 0.131).cdf(0.45)
    assert st.grading.diameter.ks == pytest.approx(0.5 + abs(f - 0.5))


def test_ks_statistic_of_tortuosity_samples():
    rng = np.random.default_rng(11)
    target = tortuosity_target(PAPER).law
    assert target.mean() == pytest.approx(1.1117, abs=1e-3)
    good = target.rvs(1000, random_state=rng)
    bad = 1.0 + np.abs(rng.normal(0.0, 0.006, 1000))  # Table 2 fibers: almost straight
    assert ks_statistic(good, target.cdf) < 0.08
    assert ks_statistic(bad, target.cdf) > 0.8
    assert math.isnan(ks_statistic([], target.cdf))


def test_summary_is_flat_json_and_table_lists_it():
    mat, network, config = tiny_mat_and_network()
    st = network_statistics(mat, network, config.model_copy(update={"targets": PAPER}))
    s = st.summary()
    text = json.dumps(s, allow_nan=False)
    assert json.loads(text) == s
    assert all(not isinstance(v, (dict, list)) for v in s.values())
    assert s["crosslink_density_per_um2"] == pytest.approx(0.01)
    assert s["n_dof"] == 4 and isinstance(s["n_dof"], int)
    assert s["fiber_orientation_order"] == pytest.approx(1 / 3)  # two at 0, one at 90 deg
    table = st.format_table()
    for key in ("crosslink_density_per_um", "ks_window_tortuosity", "n_dof"):
        assert key in table


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_figures_are_written(tmp_path):
    from espin.geometry.figures import plot_mat, plot_statistics

    rng = np.random.default_rng(5)
    n = 200
    theta = rng.uniform(0, np.pi, n)
    mat = straight_line_mat(theta, np.full(n, 0.45), 90.0, rng)
    mat = FiberMat(mat.vertices, mat.fiber_offsets, rng.integers(0, 3, n), mat.fiber_diameter,
                   90.0, 0.45, 3)
    config = Config(rve=RVEConfig(size_um=90.0, layers=3))
    st = network_statistics(mat, _trivial_network(mat), config)
    paths = [
        plot_mat(mat, tmp_path / "mat.png", window=st.window, dpi=50),
        plot_statistics(st, tmp_path / "sub" / "statistics.png", dpi=50),
    ]
    for p in paths:
        assert p.exists() and p.stat().st_size > 1000
        assert p.read_bytes()[:8] == PNG_SIGNATURE
    assert sorted(f.name for f in tmp_path.rglob("*") if f.is_file()) == [
        "mat.png", "statistics.png"
    ]


def test_orientation_moments_of_a_tiny_network_and_of_targets():
    """Length-weighted moments: 20 um of horizontal fiber and 10 um of vertical give <cos^2> =
    <cos^4> = 2/3 against a uniform target's 1/2 and 3/8; a von Mises target's moments are the
    Bessel ratios."""
    from scipy import special

    mat, network, config = tiny_mat_and_network()
    m = network_statistics(mat, network, config).orientation_moments()
    assert m["cos2"] == pytest.approx(2 / 3) and m["cos4"] == pytest.approx(2 / 3)
    assert m["tensor_12"] == pytest.approx(0.0, abs=1e-15) and m["tensor_11"] == m["cos2"]
    assert (m["target_cos2"], m["target_cos4"]) == (pytest.approx(0.5), pytest.approx(0.375))
    assert m["tensor_deviation"] == pytest.approx(np.sqrt(2) / 6)
    kappa, mean = 2.0, np.radians(30.0)
    aligned = config.model_copy(update={"rve": config.rve.model_copy(update={
        "orientation": VonMises(von_mises=VonMisesParams(mean_deg=30.0, kappa=kappa))})})
    m = network_statistics(mat, network, aligned).orientation_moments()
    r1, r2 = special.iv(1, kappa) / special.iv(0, kappa), special.iv(2, kappa) / special.iv(0, kappa)
    # p ~ exp(kappa cos 2(theta - mu)): <cos 2 theta> = r1 cos 2 mu, <cos 4 theta> = r2 cos 4 mu
    assert m["target_cos2"] == pytest.approx((1 + r1 * np.cos(2 * mean)) / 2, rel=1e-6)
    assert m["target_cos4"] == pytest.approx((3 + 4 * r1 * np.cos(2 * mean) + r2 * np.cos(4 * mean)) / 8, rel=1e-6)
    assert m["target_tensor_12"] == pytest.approx(r1 * np.sin(2 * mean) / 2, rel=1e-6)
    summary = network_statistics(mat, network, aligned).summary()
    assert summary["orientation_cos4"] == pytest.approx(2 / 3) and "orientation_tensor_deviation" in summary


def test_chords_along_an_edge_are_the_fibers_that_leave_through_the_edge_they_entered():
    # The spikes at 0 and 90 deg of the end-to-end orientation: exactly these fibers, which the
    # statistics figure draws apart as a boundary artefact.
    import espin.geometry.rve
    from espin.geometry.figures import along_an_edge
    from espin.geometry.rve_folder import rve_statistics

    rve = espin.geometry.rve.generate("plla", rve__size_ratio=100, rve__layers=5)
    mat = rve.mat
    same_edge = []
    for i in range(len(mat.fiber_offsets) - 1):
        first, last = mat.vertices[mat.fiber_offsets[i]], mat.vertices[mat.fiber_offsets[i + 1] - 1]
        same_edge.append(any(abs(first[k] - e) < 1e-9 and abs(last[k] - e) < 1e-9
                             for k in (0, 1) for e in (0.0, mat.size)))
    edge = along_an_edge(rve_statistics(rve).fiber_orientation)
    assert edge.tolist() == same_edge and 0 < edge.sum() < 0.2 * len(edge)
