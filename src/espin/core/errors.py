"""espin's exception types: every error a user can cause is one of these.

Each type carries the exit code of the command line (``exit_code``), the same table for every
command (docs/command_line.md):

====  ==========================================================================================
code  meaning
====  ==========================================================================================
0     success
1     an unexpected error: a bug (the traceback is printed; please report it)
2     usage: a bad command-line option or config value (:class:`ConfigError`; also typer's own
      errors for unknown options and missing arguments)
3     bad input data: a file that cannot be read or holds what it should not (RVE or results
      HDF5, curve CSV, SEM image, fibers table, measured targets: :class:`InputError` and its
      subclasses, :class:`RVEFileError`)
4     the solver failed: a load step did not converge (:class:`SolverError`); the converged
      steps are kept and the residual history is in ``solver.log`` of the output folder
====  ==========================================================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import StrEnum
from typing import Any, ClassVar

__all__ = [
    "EspinError",
    "ConfigError",
    "InputError",
    "RVEFileError",
    "SolverError",
    "SEMError",
    "StepFailureKind",
    "StepNotConverged",
    "InadmissibleState",
    "EXIT_USAGE",
    "EXIT_INPUT",
    "EXIT_SOLVER",
]

EXIT_USAGE = 2
EXIT_INPUT = 3
EXIT_SOLVER = 4


class EspinError(Exception):
    """Base class of espin's errors."""

    exit_code: ClassVar[int] = 1


class ConfigError(EspinError, ValueError):
    """A configuration key is unknown or a value is outside its allowed range."""

    exit_code: ClassVar[int] = EXIT_USAGE


class InputError(EspinError, ValueError):
    """Input data (a file, a curve, an image, measured values) cannot be used as given."""

    exit_code: ClassVar[int] = EXIT_INPUT


class RVEFileError(EspinError, OSError):
    """A file could not be read or written, or is not an espin file of a known schema."""

    exit_code: ClassVar[int] = EXIT_INPUT


class SolverError(EspinError, RuntimeError):
    """An equilibrium solve failed; the message says where and why."""

    exit_code: ClassVar[int] = EXIT_SOLVER


class StepFailureKind(StrEnum):
    """Why a time step did not converge (compares equal to its lower-case name)."""

    STALLED = "stalled"
    """The residual stalled within the iteration limit (or the fiber law's return mapping did)."""
    UPHILL = "uphill"
    """No step along the Newton direction lowered the potential (the tangent points uphill)."""
    INADMISSIBLE = "inadmissible"
    """An iterate left the admissible states (non-finite, an inverted RVE or element)."""
    SINGULAR = "singular"
    """The tangent could not be factorized (a part of the network without stiffness)."""
    STIFF = "stiff"
    """The time steps the plastic flow asks for fell below the smallest step, or exceeded the
    budget of a reported step."""


class StepNotConverged(SolverError):
    """One time step could not be solved: the only failure that makes a march cut a step.

    Every other exception raised inside a step (a ``ValueError``, an ``IndexError``) is a bug
    and stops the run at once.

    Parameters
    ----------
    reason
        What happened, in words.
    kind
        Why, as a :class:`StepFailureKind` (default: the class's ``default_kind``).
    history
        Residual norms [uN, or N for the specimen] at the start and after each Newton
        iteration of the attempt (of each of its solves, one after another).
    iterations
        Newton iterations the attempt took (default: those of ``history``, one solve).
    factorizations
        Tangent factorizations the attempt took.
    """

    default_kind: ClassVar[StepFailureKind] = StepFailureKind.STALLED

    def __init__(
        self,
        reason: str,
        kind: StepFailureKind | str | None = None,
        *,
        history: Sequence[float] = (),
        iterations: int | None = None,
        factorizations: int = 0,
    ) -> None:
        super().__init__(reason)
        self.reason = reason
        self.kind = StepFailureKind(kind or self.default_kind)
        self.history = list(history)
        self.iterations = max(len(self.history) - 1, 0) if iterations is None else iterations
        self.factorizations = factorizations

    def __reduce__(self) -> tuple[Any, ...]:
        # Keyword fields survive pickling (task pools carry the exception back from workers).
        return (
            _rebuild_step_failure,
            (type(self), self.reason, str(self.kind), self.history, self.iterations, self.factorizations),
        )


def _rebuild_step_failure(
    cls: type[StepNotConverged], reason: str, kind: str, history: list[float], iterations: int, factorizations: int
) -> StepNotConverged:
    return cls(reason, kind, history=history, iterations=iterations, factorizations=factorizations)


class InadmissibleState(StepNotConverged):
    """A state outside the model's domain (non-finite stretches, lambda_p <= 0, det F <= 0),
    met by an iterate: the step is cut like any other that does not converge."""

    default_kind: ClassVar[StepFailureKind] = StepFailureKind.INADMISSIBLE


class SEMError(InputError):
    """An image or table is unreadable, has no scale, no scale bar or no fibers to measure.

    Out-of-range options raise :class:`ConfigError` instead; both name the parameter (or file)
    at fault.
    """
