"""The fiber law (SPEC 3, paper Eq. 1, 4, 5): branches, flow, tangent, work, robustness."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from espin.core.config import FiberConfig
from espin.core.errors import ConfigError
from espin.mechanics.fiber_law import (
    FiberLaw,
    axial_force_and_stiffness,
    elastic_stress,
    update,
    work_increment,
    yielded,
)
from espin.mechanics.single_fiber import constant_rate_history, pull_fiber

PLLA = FiberLaw(taut_modulus=3000, slack_modulus=3, flow_rate=1e-8, flow_resistance=5,
                hardening_exponent=0.5)
NO_HARDENING = FiberLaw(3000, 3, 1e-8, 5, 0.0)
FAST_FLOW = FiberLaw(500, 50, 0.1, 2, 2.0)  # flows at low stress, strong hardening
LAWS = [PLLA, NO_HARDENING, FAST_FLOW]
LAW_IDS = ["plla", "c0", "fast"]


def paper_stress(law: FiberLaw, lam: float, lam_p: float, lam_r: float) -> float:
    """Eq. 5 written out branch by branch (with the recruitment switch of SPEC 3)."""
    e = lam / lam_p
    if e < lam_r:
        return law.slack_modulus * (e - 1)
    return law.slack_modulus * (lam_r - 1) + law.taut_modulus * (e / lam_r - 1)


def residual(law: FiberLaw, lam, lam_p_old, lam_r, dt, lam_p) -> np.ndarray:
    """Backward Euler residual of Eq. 4 in stress units, evaluated independently."""
    flow_stress = law.flow_resistance * lam_p**law.hardening_exponent
    lhs = flow_stress * np.arcsinh((lam_p - lam_p_old) / (law.flow_rate * dt))
    return lhs - np.array([paper_stress(law, *a) for a in zip(lam, lam_p, lam_r)])


# ------------------------------------------------------------------------------------------
# elastic law
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", LAWS, ids=LAW_IDS)
@pytest.mark.parametrize("lam_p", [1.0, 1.1])
@pytest.mark.parametrize("e", [0.3, 0.9, 1.0, 1.02, 1.05, 1.2, 2.0])
def test_single_element_reproduces_the_law(law, lam_p, e):
    lam_r = 1.05
    state = update(law, e * lam_p, lam_p, lam_r, dt=0.0)
    assert state.stress[0] == pytest.approx(paper_stress(law, e * lam_p, lam_p, lam_r), rel=1e-13,
                                            abs=1e-12)
    assert state.plastic_stretch[0] == lam_p
    slope = law.taut_modulus / lam_r if e >= lam_r else law.slack_modulus
    assert state.tangent[0] == pytest.approx(slope / lam_p, rel=1e-13)
    assert state.recruited[0] == (e >= lam_r)


def test_plla_numbers():
    t = elastic_stress(PLLA, [0.8, 1.02, 1.1], 1.05)
    np.testing.assert_allclose(t, [-0.6, 0.06, 0.15 + 3000 * (1.1 / 1.05 - 1)], rtol=1e-14)
    assert elastic_stress(PLLA, 1.3, 1.0) == pytest.approx(900.0)  # straight fiber: E_t only


def test_stress_is_continuous_at_recruitment():
    lam_r = np.array([1.0, 1.003, 1.5])
    below = elastic_stress(PLLA, lam_r * (1 - 1e-12), lam_r)
    above = elastic_stress(PLLA, lam_r * (1 + 1e-12), lam_r)
    np.testing.assert_allclose(below, PLLA.slack_modulus * (lam_r - 1), atol=1e-8)
    np.testing.assert_allclose(above, below, atol=1e-8)


def test_tortuosity_below_one_counts_as_one():
    a = update(PLLA, [0.9, 1.1], 1.0, 1 - 1e-15, 2.0)
    b = update(PLLA, [0.9, 1.1], 1.0, 1.0, 2.0)
    np.testing.assert_array_equal(a.stress, b.stress)


@pytest.mark.parametrize("dt", [0.0, 1.0, 1e6])
def test_zero_flow_rate_is_elastic(dt):
    law = FiberLaw(3000, 3, 0.0, 5, 0.5)
    state = update(law, [0.5, 1.01, 1.3, 5.0], 1.0, 1.02, dt)
    np.testing.assert_array_equal(state.plastic_stretch, 1.0)
    np.testing.assert_allclose(state.stress, elastic_stress(law, [0.5, 1.01, 1.3, 5.0], 1.02))


def test_from_config_and_validation():
    assert FiberLaw.from_config(FiberConfig()) == PLLA
    with pytest.raises(ConfigError, match="taut_modulus"):
        FiberLaw(3, 3000, 1e-8, 5, 0.5)
    with pytest.raises(ConfigError, match="flow_rate"):
        FiberLaw(3000, 3, -1.0, 5, 0.5)
    with pytest.raises(ValueError, match="dt"):
        update(PLLA, 1.1, 1.0, 1.0, -1.0)


def test_reported_states():
    np.testing.assert_array_equal(yielded([0.9, 1.0, 1.0009, 1.0011]), [False, False, False, True])
    assert yielded(1.02, threshold=0.05) == np.False_
    state = update(PLLA, [1.0, 1.06, 1.2], 1.0, 1.05, 2.0)
    np.testing.assert_array_equal(state.recruited, [False, True, True])


def random_elements(rng: np.random.Generator, n: int, highest_elastic_stretch: float):
    """Stretch, lambda_p_n, lambda_r and dt of n elements in compression and tension."""
    lam_p_old = rng.uniform(0.9, 1.3, n)
    lam = lam_p_old * rng.uniform(0.6, highest_elastic_stretch, n)
    lam_r = 1 + rng.exponential(0.02, n)
    dt = rng.choice([1e-3, 1.0, 100.0], n)
    return lam, lam_p_old, lam_r, dt


# ------------------------------------------------------------------------------------------
# plastic flow
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", LAWS, ids=LAW_IDS)
def test_return_mapping_solves_backward_euler(law):
    lam, lam_p_old, lam_r, dt = random_elements(np.random.default_rng(3), 200, 1.1)
    state = update(law, lam, lam_p_old, lam_r, dt)
    lp = state.plastic_stretch
    # lambda_p lies between lambda_p_n and lambda, on the side of the trial stress.
    assert np.all((lp - lam_p_old) * (lam - lam_p_old) >= 0)
    assert np.all((lp - lam) * (lam_p_old - lam) >= 0)
    expected = [paper_stress(law, *a) for a in zip(lam, lp, lam_r)]
    np.testing.assert_allclose(state.stress, expected, rtol=1e-12, atol=1e-12)
    m = np.abs(lp - lam_p_old) > 1e-6  # the residual is measurable in double precision
    r = residual(law, lam[m], lam_p_old[m], lam_r[m], dt[m], lp[m])
    assert np.max(np.abs(r) / (np.abs(state.stress[m]) + law.flow_resistance)) < 1e-8


def test_compression_takes_the_first_root():
    """c_p > 0, deep compression: R has three roots; the weak-flow one (dt -> 0) is taken."""
    lam = np.array([0.0, 1e-5, 1e-3, 0.05, 3.5e-6, 7.0e-5])
    lam_p_old = np.array([1.0, 1.0, 1.0, 1.0, 1.515, 0.8533])
    dt = np.array([2.0, 2.0, 2.0, 2.0, 2.78, 250.6])
    state = update(PLLA, lam, lam_p_old, 1.0, dt)
    trial = PLLA.slack_modulus * (np.maximum(lam, 1e-6) / lam_p_old - 1)
    weak_flow = PLLA.flow_rate * dt * np.sinh(trial / (PLLA.flow_resistance * lam_p_old**0.5))
    np.testing.assert_allclose(state.plastic_stretch - lam_p_old, weak_flow, rtol=1e-5)
    # far from the collapsed roots near lambda_p = lambda, where t = 0
    assert np.all(state.stress < -0.7 * PLLA.slack_modulus)


@pytest.mark.parametrize("rate", [5e-3, 1e-2])
def test_plateau_without_hardening(rate):
    """Constant-rate pull, c_p = 0: t -> b_p asinh(lambda_p_dot / a_p), lambda_p_dot = rate / e."""
    law = NO_HARDENING
    hist = pull_fiber(law, *constant_rate_history(1.3, rate, 150), tortuosity=1.02)
    e = hist.stretch[-1] / hist.plastic_stretch[-1]
    steady = law.flow_resistance * np.arcsinh(rate / (e * law.flow_rate))
    assert hist.stress[-1] == pytest.approx(steady, rel=1e-4)
    # SPEC 3: near b_p asinh(rate / a_p)
    assert hist.stress[-1] == pytest.approx(law.flow_resistance * np.arcsinh(rate / law.flow_rate),
                                            rel=0.01)
    plateau = hist.stress[hist.stretch > 1.15]
    assert np.ptp(plateau) < 1e-3 * plateau.mean()


def test_plateau_rises_with_rate_by_b_log_ratio():
    """Four times the rate: b_p ln 4 more stress, less b_p ln(e2 / e1) for the elastic part."""
    hist = [pull_fiber(NO_HARDENING, *constant_rate_history(1.2, r, 100)) for r in (5e-3, 2e-2)]
    t = [h.stress[-1] for h in hist]
    e = [h.stretch[-1] / h.plastic_stretch[-1] for h in hist]
    assert t[1] - t[0] == pytest.approx(5 * (np.log(4) - np.log(e[1] / e[0])), rel=1e-4)


def test_hardening_raises_the_plateau():
    """c_p > 0: quasi-steady t = b_p lambda_p^c_p asinh(lambda_p_dot / a_p) rises with lambda_p."""
    rate = 5e-3
    hist = pull_fiber(PLLA, *constant_rate_history(1.4, rate, 200), tortuosity=1.02)
    flowing = hist.stretch > 1.1
    assert np.all(np.diff(hist.stress[flowing]) > 0)
    lp, e = hist.plastic_stretch[-1], hist.stretch[-1] / hist.plastic_stretch[-1]
    steady = PLLA.flow_resistance * lp**0.5 * np.arcsinh(rate / (e * PLLA.flow_rate))
    assert hist.stress[-1] == pytest.approx(steady, rel=1e-3)
    assert hist.stress[-1] > 1.1 * NO_HARDENING.flow_resistance * np.arcsinh(rate / 1e-8)


def test_unloading_is_elastic_with_the_taut_slope_and_leaves_a_plastic_set():
    lam_r = 1.02
    hist = pull_fiber(PLLA, *constant_rate_history(1.2, 5e-3, 100, unload_to=1.0),
                      tortuosity=lam_r)
    peak = np.argmax(hist.stretch)
    lp_peak = hist.plastic_stretch[peak]
    assert lp_peak > 1.1
    back = slice(peak, None)
    lam, t, lp = hist.stretch[back], hist.stress[back], hist.plastic_stretch[back]
    # Once the stress has dropped well below the flow stress, lambda_p stops moving ...
    low = t < 30
    assert np.ptp(lp[low]) < 1e-6
    # ... the taut branch unloads with the slope E_t / (lambda_r lambda_p) ...
    taut = low & hist.recruited[back]
    slope = np.diff(t[taut]) / np.diff(lam[taut])
    np.testing.assert_allclose(slope, PLLA.taut_modulus / (lam_r * lp[taut][0]), rtol=1e-4)
    # ... and the stress vanishes at lambda = lambda_p: the plastic set.
    k = np.flatnonzero(np.diff(np.sign(t)) < 0)[0]
    lam_zero = np.interp(0.0, t[k:k + 2][::-1], lam[k:k + 2][::-1])
    assert lam_zero == pytest.approx(lp[k], abs=1e-9)
    assert 0 < lp[-1] - lp_peak < 2e-3  # flow goes on only while the stress leaves the plateau
    assert t[-1] == pytest.approx(PLLA.slack_modulus * (1.0 / lp[-1] - 1), rel=1e-6)


# ------------------------------------------------------------------------------------------
# consistent tangent
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", LAWS, ids=LAW_IDS)
@pytest.mark.parametrize("dt", [0.0, 1e-3, 2.0, 1e3])
def test_tangent_matches_central_difference(law, dt):
    rng = np.random.default_rng(7)
    n = 300
    lam_p_old = rng.uniform(0.95, 1.3, n)
    lam = lam_p_old * rng.uniform(0.4, 1.15, n)
    lam_r = 1 + rng.exponential(0.02, n)
    h = 1e-6 * lam
    state = update(law, lam, lam_p_old, lam_r, dt)
    plus = update(law, lam + h, lam_p_old, lam_r, dt)
    minus = update(law, lam - h, lam_p_old, lam_r, dt)
    smooth = plus.recruited == minus.recruited  # no kink inside the difference
    assert smooth.mean() > 0.9
    fd = (plus.stress - minus.stress) / (2 * h)
    err = np.abs(fd - state.tangent)[smooth]
    assert np.all(err <= 1e-5 * np.abs(state.tangent[smooth]) + 1e-5 * law.slack_modulus)


def test_tangent_of_a_flowing_element_lies_below_the_elastic_one():
    """Past yield the algorithmic tangent drops the more, the longer the step (SPEC 4)."""
    hist = pull_fiber(PLLA, *constant_rate_history(1.2, 5e-3, 40))
    lam_p_old = hist.plastic_stretch[-1]
    elastic = PLLA.taut_modulus / lam_p_old
    dt = np.array([1e-9, 0.2, 2.0, 20.0])
    tangent = update(PLLA, 1.2 + 5e-3 * dt, lam_p_old, 1.0, dt).tangent
    assert tangent[0] == pytest.approx(elastic, rel=1e-3)
    assert np.all(np.diff(tangent) < 0) and tangent[-1] > 0


def test_force_and_stiffness():
    area, l0 = np.array([0.16, 0.2]), np.array([2.0, 0.5])
    length = np.array([2.3, 0.51])
    state = update(PLLA, length / l0, 1.0, 1.01, 2.0)
    force, stiffness = axial_force_and_stiffness(state, area, l0)
    np.testing.assert_allclose(force, state.stress * area)
    dl = 1e-7 * length
    fd = (update(PLLA, (length + dl) / l0, 1.0, 1.01, 2.0).stress
          - update(PLLA, (length - dl) / l0, 1.0, 1.01, 2.0).stress) * area / (2 * dl)
    np.testing.assert_allclose(stiffness, fd, rtol=1e-5)


# ------------------------------------------------------------------------------------------
# incremental work (SPEC 4 potential)
# ------------------------------------------------------------------------------------------
WORK_CASES = [  # lambda_n, lambda, lambda_p_n, lambda_r, dt
    (1.00, 1.01, 1.00, 1.0, 2.0),  # elastic taut loading
    (1.02, 1.03, 1.00, 1.0, 2.0),  # through yield
    (1.00, 1.05, 1.00, 1.0, 10.0),  # a big step through yield
    (1.20, 1.21, 1.17, 1.0001, 2.0),  # on the plateau
    (1.00, 1.10, 1.00, 1.05, 20.0),  # slack, recruitment and yield in one step
    (1.20, 1.15, 1.17, 1.0001, 2.0),  # unloading into the slack branch
    (0.90, 0.50, 1.00, 1.05, 2.0),  # compression
    (1.00, 0.30, 1.00, 1.0, 1e9),  # compression, creeping to t = 0
    (1.00, 1.30, 1.00, 1.0, 1e9),  # tension, creeping to t = 0
    (1.00, 1.30, 1.00, 1.2, 1e-3),  # fast step over recruitment and yield
    (1.03, 1.01, 1.01, 1.0, 4.0),  # tension to compression
]


def reference_work(law, cases):
    """Adaptive quadrature of the algorithmic stress, one return mapping per evaluation."""
    ref = []
    for lam_n, lam, lam_p_old, lam_r, dt in cases:
        low, high = sorted((lam_n, lam))
        kink = [lam_r * lam_p_old] if low < lam_r * lam_p_old < high else None
        value = quad(lambda x: update(law, x, lam_p_old, lam_r, dt).stress[0], low, high,
                     epsabs=0, epsrel=1e-13, limit=400, points=kink)[0]
        ref.append(np.sign(lam - lam_n) * value)
    return np.array(cases, dtype=float).T, np.array(ref)


def test_work_matches_adaptive_quadrature():
    c, ref = reference_work(PLLA, WORK_CASES)
    work = work_increment(PLLA, *c)
    np.testing.assert_allclose(work, ref, rtol=3e-8)
    smooth = [0, 3, 6, 7, 8]  # no yield bend inside the step
    np.testing.assert_allclose(work[smooth], ref[smooth], rtol=1e-11)


def test_elastic_work_is_exact():
    law = FiberLaw(3000, 3, 0.0, 5, 0.5)
    c, ref = reference_work(law, WORK_CASES)
    np.testing.assert_allclose(work_increment(law, *c), ref, rtol=1e-12)
    # by hand: a straight fiber, E_t (e - 1)^2 / 2; a slack then taut one, lambda_r = 1.05
    assert work_increment(law, 1.0, 1.1, 1.0, 1.0, 0.0)[0] == pytest.approx(15.0, rel=1e-13)
    slack_then_taut = 3 * 0.1**2 / 2 + (3000 / 1.05 - 3) * 0.05**2 / 2
    assert work_increment(law, 1.0, 1.1, 1.0, 1.05, 0.0)[0] == pytest.approx(slack_then_taut,
                                                                           rel=1e-13)


@pytest.mark.parametrize("law", LAWS, ids=LAW_IDS)
def test_work_derivative_is_the_algorithmic_stress(law):
    """d(work)/d lambda = t_alg: the potential of the step is consistent with the stress."""
    lam_n, lam_p_old, lam_r, dt = 1.05, 1.02, 1.01, 2.0
    lam = np.array([0.7, 1.0, 1.04, 1.06, 1.08, 1.12])
    h = 1e-5
    dw = (work_increment(law, lam_n, lam + h, lam_p_old, lam_r, dt)
          - work_increment(law, lam_n, lam - h, lam_p_old, lam_r, dt)) / (2 * h)
    t = update(law, lam, lam_p_old, lam_r, dt).stress
    np.testing.assert_allclose(dw, t, rtol=1e-6, atol=1e-6 * law.flow_resistance)


# ------------------------------------------------------------------------------------------
# robustness and vectorization
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", [PLLA, FAST_FLOW], ids=["plla", "fast"])
def test_extreme_inputs_stay_finite(law):
    grid = np.meshgrid(
        [0.0, 1e-300, 1e-8, 1e-3, 0.5, 1.0, 1.5, 1e3, 1e10],  # stretch
        [1e-6, 1.0, 2.0, 1e3],  # plastic stretch
        [1.0, 1.5],  # tortuosity
        [0.0, 1e-300, 1e-20, 1.0, 1e12, 1e300],  # dt
        indexing="ij",
    )
    lam, lam_p_old, lam_r, dt = (g.ravel() for g in grid)
    with np.errstate(over="raise", invalid="raise"):
        state = update(law, lam, lam_p_old, lam_r, dt)
    for v in (state.stress, state.plastic_stretch, state.tangent):
        assert np.all(np.isfinite(v))
    floored = np.maximum(lam, 1e-6)
    low, high = np.minimum(floored, lam_p_old), np.maximum(floored, lam_p_old)
    assert np.all((state.plastic_stretch >= low * (1 - 1e-12))
                  & (state.plastic_stretch <= high * (1 + 1e-12)))
    # In tension the algorithmic tangent is positive; in compression with c_p > 0 it may
    # not be: the flow resistance b_p lambda_p^c_p falls as lambda_p does (softening).
    assert np.all(state.tangent[(state.stress > 0) & (lam > 1e-6)] >= 0)
    near = (lam > 1e-4) & (lam < 1e4) & (lam_p_old < 1e3)  # keep the quadrature small
    work = work_increment(law, 1.0, lam[near], lam_p_old[near], lam_r[near], dt[near])
    assert np.all(np.isfinite(work))


def test_return_mapping_does_not_cycle():
    """A soft taut branch under a large b_p makes R(w) sigmoidal; plain Newton 2-cycles there."""
    law = FiberLaw(53.9, 0.362, 1.084e-9, 50.43, 0.1046)
    lam, lam_p_old, lam_r, dt = 59.34, 2.906, 1.0001, 889.0
    lp = update(law, lam, lam_p_old, lam_r, dt).plastic_stretch
    assert lam_p_old < lp[0] < lam
    r = residual(law, [lam], lam_p_old, [lam_r], dt, lp)[0]
    assert abs(r) < 1e-9 * law.taut_modulus * lam


def test_collapsed_element_is_held_at_the_floor():
    state = update(PLLA, [0.0, 1e-9], 1.0, 1.0, 2.0)
    np.testing.assert_array_equal(state.tangent, 0.0)
    np.testing.assert_array_equal(state.stress[0], state.stress[1])
    assert state.stress[0] == pytest.approx(-PLLA.slack_modulus, rel=1e-5)


def test_vectorized_equals_element_by_element():
    rng = np.random.default_rng(11)
    n = 60
    lam_p_old = rng.uniform(0.9, 1.3, n)
    lam_n = lam_p_old * rng.uniform(0.7, 1.1, n)
    lam = lam_n + rng.normal(0, 0.02, n)
    lam_r = 1 + rng.exponential(0.02, n)
    dt = rng.choice([0.0, 1e-3, 2.0, 1e3], n)
    together = update(PLLA, lam, lam_p_old, lam_r, dt)
    work = work_increment(PLLA, lam_n, lam, lam_p_old, lam_r, dt)
    for i in range(n):
        alone = update(PLLA, lam[i], lam_p_old[i], lam_r[i], dt[i])
        for name in ("stress", "plastic_stretch", "tangent", "recruited"):
            assert getattr(alone, name)[0] == getattr(together, name)[i]
        assert work_increment(PLLA, lam_n[i], lam[i], lam_p_old[i], lam_r[i], dt[i])[0] == (
            pytest.approx(work[i], rel=1e-14, abs=1e-300))


@pytest.mark.parametrize("law", LAWS, ids=LAW_IDS)
def test_warm_start_gives_the_same_state(law):
    """A guess of lambda_p (nearby, poor, of the wrong sign or outside the bracket) changes
    the start of the return mapping only, not its result."""
    rng = np.random.default_rng(5)
    n = 400
    lam, lam_p_old, lam_r, dt = random_elements(rng, n, 1.2)
    cold = update(law, lam, lam_p_old, lam_r, dt)
    nearby = update(law, lam * (1 + rng.normal(0, 1e-4, n)), lam_p_old, lam_r, dt)
    guesses = {
        "nearby": nearby.plastic_stretch,
        "wrong sign": 2 * lam_p_old - cold.plastic_stretch,
        "beyond lambda": lam + (lam - lam_p_old),
        "lambda_p_n": lam_p_old,
    }
    for name, guess in guesses.items():
        warm = update(law, lam, lam_p_old, lam_r, dt, plastic_stretch_guess=guess)
        np.testing.assert_allclose(warm.plastic_stretch, cold.plastic_stretch, rtol=1e-14,
                                   atol=0, err_msg=name)
        np.testing.assert_allclose(warm.stress, cold.stress, rtol=1e-10, atol=1e-10, err_msg=name)
        np.testing.assert_allclose(warm.tangent, cold.tangent, rtol=1e-9, atol=1e-9, err_msg=name)
