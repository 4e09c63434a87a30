"""espin's exception types: every error a user can cause is one of these."""

from __future__ import annotations

__all__ = ["EspinError", "ConfigError", "RVEFileError", "SolverError", "SEMError"]


class EspinError(Exception):
    """Base class of espin's errors."""


class ConfigError(EspinError, ValueError):
    """A configuration key is unknown or a value is outside its allowed range."""


class RVEFileError(EspinError, OSError):
    """A file could not be read or written, or is not an espin file of a known schema."""


class SolverError(EspinError, RuntimeError):
    """An equilibrium solve failed; the message says where and why."""


class SEMError(EspinError, ValueError):
    """An image or table is unreadable, has no scale, no scale bar or no fibers to measure.

    Out-of-range options raise :class:`ConfigError` instead; both name the parameter (or file)
    at fault.
    """
