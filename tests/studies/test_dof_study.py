"""DOF of espin's model against a beam model of the same geometry (paper 4.3, Fig. 14)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_mat

from espin.core.errors import ConfigError
from espin.geometry.crosslinks import find_crosslinks
from espin.geometry.network import build_network
from espin.studies.dof import count_dof, dof_fit, dof_study, plot_dof_study


def hand_built():
    """Three fibers in one layer of a 10 um square:

    A (0,5)-(5,5)-(10,5): its corner (5,5) lies on fiber B, so the corner is the cross-link;
    B (5,0)-(5,10): straight, crossed by A at (5,5) and by C at (5,2.5);
    C (0,2)-(3,2)-(7,3)-(10,3): two corners, neither on a node.
    """
    mat = make_mat([[(0, 5), (5, 5), (10, 5)], [(5, 0), (5, 10)], [(0, 2), (3, 2), (7, 3), (10, 3)]],
                   [0, 0, 0])
    crosslinks = find_crosslinks(mat)
    return mat, crosslinks, build_network(mat, crosslinks, 1e-6)


@pytest.mark.parametrize("elements", [1, 2, 3])
def test_exact_counts_on_a_hand_built_mat(elements):
    mat, crosslinks, network = hand_built()
    assert crosslinks.n == 2 and network.n_inner == 2
    count = count_dof(mat, crosslinks, network, elements)
    # espin: 2 cross-links x 2 DOF. Beam: nodes at the 2 cross-links and C's 2 corners (A's
    # corner is a cross-link); pieces A 2, B 3, C 4 = 9, each with elements - 1 interior nodes.
    assert count.espin_dof == 4
    assert count.beam_pieces == 9
    assert count.beam_nodes == 4 + 9 * (elements - 1)
    assert count.beam_dof == 6 * count.beam_nodes
    assert count.ratio == pytest.approx(count.beam_dof / 4)


def test_a_corner_next_to_a_fiber_end_is_that_end():
    # C's last segment is trimmed to 1e-7 um: its corner sits on the border node.
    mat = make_mat([[(0, 5), (10 - 1e-7, 5), (10, 5)], [(5, 0), (5, 10)]], [0, 0])
    crosslinks = find_crosslinks(mat)
    count = count_dof(mat, crosslinks, build_network(mat, crosslinks, 1e-6), 1)
    assert count.beam_nodes == 1 and count.beam_pieces == 4


def test_bad_elements_per_segment():
    with pytest.raises(ConfigError, match="elements_per_segment"):
        count_dof(*hand_built(), 0)
    with pytest.raises(ConfigError, match="elements_per_segment"):
        dof_study([30], 2, elements_per_segment=0)


@pytest.fixture(scope="module")
def study():
    return dof_study([40, 60, 80, 100], 5, seeds=(1, 2, 3))


def test_table_is_tidy(study):
    assert list(study.columns) == ["size_ratio", "layers", "seed", "n_fibers", "n_crosslinks",
                                   "espin_dof", "beam_dof", "ratio"]
    assert len(study) == 12
    assert np.array_equal(study["espin_dof"], 2 * study["n_crosslinks"])


def test_dof_grow_quadratically(study):
    # Fiber length per layer ~ L^2, so cross-links ~ L^2 (SPEC 2); border nodes only ~ L.
    means = study.groupby("size_ratio")[["espin_dof", "beam_dof"]].mean()
    for column in ("espin_dof", "beam_dof"):
        growth = np.log(means[column][100] / means[column][40]) / np.log(2.5)
        assert 1.8 < growth < 2.3
        fit = dof_fit(study, column)
        c0, c1, c2 = fit.coef
        # Realizations scatter by about 4 % at these sizes (sd over seeds), so the mean of 3
        # by about 2.5 %: the quadratic must pass within 6 % of every mean.
        assert np.all(np.abs(fit(means.index.to_numpy()) / means[column] - 1) < 0.06)
        assert c2 > 0 and c2 * 100**2 > 10 * abs(c1 * 100 + c0)  # the L^2 term dominates


def test_beam_model_needs_more_dof(study):
    assert (study["ratio"] > 1).all()
    # With one element per piece the beam model has 6 DOF at every cross-link and corner,
    # against espin's 2 per cross-link: more than 3x.
    assert (study["ratio"] > 3).all()
    more = dof_study([40], 5, elements_per_segment=3)
    same = study[(study["size_ratio"] == 40) & (study["seed"] == 1)]
    assert more["espin_dof"].iloc[0] == same["espin_dof"].iloc[0]
    assert more["beam_dof"].iloc[0] > 2 * same["beam_dof"].iloc[0]


def test_dof_fit_needs_one_layer_count(study):
    import pandas as pd

    both = pd.concat([study, study.assign(layers=4)])
    with pytest.raises(ConfigError, match="layers"):
        dof_fit(both)
    assert np.allclose(dof_fit(both, layers=4).coef, dof_fit(study).coef)


def test_plot(study, tmp_path):
    path = plot_dof_study(study, tmp_path / "dof.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
