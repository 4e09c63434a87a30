"""The error raised when an SEM image or a fiber table cannot be measured."""

from __future__ import annotations

from espin.core.errors import EspinError

__all__ = ["SEMError"]


class SEMError(EspinError, ValueError):
    """An image or table is unreadable, has no scale, no scale bar or no fibers to measure.

    Out-of-range options raise :class:`espin.core.errors.ConfigError` instead; both name the
    parameter (or file) at fault.
    """
