"""The mechanical network (SPEC 2): cutting fibers into elements, merging, invariants."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_mat

from espin.geometry.crosslinks import find_crosslinks
from espin.geometry.network import build_network


def test_hand_built_network():
    # Fiber 0 bends at (4, 5); fiber 1 is straight and crosses it at (3, 5).
    mat = make_mat([[(0, 5), (4, 5), (10, 8)], [(3, 0), (3, 10)]], layers=[0, 0])
    net = build_network(mat, find_crosslinks(mat), tolerance=1e-4)
    assert (net.n_inner, net.n_border, net.n_elements, net.n_dof) == (1, 4, 4, 2)
    assert np.allclose(net.node_position[0], [3, 5])
    by_fiber = {f: np.flatnonzero(net.element_fiber == f) for f in (0, 1)}
    # Fiber 0: (0,5)->(3,5) straight; (3,5)->(10,8) via the vertex (4,5).
    e0, e1 = by_fiber[0]
    assert net.element_contour_length[e0] == pytest.approx(3.0)
    contour = 1.0 + np.hypot(6, 3)
    assert net.element_contour_length[e1] == pytest.approx(contour)
    assert net.element_tortuosity[e1] == pytest.approx(contour / np.hypot(7, 3))
    assert net.element_tortuosity[e0] == pytest.approx(1.0)
    # Elements run along the fiber: e1 starts where e0 ends.
    assert net.element_nodes[e0, 1] == net.element_nodes[e1, 0] == 0
    assert np.allclose(net.element_vector[e0], [3, 0])


def test_close_crosslinks_merge_into_one_node():
    # Fibers 1 and 2 are parallel and cross fiber 0 1e-4 apart along it.
    mat = make_mat(
        [[(0, 5), (10, 5)], [(2, 0), (8, 10)], [(2.0001, 0), (8.0001, 10)]], layers=[0, 0, 1]
    )
    x = find_crosslinks(mat)
    assert x.n == 2
    net = build_network(mat, x, tolerance=1e-3)
    assert net.n_inner == 1 and net.n_merged == 1
    assert len(set(net.element_fiber[np.any(net.element_nodes == 0, axis=1)])) == 3
    assert net.n_elements == 6  # each fiber: border - node - border
    assert np.all(net.element_length >= 1e-3)
    assert np.isfinite(net.element_tortuosity).all() and net.element_tortuosity.min() >= 1.0
    # Without merging, the same fibers give three nodes and short elements.
    fine = build_network(mat, x, tolerance=1e-9)
    assert fine.n_inner == 2 and fine.n_merged == 0 and fine.element_length.min() < 1e-3


def test_crosslink_at_a_fiber_end_becomes_a_border_node():
    mat = make_mat([[(0, 5), (10, 5)], [(1e-5, 0), (1e-5, 10)]], layers=[0, 0])
    net = build_network(mat, find_crosslinks(mat), tolerance=1e-3)
    assert net.n_inner == 0 and net.n_border == 4 and net.n_merged == 1 and net.n_elements == 3
    assert np.all(net.element_length > 1e-3)


def test_generated_network_invariants(small_rve):
    mat, x, net = small_rve.mat, small_rve.crosslinks, small_rve.network
    assert net.n_dof == 2 * net.n_inner
    # Each cross-link cuts two fibers; each merge removes at least one cut.
    assert net.n_elements <= mat.n_fibers + 2 * x.n - net.n_merged
    assert net.n_elements >= mat.n_fibers + 2 * x.n - 2 * net.n_merged
    assert net.element_length.min() >= net.merge_tolerance
    assert net.element_tortuosity.min() >= 1.0 and np.isfinite(net.element_tortuosity).all()
    # The elements of a fiber cover its contour (merged bits are shorter than the tolerance).
    covered = np.bincount(net.element_fiber, net.element_contour_length, minlength=mat.n_fibers)
    assert np.abs(covered - mat.contour_length).max() < 4 * net.merge_tolerance
    # Every inner node joins at least two fibers (four elements); border nodes lie on the border.
    degree = np.bincount(net.element_nodes.ravel(), minlength=net.n_nodes)
    assert degree[: net.n_inner].min() >= 4 and degree.min() >= 1
    b = net.node_position[net.n_inner:]
    dist = np.minimum.reduce([b[:, 0], b[:, 1], net.size - b[:, 0], net.size - b[:, 1]])
    assert np.abs(dist).max() < 1e-9
    # Distinct fibers at every inner node: at least two.
    pairs = np.unique(np.c_[net.element_nodes.ravel(), np.repeat(net.element_fiber, 2)], axis=0)
    fibers_per_node = np.bincount(pairs[:, 0], minlength=net.n_nodes)
    assert fibers_per_node[: net.n_inner].min() >= 2
