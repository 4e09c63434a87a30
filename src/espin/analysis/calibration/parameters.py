"""The parameters :func:`espin.analysis.calibration.fit` can calibrate: names, allowed ranges, bounds."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from espin.core.config import Config
from espin.core.errors import ConfigError

ETA_KEY = "rve.volume_fraction"


@dataclass(frozen=True)
class FitParameter:
    """A config key that :func:`fit` can calibrate.

    Attributes
    ----------
    key : str
        Dotted config key, e.g. ``fiber.flow_resistance_MPa``.
    symbol : str
        The paper's symbol (``eta``, ``E_t``, ``E_b``, ``a_p``, ``b_p``, ``c_p``).
    log_scale : bool
        Fitted on log(value) (positive parameters spanning decades) rather than on the value.
    lower, upper : float
        Limits of the allowed range (the config's, tightened to > 0 for a log-scale parameter).
    closed_lower : bool
        Whether ``lower`` itself is allowed.
    default_span : float
        Default bounds: value / span to value * span (log scale); for linear scale see
        :func:`default_bounds`.
    """

    key: str
    symbol: str
    log_scale: bool
    lower: float
    upper: float
    closed_lower: bool
    default_span: float

    @property
    def name(self) -> str:
        """The key without its section, e.g. ``flow_resistance_MPa``."""
        return self.key.split(".", 1)[1]

    @property
    def allowed(self) -> str:
        """The allowed range, in words."""
        low = f">= {self.lower:g}" if self.closed_lower else f"> {self.lower:g}"
        return low if math.isinf(self.upper) else f"{low} and < {self.upper:g}"

    def admits(self, value: float) -> bool:
        """Whether ``value`` lies in the allowed range."""
        above = value >= self.lower if self.closed_lower else value > self.lower
        return bool(np.isfinite(value) and above and value < self.upper)


FIT_PARAMETERS: dict[str, FitParameter] = {
    p.key: p
    for p in (
        FitParameter(ETA_KEY, "eta", False, 0.0, 1.0, False, 2.0),
        FitParameter("fiber.taut_modulus_MPa", "E_t", True, 0.0, math.inf, False, 10.0),
        FitParameter("fiber.slack_modulus_MPa", "E_b", True, 0.0, math.inf, False, 10.0),
        FitParameter("fiber.flow_rate_per_s", "a_p", True, 0.0, math.inf, False, 1e3),
        FitParameter("fiber.flow_resistance_MPa", "b_p", True, 0.0, math.inf, False, 5.0),
        FitParameter("fiber.hardening_exponent", "c_p", False, 0.0, math.inf, True, 3.0),
    )
}
"""The fittable parameters, in the order results are reported."""


def parameter_key(name: str) -> str:
    """The dotted config key of a fit parameter given by key, short name or symbol.

    ``"fiber.flow_resistance_MPa"``, ``"flow_resistance_MPa"`` and ``"b_p"`` all name b_p;
    ``"eta"`` and ``"volume_fraction"`` name ``rve.volume_fraction``.

    Raises
    ------
    ConfigError
        For a name that is none of these, listing the allowed names.
    """
    text = name.strip()
    for p in FIT_PARAMETERS.values():
        if text in (p.key, p.name) or text.lower() == p.symbol.lower():
            return p.key
    choices = ", ".join(f"{p.name} ({p.symbol})" for p in FIT_PARAMETERS.values())
    raise ConfigError(f"unknown fit parameter {name!r}; choose from {choices}")


def default_bounds(parameter: FitParameter, value: float) -> tuple[float, float]:
    """Bounds used when none are given, around the base value.

    Log-scale parameters: value / span to value * span. eta: value / 2 to min(2 value, 0.9).
    c_p: 0 to max(span, span * value).
    """
    if parameter.log_scale:
        return value / parameter.default_span, value * parameter.default_span
    if parameter.key == ETA_KEY:
        return value / parameter.default_span, min(parameter.default_span * value, 0.9)
    return 0.0, max(parameter.default_span, parameter.default_span * value)


def _keys_of(names: Sequence[str] | Mapping[str, Any] | None, what: str) -> list[str]:
    keys = [parameter_key(n) for n in (names or ())]
    if len(set(keys)) != len(keys):
        raise ConfigError(f"{what}: a parameter is named twice ({', '.join(names or ())})")
    return keys


def _check_bounds(key: str, bound: Sequence[float]) -> tuple[float, float]:
    p = FIT_PARAMETERS[key]
    try:
        lo, hi = (float(b) for b in bound)
    except (TypeError, ValueError):
        raise ConfigError(f"bounds for {key}: expected (low, high), got {bound!r}") from None
    if not lo < hi:
        raise ConfigError(f"bounds for {key}: low must be < high (got {lo:g}, {hi:g})")
    if not (p.admits(lo) and p.admits(hi)):
        raise ConfigError(f"bounds for {key} ({p.symbol}): ({lo:g}, {hi:g}) leave the allowed range {p.allowed}")
    return lo, hi


def _check_moduli(base: Config, bounds: Mapping[str, tuple[float, float]]) -> None:
    """E_t must stay above E_b for every point inside the bounds."""
    taut = bounds.get("fiber.taut_modulus_MPa", (base.fiber.taut_modulus_MPa,) * 2)
    slack = bounds.get("fiber.slack_modulus_MPa", (base.fiber.slack_modulus_MPa,) * 2)
    if taut[0] <= slack[1]:
        raise ConfigError(
            f"fiber.taut_modulus_MPa (E_t, lowest {taut[0]:g}) must stay > "
            f"fiber.slack_modulus_MPa (E_b, highest {slack[1]:g}): adjust the bounds"
        )


def _bounds_table(
    config: Config, keys: Sequence[str], bounds: Mapping[str, Any] | None
) -> dict[str, tuple[float, float]]:
    """(low, high) of every fitted key: the given ones checked, the others by default."""
    stray = sorted(set(_keys_of(bounds, "bounds")) - set(keys))
    if stray:
        raise ConfigError(f"bounds given for {', '.join(stray)}, which is not fitted")
    chosen = {parameter_key(k): _check_bounds(parameter_key(k), b) for k, b in (bounds or {}).items()}
    table = {}
    for key in FIT_PARAMETERS:
        if key in keys:
            section, name = key.split(".")
            value = float(getattr(getattr(config, section), name))
            table[key] = chosen.get(key) or _check_bounds(key, default_bounds(FIT_PARAMETERS[key], value))
    _check_moduli(config, table)
    return table
