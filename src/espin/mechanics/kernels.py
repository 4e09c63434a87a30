"""Compiled element loops: the fiber law's return mapping and the tangent fill (numba).

The fiber law (:mod:`espin.mechanics.fiber_law`) and the assembly of gradients and
tangents (:mod:`espin.mechanics.assembly`) run element by element here, compiled by numba
with IEEE semantics (no fast-math) and the GIL released, so that the law's threads
(:class:`espin.mechanics.equilibrium._ThreadedLaw`) run in parallel. Each element's return
mapping evaluates each transcendental function once per iteration and leaves the loop as
soon as it converges; the numpy formulation it replaces evaluated both branches of every
``where`` over whole arrays. The gradient and the tangent values are summed in the order
``numpy.bincount`` sums them, so they are the same to the last bit.

Compiled code is cached on disk next to this module (numba's ``cache=True``, in
``__pycache__``), so the compile cost is paid once per install and Python version
(docs/performance.md gives both costs).

Units as in the callers: stresses and moduli MPa, a_p dt dimensionless (a stretch rate times
a time), forces uN, stiffnesses uN/um.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "STRETCH_FLOOR",
    "MAX_ITERATIONS",
    "law_update",
    "return_map",
    "recruitment_flow",
    "kinematics",
    "lengths",
    "gradient",
    "fill_tangent",
]

STRETCH_FLOOR = 1e-6
"""Length floor of the fiber law (:data:`espin.mechanics.fiber_law.STRETCH_FLOOR`)."""

MAX_ITERATIONS = 200
"""Return-mapping iterations at most per element (it falls back on bisection, so not reached)."""
_RTOL = 4.0 * np.finfo(float).eps
_KINK_SHIFT = 1e-12  # relative offset of the start from recruitment, to its taut side
_LARGE_W = 700.0  # expm1(w) and exp(w) are finite below this
_LOG2 = math.log(2.0)
_FLOW, _RECRUITMENT = 0, 1  # the two residuals of _newton

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _stress(Et: float, Eb: float, e: float, lr: float) -> float:
    """t(e) of the bilinear elastic law [MPa] (lr >= 1)."""
    return Eb * (e - 1.0) + (Et / lr - Eb) * max(e - lr, 0.0)


@_jit
def _modulus(Et: float, Eb: float, e: float, lr: float) -> float:
    """dt/de [MPa]: E_t / lambda_r when recruited, else E_b."""
    return Et / lr if e >= lr else Eb


@_jit
def _power(x: float, c: float) -> float:
    """x**c, by a square root for c = 1/2 (plla) and exactly for c in {0, 1, 2}, as numpy's
    array power does."""
    if c == 0.5:
        return math.sqrt(x)
    if c == 0.0:
        return 1.0
    if c == 1.0:
        return x
    if c == 2.0:
        return x * x
    return x**c


@_jit
def _log1p_ratio(num: float, den: float) -> float:
    """log(1 + num / den) for num >= 0, den > 0, without overflow of the ratio."""
    ratio = num / den
    if ratio < 1e300:
        return math.log1p(ratio)
    return math.log(num) - math.log(den)  # 1 + ratio rounds to ratio


@_jit
def _log1p_sinh(g: float) -> float:
    """log(1 + sinh(g)) for g >= 0, without overflow."""
    if g < 1.0:
        return math.log1p(math.sinh(g))
    q = math.exp(-g)
    return g - _LOG2 + math.log1p(2.0 * q - q * q)


@_jit
def _expm1_flow(w: float, adt: float) -> tuple[float, float]:
    """expm1(w) (inf from _LARGE_W on) and |lambda_p - lambda_p_n| = a_p dt expm1(w),
    without overflow for large w."""
    if w >= _LARGE_W:
        return math.inf, math.exp(math.log(adt) + w)
    em = math.expm1(w)
    return em, adt * em


@_jit
def _newton(
    kind: int,
    w: float,
    em: float,
    flow: float,
    lo: float,
    hi: float,
    adt: float,
    plastic_old: float,
    sign: float,
    stretch: float,
    lr: float,
    g_r: float,
    Et: float,
    Eb: float,
    bp: float,
    cp: float,
) -> tuple[float, bool]:
    """|lambda_p - lambda_p_n| at the root of R in the bracket [lo, hi], and whether it converged.

    Started from ``w`` with its ``em`` = expm1(w) and ``flow`` = a_p dt em (:func:`_expm1_flow`).

    R(w) = asinh(expm1(w)) - (normalized stress term). ``kind`` _FLOW: the return mapping,
    stress term sign g(lambda, lambda_p) with g = t / (b_p lambda_p^c_p); _RECRUITMENT:
    g_r / lambda_p^c_p of an element recruited at the step's end (``g_r`` = E_b (lambda_r - 1)
    / b_p). Safeguarded Newton from ``w`` (R(lo) <= 0 <= R(hi)): the step is taken in w while
    the slope of the first term dominates and in lambda_p when the second's does; a step that
    leaves the bracket or fails to halve the step of two iterations ago is replaced by
    bisection in w, as in Numerical Recipes' rtsafe (Newton may cycle where R(w) is sigmoidal:
    a steep stress term near the root). Converged when lambda_p moves by less than 4 machine epsilons or the
    bracket closes. One expm1, asinh, square root and power per iteration.
    """
    step = hi - lo
    step_before = step
    for _ in range(MAX_ITERATIONS):
        if w < _LARGE_W:
            lhs = math.asinh(em)
            q = 1.0 / (1.0 + em)  # exp(-w); expm1(-w) = -em q
            slope_flow = 1.0 / math.sqrt(q * q + (em * q) ** 2)
        else:
            lhs = w + _LOG2
            slope_flow = 1.0
        if kind == _FLOW:
            plastic = plastic_old + sign * flow
            e = stretch / plastic
            scale = 1.0 / (bp * _power(plastic, cp))
            t = _stress(Et, Eb, e, lr)
            r = lhs - sign * (t * scale)
            slope_stress = (_modulus(Et, Eb, e, lr) * e + cp * t) / plastic * scale * (adt + flow)
        else:
            plastic = plastic_old + flow
            g = g_r / _power(plastic, cp)
            r = lhs - g
            slope_stress = cp * g / plastic * (adt + flow)
        if r == 0.0:
            return flow, True
        if r < 0.0:
            lo = w
        elif r > 0.0:
            hi = w
        delta = r / (slope_flow + slope_stress)
        w_new = w + math.log1p(-delta) if slope_stress > slope_flow else w - delta
        if not (w_new >= lo and w_new <= hi and abs(w_new - w) <= 0.5 * step_before):
            w_new = 0.5 * (lo + hi)
        step_before, step = step, abs(w_new - w)
        em, flow_new = _expm1_flow(w_new, adt)
        if abs(flow_new - flow) <= _RTOL * (plastic_old + flow) or hi - lo <= _RTOL * hi:
            return flow_new, True
        w, flow = w_new, flow_new
    return math.nan, False


@_jit
def _plastic_increment(
    stretch: float,
    plastic_old: float,
    lr: float,
    adt: float,
    guess: float,
    has_guess: bool,
    Et: float,
    Eb: float,
    bp: float,
    cp: float,
) -> tuple[float, bool]:
    """Signed lambda_p - lambda_p_n of one element (stretch floored, lr >= 1), and whether
    its return mapping converged; ``guess`` (signed increment) starts it if ``has_guess``
    and it flows the same way and lies strictly inside the bracket."""
    trial = _stress(Et, Eb, stretch / plastic_old, lr)
    if not (adt > 0.0 and trial != 0.0):
        return 0.0, True
    sign = 1.0 if trial > 0.0 else -1.0
    # The root lies where lambda_p is between lambda_p_n and lambda (t = 0 there).
    gap = abs(stretch - plastic_old)
    lo = 0.0
    hi = _log1p_ratio(gap, adt)
    if has_guess and guess != 0.0 and (guess > 0.0) == (sign > 0.0) and abs(guess) < gap:
        em = abs(guess) / adt
        w = math.log1p(em)
        if w > lo and w < hi and w < _LARGE_W:
            flow, ok = _newton(
                _FLOW, w, em, abs(guess), lo, hi, adt, plastic_old, sign, stretch, lr, 0.0, Et, Eb, bp, cp
            )
            return sign * flow, ok
    g_trial = abs(trial) / (bp * _power(plastic_old, cp))
    # Upper bound of |g| at the root: |t| <= |trial| and lambda_p >= min(lambda, lambda_p_n).
    g_bound = g_trial * _power(plastic_old / min(stretch, plastic_old), cp)
    hi = min(hi, _log1p_sinh(g_bound))
    # Start where asinh(...) = |g_trial|, or at recruitment (just on its taut side) in
    # tension when that lies inside the bracket (fiber_law module notes).
    w = min(hi, _log1p_sinh(g_trial))
    kink_gap = stretch / lr * (1.0 - _KINK_SHIFT) - plastic_old
    if sign > 0.0 and kink_gap > 0.0:
        w = min(w, _log1p_ratio(kink_gap, adt))
    em, flow = _expm1_flow(w, adt)
    flow, ok = _newton(_FLOW, w, em, flow, lo, hi, adt, plastic_old, sign, stretch, lr, 0.0, Et, Eb, bp, cp)
    return sign * flow, ok


@_jit
def law_update(
    stretch: np.ndarray,
    plastic_old: np.ndarray,
    tortuosity: np.ndarray,
    adt: np.ndarray,
    guess: np.ndarray,
    Et: float,
    Eb: float,
    bp: float,
    cp: float,
    stress: np.ndarray,
    plastic: np.ndarray,
    tangent: np.ndarray,
    recruited: np.ndarray,
    plastic_rate: np.ndarray,
) -> int:
    """One backward Euler step of the fiber law for every element (1-D arrays of one length).

    Parameters
    ----------
    stretch, plastic_old, tortuosity, adt
        lambda (values below :data:`STRETCH_FLOOR` are evaluated at it, with a zero
        tangent), lambda_p_n > 0, lambda_r (values below 1 count as 1) and a_p dt >= 0.
    guess
        A guess of each element's lambda_p, or an empty array for none.
    Et, Eb, bp, cp
        E_t, E_b [MPa], b_p [MPa], c_p.
    stress, plastic, tangent, recruited, plastic_rate
        Outputs: t [MPa], lambda_p, dt/dlambda [MPa], e >= lambda_r and d lambda_p / d lambda.

    Returns
    -------
    int
        Number of elements whose return mapping did not converge (their outputs are NaN).
    """
    has_guess = guess.size > 0
    failed = 0
    for i in range(stretch.size):
        lam = max(stretch[i], STRETCH_FLOOR)
        lr = max(tortuosity[i], 1.0)
        p0 = plastic_old[i]
        a = adt[i]
        flow, ok = _plastic_increment(lam, p0, lr, a, guess[i] - p0 if has_guess else 0.0, has_guess, Et, Eb, bp, cp)
        failed += not ok
        # The root lies between lambda_p_n and lambda; keep the rounding of p0 + flow there
        # too (it matters where an element relaxes completely, lambda_p -> lambda << p0).
        p = min(max(p0 + flow, min(lam, p0)), max(lam, p0))
        e = lam / p
        scale = 1.0 / (bp * _power(p, cp))
        t = _stress(Et, Eb, e, lr)
        m = _modulus(Et, Eb, e, lr)
        dg_dstretch = m / p * scale
        dg_dplastic = -(m * e + cp * t) / p * scale
        h = math.hypot(a, flow)  # 1 / (dR/d lambda_p of the asinh term); 0 when elastic
        dplastic = dg_dstretch * h / (1.0 - dg_dplastic * h)
        stress[i] = t
        plastic[i] = p
        floored = stretch[i] < STRETCH_FLOOR
        tangent[i] = 0.0 if floored else m / p * (1.0 - e * dplastic)
        recruited[i] = e >= lr
        plastic_rate[i] = 0.0 if floored else dplastic
    return failed


@_jit
def return_map(
    stretch: np.ndarray,
    plastic_old: np.ndarray,
    tortuosity: np.ndarray,
    adt: np.ndarray,
    Et: float,
    Eb: float,
    bp: float,
    cp: float,
    flow: np.ndarray,
) -> int:
    """Signed plastic increment lambda_p - lambda_p_n of every element into ``flow``
    (stretch already floored, tortuosity >= 1); returns the number not converged."""
    failed = 0
    for i in range(stretch.size):
        flow[i], ok = _plastic_increment(stretch[i], plastic_old[i], tortuosity[i], adt[i], 0.0, False, Et, Eb, bp, cp)
        failed += not ok
    return failed


@_jit
def recruitment_flow(
    plastic_old: np.ndarray,
    tortuosity: np.ndarray,
    adt: np.ndarray,
    limit: np.ndarray,
    Eb: float,
    bp: float,
    cp: float,
    flow: np.ndarray,
) -> int:
    """lambda_p - lambda_p_n, at most ``limit``, of elements recruited at the step's end
    (adt > 0, tortuosity >= 1) into ``flow``; returns the number not converged.

    Root of asinh(expm1(w)) = t_r / (b_p lambda_p^c_p), t_r = E_b (lambda_r - 1) >= 0, whose
    left side increases and right side decreases with w; the start
    w = log1p(sinh(t_r / (b_p lambda_p_n^c_p))) is an upper bound.
    """
    failed = 0
    for i in range(plastic_old.size):
        g_r = Eb * (tortuosity[i] - 1.0) / bp
        hi = min(_log1p_sinh(g_r / _power(plastic_old[i], cp)), _log1p_ratio(limit[i], adt[i]))
        em, start = _expm1_flow(hi, adt[i])
        flow[i], ok = _newton(
            _RECRUITMENT, hi, em, start, 0.0, hi, adt[i], plastic_old[i], 1.0, 0.0, 1.0, g_r, 0.0, Eb, bp, cp
        )
        failed += not ok
    return failed


@_jit
def kinematics(
    x: np.ndarray, nodes: np.ndarray, reference_unit: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vector x_e2 - x_e1 [um], length and unit vector of every element.

    ``x``: (n_nodes, 2) positions; ``nodes``: (n_elements, 2) end nodes; ``reference_unit``:
    (n_elements, 2) the direction taken where an element has zero length.
    """
    n = nodes.shape[0]
    vector = np.empty((n, 2))
    length = np.empty(n)
    unit = np.empty((n, 2))
    for e in range(n):
        vx = x[nodes[e, 1], 0] - x[nodes[e, 0], 0]
        vy = x[nodes[e, 1], 1] - x[nodes[e, 0], 1]
        size = math.hypot(vx, vy)
        vector[e, 0], vector[e, 1], length[e] = vx, vy, size
        if size > 0.0:
            unit[e, 0], unit[e, 1] = vx / size, vy / size
        else:
            unit[e, 0], unit[e, 1] = reference_unit[e, 0], reference_unit[e, 1]
    return vector, length, unit


@_jit
def lengths(x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Length [um] of every element (:func:`kinematics`'s second output alone)."""
    n = nodes.shape[0]
    length = np.empty(n)
    for e in range(n):
        length[e] = math.hypot(x[nodes[e, 1], 0] - x[nodes[e, 0], 0], x[nodes[e, 1], 1] - x[nodes[e, 0], 1])
    return length


@_jit
def gradient(dof: np.ndarray, force: np.ndarray, unit: np.ndarray, n_dof: int) -> np.ndarray:
    """(n_dof,) sum of -T a at each element's first node and +T a at its second [uN].

    ``dof``: (n_elements, 4) DOF of the two nodes (x1, y1, x2, y2); ``unit``: (n_elements, 2).
    """
    out = np.zeros(n_dof)
    for e in range(force.size):
        tx = force[e] * unit[e, 0]
        ty = force[e] * unit[e, 1]
        out[dof[e, 0]] += -tx
        out[dof[e, 1]] += -ty
        out[dof[e, 2]] += tx
        out[dof[e, 3]] += ty
    return out


@_jit
def fill_tangent(
    slot: np.ndarray,
    axial: np.ndarray,
    transverse: np.ndarray,
    unit: np.ndarray,
    joint_values: np.ndarray,
    nnz: int,
) -> np.ndarray:
    """Values of a sparse pattern: each element-matrix entry summed into its slot.

    Entry ``16 e + 4 r + c`` of ``slot`` (-1: not in this pattern) is row r, column c of
    element e's 4 x 4 matrix [[k, -k], [-k, k]] with k = axial a (x) a + transverse
    (I - a (x) a) [uN/um]; the entries from ``16 n_elements`` on are ``joint_values``
    (flattened joint matrices), if any. Entries are summed in ascending order.
    """
    data = np.zeros(nnz)
    k = np.empty((2, 2))
    n_elements = axial.size
    for e in range(n_elements):
        for i in range(2):
            for j in range(2):
                aa = unit[e, i] * unit[e, j]
                k[i, j] = axial[e] * aa + transverse[e] * ((1.0 if i == j else 0.0) - aa)
        base = 16 * e
        for r in range(4):
            for c in range(4):
                s = slot[base + 4 * r + c]
                if s >= 0:
                    value = k[r % 2, c % 2]
                    data[s] += value if (r < 2) == (c < 2) else -value
    base = 16 * n_elements
    for j in range(joint_values.size):
        s = slot[base + j]
        if s >= 0:
            data[s] += joint_values[j]
    return data
