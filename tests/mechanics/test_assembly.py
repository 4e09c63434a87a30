"""Assembly and homogenization: tangent against finite differences, exact stresses."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import grid_network

from espin.core.config import FiberConfig
from espin.mechanics.assembly import NetworkAssembler
from espin.mechanics.fiber_law import FiberLaw, axial_force_and_stiffness, update
from espin.mechanics.homogenization import cauchy_stress, nominal_stress, paper_stress


def _state(asm, law, net, inner, F, plastic_old, dt):
    x = asm.positions(inner, F)
    kin = asm.kinematics(x)
    st = update(law, kin.length / net.element_length, plastic_old, net.element_tortuosity, dt)
    force, stiffness = axial_force_and_stiffness(st, net.element_area, net.element_length)
    return kin, st, force, stiffness


def test_tangent_matches_finite_differences(small_rve):
    """Exact tangent blocks II, IB, BB against central differences of the gradient, in a
    deformed, partly recruited, partly yielded, partly compressed state."""
    net = small_rve.network
    law = FiberLaw.from_config(FiberConfig(flow_rate_per_s=1e-3, flow_resistance_MPa=2.0))
    asm = NetworkAssembler(net)
    rng = np.random.default_rng(0)
    F = np.array([[1.04, 0.01], [0.0, 0.985]])
    inner = asm.reference[: net.n_inner] @ F.T + rng.normal(0, 0.02, (net.n_inner, 2))
    plastic_old = 1.0 + rng.uniform(0, 0.01, net.n_elements)
    dt = 2.0
    kin, st, force, stiffness = _state(asm, law, net, inner, F, plastic_old, dt)
    assert 0.05 < st.recruited.mean() < 0.999 and np.any(force < 0)
    assert np.any(st.plastic_stretch > plastic_old + 1e-4)
    transverse = force / kin.length
    K = {p: asm.tangent(p, stiffness, transverse, kin).toarray() for p in ("II", "IB", "BB")}
    full = np.block([[K["II"], K["IB"]], [K["IB"].T, K["BB"]]])
    x0 = asm.positions(inner, F)
    h = 1e-6
    n = 2 * net.n_inner
    for dof in rng.choice(asm.n_dof, 25, replace=False):
        grads = []
        for sign in (1, -1):
            x = x0.copy()
            x.ravel()[dof] += sign * h
            k2 = asm.kinematics(x)
            s2 = update(law, k2.length / net.element_length, plastic_old, net.element_tortuosity, dt)
            f2, _ = axial_force_and_stiffness(s2, net.element_area, net.element_length)
            grads.append(asm.gradient(f2, k2))
        fd = (grads[0] - grads[1]) / (2 * h)
        scale = np.abs(full[:, dof]).max()
        assert np.allclose(fd, full[:, dof], atol=1e-5 * scale), dof
    assert np.allclose(K["II"], K["II"].T)
    assert K["II"].shape == (n, n)


def test_affine_grid_is_in_equilibrium_with_the_exact_stress():
    net = grid_network()
    law = FiberLaw.from_config(FiberConfig(flow_rate_per_s=0.0))
    asm = NetworkAssembler(net)
    F = np.diag([1.02, 1.0])
    inner = asm.reference[: net.n_inner] @ F.T
    kin, st, force, _ = _state(asm, law, net, inner, F, np.ones(net.n_elements), 1.0)
    g = asm.gradient(force, kin)
    assert np.abs(g[: 2 * net.n_inner]).max() < 1e-12  # the affine field is the equilibrium
    # Horizontal fibers carry t = E_t * 0.02 over their whole length L; vertical ones nothing.
    A = np.pi * 0.2**2 / 4
    expected = 4 * 3000.0 * 0.02 * A * 10.0 / net.reference_volume
    P = nominal_stress(net, force, kin)
    assert P == pytest.approx(np.diag([expected, 0.0]), abs=1e-12)
    # Eq. 17 uses the fiber volume A L0 and a (x) a: the same here (t uniform, straight fibers).
    assert paper_stress(net, st.stress, kin) == pytest.approx(np.diag([expected, 0.0]), abs=1e-12)
    assert cauchy_stress(net, force, kin, F) == pytest.approx(np.diag([expected, 0.0]), abs=1e-12)


def test_rigid_rotation_gives_zero_stress(small_rve):
    net = small_rve.network
    law = FiberLaw.from_config(FiberConfig())
    asm = NetworkAssembler(net)
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s], [s, c]])
    inner = asm.reference[: net.n_inner] @ R.T
    kin, st, force, _ = _state(asm, law, net, inner, R, np.ones(net.n_elements), 1.0)
    assert np.abs(force).max() < 1e-9
    assert np.abs(nominal_stress(net, force, kin)).max() < 1e-12


def test_virial_stress_equals_border_forces(small_rve):
    """At equilibrium P = (1 / V0) sum over border nodes f_b (x) X_b (SPEC 5): the element
    sum of P is (1 / V0) sum over all nodes f (x) X, the inner forces are within the solver's
    tolerance, and what they add to P is all that parts it from the border-force sum."""
    from espin.mechanics.equilibrium import EquilibriumSolver, StepState
    from espin.mechanics.linear_solvers import make_linear_solver

    net = small_rve.network
    law = FiberLaw.from_config(FiberConfig(flow_rate_per_s=0.0))
    solver = EquilibriumSolver(net, law, small_rve.config.solver, make_linear_solver("auto"))
    asm = solver.asm
    F = np.array([[1.03, 0.02], [-0.01, 0.99]])
    X = asm.reference[: net.n_inner]
    start = StepState(0.0, X, np.zeros(0), np.eye(2), np.ones(net.n_elements), np.zeros(net.n_elements))
    step = solver.solve(start, 1.0, F, np.zeros((0, 2, 2)), X @ F.T, np.zeros(0))
    assert step.iterations > 0  # the affine guess was not the equilibrium
    g = asm.gradient(step.force, step.kinematics).reshape(-1, 2)
    n = net.n_inner
    assert np.abs(g[:n]).max() <= step.residual
    border = g[n:].T @ asm.reference[n:] / net.reference_volume
    P = nominal_stress(net, step.force, step.kinematics)
    inner = g[:n].T @ X / net.reference_volume
    assert np.abs(inner).max() <= 1e-5 * np.abs(P).max()  # equilibrium, to the solver's tolerance
    np.testing.assert_allclose(P, border + inner, rtol=0.0, atol=1e-12 * np.abs(P).max())
