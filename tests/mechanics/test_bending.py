"""Opt-in fiber bending across nodes: the joints' springs, their derivatives, the stress they
add, and that the paper's model (no bending) is untouched."""

from __future__ import annotations

import numpy as np
import pytest

import espin
from espin.core.config import FiberConfig
from espin.geometry.network import Network
from espin.mechanics.bending import fiber_joints
from espin.mechanics.equilibrium import EquilibriumSolver, StepState
from espin.mechanics.fiber_law import FiberLaw
from espin.mechanics.homogenization import nominal_stress
from espin.mechanics.linear_solvers import make_linear_solver

E_BEND = 3000.0  # MPa, plla's E_t


def _perturbed(net: Network, sd: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return net.node_position + rng.normal(0.0, sd, net.node_position.shape)


def test_joints_follow_the_fibers(small_rve):
    """One joint per pair of consecutive elements of a fiber, none across fibers; k = E I / lbar."""
    net = small_rve.network
    joints = fiber_joints(net, E_BEND)
    expected, stiffness = [], []
    for fiber in np.unique(net.element_fiber):
        elements = np.flatnonzero(net.element_fiber == fiber)
        for e, f in zip(elements[:-1], elements[1:]):
            assert net.element_nodes[e, 1] == net.element_nodes[f, 0]  # a fiber is a chain
            expected.append((net.element_nodes[e, 0], net.element_nodes[e, 1], net.element_nodes[f, 1]))
            D = 0.5 * (net.element_diameter[e] + net.element_diameter[f])
            lbar = 0.5 * (net.element_contour_length[e] + net.element_contour_length[f])
            stiffness.append(E_BEND * np.pi * D**4 / 64 / lbar)
    assert np.array_equal(joints.nodes, np.array(expected))
    assert np.allclose(joints.stiffness, stiffness, rtol=1e-12)
    # the reference state stores no bending energy
    assert joints.energy(net.node_position) == pytest.approx(0.0, abs=1e-20)


def test_a_bent_joint_stores_k_delta_squared_over_two():
    """Three nodes on a line, the last one turned by delta about the middle: W = k (1 - cos delta),
    k delta^2 / 2 for a small delta, and the end force is the moment over the arm, k delta / l."""
    l, D = 2.0, 0.5
    net = Network(node_position=np.array([[0.0, 0.0], [l, 0.0], [2 * l, 0.0]]), n_inner=1,
                  element_nodes=np.array([[0, 1], [1, 2]]), element_contour_length=np.array([l, l]),
                  element_diameter=np.array([D, D]), element_layer=np.zeros(2, np.int64),
                  element_fiber=np.zeros(2, np.int64), size=2 * l, thickness=D, n_layers=1,
                  n_merged=0, merge_tolerance=0.0)
    # nodes: inner first (node 0 here is inner only by the constructor's count; fine for joints)
    joints = fiber_joints(net, E_BEND)
    k = E_BEND * np.pi * D**4 / 64 / l
    delta = 1e-3
    x = net.node_position.copy()
    x[2] = [l + l * np.cos(delta), l * np.sin(delta)]
    assert joints.energy(x) == pytest.approx(k * (1 - np.cos(delta)), rel=1e-9)
    assert joints.energy(x) == pytest.approx(k * delta**2 / 2, rel=1e-6)
    force = joints.gradient(x, 6).reshape(3, 2)
    assert np.hypot(*force[2]) == pytest.approx(k * np.sin(delta) / l, rel=1e-9)
    assert np.abs(force.sum(axis=0)).max() < 1e-12 * k  # no net force


def test_gradient_and_hessian_match_finite_differences(small_rve):
    net = small_rve.network
    joints = fiber_joints(net, E_BEND)
    x = _perturbed(net, 0.1)
    n_dof = 2 * net.n_nodes
    g = joints.gradient(x, n_dof)
    blocks = joints.blocks(x, exact=True)
    rows = np.repeat(joints.dof, 6, axis=1).ravel()
    cols = np.tile(joints.dof, (1, 6)).ravel()
    from scipy.sparse import coo_matrix

    H = coo_matrix((blocks.ravel(), (rows, cols)), shape=(n_dof, n_dof)).tocsr()
    rng = np.random.default_rng(2)
    h = 1e-6
    for dof in rng.choice(n_dof, 20, replace=False):
        up, down = x.copy(), x.copy()
        up.ravel()[dof] += h
        down.ravel()[dof] -= h
        assert (joints.energy(up) - joints.energy(down)) / (2 * h) == pytest.approx(g[dof], abs=1e-6 * np.abs(g).max())
        column = (joints.gradient(up, n_dof) - joints.gradient(down, n_dof)) / (2 * h)
        assert np.allclose(column, H[:, dof].toarray().ravel(), atol=1e-6 * abs(H).max())
    assert abs(H - H.T).max() <= 1e-9 * abs(H).max()
    # the clipped blocks are positive semi-definite
    assert np.linalg.eigvalsh(joints.blocks(x, exact=False)).min() >= -1e-9 * abs(H).max()


def test_clipped_blocks_are_the_rank_one_part_with_a_clipped_cosine(small_rve):
    """exact=False keeps k max(cos(Delta), 0) J J^T, J = d theta / dx: zero for the joints
    turned past 90 degrees, and the exact blocks minus it is the curvature term k sin(Delta)
    d^2 theta / dx^2, whose trace vanishes (theta is harmonic in each node's position)."""
    net = small_rve.network
    joints = fiber_joints(net, E_BEND)
    x = _perturbed(net, 0.3, seed=4)
    change, jacobian, _, _ = joints._geometry(x)
    assert np.any(np.cos(change) < 0)  # some joints are turned past 90 degrees
    rank_one = jacobian[:, :, None] * jacobian[:, None, :]
    clipped = joints.blocks(x, exact=False)
    expected = (joints.stiffness * np.maximum(np.cos(change), 0.0))[:, None, None] * rank_one
    assert np.allclose(clipped, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    curvature = joints.blocks(x, exact=True) - (joints.stiffness * np.cos(change))[:, None, None] * rank_one
    scale = np.abs(curvature).max()
    assert scale > 0
    assert np.abs(np.trace(curvature, axis1=1, axis2=2)).max() <= 1e-9 * scale


def test_rigid_motion_stores_nothing(small_rve):
    net = small_rve.network
    joints = fiber_joints(net, E_BEND)
    c, s = np.cos(0.9), np.sin(0.9)
    x = net.node_position @ np.array([[c, -s], [s, c]]).T + [3.0, -1.0]
    assert joints.energy(x) < 1e-9 * np.sum(joints.stiffness)
    assert np.abs(joints.gradient(x, 2 * net.n_nodes)).max() < 1e-9 * joints.stiffness.max()


def test_stress_with_bending_equals_the_border_forces():
    """At equilibrium P = (1 / V0) sum over border nodes f_b (x) X_b, bending included (the
    element sum alone misses the joints' part), and the macroscopic tangent includes the joints:
    it matches finite differences of P."""
    import espin.geometry.rve

    rve = espin.geometry.rve.generate("plla", rve__size_ratio=30, rve__layers=2)
    net = rve.network
    law = FiberLaw.from_config(FiberConfig(flow_rate_per_s=0.0))
    solver = EquilibriumSolver(net, law, rve.config.solver, make_linear_solver("auto"), bending_modulus_MPa=E_BEND)
    asm = solver.asm
    X = asm.reference[: net.n_inner]
    start = StepState(0.0, X, np.zeros(0), np.eye(2), np.ones(net.n_elements), np.zeros(net.n_elements))
    F = np.array([[1.03, 0.004], [0.002, 0.99]])
    step = solver.solve(start, 1.0, F, np.zeros((0, 2, 2)), X @ F.T, np.zeros(0))

    def solved(F_near):  # from the solution at F, mapped
        guess = step.state.inner @ np.linalg.solve(F, F_near).T
        return solver.solve(start, 1.0, F_near, np.zeros((0, 2, 2)), guess, np.zeros(0))

    x = asm.positions(step.state.inner, F)
    g = asm.gradient(step.force, step.kinematics) + solver.joints.gradient(x, asm.n_dof)
    g = g.reshape(-1, 2)
    n = net.n_inner
    border = g[n:].T @ asm.reference[n:] / net.reference_volume
    P = nominal_stress(net, step.force, step.kinematics, solver.joints, x)
    assert np.allclose(border, P, rtol=1e-6, atol=1e-9 * np.abs(P).max())
    central = nominal_stress(net, step.force, step.kinematics)
    assert np.abs(P - central).max() > 1e-5 * np.abs(P).max()  # the joints carry a little (1e-4 here)

    tangent = solver.macroscopic_tangent(step)
    h = 1e-6
    for k, L in ((0, 0), (1, 1), (0, 1)):
        dF = np.zeros((2, 2))
        dF[k, L] = h
        up, down = solved(F + dF), solved(F - dF)
        P_up = nominal_stress(net, up.force, up.kinematics, solver.joints, asm.positions(up.state.inner, F + dF))
        P_down = nominal_stress(net, down.force, down.kinematics, solver.joints, asm.positions(down.state.inner, F - dF))
        assert np.allclose((P_up - P_down) / (2 * h), tangent[:, :, k, L], atol=1e-6 * np.abs(tangent).max())


# P at steps 2 and 4 of the case below, computed by espin before fiber bending existed (4965d11)
P_BEFORE_BENDING = (np.array([[4.819160209077259, 0.23373882599529477], [0.22915571177162886, 1.5277534672451025]]),
                    np.array([[6.725006994497316, 0.28445637692001585], [0.2735157470516658, 2.8361176288925045]]))


def test_bending_off_is_the_paper_model(monkeypatch):
    """bending_modulus_MPa = 0 (default) gives the curve espin gave before bending existed, and a
    small physical bending moves the lateral-fixed stress little. The values were computed with
    Newton iterations alone: with the node relaxation off they are met to the last digits, with
    it on to the solver's tolerance (the relaxation stops once the residual is within it)."""
    import espin.mechanics.equilibrium as equilibrium

    kw = dict(rve__size_ratio=30, rve__layers=2, loading__max_strain=0.04, loading__steps=4)
    off = espin.simulate("plla", **kw)
    on = espin.simulate("plla", fiber__bending_modulus_MPa=E_BEND, **kw)
    for P, before in zip((off.P[2], off.P[-1]), P_BEFORE_BENDING):
        assert np.allclose(P, before, rtol=1e-7, atol=1e-7 * np.abs(before).max())
    with monkeypatch.context() as patch:
        patch.setattr(equilibrium, "_RELAX_ROUNDS", 0)
        newton_only = espin.simulate("plla", **kw)
    for P, before in zip((newton_only.P[2], newton_only.P[-1]), P_BEFORE_BENDING):
        assert np.allclose(P, before, rtol=1e-12, atol=1e-12 * np.abs(before).max())
    assert not np.array_equal(off.P, on.P)
    assert np.allclose(on.P[-1], off.P[-1], rtol=0.02, atol=0.02 * np.abs(off.P[-1]).max())


def test_a_collapsed_element_switches_its_joints_off(small_rve):
    """A joint whose element has shrunk below the length floor carries nothing (its angle is
    undefined); the other joints are unchanged and everything stays finite."""
    net = small_rve.network
    joints = fiber_joints(net, E_BEND)
    x = _perturbed(net, 0.05)
    a, b, c = joints.nodes[10]
    collapsed = x.copy()
    collapsed[c] = collapsed[b]  # element b-c of joint 10 has zero length
    g, g0 = joints.gradient(collapsed, 2 * net.n_nodes), joints.gradient(x, 2 * net.n_nodes)
    blocks = joints.blocks(collapsed, exact=True)
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(blocks))
    assert np.all(blocks[10] == 0.0)
    others = ~np.any(np.isin(joints.nodes, [c]), axis=1)  # joints that do not touch node c
    untouched = np.setdiff1d(np.arange(net.n_nodes), joints.nodes[~others].ravel())
    dof = np.stack([2 * untouched, 2 * untouched + 1], axis=1).ravel()
    assert np.allclose(g[dof], g0[dof])


def test_bending_next_to_a_tiny_element_reaches_the_affine_equilibrium():
    """Straight fibers stay straight under F, so the affine state is the exact equilibrium, bending
    or not. With a merge tolerance of 1e-6 D two crossings 2e-6 D apart leave a tiny element whose
    joints' forces are known only to about 1e-4 uN (rounding of the positions), far above the force
    tolerance: the solve stalled at step 1 before the equilibrium accepted that precision. Now P
    equals the affine P to 1e-9 (issue 35)."""
    from espin.core.config import config_from_dict
    from espin.geometry.crosslinks import find_crosslinks
    from espin.geometry.network import build_network
    from espin.mechanics.driver import run_program
    from tests.conftest import make_mat

    D, S, gap = 0.45, 30.0, 2e-6 * 0.45
    fibers = [[(0.0, y), (S, y + 0.7)] for y in (7.3, 15.1, 22.9)]
    fibers += [[(x + shift, 0.0), (x + shift + 0.9, S)] for x in (6.1, 13.7, 21.3) for shift in (0.0, gap)]
    mat = make_mat(fibers, [0, 0, 0] + [1] * 6, size=S, diameter=D, n_layers=2)
    net = build_network(mat, find_crosslinks(mat), 1e-6 * D)
    assert net.element_length.min() < 3e-6 * D
    base = {"fiber": {"flow_rate_per_s": 0.0}, "loading": {"max_strain": 0.02, "steps": 2}}
    affine = run_program(net, config_from_dict(base | {"solver": {"kinematics": "affine"}}), make_linear_solver("superlu"))
    bent = run_program(net, config_from_dict(base | {"fiber": base["fiber"] | {"bending_modulus_MPa": E_BEND}}),
                       make_linear_solver("superlu"))
    np.testing.assert_allclose(bent.P, affine.P, rtol=0.0, atol=1e-9 * np.abs(affine.P).max())
