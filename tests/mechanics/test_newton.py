"""Newton's method across the slack/taut kink (docs/mechanics.md, Newton iterations)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from espin.geometry.rve import generate
from espin.mechanics.driver import run_program
from espin.mechanics.equilibrium import low_rank_step
from espin.mechanics.linear_solvers import make_linear_solver


def test_low_rank_step_solves_the_changed_system():
    """The Sherman-Morrison-Woodbury step equals a direct solve of (K + B D B^T) d = -r - B c,
    for stiffening and softening changes alike."""
    rng = np.random.default_rng(4)
    n, m = 12, 3
    A = rng.normal(size=(n, n))
    K = A @ A.T + n * np.eye(n)
    r = rng.normal(size=n)
    B = rng.normal(size=(n, m))
    delta = np.array([1000.0, -0.5, 30.0])
    shift = rng.normal(size=m)
    factor = scipy.linalg.cho_factor(K)
    got = low_rank_step(scipy.linalg.cho_solve(factor, -r), B, scipy.linalg.cho_solve(factor, B), delta, shift)
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
