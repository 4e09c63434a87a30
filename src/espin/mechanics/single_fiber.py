"""One fiber pulled along a prescribed stretch history (paper Fig. 6, docs/model.md section 3).

A check of the fiber law on its own, without a network: the stretch lambda(t) of a single
element is prescribed and the law (:mod:`espin.mechanics.fiber_law`) is integrated step by step.
Units: time s, stress MPa, stretches dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from espin.mechanics.fiber_law import FiberLaw, LawState, elastic_stress, update
from espin.mechanics.march import ReportTally, StepPolicy, march
from espin.mechanics.time_steps import local_error

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


@dataclass(frozen=True, eq=False)
class _FiberStep:
    """One time step of the fiber law: its state at the end and the step's stretch and length."""

    state: LawState
    stretch: float
    dt: float
    iterations: int = 0  # the law is solved element by element, not by the march's Newton
    factorizations: int = 0


class _Fiber:
    """The fiber as a :class:`~espin.mechanics.march.StepProblem`: the stretch is linear in
    time within each interval of the history, and the law integrated by backward Euler."""

    iteration_limit = None

    def __init__(self, law: FiberLaw, time: np.ndarray, stretch: np.ndarray, tortuosity: float) -> None:
        self.law, self.time, self.history, self.tortuosity = law, time, stretch, tortuosity
        self.interval = 1  # the interval being integrated: time[interval - 1] to time[interval]
        self.stress = np.empty_like(stretch)
        self.plastic = np.ones_like(stretch)
        self.stress[0] = elastic_stress(law, stretch[0], tortuosity)
        self.committed = (float(self.stress[0]), 1.0)  # (stress [MPa], lambda_p) now

    def attempt(self, start: float, end: float) -> _FiberStep:
        k = self.interval
        at = (
            self.history[k]
            if end == self.time[k]
            else np.interp(end, self.time[k - 1 : k + 1], self.history[k - 1 : k + 1])
        )
        return _FiberStep(update(self.law, at, self.committed[1], self.tortuosity, end - start), float(at), end - start)

    def error(self, trial: _FiberStep) -> float:
        return local_error(
            self.law,
            self.committed[0],
            self.committed[1],
            trial.state.stress,
            trial.state.plastic_stretch,
            trial.stretch,
            self.tortuosity,
            trial.dt,
        )

    def commit(self, trial: _FiberStep) -> None:
        self.committed = (float(trial.state.stress[0]), float(trial.state.plastic_stretch[0]))

    def rollback(self) -> None:
        pass


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
    fiber = _Fiber(law, time, stretch, tortuosity)
    substeps = np.zeros(len(stretch), dtype=np.int64)

    def reached(tally: ReportTally[_FiberStep]) -> None:
        fiber.interval += 1
        fiber.stress[tally.index], fiber.plastic[tally.index] = fiber.committed
        substeps[tally.index] = tally.substeps

    march(fiber, time[1:], StepPolicy(time_rtol=time_rtol), start=float(time[0]), on_report=reached)
    stress, plastic = fiber.stress, fiber.plastic
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
