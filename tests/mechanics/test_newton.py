"""Newton's method across the slack/taut kink (docs/mechanics.md, Newton iterations)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from espin.geometry.rve import generate
from espin.mechanics.driver import run_program
from espin.mechanics.kink_correction import KinkColumns
from espin.mechanics.linear_solvers import make_linear_solver


def test_kink_columns_solve_the_changed_system():
    """The Sherman-Morrison-Woodbury step equals a direct solve of (K + B D B^T) d = -r - B c,
    for stiffening and softening changes alike, over columns held in two batches and taken
    in any order and subset."""
    rng = np.random.default_rng(4)
    n = 12
    A = rng.normal(size=(n, n))
    K = A @ A.T + n * np.eye(n)
    r = rng.normal(size=n)
    B_all = rng.normal(size=(n, 5))
    B_all[rng.random(B_all.shape) < 0.5] = 0.0  # sparse columns, as d l_e / d z are
    factor = scipy.linalg.cho_factor(K)
    columns = KinkColumns(lambda b: scipy.linalg.cho_solve(factor, b))
    columns.add(np.array([7, 3]), B_all[:, :2])
    np.testing.assert_array_equal(columns.missing(np.array([3, 11, 7, 2])), [11, 2])
    columns.add(np.array([11, 2, 5]), B_all[:, 2:])
    elements, which = np.array([5, 7, 11]), [4, 0, 2]
    B = B_all[:, which]
    delta = np.array([1000.0, -0.5, 30.0])
    shift = rng.normal(size=3)
    got = columns.step(scipy.linalg.cho_solve(factor, -r), elements, delta, shift)
    expected = np.linalg.solve(K + B @ np.diag(delta) @ B.T, -r - B @ shift)
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)


def test_kink_correction_saves_iterations_and_keeps_the_curve(monkeypatch):
    """Through the yield knee of a plla mat, taking the crossing elements' side from the full
    step saves factorizations and costs no iterations (91 / 48 against 91 / 52; 104 / 56
    against 106 / 60 when rejected steps were solved); the curve is the same to the tolerance."""
    import espin.mechanics.equilibrium as equilibrium

    rve = generate("plla", rve__size_ratio=60, rve__layers=4, loading__max_strain=0.06, loading__steps=6)
    linear = make_linear_solver("auto")
    corrected = run_program(rve.network, rve.config, linear)
    monkeypatch.setattr(equilibrium, "_KINK_ROUNDS", 0)
    plain = run_program(rve.network, rve.config, linear)
    assert corrected.iterations.sum() <= plain.iterations.sum()
    assert corrected.factorizations.sum() < plain.factorizations.sum()
    np.testing.assert_allclose(corrected.P[:, 0, 0], plain.P[:, 0, 0], rtol=1e-5)


def test_steps_rejected_at_their_predictor_keep_the_time_steps_and_save_factorizations(monkeypatch):
    """Through the yield knee of a plla mat the time error foreseen at a step's predictor
    rejects the steps the solved ones would have rejected, unsolved: the same time steps and
    curve, fewer factorizations. The kept evaluation of the predictor starts the solve."""
    from espin.mechanics.driver import _ProgramSteps

    rve = generate("plla", rve__size_ratio=60, rve__layers=4, loading__max_strain=0.06, loading__steps=6)
    linear = make_linear_solver("auto")
    foreseen = run_program(rve.network, rve.config, linear)
    monkeypatch.setattr(_ProgramSteps, "estimate", lambda self, start, end: 0.0)
    solved = run_program(rve.network, rve.config, linear)
    np.testing.assert_array_equal(foreseen.substeps, solved.substeps)
    np.testing.assert_array_equal(foreseen.P, solved.P)
    assert foreseen.factorizations.sum() < solved.factorizations.sum()


def test_crossing_elements_are_linearized_about_their_kink():
    """The kink correction's linearization of an element is its law's at the slack/taut kink
    e = lambda_r: the force is continuous there, the taut side E_t / lambda_r stiffer than the
    slack side's E_b (the law's 1000:1 for plla), for elements that have flowed too."""
    from espin.mechanics.equilibrium import EquilibriumSolver, StepState
    from espin.mechanics.fiber_law import update

    rve = generate("plla", rve__size_ratio=30, rve__layers=2)
    network, config = rve.network, rve.config
    solver = EquilibriumSolver.from_config(network, config, make_linear_solver("auto"))
    rng = np.random.default_rng(0)
    n = network.n_elements
    plastic = 1.0 + rng.uniform(0.0, 0.05, n)  # some have flowed
    X = solver.asm.reference[: network.n_inner]
    F = np.diag([1.02, 1.0])
    start = StepState(0.0, X, np.zeros(0), np.eye(2), plastic, np.zeros(n))
    step = solver._context(start, 0.1, F, np.zeros((0, 2, 2)), solver.law, None)
    p = solver._evaluate((X @ F.T).ravel(), step)  # the affine iterate
    elements = np.arange(n)
    lr = np.maximum(network.element_tortuosity, 1.0)
    l_t, force_t, k_t = solver._at_kink(elements, np.ones(n, dtype=bool), p, step)
    l_s, force_s, k_s = solver._at_kink(elements, np.zeros(n, dtype=bool), p, step)
    law_t = update(solver.law, l_t / solver.l0, plastic, lr, step.dt)
    law_s = update(solver.law, l_s / solver.l0, plastic, lr, step.dt)
    assert law_t.recruited.all() and not law_s.recruited.any()
    np.testing.assert_allclose(l_t / solver.l0 / law_t.plastic_stretch, lr, rtol=1e-8)
    # Continuous at the kink: the two sides, evaluated 1e-9 either side of it, differ by the
    # taut stiffness over that gap at most.
    assert np.all(np.abs(force_t - force_s) <= 1.01 * k_t * (l_t - l_s) + 1e-15)
    law = solver.law
    np.testing.assert_allclose(k_t / k_s, law.taut_modulus / lr / law.slack_modulus, rtol=1e-3)


def test_the_node_block_is_the_exact_tangent_on_those_nodes():
    """The dense block the node relaxation solves is the assembled exact tangent restricted to
    the nodes' DOF, for scattered nodes and for neighbours sharing elements."""
    from espin.mechanics.equilibrium import EquilibriumSolver, StepState

    rve = generate("plla", rve__size_ratio=30, rve__layers=2)
    network, config = rve.network, rve.config
    solver = EquilibriumSolver.from_config(network, config, make_linear_solver("auto"))
    rng = np.random.default_rng(1)
    n = network.n_elements
    start = StepState(0.0, network.node_position[: network.n_inner], np.zeros(0), np.eye(2), np.ones(n), np.zeros(n))
    step = solver._context(start, 0.1, np.diag([1.03, 1.0]), np.zeros((0, 2, 2)), solver.law, None)
    inner = network.node_position[: network.n_inner]
    p = solver._evaluate((inner + rng.normal(scale=1e-3, size=inner.shape)).ravel(), step)
    K = solver._hessian(p, step, clipped=False).toarray()
    first = network.element_nodes[0]
    neighbours = first[first < network.n_inner]
    for nodes in (rng.choice(network.n_inner, 9, replace=False), neighbours):
        dof = (2 * nodes[:, None] + np.arange(2)).ravel()
        np.testing.assert_allclose(solver._node_block(p, nodes.size, *solver._node_elements(nodes)), K[np.ix_(dof, dof)], rtol=1e-12, atol=1e-12)


def test_node_relaxation_saves_factorizations_and_keeps_the_curve(monkeypatch):
    """Through the yield knee of a plla mat, local Newton steps on the few nodes left over the
    tolerance after a Newton iteration (with their neighbours) save factorizations and
    iterations (44 / 42 against 90 / 47); the curve is the same to the tolerance."""
    import espin.mechanics.equilibrium as equilibrium

    rve = generate("plla", rve__size_ratio=60, rve__layers=4, loading__max_strain=0.06, loading__steps=6)
    linear = make_linear_solver("auto")
    relaxed = run_program(rve.network, rve.config, linear)
    monkeypatch.setattr(equilibrium, "_RELAX_ROUNDS", 0)
    plain = run_program(rve.network, rve.config, linear)
    assert relaxed.iterations.sum() < plain.iterations.sum()
    assert relaxed.factorizations.sum() < plain.factorizations.sum()
    np.testing.assert_allclose(relaxed.P[:, 0, 0], plain.P[:, 0, 0], rtol=1e-5)
