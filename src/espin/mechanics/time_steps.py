"""Time steps that follow the local error of the plastic update (docs/model.md section 4).

Backward Euler integrates the flow rule (Eq. 4) with first-order accuracy: over a step dt
its plastic stretch differs from the trapezoidal rule's by

    d lambda_p = dt / 2 |r(t_n+1) - r(t_n)|,    r = d lambda_p / dt,

an estimate of the step's local error that costs no extra solve: the rate at the end is the
step's own (lambda_p - lambda_p_n) / dt, the rate at the start follows from the stress there.
An element's stress error is the elastic modulus times the elastic-stretch error it causes,
M(e) e / lambda_p d lambda_p; a step's error is the volume-weighted sum of those over the
volume-weighted sum of |t|, a relative stress error. The march (:mod:`espin.mechanics.march`)
accepts a step when that is at most the tolerance (``solver.time_rtol``) and scales the next
by 0.9 sqrt(tol / error) (the local error is O(dt^2)).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from espin.mechanics.fiber_law import FiberLaw, elastic_modulus

__all__ = ["flow_rate", "local_error", "local_errors"]

_MAX_ARGUMENT = 700.0  # sinh overflows beyond ~710


def flow_rate(law: FiberLaw, stress: ArrayLike, plastic_stretch: ArrayLike) -> np.ndarray:
    """Plastic stretch rate r = a_p sinh(t / (b_p lambda_p^c_p)) of Eq. 4 [1/s]."""
    stress = np.asarray(stress, dtype=float)
    plastic_stretch = np.asarray(plastic_stretch, dtype=float)
    g = stress / (law.flow_resistance * plastic_stretch**law.hardening_exponent)
    return law.flow_rate * np.sinh(np.clip(g, -_MAX_ARGUMENT, _MAX_ARGUMENT))


def local_error(
    law: FiberLaw,
    start_stress: ArrayLike,
    start_plastic_stretch: ArrayLike,
    end_stress: ArrayLike,
    end_plastic_stretch: ArrayLike,
    stretch: ArrayLike,
    tortuosity: ArrayLike,
    dt: float,
    weight: ArrayLike | float = 1.0,
) -> float:
    """Relative stress error of one backward-Euler step of the fiber law (module docstring).

    Parameters
    ----------
    law
        The fiber law.
    start_stress, start_plastic_stretch
        (n,) stress t [MPa] and lambda_p at the start of the step.
    end_stress, end_plastic_stretch
        (n,) t [MPa] and lambda_p at the end of the step (the fiber law's update).
    stretch
        (n,) stretch lambda at the end of the step.
    tortuosity
        (n,) lambda_r.
    dt
        Step [s], > 0.
    weight
        (n,) weights of the elements, e.g. their volume A l0 [um^3].

    Returns
    -------
    float
        sum w |dt_e| / sum w |t_e|: 0 for an elastic law or a step without stress.
    """
    return float(
        local_errors(
            law, start_stress, start_plastic_stretch, end_stress, end_plastic_stretch, stretch, tortuosity, dt, weight
        )
    )


def local_errors(
    law: FiberLaw,
    start_stress: ArrayLike,
    start_plastic_stretch: ArrayLike,
    end_stress: ArrayLike,
    end_plastic_stretch: ArrayLike,
    stretch: ArrayLike,
    tortuosity: ArrayLike,
    dt: float,
    weight: ArrayLike | float = 1.0,
) -> np.ndarray:
    """:func:`local_error` of several networks at once: element arrays (..., n), the sums over
    the last axis (the same sums as :func:`local_error`'s); ``tortuosity`` and ``weight``
    broadcast against them. Returns an array of the leading shape (a 0-d array for (n,))."""
    plastic = np.asarray(end_plastic_stretch, dtype=float)
    if law.flow_rate == 0.0 or dt <= 0.0:
        return np.zeros(plastic.shape[:-1])
    rate_end = (plastic - np.asarray(start_plastic_stretch, dtype=float)) / dt
    rate_start = flow_rate(law, start_stress, start_plastic_stretch)
    plastic_error = 0.5 * dt * np.abs(rate_end - rate_start)
    elastic_stretch = np.asarray(stretch, dtype=float) / plastic
    stress_error = elastic_modulus(law, elastic_stretch, tortuosity) * elastic_stretch / plastic * plastic_error
    weight = np.broadcast_to(np.asarray(weight, dtype=float), plastic.shape)
    scale = np.sum(weight * np.abs(np.asarray(end_stress, dtype=float)), axis=-1)
    error = np.sum(weight * stress_error, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(error == 0.0, 0.0, np.where(scale > 0.0, error / scale, np.inf))
