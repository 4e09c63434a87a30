"""The adaptive march in time: the one loop that takes every time step espin integrates.

A march reaches a sequence of reported times exactly (the recorded points of a curve, a
specimen's grip steps, a fiber's stretch history). Between two reports it takes time steps
whose size follows one :class:`StepPolicy`:

* the interval to the next report is cut into equal steps no longer than the carried step
  (the first step of a march: the whole interval);
* a step that does not converge (:class:`~espin.core.errors.StepNotConverged`, the only
  failure that cuts) is rolled back and halved; more than ``max_cuts`` halvings in a row stop
  the march (:class:`MarchFailed`);
* a converged step is judged by its local time error when ``time_rtol`` is set: over the
  tolerance it is rolled back and done again with the step the error asks for
  (0.9 sqrt(tol / error) times the step, by a factor between 1/5 and 2; docs/model.md
  section 4); the step after a rejected one does not grow;
* with an ``estimate`` of the local time error before a step is solved (the RVE's: the fiber
  law at the step's predictor), a step whose estimate is over the tolerance is rejected
  unsolved, with the step the estimate asks for, as if it had been solved and judged;
* an accepted step lets the next one double when it converged in fewer than
  ``easy_fraction`` of the problem's iteration limit, never right after a cut, and never
  beyond what the error allows;
* a step shorter than ``smallest`` of the reported interval, or more than ``budget`` time
  steps for one reported interval, stop the march: with the failure of the last halving when
  halvings made the step that small, else of kind ``stiff`` (the plastic flow asks for steps
  too small to follow).

The problem being marched is a :class:`StepProblem`: it attempts a step from its committed
state, estimates the attempt's local time error, commits or rolls back. The RVE's loading
program (:mod:`espin.mechanics.driver`), the tensile specimen (:mod:`espin.specimen.solver`)
and the single fiber (:mod:`espin.mechanics.single_fiber`) are such problems.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import numpy as np

from espin.core.config import SolverConfig
from espin.core.errors import SolverError, StepFailureKind, StepNotConverged

__all__ = ["StepPolicy", "Trial", "StepProblem", "ReportTally", "MarchFailed", "march"]

log = logging.getLogger(__name__)

_SAFETY = 0.9
_SHRINK_MIN = 0.2
_GROW_MAX = 2.0


@dataclass(frozen=True)
class StepPolicy:
    """How a march sizes its time steps (module docstring).

    Attributes
    ----------
    time_rtol : float or None
        Relative local time error allowed per step, in (0, 1); None: no error control.
    max_cuts : int
        Halvings in a row (without a converged step between them) before the march fails.
    easy_fraction : float
        A step that converged in fewer Newton iterations than this fraction of the problem's
        iteration limit lets the next one double.
    smallest : float
        The shortest step, as a fraction of the reported interval it lies in.
    budget : int
        Time steps (accepted, rejected or cut) one reported interval may take.
    """

    time_rtol: float | None = None
    max_cuts: int = 12
    easy_fraction: float = 0.2
    smallest: float = 1e-9
    budget: int = 10_000

    @classmethod
    def from_solver(cls, solver: SolverConfig) -> StepPolicy:
        """The policy of a config's ``solver`` section (``time_rtol``, ``max_cuts``)."""
        return cls(time_rtol=None if solver.time_rtol == "off" else solver.time_rtol, max_cuts=solver.max_cuts)


class Trial(Protocol):
    """What a march reads of an attempted step."""

    @property
    def iterations(self) -> int:
        """Newton iterations the attempt took (0 for a step solved in closed form)."""

    @property
    def factorizations(self) -> int:
        """Tangent factorizations the attempt took."""


T = TypeVar("T", bound=Trial)


class StepProblem(Protocol[T]):
    """A problem marched in time: one committed state, attempts from it, commit or rollback.

    ``iteration_limit`` is the Newton iterations an attempt may take (the scale of an easy
    step), or None for a problem without iterations (its steps never grow by that rule).
    """

    @property
    def iteration_limit(self) -> int | None: ...

    def attempt(self, start: float, end: float) -> T:
        """The step from the committed state at ``start`` to ``end`` [s].

        Raises :class:`~espin.core.errors.StepNotConverged` when it cannot be solved; any
        other exception stops the march."""

    def error(self, trial: T) -> float:
        """Relative local time error of an attempted step (0: exact in time)."""

    def commit(self, trial: T) -> None:
        """The attempted step becomes the committed state."""

    def rollback(self) -> None:
        """Forget what attempts changed since the last commit."""


@dataclass(eq=False)
class ReportTally(Generic[T]):
    """What one reported interval took.

    Attributes
    ----------
    index : int
        The report (1 is the first after the start).
    time : float [s]
        The reported time.
    trial : T or None
        The last committed step (the state at the report).
    iterations, factorizations : int
        Newton iterations and factorizations of every attempt (cut and rejected included).
    cuts, rejected, substeps : int
        Halvings of failed steps, steps done again because their time error was too large,
        and time steps taken.
    """

    index: int
    time: float
    trial: T | None = None
    iterations: int = 0
    factorizations: int = 0
    cuts: int = 0
    rejected: int = 0
    substeps: int = 0


class MarchFailed(SolverError):
    """A reported time could not be reached.

    Attributes
    ----------
    failure : StepNotConverged
        The last attempt's failure (kind ``stiff`` when the steps fell below the smallest or
        exceeded the budget).
    tally : ReportTally
        The failed report's counts so far (its ``index``: the report that failed).
    time : float [s]
        The end of the last attempted step.
    """

    def __init__(self, failure: StepNotConverged, tally: ReportTally, time: float) -> None:
        super().__init__(failure.reason)
        self.failure, self.tally, self.time = failure, tally, time


def split(remaining: float, step: float | None) -> float:
    """The next step [s] towards a report ``remaining`` seconds away: the interval cut into
    equal steps no longer than ``step`` (None: one step)."""
    if step is None or remaining <= 0.0:
        return remaining
    return remaining / max(1.0, np.ceil(remaining / step - 1e-9))


def error_step(dt: float, error: float, tolerance: float) -> float:
    """The step [s] after one of ``dt`` with relative local ``error`` (accepted or not)."""
    if error == 0.0:
        return _GROW_MAX * dt
    return dt * float(np.clip(_SAFETY * np.sqrt(tolerance / error), _SHRINK_MIN, _GROW_MAX))


def march(
    problem: StepProblem[T],
    reports: Sequence[float] | np.ndarray,
    policy: StepPolicy,
    *,
    start: float = 0.0,
    on_report: Callable[[ReportTally[T]], None] | None = None,
    estimate: Callable[[float, float], float] | None = None,
) -> None:
    """March ``problem`` from ``start`` through every reported time (module docstring).

    Parameters
    ----------
    problem
        The problem, committed at ``start``.
    reports
        Reported times [s], non-decreasing, after ``start``; a report at the time of the one
        before takes one step of zero length.
    policy
        Step sizes, cuts, error control, limits.
    start
        Time of the committed state [s].
    on_report
        Called with each report's :class:`ReportTally` once its time is reached.
    estimate
        ``estimate(start, end)``: the relative local time error of the step from the
        committed state at ``start`` to ``end`` [s], foreseen before it is solved (used only
        with ``policy.time_rtol``); None: every step is solved before it is judged.

    Raises
    ------
    MarchFailed
        When a report cannot be reached (module docstring); the problem stays committed at
        the last converged step.
    """
    limit = problem.iteration_limit
    rejected_before = False  # the last judged step was rejected: the next may not grow
    cut_by: StepNotConverged | None = None  # the failure that last shrank the step (None: the time error did)
    step: float | None = None  # carried from report to report
    t = start
    for index, t_end in enumerate(reports, start=1):
        tally: ReportTally[T] = ReportTally(index, float(t_end))
        smallest = policy.smallest * (t_end - t)
        in_a_row = 0
        while True:
            remaining = t_end - t
            h = split(remaining, step)
            end = t_end if h == remaining else t + h
            if tally.cuts + tally.rejected + tally.substeps >= policy.budget:
                raise MarchFailed(
                    StepNotConverged(
                        f"the plastic flow needed more than {policy.budget:,} time steps to reach the reported time "
                        f"(the last {h:.3g} s long)",
                        StepFailureKind.STIFF,
                    ),
                    tally,
                    end,
                )
            if 0.0 < h < smallest:
                below = (
                    f"the time step fell to {h:.3g} s, below the smallest ({policy.smallest:g} of the reported "
                    "interval)"
                )
                if cut_by is not None:  # Newton's failures made it so small, not the plastic flow
                    raise MarchFailed(
                        StepNotConverged(
                            f"{cut_by.reason}; {below} after {tally.cuts} halvings",
                            cut_by.kind,
                            history=cut_by.history,
                            iterations=cut_by.iterations,
                            factorizations=cut_by.factorizations,
                        ),
                        tally,
                        end,
                    )
                raise MarchFailed(StepNotConverged(below, StepFailureKind.STIFF), tally, end)
            if estimate is not None and policy.time_rtol is not None and h > 0.0:
                foreseen = estimate(t, end)
                if foreseen > policy.time_rtol:  # rejected unsolved, as below
                    step = error_step(h, foreseen, policy.time_rtol)
                    rejected_before = True
                    tally.rejected += 1
                    cut_by = None
                    log.debug(
                        "time %.6g s: step rejected unsolved (foreseen error %.3g), next %.3g s", end, foreseen, step
                    )
                    continue
            try:
                trial = problem.attempt(t, end)
            except StepNotConverged as failure:
                problem.rollback()
                tally.iterations += failure.iterations
                tally.factorizations += failure.factorizations
                if in_a_row == policy.max_cuts:
                    raise MarchFailed(failure, tally, end) from None
                tally.cuts += 1
                in_a_row += 1
                cut_by = failure
                step = 0.5 * h
                log.info("time %.6g s: step cut to %.3g s (%s)", end, step, failure.reason)
                continue
            tally.iterations += trial.iterations
            tally.factorizations += trial.factorizations
            if limit is not None:  # an easy step lets the next double, never right after a cut
                easy = trial.iterations < policy.easy_fraction * limit and not in_a_row
                step = 2.0 * h if easy else h
            if policy.time_rtol is not None and h > 0.0:
                error = problem.error(trial)
                accepted = error <= policy.time_rtol
                wanted = error_step(h, error, policy.time_rtol)
                if accepted and rejected_before:
                    wanted = min(wanted, h)
                rejected_before = not accepted
                step = wanted if step is None or limit is None else min(step, wanted)
                if not accepted:
                    problem.rollback()
                    tally.rejected += 1
                    cut_by = None
                    log.debug("time %.6g s: step rejected (local error %.3g), next %.3g s", end, error, step)
                    continue
            in_a_row = 0
            problem.commit(trial)
            tally.trial = trial
            tally.substeps += 1
            t = end
            if end == t_end:
                break
        if on_report is not None:
            on_report(tally)
