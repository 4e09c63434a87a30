"""Opt-in compression limit of the fiber segments: its contact force and stiffness, that the
paper's model is untouched with it off, that it makes a collapsing step solvable and that its
force is in P."""

from __future__ import annotations

import numpy as np
import pytest

import espin
import espin.geometry.rve
from espin.core.config import FiberConfig, load_config
from espin.core.errors import ConfigError, StepNotConverged
from espin.mechanics.compression_limit import CompressionLimit
from espin.mechanics.equilibrium import EquilibriumSolver, StepState
from espin.mechanics.fiber_law import FiberLaw
from espin.mechanics.homogenization import nominal_stress
from espin.mechanics.linear_solvers import make_linear_solver

E_T = 3000.0  # MPa, plla's taut modulus


def test_contact_force_and_stiffness():
    """Zero at and above lambda_c, continuous there, compressive below, unbounded as the element
    vanishes, and dT/dl is the derivative of T."""
    limit = CompressionLimit(0.5, E_T)
    area, l0 = np.full(7, 0.16), np.full(7, 2.0)
    stretch = np.array([1.3, 1.0, 0.5, 0.5 - 1e-9, 0.4, 0.1, 1e-3])
    zero = np.zeros(7)
    force, stiffness = limit.add(zero, zero, stretch, area, l0)
    assert np.all(force[:3] == 0.0) and np.all(stiffness[:3] == 0.0)
    assert -3e-9 * area[0] * E_T < force[3] < 0.0  # A E_t (1 - 0.5 / (0.5 - 1e-9)) = -2e-9 A E_t
    assert force[4] == pytest.approx(area[0] * E_T * (1 - 0.5 / 0.4), rel=1e-14)
    assert force[6] == pytest.approx(-499 * area[0] * E_T, rel=1e-12)  # unbounded: 1 - lambda_c / lambda
    h = 1e-7
    up = limit.add(zero, zero, stretch + h / l0, area, l0)[0]
    down = limit.add(zero, zero, stretch - h / l0, area, l0)[0]
    assert np.allclose((up - down)[4:] / (2 * h), stiffness[4:], rtol=1e-6)
    # added to what the fiber law gives
    law_force, law_stiffness = np.linspace(-1, 1, 7), np.linspace(2, 3, 7)
    total = limit.add(law_force, law_stiffness, stretch, area, l0)
    assert np.array_equal(total[0], law_force + force) and np.array_equal(total[1], law_stiffness + stiffness)


@pytest.mark.parametrize("stretch", [0.0, 1.0, float("nan")])
def test_bad_limits_are_refused(stretch):
    with pytest.raises(ValueError, match="stretch"):
        CompressionLimit(stretch, E_T)
    with pytest.raises(ValueError, match="modulus"):
        CompressionLimit(0.5, 0.0)


def test_config_range_and_affine():
    with pytest.raises(ValueError, match="compression_limit"):
        FiberConfig(compression_limit=0.95)
    with pytest.raises(ConfigError, match="compression_limit"):
        load_config("plla", {"fiber.compression_limit": 0.5, "solver.kinematics": "affine"})


@pytest.mark.slow
def test_limit_off_is_unchanged():
    """lambda_c = 0 given explicitly is the default: the same P bit for bit."""
    kw = dict(rve__size_ratio=30, rve__layers=2, loading__max_strain=0.02, loading__steps=2,
              fiber__bending_modulus_MPa=E_T, fiber__fused_crossing_fraction=1.0)
    default = espin.simulate("plla", **kw)
    off = espin.simulate("plla", fiber__compression_limit=0.0, **kw)
    assert np.array_equal(default.P, off.P)
    assert np.array_equal(default.iterations, off.iterations)


@pytest.mark.slow
def test_the_limit_makes_a_collapse_solvable_and_its_force_is_in_P():
    """A 30 % lateral compression in one step with fused crossings: without the limit Newton
    does not find the equilibrium (short elements are crushed through zero length); with it
    the step converges, no element is much below lambda_c, and at equilibrium
    P = (1 / V0) sum over border nodes f_b (x) X_b (the contact forces are in the stress)."""
    rve = espin.geometry.rve.generate("plla", rve__size_ratio=30, rve__layers=2)
    net = rve.network
    law = FiberLaw.from_config(FiberConfig(flow_rate_per_s=0.0))
    F = np.diag([1.0, 0.7])

    def solve(limit):
        solver = EquilibriumSolver(net, law, rve.config.solver, make_linear_solver("auto"), bending_modulus_MPa=E_T,
                                   fused_crossing_fraction=1.0, crossing_seed=1, crossing_stiffness_ratio=4.0,
                                   compression_limit=limit)
        X = solver.asm.reference[: net.n_inner]
        start = StepState(0.0, X, np.zeros(0), np.eye(2), np.ones(net.n_elements), np.zeros(net.n_elements))
        return solver, solver.solve(start, 1.0, F, np.zeros((0, 2, 2)), X @ F.T, np.zeros(0))

    with pytest.raises(StepNotConverged):
        solve(0.0)
    solver, step = solve(0.5)
    stretch = step.kinematics.length / net.element_length
    assert 0.45 < stretch.min() < 0.5  # the limit is reached, and holds
    asm = solver.asm
    x = asm.positions(step.state.inner, F)
    g = (asm.gradient(step.force, step.kinematics) + solver.joints.gradient(x, asm.n_dof)).reshape(-1, 2)
    n = net.n_inner
    border = g[n:].T @ asm.reference[n:] / net.reference_volume
    P = nominal_stress(net, step.force, step.kinematics, solver.joints, x)
    assert np.allclose(border, P, rtol=1e-6, atol=1e-9 * np.abs(P).max())
    # the macroscopic tangent carries the contact's stiffness: it predicts a small change of P
    A = solver.macroscopic_tangent(step)
    dF = np.diag([0.0, -1e-6])
    X = asm.reference[: net.n_inner]
    moved = solver.solve(step.state, 2.0, F + dF, np.zeros((0, 2, 2)), step.state.inner + X @ dF.T, np.zeros(0))
    change = nominal_stress(net, moved.force, moved.kinematics, solver.joints,
                            asm.positions(moved.state.inner, F + dF)) - P
    assert np.allclose(change, np.einsum("iJkL,kL->iJ", A, dF), rtol=1e-3, atol=1e-3 * np.abs(change).max())


@pytest.mark.slow
def test_the_trust_region_changes_the_path_not_the_equilibrium():
    """solver.max_move_ratio shortens Newton steps (more iterations at a tight cap) but the
    equilibrium is the same: lateral fixed (unique), P within the solver's tolerance."""
    kw = dict(rve__size_ratio=30, rve__layers=2, loading__max_strain=0.03, loading__steps=2)
    free = espin.simulate("plla", **kw)
    capped = espin.simulate("plla", solver__max_move_ratio=1e-3, **kw)
    assert capped.iterations.sum() > free.iterations.sum()
    assert np.allclose(capped.P, free.P, rtol=1e-6, atol=1e-6 * np.abs(free.P).max())


def test_the_bonded_preset():
    c = load_config("plla-bonded")
    plla = load_config("plla")
    f = c.fiber
    assert (f.bending_modulus_MPa, f.fused_crossing_fraction, f.fused_crossing_stiffness_ratio) == (3000, 1, 4)
    assert f.compression_limit == 0.5 and c.solver.max_move_ratio == 0.5 and c.loading.lateral == "free"
    # the rest is the paper's mat
    assert c.rve == plla.rve and c.targets == plla.targets
    assert f.model_copy(update={"bending_modulus_MPa": 0.0, "fused_crossing_fraction": 0.0,
                                "fused_crossing_stiffness_ratio": 1.0, "compression_limit": 0.0}) == plla.fiber
