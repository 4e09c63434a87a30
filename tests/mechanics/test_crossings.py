"""Opt-in fused crossings: springs between the fibers meeting at a cross-link, their
derivatives, that rigid motions cost nothing, that the paper's model is untouched with the
term off, and that the term gives the mat lateral stiffness."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix

import espin
from espin.core.config import FiberConfig
from espin.mechanics.bending import fiber_joints
from espin.mechanics.crossings import crossing_joints, with_crossings

E_BEND = 3000.0  # MPa, plla's E_t


def _perturbed(positions: np.ndarray, sd: float, seed: int = 0) -> np.ndarray:
    return positions + np.random.default_rng(seed).normal(0.0, sd, positions.shape)


def test_springs_join_arms_of_different_fibers_at_crossings(small_rve):
    """Every spring's a-b and b-c are elements of two different fibers meeting at b; with phi = 1
    every pair of such arms at every crossing has one; k = E I / lbar; no energy in the reference."""
    net = small_rve.network
    joints = crossing_joints(net, E_BEND, 1.0, seed=1)
    element_of: dict[tuple[int, int], list[int]] = {}  # two fibers can join the same two nodes
    for e, (n1, n2) in enumerate(net.element_nodes):
        element_of.setdefault((n1, n2), []).append(e)
        element_of.setdefault((n2, n1), []).append(e)
    expected = 0
    for node in range(net.n_nodes):
        arms = np.flatnonzero(np.any(net.element_nodes == node, axis=1))
        fibers = net.element_fiber[arms]
        expected += sum(int(fibers[i] != fibers[j]) for i in range(len(arms)) for j in range(i + 1, len(arms)))
    assert len(joints.stiffness) == expected > net.n_inner  # about four per two-fiber crossing
    for (a, b, c), k in zip(joints.nodes, joints.stiffness):
        candidates = [E_BEND * np.pi * (0.5 * (net.element_diameter[e] + net.element_diameter[f]))**4 / 64
                      / (0.5 * (net.element_contour_length[e] + net.element_contour_length[f]))
                      for e in element_of[(a, b)] for f in element_of[(b, c)]
                      if net.element_fiber[e] != net.element_fiber[f]]
        assert np.min(np.abs(np.array(candidates) - k)) <= 1e-12 * k
    assert joints.energy(net.node_position) == pytest.approx(0.0, abs=1e-20)


def test_the_fused_fraction_draws_a_share_of_the_crossings(small_rve):
    """phi picks whole crossings, reproducibly from the seed; about phi of them."""
    net = small_rve.network
    every = crossing_joints(net, E_BEND, 1.0, seed=1)
    half = crossing_joints(net, E_BEND, 0.5, seed=1)
    assert np.array_equal(half.nodes, crossing_joints(net, E_BEND, 0.5, seed=1).nodes)
    assert not np.array_equal(half.nodes, crossing_joints(net, E_BEND, 0.5, seed=2).nodes)
    fused, all_crossings = np.unique(half.nodes[:, 1]), np.unique(every.nodes[:, 1])
    assert 0.35 < len(fused) / len(all_crossings) < 0.65
    # a fused crossing has all its springs
    for node in fused[:10]:
        assert np.sum(half.nodes[:, 1] == node) == np.sum(every.nodes[:, 1] == node)


def test_the_stiffness_ratio_scales_the_welds_only(small_rve):
    net = small_rve.network
    one = crossing_joints(net, E_BEND, 1.0, seed=1)
    stiff = crossing_joints(net, E_BEND, 1.0, seed=1, stiffness_ratio=4.0)
    assert np.array_equal(one.nodes, stiff.nodes)
    assert np.allclose(stiff.stiffness, 4.0 * one.stiffness, rtol=1e-15)
    assert np.array_equal(one.reference_angle, stiff.reference_angle)


def test_gradient_and_hessian_match_finite_differences(small_rve):
    net = small_rve.network
    joints = with_crossings(fiber_joints(net, E_BEND), crossing_joints(net, E_BEND, 1.0, seed=1))
    x = _perturbed(net.node_position, 0.1)
    n_dof = 2 * net.n_nodes
    g = joints.gradient(x, n_dof)
    blocks = joints.blocks(x, exact=True)
    rows = np.repeat(joints.dof, 6, axis=1).ravel()
    cols = np.tile(joints.dof, (1, 6)).ravel()
    H = coo_matrix((blocks.ravel(), (rows, cols)), shape=(n_dof, n_dof)).tocsr()
    h = 1e-6
    for dof in np.random.default_rng(2).choice(n_dof, 20, replace=False):
        up, down = x.copy(), x.copy()
        up.ravel()[dof] += h
        down.ravel()[dof] -= h
        assert (joints.energy(up) - joints.energy(down)) / (2 * h) == pytest.approx(g[dof], abs=1e-6 * np.abs(g).max())
        column = (joints.gradient(up, n_dof) - joints.gradient(down, n_dof)) / (2 * h)
        assert np.allclose(column, H[:, dof].toarray().ravel(), atol=1e-6 * abs(H).max())
    assert abs(H - H.T).max() <= 1e-9 * abs(H).max()
    assert np.linalg.eigvalsh(joints.blocks(x, exact=False)).min() >= -1e-9 * abs(H).max()


def test_rigid_motion_costs_nothing_and_scissoring_does(small_rve):
    net = small_rve.network
    joints = crossing_joints(net, E_BEND, 1.0, seed=1)
    c, s = np.cos(0.9), np.sin(0.9)
    x = net.node_position @ np.array([[c, -s], [s, c]]).T + [3.0, -1.0]
    assert joints.energy(x) < 1e-9 * np.sum(joints.stiffness)
    assert np.abs(joints.gradient(x, 2 * net.n_nodes)).max() < 1e-9 * joints.stiffness.max()
    # a uniaxial stretch with lateral contraction turns the fibers toward the axis: it costs
    assert joints.energy(net.node_position @ np.diag([1.1, 0.9])) > 1e-4 * np.sum(joints.stiffness)


def test_fused_crossings_need_a_fiber_modulus():
    with pytest.raises(ValueError, match="bending_modulus_MPa"):
        FiberConfig(fused_crossing_fraction=0.5)
    assert FiberConfig(fused_crossing_fraction=0.5, bending_modulus_MPa=E_BEND).fused_crossing_fraction == 0.5


def test_term_off_is_unchanged():
    """phi = 0 given explicitly is the default: the same P bit for bit, with and without bending."""
    kw = dict(rve__size_ratio=30, rve__layers=2, loading__max_strain=0.02, loading__steps=2)
    for bending in (0.0, E_BEND):
        default = espin.simulate("plla", fiber__bending_modulus_MPa=bending, **kw)
        off = espin.simulate("plla", fiber__bending_modulus_MPa=bending, fiber__fused_crossing_fraction=0.0, **kw)
        assert np.array_equal(default.P, off.P)
        assert np.array_equal(default.iterations, off.iterations)


def test_fused_crossings_hold_the_width():
    """Lateral free: fused crossings contract the mat less than pin joints (with bending alone),
    and the stress they carry is in P (P22 stays at its target, zero)."""
    kw = dict(rve__size_ratio=30, rve__layers=2, loading__max_strain=0.02, loading__steps=2,
              loading__lateral="free", fiber__bending_modulus_MPa=E_BEND)
    pinned = espin.simulate("plla", **kw)
    fused = espin.simulate("plla", fiber__fused_crossing_fraction=1.0, **kw)
    assert fused.F[-1][1, 1] > pinned.F[-1][1, 1] + 0.02
    assert abs(fused.P[-1][1, 1]) < 1e-3 * fused.P[-1][0, 0]


def test_the_welds_stress_is_in_P():
    """At equilibrium with fused crossings P = (1 / V0) sum over border nodes f_b (x) X_b: the
    welds' forces are in the stress (through the joints' virial)."""
    import espin.geometry.rve
    from espin.mechanics.equilibrium import EquilibriumSolver, StepState
    from espin.mechanics.fiber_law import FiberLaw
    from espin.mechanics.homogenization import nominal_stress
    from espin.mechanics.linear_solvers import make_linear_solver

    rve = espin.geometry.rve.generate("plla", rve__size_ratio=30, rve__layers=2)
    net = rve.network
    law = FiberLaw.from_config(FiberConfig(flow_rate_per_s=0.0))
    solver = EquilibriumSolver(net, law, rve.config.solver, make_linear_solver("auto"), bending_modulus_MPa=E_BEND,
                               fused_crossing_fraction=1.0, crossing_seed=1, crossing_stiffness_ratio=4.0)
    asm = solver.asm
    X = asm.reference[: net.n_inner]
    start = StepState(0.0, X, np.zeros(0), np.eye(2), np.ones(net.n_elements), np.zeros(net.n_elements))
    F = np.array([[1.03, 0.004], [0.002, 0.99]])
    step = solver.solve(start, 1.0, F, np.zeros((0, 2, 2)), X @ F.T, np.zeros(0))
    x = asm.positions(step.state.inner, F)
    g = (asm.gradient(step.force, step.kinematics) + solver.joints.gradient(x, asm.n_dof)).reshape(-1, 2)
    n = net.n_inner
    border = g[n:].T @ asm.reference[n:] / net.reference_volume
    P = nominal_stress(net, step.force, step.kinematics, solver.joints, x)
    assert np.allclose(border, P, rtol=1e-6, atol=1e-9 * np.abs(P).max())
    bending_only = EquilibriumSolver(net, law, rve.config.solver, make_linear_solver("auto"),
                                     bending_modulus_MPa=E_BEND)
    assert len(solver.joints.stiffness) > len(bending_only.joints.stiffness)
