"""espin's exception types: every error a user can cause is one of these."""

from __future__ import annotations

__all__ = ["EspinError", "ConfigError", "RVEFileError", "SolverError"]


class EspinError(Exception):
    """Base class of espin's errors."""


class ConfigError(EspinError, ValueError):
    """A configuration key is unknown or a value is outside its allowed range."""


class RVEFileError(EspinError, OSError):
    """A file could not be read or written, or is not an espin file of a known schema."""


class SolverError(EspinError, RuntimeError):
    """An equilibrium solve failed; the message says where and why."""
