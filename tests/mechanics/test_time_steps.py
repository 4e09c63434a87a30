"""Time accuracy (docs/model.md section 4): the local error estimate of the plastic update,
adaptive time steps against an accurate ODE solution, and the network's curve against a
time-converged one."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from espin.core.config import apply_overrides, load_config
from espin.core.errors import ConfigError
from espin.mechanics.driver import _predict, run_program
from espin.mechanics.equilibrium import EquilibriumSolver, StepState
from espin.mechanics.fiber_law import FiberLaw, elastic_stress, update
from espin.mechanics.linear_solvers import make_linear_solver
from espin.mechanics.single_fiber import constant_rate_history, pull_fiber
from espin.mechanics.time_steps import flow_rate, local_error

RATE = 5e-3  # 1/s, plla's strain rate


@pytest.fixture(scope="module")
def law():
    return FiberLaw.from_config(load_config("plla").fiber)


def _exact(law, t0, t1, plastic0, t_eval=None):
    """lambda_p(t) of a fiber pulled at RATE from lambda_p(t0) = plastic0 (Radau, rtol 1e-10)."""
    def rhs(t, y):
        stress = elastic_stress(law, (1.0 + RATE * t) / y[0], 1.0)
        return [flow_rate(law, stress, y[0])]

    return solve_ivp(rhs, (t0, t1), [plastic0], method="Radau", rtol=1e-10, atol=1e-14, t_eval=t_eval)


def test_error_estimate_follows_the_true_local_error(law):
    """In the yield knee, the estimate of one backward-Euler step is within 2x of its true
    error against the exact flow from the same start, and both shrink as dt^2."""
    t0 = 0.015 / RATE
    plastic0 = _exact(law, 0.0, t0, 1.0).y[0, -1]
    stress0 = elastic_stress(law, (1.0 + RATE * t0) / plastic0, 1.0)
    true, estimate = [], []
    for h in (0.1, 0.05, 0.025):
        stretch = 1.0 + RATE * (t0 + h)
        step = update(law, stretch, plastic0, 1.0, h)
        exact = elastic_stress(law, stretch / _exact(law, t0, t0 + h, plastic0).y[0, -1], 1.0)
        true.append(abs(step.stress[0] / exact - 1.0))
        estimate.append(local_error(law, stress0, plastic0, step.stress, step.plastic_stretch, stretch, 1.0, h))
    ratio = np.array(estimate) / np.array(true)
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    assert true[0] / true[1] == pytest.approx(4.0, rel=0.2)
    assert estimate[1] / estimate[2] == pytest.approx(4.0, rel=0.2)


def test_adaptive_fiber_meets_the_accuracy_uniform_steps_miss(law):
    """A fiber pulled to 30 % in 30 reported steps: one backward-Euler step per report is
    more than 3 % off the exact curve at the knee; with time_rtol = 1e-3 the error stays
    below 0.5 % at every strain >= 0.5 %, with fewer than 3x the steps."""
    time, stretch = constant_rate_history(1.3, RATE, 30)
    exact = elastic_stress(law, stretch / _exact(law, 0.0, time[-1], 1.0, t_eval=time).y[0], 1.0)
    check = stretch - 1.0 >= 0.005 - 1e-12

    def worst(history):
        return float(np.max(np.abs(history.stress[check] / exact[check] - 1.0)))

    uniform = pull_fiber(law, time, stretch)
    adaptive = pull_fiber(law, time, stretch, time_rtol=1e-3)
    finer = pull_fiber(law, time, stretch, time_rtol=1e-4)
    assert worst(uniform) > 0.03
    assert worst(adaptive) < 0.005
    assert worst(finer) < worst(adaptive)
    assert 30 < adaptive.substeps.sum() < 90
    assert adaptive.substeps[2] > 1 and adaptive.substeps[-1] == 1  # small steps at the knee only


def test_time_rtol_is_validated():
    for bad in (0.0, 1e-300, 1.0, "on"):
        with pytest.raises(ConfigError, match="time_rtol"):
            load_config("plla", {"solver.time_rtol": bad})
    assert load_config("plla", {"solver.time_rtol": "off"}).solver.time_rtol == "off"


def test_a_flow_too_fast_to_follow_fails_with_advice_instead_of_running_on(small_rve):
    """A large a_p with a tiny b_p asks for ever smaller time steps: the run stops when they
    fall below the smallest step (1e-9 of the reported interval), naming the keys to check."""
    from espin.mechanics.driver import SimulationFailed

    config = apply_overrides(small_rve.config, {"fiber.flow_rate_per_s": 1e3, "fiber.flow_resistance_MPa": 1e-6,
                                                "loading.max_strain": 0.02, "loading.steps": 2})
    with pytest.raises(SimulationFailed, match="below the smallest") as failure:
        run_program(small_rve.network, config, make_linear_solver("auto"))
    assert failure.value.kind == "stiff" and "fiber.flow_resistance_MPa" in str(failure.value)
    assert failure.value.exit_code == 4


def _P11(network, config, steps, **overrides):
    config = apply_overrides(config, {"loading.steps": steps, **overrides})
    return run_program(network, config, make_linear_solver("auto"))


@pytest.mark.slow
def test_network_curve_is_converged_in_time(small_rve):
    """The default curve (10 reported steps to 10 %) lies within 0.5 % of a time-converged
    one (Richardson from 80 and 160 uniform steps) at every reported strain >= 0.5 %, where
    one step per report is more than 2 % off at the knee."""
    network, config = small_rve.network, apply_overrides(small_rve.config, {"loading.max_strain": 0.1})
    coarse = _P11(network, config, 80, **{"solver.time_rtol": "off"}).P[::8, 0, 0]
    fine = _P11(network, config, 160, **{"solver.time_rtol": "off"}).P[::16, 0, 0]
    reference = 2.0 * fine - coarse
    default = _P11(network, config, 10)
    uniform = _P11(network, config, 10, **{"solver.time_rtol": "off"})
    error = np.abs(default.P[1:, 0, 0] / reference[1:] - 1.0)
    assert error.max() < 0.005
    assert np.abs(uniform.P[1:, 0, 0] / reference[1:] - 1.0).max() > 0.02
    assert default.substeps[1:].sum() > 10


@pytest.mark.slow
def test_load_hold_unload_keeps_its_strains_and_accuracy(small_rve):
    """A program that loads, holds and unloads reports its own strains exactly, and its
    stresses lie within 0.5 % of the largest stress of a 16x finer uniform run."""
    program = [{"to_strain": 0.04, "steps": 4}, {"hold_s": 20.0, "steps": 2},
               {"to_strain": 0.02, "steps": 2}]
    config = apply_overrides(small_rve.config, {"loading.program": program})
    result = run_program(small_rve.network, config, make_linear_solver("auto"))
    assert result.strain.tolist() == result.program.strain.tolist()
    fine_program = [dict(s, steps=16 * s["steps"]) for s in program]
    fine = run_program(small_rve.network,
                       apply_overrides(config, {"loading.program": fine_program, "solver.time_rtol": "off"}),
                       make_linear_solver("auto"))
    scale = np.abs(fine.P[:, 0, 0]).max()
    assert np.abs(result.P[:, 0, 0] - fine.P[::16, 0, 0]).max() < 0.005 * scale


def test_predictor_residual_is_second_order(small_rve):
    """From two converged states dt apart, the extrapolating predictor of the next step
    leaves a residual O(dt^2): halving dt quarters it (elastic, equibiaxial)."""
    config = load_config("plla", {"fiber.flow_rate_per_s": 0.0, "loading.test": "equibiaxial"})
    network = small_rve.network
    solver = EquilibriumSolver(network, FiberLaw.from_config(config.fiber), config.solver,
                               make_linear_solver("auto"))
    n = network.n_inner
    reference = solver.asm.reference[:n]

    def converged(strain):
        F = np.diag([1.0 + strain, 1.0 + strain])
        start = StepState(0.0, reference @ F.T, np.zeros(0), F, np.ones(network.n_elements),
                          np.zeros(network.n_elements))
        return solver.solve(start, strain, F, np.zeros((0, 2, 2)), reference @ F.T, np.zeros(0)).state

    residuals = []
    for h in (4e-3, 2e-3):
        older, newer = converged(0.02), converged(0.02 + h)
        F_next = np.diag([1.02 + 2 * h] * 2)
        guess, _ = _predict(newer, older, 0.02 + 2 * h, F_next, np.zeros((0, 2, 2)), solver.asm, n)
        start = StepState(0.02 + h, newer.inner, newer.free, newer.F, newer.plastic_stretch, newer.stress)
        residuals.append(solver.solve(start, 0.02 + 2 * h, F_next, np.zeros((0, 2, 2)), guess,
                                      np.zeros(0)).residual_history[0])
    assert residuals[0] / residuals[1] == pytest.approx(4.0, rel=0.25)
