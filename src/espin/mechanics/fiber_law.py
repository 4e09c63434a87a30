"""The fiber constitutive law (paper Eq. 1, 4, 5; docs/model.md section 3) for arrays of elements.

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
and poor steps are replaced by bisection in ``w``. The iteration starts at
recruitment when that splits the bracket, so it never crosses the kink of the law, and stops
when ``lambda_p`` moves by less than 4 machine epsilons (the result is good to a few
epsilons). ``sinh`` is never evaluated on a stress, and no finite input overflows. The
iteration runs element by element in compiled code (:mod:`espin.mechanics.kernels`).

Units: stress and moduli MPa, time s, stretches dimensionless; forces uN = MPa um^2.
The axial force of an element of reference area ``A`` and length ``l0`` is ``T = A t`` and its
algorithmic stiffness ``dT/dl = (A / l0) dt/dlambda`` (:func:`axial_force_and_stiffness`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from espin.core.errors import ConfigError, InadmissibleState, StepNotConverged
from espin.mechanics import kernels

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

STRETCH_FLOOR = kernels.STRETCH_FLOOR
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

    def kernel_constants(self) -> tuple[float, float, float, float]:
        """E_t [MPa], E_b [MPa], b_p [MPa] and c_p [-] as the compiled kernels take them."""
        return self.taut_modulus, self.slack_modulus, self.flow_resistance, self.hardening_exponent

    def flow_scale(self, dt: ArrayLike) -> np.ndarray:
        """a_p dt [-] over time steps ``dt`` [s], capped so that a huge step stays finite."""
        return np.minimum(self.flow_rate * np.asarray(dt), _MAX_FLOW_SCALE)

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
    plastic_rate : (n,) float64
        d lambda_p / d lambda of the step (0 below the stretch floor): with it a nearby
        stretch's lambda_p is guessed to first order.
    """

    stress: np.ndarray
    plastic_stretch: np.ndarray
    tangent: np.ndarray
    recruited: np.ndarray
    plastic_rate: np.ndarray


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


def _not_converged(failed: int) -> StepNotConverged:
    return StepNotConverged(
        f"the fiber law's return mapping did not converge in {kernels.MAX_ITERATIONS} iterations for {failed} elements"
    )


def _recruitment_flow(
    law: FiberLaw, plastic_old: np.ndarray, lr: np.ndarray, adt: np.ndarray, limit: np.ndarray
) -> np.ndarray:
    """lambda_p - lambda_p_n, at most ``limit``, of elements recruited at the step's end
    (1-D arrays, adt > 0, lr >= 1; :func:`espin.mechanics.kernels.recruitment_flow`)."""
    flow = np.empty_like(plastic_old)
    failed = kernels.recruitment_flow(
        plastic_old, lr, adt, limit, law.slack_modulus, law.flow_resistance, law.hardening_exponent, flow
    )
    if failed:
        raise _not_converged(failed)
    return flow


def _return_map(
    law: FiberLaw, stretch: np.ndarray, plastic_old: np.ndarray, lr: np.ndarray, adt: np.ndarray
) -> np.ndarray:
    """Signed plastic increment of every element (1-D arrays; stretch already floored, lr >= 1)."""
    flow = np.empty_like(stretch)
    failed = kernels.return_map(stretch, plastic_old, lr, adt, *law.kernel_constants(), flow)
    if failed:
        raise _not_converged(failed)
    return flow


def _prepare(law: FiberLaw, dt: ArrayLike, *arrays: ArrayLike) -> tuple[np.ndarray, ...]:
    """``arrays`` (stretches, then plastic stretch and tortuosity) and a_p dt (capped),
    validated and broadcast together as 1-D float64 copies."""
    *out, dt = (np.array(x, dtype=float).ravel() for x in np.broadcast_arrays(*arrays, dt))
    if not np.all(np.isfinite(dt) & (dt >= 0)):
        raise ValueError("dt must be finite and >= 0")
    if not all(np.all(np.isfinite(x)) for x in out) or np.any(out[-2] <= 0):
        raise InadmissibleState("the fiber law met a non-finite stretch or tortuosity, or a plastic stretch <= 0")
    return (*out, law.flow_scale(dt))


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
    guess = np.empty(0)
    if plastic_stretch_guess is not None:
        guess = np.ascontiguousarray(np.broadcast_to(np.asarray(plastic_stretch_guess, dtype=float), lam.shape))
    stress, plastic, tangent, rate = (np.empty_like(lam) for _ in range(4))
    recruited = np.empty(lam.shape, dtype=bool)
    failed = kernels.law_update(
        lam, plastic_old, lr, adt, guess, *law.kernel_constants(), stress, plastic, tangent, recruited, rate
    )
    if failed:
        raise _not_converged(failed)
    return LawState(stress=stress, plastic_stretch=plastic, tangent=tangent, recruited=recruited, plastic_rate=rate)


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
