"""One fiber pulled along a prescribed stretch history (paper Fig. 6, docs/model.md section 3).

A check of the fiber law on its own, without a network: the stretch lambda(t) of a single
element is prescribed and the law (:mod:`espin.mechanics.fiber_law`) is integrated step by step.
Units: time s, stress MPa, stretches dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from espin.mechanics.fiber_law import FiberLaw, elastic_stress, update
from espin.mechanics.time_steps import StepSizeControl, local_error, split

__all__ = ["FiberHistory", "constant_rate_history", "pull_fiber"]


@dataclass(frozen=True, eq=False)
class FiberHistory:
    """Response of one fiber along a stretch history of n points.

    Attributes
    ----------
    time : (n,) float64 [s]
        Time of each point.
    stretch : (n,) float64
        Prescribed end-to-end stretch lambda.
    stress : (n,) float64 [MPa]
        Engineering stress t.
    plastic_stretch : (n,) float64
        Plastic stretch lambda_p (1 at the first point).
    recruited : (n,) bool
        Whether the fiber is taut, lambda / lambda_p >= lambda_r.
    law : FiberLaw
        The law that was integrated.
    tortuosity : float
        lambda_r of the fiber.
    substeps : (n,) int64
        Time steps of the law taken to reach each point (0 at the first).
    """

    time: np.ndarray
    stretch: np.ndarray
    stress: np.ndarray
    plastic_stretch: np.ndarray
    recruited: np.ndarray
    law: FiberLaw
    tortuosity: float
    substeps: np.ndarray


def constant_rate_history(
    max_stretch: float,
    rate_per_s: float,
    steps: int,
    unload_to: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Times and stretches of a pull from lambda = 1 to ``max_stretch`` at a constant rate.

    Parameters
    ----------
    max_stretch
        Largest stretch, > 1.
    rate_per_s
        Stretch rate d lambda / dt [1/s] (the engineering strain rate), > 0.
    steps
        Number of loading steps, >= 1.
    unload_to
        If given, the stretch is then brought back to this value at the same rate, with
        steps of the same size (at least one).

    Returns
    -------
    time : (n,) float64 [s]
    stretch : (n,) float64
    """
    if not (max_stretch > 1 and rate_per_s > 0 and steps >= 1):
        raise ValueError("need max_stretch > 1, rate_per_s > 0 and steps >= 1")
    stretch = np.linspace(1.0, max_stretch, steps + 1)
    if unload_to is not None:
        if not 0 < unload_to < max_stretch:
            raise ValueError(f"unload_to must be in (0, max_stretch = {max_stretch})")
        n_back = max(1, round(steps * (max_stretch - unload_to) / (max_stretch - 1.0)))
        stretch = np.concatenate([stretch, np.linspace(max_stretch, unload_to, n_back + 1)[1:]])
    time = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(stretch))) / rate_per_s])
    return time, stretch


def pull_fiber(
    law: FiberLaw,
    time: ArrayLike,
    stretch: ArrayLike,
    tortuosity: float = 1.0,
    time_rtol: float | None = None,
) -> FiberHistory:
    """Integrate the fiber law (Eq. 1, 4, 5) along a prescribed stretch history.

    One backward-Euler step per interval of the history, or, with ``time_rtol``, as many as
    the local error control of :mod:`espin.mechanics.time_steps` asks for, the stretch
    varying linearly in time within an interval.

    Parameters
    ----------
    law
        The fiber law.
    time
        (n,) non-decreasing times [s]; a zero step is elastic.
    stretch
        (n,) stretches lambda > 0; the fiber starts undeformed (lambda_p = 1) at ``time[0]``.
    tortuosity
        lambda_r >= 1 of the fiber.
    time_rtol
        Relative stress tolerance of each step's local error, in (0, 1); None: one step
        per interval.

    Returns
    -------
    FiberHistory
    """
    time = np.asarray(time, dtype=float)
    stretch = np.asarray(stretch, dtype=float)
    if time.ndim != 1 or time.shape != stretch.shape or np.any(np.diff(time) < 0):
        raise ValueError("time and stretch must be 1-D of equal length, time non-decreasing")
    if time_rtol is not None and not 0.0 < time_rtol < 1.0:
        raise ValueError(f"time_rtol must be in (0, 1), got {time_rtol}")
    stress = np.empty_like(stretch)
    plastic = np.ones_like(stretch)
    substeps = np.zeros(len(stretch), dtype=np.int64)
    stress[0] = elastic_stress(law, stretch[0], tortuosity)
    step = None  # the adaptive step, carried between intervals
    control = StepSizeControl(time_rtol) if time_rtol is not None else None
    for k in range(1, len(stretch)):
        t, t_end = time[k - 1], time[k]
        t_stress, t_plastic = stress[k - 1], plastic[k - 1]
        while True:
            remaining = t_end - t
            h = split(remaining, step) if remaining > 0.0 else remaining
            last = h == remaining
            at = stretch[k] if last else np.interp(t + h, time[k - 1:k + 1], stretch[k - 1:k + 1])
            state = update(law, at, t_plastic, tortuosity, h)
            if time_rtol is not None and h > 0.0:
                accepted, step = control.judge(h, local_error(law, t_stress, t_plastic, state, at, tortuosity, h))
                if not accepted:
                    continue
            substeps[k] += 1
            t_stress, t_plastic = state.stress[0], state.plastic_stretch[0]
            if last:
                break
            t += h
        stress[k], plastic[k] = t_stress, t_plastic
    return FiberHistory(
        time=time,
        stretch=stretch,
        stress=stress,
        plastic_stretch=plastic,
        recruited=stretch / plastic >= max(tortuosity, 1.0),
        law=law,
        tortuosity=tortuosity,
        substeps=substeps,
    )
