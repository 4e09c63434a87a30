"""The batched RVE solves of points that share a network (espin.specimen.batched_points) against the
per-point solver, one point at a time: the same equilibria, stresses, tangents, plastic states and
local errors, elastic and yielding, in tension, shear and compression; a failing point is named."""

from __future__ import annotations

import numpy as np
import pytest

import espin
from espin.core.config import apply_overrides
from espin.core.errors import StepNotConverged
from espin.mechanics.equilibrium import EquilibriumSolver, StepState
from espin.mechanics.homogenization import nominal_stress
from espin.mechanics.linear_solvers import make_linear_solver
from espin.specimen.batched_points import BatchedRVE
from espin.specimen.rve_points import rve_tolerance

# (e11, shear): elastic, at the yield knee, well past it, with shear, in compression.
LOADS = [(0.002, 0.0), (0.02, 0.004), (0.06, -0.01), (0.1, 0.02), (-0.01, 0.003)]


@pytest.fixture(scope="module")
def rve():
    return espin.generate("plla", rve__size_ratio=30, rve__layers=2)


def _F(e: float, g: float) -> np.ndarray:
    return np.array([[1.0 + e, g], [0.3 * g, 1.0 - 0.3 * e]])


def _one_by_one(solver, start, time, F, guess):
    result = solver.solve(start, time, F, np.zeros((0, 2, 2)), guess, np.zeros(0))
    P = nominal_stress(solver.network, result.force, result.kinematics)
    return result, P, solver.macroscopic_tangent(result), solver.time_error(start, result)


def test_batched_solves_equal_the_per_point_solves_from_a_yielded_start(rve):
    """Two steps: from the undeformed state to the loads, then on from those (yielded) states."""
    config = rve_tolerance(rve.config, 1e-6)
    network = rve.network
    batch = BatchedRVE(network, config)
    solver = EquilibriumSolver.from_config(network, config, make_linear_solver(config.solver.linear))
    X = solver.asm.reference[: network.n_inner]
    k, n_el = len(LOADS), network.n_elements
    rate = config.loading.strain_rate_per_s
    F1 = np.array([_F(e, g) for e, g in LOADS])
    F2 = np.array([_F(1.5 * e, 1.5 * g) for e, g in LOADS])
    t1, t2 = 0.03 / rate, 0.05 / rate
    starts = [StepState(0.0, X.copy(), np.zeros(0), np.eye(2), np.ones(n_el), np.zeros(n_el)) for _ in LOADS]
    for F, time in ((F1, t1), (F2, t2)):
        guess = np.array([s.inner + X @ (F_i - s.F).T for s, F_i in zip(starts, F)])
        solved = batch.solve(starts[0].time, np.array([s.F for s in starts]), np.array([s.inner for s in starts]),
                             np.array([s.plastic_stretch for s in starts]), np.array([s.stress for s in starts]),
                             time, F, guess, np.arange(k))
        for i in range(k):
            result, P, A, error = _one_by_one(solver, starts[i], time, F[i], guess[i])
            scale = np.abs(P).max()
            # The RVE tolerance: 1e-9 of the largest element force; the stresses follow to about that.
            assert np.abs(solved.P[i] - P).max() <= 1e-7 * scale
            assert np.abs(solved.A[i] - A).max() <= 1e-6 * np.abs(A).max()
            assert np.abs(solved.inner[i] - result.state.inner).max() <= 1e-6 * network.size
            # The two solvers stop at different iterates within the tolerance (the per-point one
            # also relaxes single nodes): an element's lambda_p moves with its stretch at most
            # one for one (all of it where the flow is on its plateau).
            stretches = [solver.asm.kinematics(solver.asm.positions(inner.ravel(), F[i])).length / solver.l0
                         for inner in (solved.inner[i], result.state.inner)]
            plastic_gap = np.abs(solved.plastic_stretch[i] - result.state.plastic_stretch).max()
            assert plastic_gap <= np.abs(stretches[0] - stretches[1]).max() + 1e-12
            assert solved.local_error[i] == pytest.approx(error, rel=1e-6, abs=1e-12)
            # Iteration counts differ: the per-point solver also linearizes the elements that cross
            # the slack/taut kink within a step and relaxes single nodes, the batched one takes
            # plain Newton steps.
        starts = [StepState(time, solved.inner[i], np.zeros(0), F[i], solved.plastic_stretch[i], solved.stress[i])
                  for i in range(k)]
    assert np.all(solved.yielded_fraction[1:4] > 0.1)  # the loads past the knee did yield
    assert solved.yielded_fraction[0] == 0.0


def test_a_batched_point_that_does_not_converge_is_named(rve):
    config = apply_overrides(rve_tolerance(rve.config, 1e-6), {"solver.max_iterations": 1})
    batch = BatchedRVE(rve.network, config)
    X = batch.X_inner
    k, n_el = 3, rve.network.n_elements
    F = np.array([np.eye(2), np.eye(2), np.diag([1.05, 1.0])])
    guess = np.einsum("nJ,kiJ->kni", X, F)
    with pytest.raises(StepNotConverged, match="RVE point 12: "):
        batch.solve(0.0, np.tile(np.eye(2), (k, 1, 1)), np.tile(X, (k, 1, 1)), np.ones((k, n_el)),
                    np.zeros((k, n_el)), 5.0, F, guess, np.array([10, 11, 12]))


def test_the_sensitivity_of_the_inner_nodes_is_their_derivative_in_F(rve):
    """dz/dF at a solution (the predictor of the next solve) against central differences of the
    solutions at F +- h dF, the same step (start, time); past the yield knee, with shear."""
    config = rve_tolerance(rve.config, 1e-9)
    network = rve.network
    batch = BatchedRVE(network, config)
    X = batch.X_inner
    n_el = network.n_elements
    time = 0.04 / config.loading.strain_rate_per_s
    F = _F(0.04, 0.01)
    dF = np.array([[0.3, -0.2], [0.5, -0.4]])
    h = 1e-6
    Fs = np.array([F, F + h * dF, F - h * dF])
    solved = batch.solve(0.0, np.tile(np.eye(2), (3, 1, 1)), np.tile(X, (3, 1, 1)), np.ones((3, n_el)),
                         np.zeros((3, n_el)), time, Fs, np.einsum("nJ,kiJ->kni", X, Fs), np.arange(3))
    difference = (solved.inner[1] - solved.inner[2]).ravel() / (2.0 * h)
    predicted = solved.sensitivity[0] @ dF.ravel()
    assert np.abs(predicted - difference).max() <= 1e-6 * np.abs(difference).max()
    # The predictor starts the next trial closer than the affine guess: fewer iterations.
    F_next = F + 2e-3 * dF
    guesses = {"affine": solved.inner[0] + X @ (F_next - F).T,
               "predictor": solved.inner[0] + (solved.sensitivity[0] @ (F_next - F).ravel()).reshape(-1, 2)}
    iterations = {}
    for name, guess in guesses.items():
        again = batch.solve(0.0, np.eye(2)[None], X[None], np.ones((1, n_el)), np.zeros((1, n_el)), time,
                            F_next[None], guess[None], np.arange(1))
        iterations[name] = int(again.iterations[0])
    assert iterations["predictor"] < iterations["affine"]
