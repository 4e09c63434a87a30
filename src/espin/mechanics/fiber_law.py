"""The fiber constitutive law (paper Eq. 1, 4, 5; docs/model.md section 3), vectorized over elements.

An element of end-to-end stretch ``lambda = l / l0``, plastic stretch ``lambda_p`` (1 at
deposition) and tortuosity ``lambda_r = L0 / l0 >= 1`` has the elastic stretch
``e = lambda / lambda_p`` and the engineering (first Piola-Kirchhoff) stress per reference area

    t(e) = E_b (e - 1) + (E_t / lambda_r - E_b) max(e - lambda_r, 0)          (Eq. 1 and 5)

that is ``E_b (e - 1)`` while slack (``e < lambda_r``, compression included) and
``E_b (lambda_r - 1) + E_t (e / lambda_r - 1)`` once recruited (``e >= lambda_r``). The plastic
stretch flows as ``d lambda_p / dt = a_p sinh(t / (b_p lambda_p^c_p))`` (Eq. 4), integrated by
backward Euler over a time step ``dt`` in the overflow-free form

    asinh((lambda_p - lambda_p_n) / (a_p dt)) = t(lambda / lambda_p) / (b_p lambda_p^c_p).

The root lies between ``lambda_p_n`` and ``lambda`` (where ``e = 1`` and ``t = 0``): above
``lambda_p_n`` in tension, where it is unique, and below it in compression. (With c_p > 0 the
flow resistance ``b_p lambda_p^c_p`` falls as a compressed element flows, so for deep
compression the equation can have three roots; the first one, continuous with ``dt -> 0``, is
taken.) Each element is solved by a safeguarded Newton iteration on
``w = log1p(|lambda_p - lambda_p_n| / (a_p dt))``, which maps the bracket onto
``[0, log1p(|lambda - lambda_p_n| / (a_p dt))]`` and makes the left side ``asinh(expm1(w))``
nearly linear (slope between 1 and sqrt(2)) from barely flowing elements (``w ~ 1e-10``) to
elements on the flow plateau (``w ~ 14``); on the plateau the step is taken in ``lambda_p``,
and poor steps are replaced by bisection in ``w`` (:func:`_newton`). The iteration starts at
recruitment when that splits the bracket, so it never crosses the kink of the law, and stops
when ``lambda_p`` moves by less than 4 machine epsilons (the result is good to a few
epsilons). ``sinh`` is never evaluated on a stress, and no finite input overflows.

Units: stress and moduli MPa, time s, stretches dimensionless; forces uN = MPa um^2.
The axial force of an element of reference area ``A`` and length ``l0`` is ``T = A t`` and its
algorithmic stiffness ``dT/dl = (A / l0) dt/dlambda`` (:func:`axial_force_and_stiffness`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from espin.core.errors import ConfigError, InadmissibleState, StepNotConverged

if TYPE_CHECKING:
    from espin.core.config import FiberConfig

__all__ = [
    "FiberLaw",
    "LawState",
    "STRETCH_FLOOR",
    "GAUSS_ORDER",
    "PANEL_WIDTH",
    "MAX_PANELS",
    "YIELD_THRESHOLD",
    "elastic_stress",
    "elastic_modulus",
    "update",
    "work_increment",
    "axial_force_and_stiffness",
    "yielded",
]

STRETCH_FLOOR = 1e-6
"""Length floor: stretches below it are evaluated at it (the stress is constant there and
the tangent zero), so a collapsed element never divides by zero nor flows to lambda_p = 0."""

GAUSS_ORDER = 8
"""Gauss-Legendre points per panel in :func:`work_increment` (flow correction only)."""

PANEL_WIDTH = 8.0
"""Widest quadrature panel of :func:`work_increment`, in yield-bend widths b_p lambda_p / (dt/de):
the stretch over which the stress of a flowing element bends from elastic to plateau."""

MAX_PANELS = 64
"""Most quadrature panels per element (reached only by stretch increments > 0.5 or so)."""

YIELD_THRESHOLD = 1e-3
"""An element counts as yielded when lambda_p - 1 exceeds this (docs/model.md section 3)."""

_MAX_ITERATIONS = 200
_RTOL = 4.0 * np.finfo(float).eps
_KINK_SHIFT = 1e-12  # relative offset of the start from recruitment, to its taut side
_LARGE_W = 700.0  # expm1(w) and exp(w) are finite below this
# a_p dt is capped here: beyond it the element relaxes to t = 0 to within 1e-90 MPa anyway,
# and derivatives times a_p dt stay finite.
_MAX_FLOW_SCALE = 1e100


@dataclass(frozen=True)
class FiberLaw:
    """Parameters of the elastic-plastic fiber law (paper Eq. 1, 4, 5; Table 3).

    Attributes
    ----------
    taut_modulus : float [MPa]
        E_t, modulus of a straight (recruited) fiber; > slack_modulus.
    slack_modulus : float [MPa]
        E_b, modulus of a wrinkled fiber and in compression; > 0.
    flow_rate : float [1/s]
        a_p, plastic flow rate coefficient; >= 0, 0 means elastic.
    flow_resistance : float [MPa]
        b_p, initial resistance to flow; > 0.
    hardening_exponent : float
        c_p, post-yield hardening exponent; >= 0.
    """

    taut_modulus: float
    slack_modulus: float
    flow_rate: float
    flow_resistance: float
    hardening_exponent: float

    def __post_init__(self) -> None:
        checks = {
            "slack_modulus": (self.slack_modulus > 0, "> 0"),
            "taut_modulus": (self.taut_modulus > self.slack_modulus, "> slack_modulus"),
            "flow_rate": (self.flow_rate >= 0, ">= 0"),
            "flow_resistance": (self.flow_resistance > 0, "> 0"),
            "hardening_exponent": (self.hardening_exponent >= 0, ">= 0"),
        }
        for name, (ok, allowed) in checks.items():
            if not (ok and np.isfinite(getattr(self, name))):
                raise ConfigError(f"FiberLaw.{name} must be finite and {allowed}")

    @classmethod
    def from_config(cls, cfg: FiberConfig) -> FiberLaw:
        """The law of a validated ``fiber`` config section."""
        return cls(
            taut_modulus=cfg.taut_modulus_MPa,
            slack_modulus=cfg.slack_modulus_MPa,
            flow_rate=cfg.flow_rate_per_s,
            flow_resistance=cfg.flow_resistance_MPa,
            hardening_exponent=cfg.hardening_exponent,
        )


@dataclass(frozen=True, eq=False)
class LawState:
    """Result of one time step of the fiber law for n elements.

    Attributes
    ----------
    stress : (n,) float64 [MPa]
        Engineering stress t (force per reference area).
    plastic_stretch : (n,) float64
        Plastic stretch lambda_p at the end of the step.
    tangent : (n,) float64 [MPa]
        Consistent algorithmic tangent dt/dlambda, including d lambda_p / d lambda.
    recruited : (n,) bool
        Whether the element is taut, e = lambda / lambda_p >= lambda_r.
    """

    stress: np.ndarray
    plastic_stretch: np.ndarray
    tangent: np.ndarray
    recruited: np.ndarray


def elastic_stress(law: FiberLaw, elastic_stretch: ArrayLike, tortuosity: ArrayLike) -> np.ndarray:
    """Engineering stress t(e) of the bilinear elastic law (paper Eq. 1, Eq. 5 with e).

    Parameters
    ----------
    law
        The fiber law.
    elastic_stretch
        e = lambda / lambda_p, dimensionless, >= 0.
    tortuosity
        lambda_r = L0 / l0 (recruitment elastic stretch); values below 1 count as 1.

    Returns
    -------
    numpy.ndarray [MPa]
        ``E_b (e - 1)`` for e < lambda_r, ``E_b (lambda_r - 1) + E_t (e / lambda_r - 1)`` else.
    """
    e = np.asarray(elastic_stretch, dtype=float)
    lr = np.maximum(tortuosity, 1.0)
    eb = law.slack_modulus
    return eb * (e - 1.0) + (law.taut_modulus / lr - eb) * np.maximum(e - lr, 0.0)


def elastic_modulus(law: FiberLaw, elastic_stretch: ArrayLike, tortuosity: ArrayLike) -> np.ndarray:
    """dt/de of :func:`elastic_stress` [MPa]: E_t / lambda_r when recruited, else E_b."""
    lr = np.maximum(tortuosity, 1.0)
    return np.where(np.asarray(elastic_stretch) >= lr, law.taut_modulus / lr, law.slack_modulus)


def _flow_terms(law: FiberLaw, stretch: np.ndarray, plastic: np.ndarray, lr: np.ndarray) -> tuple[np.ndarray, ...]:
    """g = t / (b_p lambda_p^c_p) and its partial derivatives by lambda and lambda_p."""
    e = stretch / plastic
    t = elastic_stress(law, e, lr)
    m = elastic_modulus(law, e, lr)
    scale = 1.0 / (law.flow_resistance * plastic**law.hardening_exponent)
    g = t * scale
    dg_dstretch = m / plastic * scale
    dg_dplastic = -(m * e + law.hardening_exponent * t) / plastic * scale
    return t, g, dg_dstretch, dg_dplastic


def _log1p_ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """log(1 + num / den) for num >= 0, den > 0, without overflow of the ratio."""
    with np.errstate(divide="ignore"):
        return np.logaddexp(0.0, np.log(num) - np.log(den))


def _log1p_sinh(g: np.ndarray) -> np.ndarray:
    """log(1 + sinh(g)) for g >= 0, without overflow."""
    small = np.minimum(g, 1.0)
    large = g - np.log(2.0) + np.log1p(2.0 * np.exp(-g) - np.exp(-2.0 * g))
    return np.where(g < 1.0, np.log1p(np.sinh(small)), large)


def _flow_magnitude(w: np.ndarray, adt: np.ndarray) -> np.ndarray:
    """|lambda_p - lambda_p_n| = a_p dt expm1(w), without overflow for large w."""
    flow = adt * np.expm1(np.minimum(w, _LARGE_W))
    large = w >= _LARGE_W
    if large.any():
        flow[large] = np.exp(np.log(adt[large]) + w[large])
    return flow


def _asinh_expm1(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """asinh(expm1(w)) and its derivative (in [1, sqrt(2)]) for w >= 0, without overflow."""
    value = np.arcsinh(np.expm1(np.minimum(w, _LARGE_W)))
    value = np.where(w < _LARGE_W, value, w + np.log(2.0))
    return value, 1.0 / np.sqrt(np.exp(-2.0 * w) + np.expm1(-w) ** 2)


_Residual = Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def _newton(
    residual: _Residual,
    w: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    adt: np.ndarray,
    plastic_old: np.ndarray,
    *args: np.ndarray,
) -> np.ndarray:
    """Solve residual(w, adt, plastic_old, *args) = 0 per element; return |lambda_p - lambda_p_n|.

    Safeguarded Newton from ``w`` inside the bracket [lo, hi] (R(lo) <= 0 <= R(hi)); all
    arrays are 1-D, and elements leave the iteration as they converge. ``residual`` returns
    R(w) = asinh(expm1(w)) - (normalized stress term), the slope of the first term, the
    slope of the second and the flow |lambda_p - lambda_p_n|. The step is taken in w while
    the first slope dominates (weak flow, where R is nearly linear in w) and in lambda_p
    when the second does (on the plateau, where R is nearly linear in lambda_p); a step that
    leaves the bracket or fails to halve the step of two iterations ago is replaced by
    bisection in w (as in Numerical Recipes' rtsafe). Converged when lambda_p moves by less
    than 4 machine epsilons or the bracket closes.
    """
    out = np.empty_like(w)
    index = np.arange(w.size)
    step = step_before = hi - lo
    for _ in range(_MAX_ITERATIONS):
        r, slope_flow, slope_stress, flow = residual(w, adt, plastic_old, *args)
        lo = np.where(r < 0, w, lo)
        hi = np.where(r > 0, w, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = r / (slope_flow + slope_stress)
            w_new = np.where(slope_stress > slope_flow, w + np.log1p(-delta), w - delta)
        # Bisect when Newton leaves the bracket or does not halve the step of two iterations
        # ago (it may cycle where R(w) is sigmoidal: a steep stress term near the root).
        newton = (w_new >= lo) & (w_new <= hi) & (np.abs(w_new - w) <= 0.5 * step_before)
        w_new = np.where(newton, w_new, 0.5 * (lo + hi))
        step_before, step = step, np.abs(w_new - w)
        flow_new = _flow_magnitude(w_new, adt)
        done = (r == 0) | (np.abs(flow_new - flow) <= _RTOL * (plastic_old + flow)) | (hi - lo <= _RTOL * hi)
        out[index[done]] = np.where(r == 0, flow, flow_new)[done]
        more = ~done
        if not more.any():
            return out
        index, w, lo, hi, step, step_before, adt, plastic_old = (
            v[more] for v in (index, w_new, lo, hi, step, step_before, adt, plastic_old)
        )
        args = tuple(v[more] for v in args)
    raise StepNotConverged(
        f"the fiber law's return mapping did not converge in {_MAX_ITERATIONS} iterations for {index.size} elements"
    )


def _flow_residual(
    law: FiberLaw,
    w: np.ndarray,
    adt: np.ndarray,
    plastic_old: np.ndarray,
    sign: np.ndarray,
    stretch: np.ndarray,
    lr: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return-mapping residual asinh(expm1(w)) - sign g(lambda, lambda_p) for :func:`_newton`."""
    flow = _flow_magnitude(w, adt)
    _, g, _, dg_dplastic = _flow_terms(law, stretch, plastic_old + sign * flow, lr)
    lhs, slope = _asinh_expm1(w)
    return lhs - sign * g, slope, -dg_dplastic * (adt + flow), flow


def _solve_flow(
    law: FiberLaw,
    stretch: np.ndarray,
    plastic_old: np.ndarray,
    lr: np.ndarray,
    adt: np.ndarray,
    trial: np.ndarray,
    guess: np.ndarray | None = None,
) -> np.ndarray:
    """Signed plastic increment lambda_p - lambda_p_n of flowing elements (1-D, trial != 0).

    ``guess`` (signed increments, e.g. of a nearby stretch) replaces the start wherever it
    flows the same way and lies strictly inside the bracket.
    """
    sign = np.sign(trial)
    c = law.hardening_exponent
    g_trial = np.abs(trial) / (law.flow_resistance * plastic_old**c)
    # Upper bound of |g| at the root: |t| <= |trial| and lambda_p >= min(lambda, lambda_p_n).
    g_bound = g_trial * (plastic_old / np.minimum(stretch, plastic_old)) ** c
    lo = np.zeros_like(stretch)
    hi = np.minimum(_log1p_ratio(np.abs(stretch - plastic_old), adt), _log1p_sinh(g_bound))
    # Start where asinh(...) = |g_trial|. That is an upper bound of the root where |g| falls
    # as the element flows (tension, mild compression) and a lower bound where it grows
    # (deep compression with c_p > 0, where R(w) can have three roots): Newton then
    # approaches the first root, the one continuous with dt -> 0, from below. In tension,
    # start at recruitment instead when it lies inside the bracket, just on its taut side:
    # that splits the bracket at the kink of R, so the iteration stays on one smooth branch.
    kink_gap = stretch / lr * (1.0 - _KINK_SHIFT) - plastic_old
    w_kink = _log1p_ratio(np.maximum(kink_gap, 0.0), adt)
    w = np.minimum(hi, _log1p_sinh(g_trial))
    w = np.where((sign > 0) & (kink_gap > 0) & (w_kink < w), w_kink, w)
    if guess is not None:
        w_guess = _log1p_ratio(np.abs(guess), adt)
        w = np.where((np.sign(guess) == sign) & (w_guess > lo) & (w_guess < hi), w_guess, w)
    residual = partial(_flow_residual, law)
    return sign * _newton(residual, w, lo, hi, adt, plastic_old, sign, stretch, lr)


def _recruitment_residual(
    law: FiberLaw, w: np.ndarray, adt: np.ndarray, plastic_old: np.ndarray, g_r: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Residual asinh(expm1(w)) - g_r / lambda_p^c_p of :func:`_recruitment_flow`."""
    flow = _flow_magnitude(w, adt)
    plastic = plastic_old + flow
    g = g_r / plastic**law.hardening_exponent
    lhs, slope = _asinh_expm1(w)
    return lhs - g, slope, law.hardening_exponent * g / plastic * (adt + flow), flow


def _recruitment_flow(
    law: FiberLaw, plastic_old: np.ndarray, lr: np.ndarray, adt: np.ndarray, limit: np.ndarray
) -> np.ndarray:
    """lambda_p - lambda_p_n, at most ``limit``, of an element recruited at the step's end.

    Root of asinh(expm1(w)) = t_r / (b_p lambda_p^c_p), t_r = E_b (lambda_r - 1) >= 0, whose
    left side increases and right side decreases with w; the start
    w = log1p(sinh(t_r / (b_p lambda_p_n^c_p))) is an upper bound. A root beyond ``limit``
    returns ``limit``.
    """
    g_r = law.slack_modulus * (lr - 1.0) / law.flow_resistance
    hi = np.minimum(_log1p_sinh(g_r / plastic_old**law.hardening_exponent), _log1p_ratio(limit, adt))
    residual = partial(_recruitment_residual, law)
    return _newton(residual, hi, np.zeros_like(hi), hi, adt, plastic_old, g_r)


def _return_map(
    law: FiberLaw,
    stretch: np.ndarray,
    plastic_old: np.ndarray,
    lr: np.ndarray,
    adt: np.ndarray,
    guess: np.ndarray | None = None,
) -> np.ndarray:
    """Signed plastic increment of every element (1-D arrays; stretch already floored);
    ``guess``: a guess of it, or None."""
    trial = elastic_stress(law, stretch / plastic_old, lr)
    flow = np.zeros_like(stretch)
    i = np.flatnonzero((adt > 0) & (trial != 0))
    if i.size:
        flow[i] = _solve_flow(
            law, stretch[i], plastic_old[i], lr[i], adt[i], trial[i], None if guess is None else guess[i]
        )
    return flow


def _prepare(law: FiberLaw, dt: ArrayLike, *arrays: ArrayLike) -> tuple[np.ndarray, ...]:
    """``arrays`` (stretches, then plastic stretch and tortuosity) and a_p dt (capped),
    validated and broadcast together as 1-D float64 copies."""
    *out, dt = (np.array(x, dtype=float).ravel() for x in np.broadcast_arrays(*arrays, dt))
    if not np.all(np.isfinite(dt) & (dt >= 0)):
        raise ValueError("dt must be finite and >= 0")
    if not all(np.all(np.isfinite(x)) for x in out) or np.any(out[-2] <= 0):
        raise InadmissibleState("the fiber law met a non-finite stretch or tortuosity, or a plastic stretch <= 0")
    return (*out, np.minimum(law.flow_rate * dt, _MAX_FLOW_SCALE))


def update(
    law: FiberLaw,
    stretch: ArrayLike,
    plastic_stretch_old: ArrayLike,
    tortuosity: ArrayLike,
    dt: ArrayLike,
    plastic_stretch_guess: ArrayLike | None = None,
) -> LawState:
    """Stress, plastic stretch and algorithmic tangent after one time step (Eq. 4, 5).

    Backward Euler on the flow rule (Eq. 4), solved element by element in the asinh form
    (module docstring). The tangent differentiates the converged residual
    ``R = asinh((lambda_p - lambda_p_n) / (a_p dt)) - t / (b_p lambda_p^c_p)`` implicitly:
    ``d lambda_p / d lambda = (dg/d lambda) / (1 / hypot(a_p dt, lambda_p - lambda_p_n)
    - dg/d lambda_p)`` with ``g = t / (b_p lambda_p^c_p)``, and
    ``dt/d lambda = (t'(e) / lambda_p) (1 - e d lambda_p / d lambda)``.

    Parameters
    ----------
    law
        The fiber law.
    stretch
        lambda = l / l0 at the end of the step, shape (n,) (or broadcastable). Values below
        :data:`STRETCH_FLOOR` are evaluated at the floor (zero tangent there).
    plastic_stretch_old
        lambda_p_n at the start of the step, > 0.
    tortuosity
        lambda_r = L0 / l0; values below 1 (rounding) count as 1.
    dt
        Time step [s], finite and >= 0. ``dt = 0`` or ``a_p = 0`` is elastic.
    plastic_stretch_guess
        Optional guess of the result's plastic stretch, e.g. from a nearby stretch of the same
        step (a Newton iterate of the network): the return mapping starts from it wherever it
        lies inside the bracket and flows the same way, and then needs two or three
        iterations instead of about seven. The result does not depend on it beyond rounding.

    Returns
    -------
    LawState
        Stress [MPa], plastic stretch, tangent dt/dlambda [MPa] and recruited flags, shape (n,).

    Raises
    ------
    StepNotConverged
        If the return mapping does not converge (not expected: it falls back on bisection).
    InadmissibleState
        If a stretch or the tortuosity is not finite, or lambda_p_n <= 0 (an iterate out of the
        model's domain: the caller's step is cut).
    ValueError
        If ``dt`` is negative or not finite (a programming error).

    Notes
    -----
    In tension the tangent is positive. In compression with c_p > 0 it can be negative:
    the flow resistance ``b_p lambda_p^c_p`` falls as lambda_p does (softening), which the
    global solver must expect in compressed elements.
    """
    lam, plastic_old, lr, adt = _prepare(law, dt, stretch, plastic_stretch_old, tortuosity)
    floored = lam < STRETCH_FLOOR
    lam, lr = np.maximum(lam, STRETCH_FLOOR), np.maximum(lr, 1.0)
    guess = None
    if plastic_stretch_guess is not None:
        guess = np.broadcast_to(np.asarray(plastic_stretch_guess, dtype=float), lam.shape) - plastic_old
    flow = _return_map(law, lam, plastic_old, lr, adt, guess)
    plastic = plastic_old + flow
    t, _, dg_dstretch, dg_dplastic = _flow_terms(law, lam, plastic, lr)
    e = lam / plastic
    h = np.hypot(adt, flow)  # 1 / (dR/d lambda_p of the asinh term); 0 when elastic
    dplastic = dg_dstretch * h / (1.0 - dg_dplastic * h)
    tangent = elastic_modulus(law, e, lr) / plastic * (1.0 - e * dplastic)
    return LawState(
        stress=t,
        plastic_stretch=plastic,
        tangent=np.where(floored, 0.0, tangent),
        recruited=e >= lr,
    )


def _elastic_work(law: FiberLaw, lam0: np.ndarray, lam1: np.ndarray, plastic: np.ndarray, lr: np.ndarray) -> np.ndarray:
    """Exact integral of t(max(lambda', floor) / lambda_p) d lambda' from lam0 to lam1 [MPa]."""
    a, b = np.maximum(lam0, STRETCH_FLOOR), np.maximum(lam1, STRETCH_FLOOR)
    ea, eb = a / plastic, b / plastic
    pa, pb = np.maximum(ea - lr, 0.0), np.maximum(eb - lr, 0.0)
    slack = law.slack_modulus * (b - a) * (ea + eb - 2.0)
    taut = (law.taut_modulus / lr - law.slack_modulus) * plastic * (pb - pa) * (pb + pa)
    below = elastic_stress(law, STRETCH_FLOOR / plastic, lr) * ((lam1 - b) - (lam0 - a))
    return 0.5 * (slack + taut) + below


def work_increment(
    law: FiberLaw,
    stretch_old: ArrayLike,
    stretch: ArrayLike,
    plastic_stretch_old: ArrayLike,
    tortuosity: ArrayLike,
    dt: ArrayLike,
    order: int = GAUSS_ORDER,
) -> np.ndarray:
    """Algorithmic work density of the step, integral of t_alg d lambda' from lambda_n to lambda.

    ``t_alg(lambda')`` is the stress :func:`update` returns for stretch ``lambda'`` from the
    same ``lambda_p_n`` and ``dt``, so this is the element potential whose derivative is the
    algorithmic stress (docs/model.md section 4: ``Pi = sum_e A_e l0_e * work``). It is the exact integral of
    the trial stress (``lambda_p = lambda_p_n``, piecewise quadratic) plus the integral of the
    flow correction ``t_alg - t_trial`` by composite Gauss-Legendre quadrature, one return
    mapping per point. The increment is cut at the two recruitment kinks (of the trial stress,
    at ``lambda_r lambda_p_n``, and of the algorithmic one, after the flow of the step), and
    each piece into equal panels no wider than :data:`PANEL_WIDTH` yield-bend widths (at most
    :data:`MAX_PANELS` per piece), with ``order`` points each. Elastic elements
    (``a_p dt = 0``) are exact. With the defaults the relative error is below 1e-11 away from
    yield and about 1e-8 at worst (steps through the yield bend), checked against adaptive
    quadrature; a plla element in a 1 % stretch step needs one panel (8 return mappings).
    The increment is evaluated directly, never as a difference of two totals.

    Parameters
    ----------
    law
        The fiber law.
    stretch_old, stretch
        lambda_n and lambda, start and end of the step, shape (n,) (or broadcastable).
    plastic_stretch_old
        lambda_p_n at the start of the step.
    tortuosity
        lambda_r; values below 1 count as 1.
    dt
        Time step [s], finite and >= 0.
    order
        Gauss-Legendre points per panel for the flow correction.

    Returns
    -------
    numpy.ndarray, shape (n,) [MPa]
        Work per unit reference volume ``A l0`` (negative when the element shortens under
        tension).
    """
    lam0, lam1, plastic_old, lr, adt = _prepare(law, dt, stretch_old, stretch, plastic_stretch_old, tortuosity)
    lr = np.maximum(lr, 1.0)
    work = _elastic_work(law, lam0, lam1, plastic_old, lr)
    i = np.flatnonzero((adt > 0) & (lam1 != lam0))
    if i.size == 0:
        return work
    # Pieces between the kinks of t_trial (recruitment at lambda_r lambda_p_n) and of t_alg
    # (recruitment after the flow of the step), ascending; each is cut into equal panels no
    # wider than PANEL_WIDTH yield-bend widths b_p lambda_p_n / (dt/de).
    low, high = np.minimum(lam0[i], lam1[i]), np.maximum(lam0[i], lam1[i])
    kink_trial = lr[i] * plastic_old[i]
    limit = np.maximum(high / lr[i] - plastic_old[i], 0.0)  # kinks beyond high do not matter
    flow_r = _recruitment_flow(law, plastic_old[i], lr[i], adt[i], limit)
    kink_alg = lr[i] * (plastic_old[i] + flow_r)
    cuts = np.sort(np.column_stack([low, np.clip(kink_trial, low, high), np.clip(kink_alg, low, high), high]), axis=1)
    modulus = elastic_modulus(law, high / plastic_old[i], lr[i])
    width = PANEL_WIDTH * law.flow_resistance * plastic_old[i] / modulus
    lengths = np.diff(cuts, axis=1)
    panels = np.minimum(np.ceil(lengths / width[:, None]), MAX_PANELS).astype(np.int64).ravel()
    h = np.repeat((lengths.ravel() / np.maximum(panels, 1)), panels)
    start = np.repeat(cuts[:, :3].ravel(), panels)
    elem = np.repeat(np.repeat(i, 3), panels)
    k = np.arange(elem.size) - np.repeat(np.cumsum(panels) - panels, panels)
    x, weight = np.polynomial.legendre.leggauss(order)
    lam_q = np.maximum(start + h * (k + 0.5 + 0.5 * x[:, None]), STRETCH_FLOOR).ravel()
    plastic_q, lr_q, adt_q = (np.tile(v[elem], order) for v in (plastic_old, lr, adt))
    flow = _return_map(law, lam_q, plastic_q, lr_q, adt_q)
    correction = elastic_stress(law, lam_q / (plastic_q + flow), lr_q) - elastic_stress(law, lam_q / plastic_q, lr_q)
    panel_work = 0.5 * h * (weight @ correction.reshape(order, elem.size))
    return work + np.sign(lam1 - lam0) * np.bincount(elem, panel_work, minlength=work.size)


def axial_force_and_stiffness(
    state: LawState, area: ArrayLike, reference_length: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Axial force T = A t [uN] and algorithmic stiffness dT/dl = (A / l0) dt/dlambda [uN/um].

    Parameters
    ----------
    state
        Result of :func:`update` for the elements.
    area
        Reference cross-section A_e [um^2], shape (n,).
    reference_length
        End-to-end reference length l0 [um], shape (n,).
    """
    area = np.asarray(area, dtype=float)
    return state.stress * area, state.tangent * area / np.asarray(reference_length, dtype=float)


def yielded(plastic_stretch: ArrayLike, threshold: float = YIELD_THRESHOLD) -> np.ndarray:
    """Whether each element has yielded, lambda_p - 1 > threshold (docs/model.md section 3)."""
    return np.asarray(plastic_stretch) - 1.0 > threshold
