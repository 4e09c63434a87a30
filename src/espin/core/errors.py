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

from typing import ClassVar

__all__ = ["EspinError", "ConfigError", "InputError", "RVEFileError", "SolverError", "SEMError",
           "EXIT_USAGE", "EXIT_INPUT", "EXIT_SOLVER"]

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


class SEMError(InputError):
    """An image or table is unreadable, has no scale, no scale bar or no fibers to measure.

    Out-of-range options raise :class:`ConfigError` instead; both name the parameter (or file)
    at fault.
    """
