"""What a design may change: numeric config keys with bounds, and constraints on the mat.

A design variable is a numeric key of the ``[rve]`` config (dotted, or a short name of
:data:`SHORT_NAMES`) with bounds. The search works in the unit cube: a variable maps
linearly (``log=True``: logarithmically) to its bounds. Integer keys (``rve.layers``) are
searched as continuous and rounded before a mat is generated, so two points that round alike
are the same evaluation. Choices between models (the walk) are not variables: run one design
per choice (each with its own keys) and compare.

The absolute fiber diameter does not change the stresses of this model (every length is a
multiple of D and the RVE volume scales with D), so it is not a variable; it enters through
constraints. The diameter's spread is a variable as its coefficient of variation
``diameter_cv`` (``rve.diameter_sd_um = cv * rve.diameter_um``).

Constraints bound quantities of the mat (:data:`CONSTRAINT_QUANTITIES`): ``porosity >= 0.8``
(porosity = 1 - volume fraction), ``diameter_cv <= 0.3``. Candidates that break one are never
evaluated.
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from espin.core.config import Config, apply_overrides
from espin.core.errors import ConfigError

__all__ = [
    "SHORT_NAMES",
    "DERIVED_KEYS",
    "CONSTRAINT_QUANTITIES",
    "DesignVariable",
    "Constraint",
    "DesignSpace",
    "parse_variable",
    "parse_constraint",
    "constraint_value",
]

SHORT_NAMES = {
    "eta": "rve.volume_fraction",
    "volume_fraction": "rve.volume_fraction",
    "kappa": "rve.orientation.von_mises.kappa",
    "mean_deg": "rve.orientation.von_mises.mean_deg",
    "max_deviation_deg": "rve.max_deviation_deg",
    "segment_ratio": "rve.segment_ratio",
    "waviness_deg": "rve.waviness_deg",
    "waviness_length_ratio": "rve.waviness_length_ratio",
    "layers": "rve.layers",
    "diameter_cv": "diameter_cv",
}
"""Short names of the usual design variables."""
DERIVED_KEYS = {"diameter_cv": "coefficient of variation of the fiber diameter, sd / mean"}
"""Variables that are not config keys themselves (see :meth:`DesignSpace.overrides`)."""
_INTEGER_KEYS = {"rve.layers"}
_FIBER_SYMBOLS = {
    "E_t",
    "E_b",
    "a_p",
    "b_p",
    "c_p",
    "taut_modulus_MPa",
    "slack_modulus_MPa",
    "flow_rate_per_s",
    "flow_resistance_MPa",
    "hardening_exponent",
}
_NOT_VARIABLES = {
    "rve.diameter_um": "the fiber diameter does not change the stresses (every length scales with it); "
    "bound it with a constraint instead",
    "rve.seed": "realizations are chosen by the design run",
    "rve.size_ratio": "the RVE size is a numerical choice, not a property of the mat",
    "rve.size_um": "the RVE size is a numerical choice, not a property of the mat",
    "rve.diameter_sd_um": "search the diameter's spread as diameter_cv (sd / mean diameter)",
}


@dataclass(frozen=True)
class DesignVariable:
    """One searched quantity.

    Attributes
    ----------
    key : str
        Dotted config key (``rve.volume_fraction``) or a derived key of :data:`DERIVED_KEYS`.
    low, high : float
        Bounds, in the key's unit.
    integer : bool
        Rounded to an integer before use.
    log : bool
        Searched on a logarithmic scale (positive bounds only).
    """

    key: str
    low: float
    high: float
    integer: bool = False
    log: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise ConfigError(
                f"variable {self.key}: bounds must be finite with low < high (got {self.low:g}, {self.high:g})"
            )
        if self.log and self.low <= 0.0:
            raise ConfigError(f"variable {self.key}: a log scale needs positive bounds (got low {self.low:g})")

    @property
    def name(self) -> str:
        """The key without its ``rve.`` prefix."""
        return self.key.removeprefix("rve.")

    def value(self, unit: np.ndarray | float) -> np.ndarray | float:
        """The value at unit-cube coordinate(s) ``unit`` in [0, 1] (rounded if integer)."""
        u = np.clip(unit, 0.0, 1.0)
        if self.log:
            value = np.exp(np.log(self.low) + u * (np.log(self.high) - np.log(self.low)))
        else:
            value = self.low + u * (self.high - self.low)
        return np.round(value) if self.integer else value

    def unit(self, value: np.ndarray | float) -> np.ndarray | float:
        """Unit-cube coordinate of ``value``."""
        if self.log:
            return (np.log(value) - np.log(self.low)) / (np.log(self.high) - np.log(self.low))
        return (np.asarray(value, dtype=float) - self.low) / (self.high - self.low)


_OPS: dict[str, Callable[[Any, Any], Any]] = {">=": operator.ge, "<=": operator.le}
CONSTRAINT_QUANTITIES = {
    "porosity": "1 - rve.volume_fraction",
    "volume_fraction": "rve.volume_fraction",
    "diameter_um": "rve.diameter_um [um]",
    "diameter_sd_um": "rve.diameter_sd_um [um]",
    "diameter_cv": "rve.diameter_sd_um / rve.diameter_um",
    "layers": "rve.layers",
}
"""Quantities a constraint may bound, and what they are."""


def constraint_value(base: Config, values: Mapping[str, float], name: str) -> float:
    """A constraint quantity of the mat at variable ``values`` (other keys from ``base``)."""
    rve = base.rve
    eta = values.get("rve.volume_fraction", rve.volume_fraction)
    cv = values.get("diameter_cv", rve.diameter_sd_um / rve.diameter_um)
    return {
        "porosity": 1.0 - eta,
        "volume_fraction": eta,
        "diameter_um": rve.diameter_um,
        "diameter_sd_um": cv * rve.diameter_um,
        "diameter_cv": cv,
        "layers": float(values.get("rve.layers", rve.layers)),
    }[name]


@dataclass(frozen=True)
class Constraint:
    """``quantity op bound`` on a candidate's config (op ``>=`` or ``<=``).

    Attributes
    ----------
    quantity : str
        One of :data:`CONSTRAINT_QUANTITIES`.
    op : str
        ``">="`` or ``"<="``.
    bound : float
        The bound, in the quantity's unit.
    """

    quantity: str
    op: str
    bound: float

    def __post_init__(self) -> None:
        if self.quantity not in CONSTRAINT_QUANTITIES:
            raise ConfigError(
                f"constraint: unknown quantity {self.quantity!r}; one of {', '.join(CONSTRAINT_QUANTITIES)}"
            )
        if self.op not in _OPS:
            raise ConfigError(f"constraint {self.quantity}: the operator is >= or <= (got {self.op!r})")
        if not math.isfinite(self.bound):
            raise ConfigError(f"constraint {self.quantity}: the bound must be finite (got {self.bound})")

    def holds(self, base: Config, values: Mapping[str, float]) -> bool:
        """Whether the mat of ``base`` with the variables at ``values`` meets the constraint."""
        return bool(_OPS[self.op](constraint_value(base, values, self.quantity), self.bound))

    def __str__(self) -> str:
        return f"{self.quantity} {self.op} {self.bound:g}"


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def parse_variable(text: str | tuple[str, float, float]) -> DesignVariable:
    """A variable from ``NAME=LOW:HIGH`` (``eta=0.1:0.3``, ``kappa=0:8``; ``log:`` before LOW
    for a log scale: ``kappa=log:0.5:8``) or a (name, low, high) tuple."""
    if isinstance(text, str):
        match = re.fullmatch(rf"\s*([\w.]+)\s*=\s*(log:)?\s*({_NUMBER})\s*:\s*({_NUMBER})\s*", text)
        if match is None:
            raise ConfigError(f"variable {text!r}: write NAME=LOW:HIGH (eta=0.1:0.3), log:LOW:HIGH for a log scale")
        name, log, low, high = match[1], bool(match[2]), float(match[3]), float(match[4])
    else:
        name, low, high = text
        log = False
    if name in _FIBER_SYMBOLS or name.startswith("fiber."):
        raise ConfigError(
            f"variable {name}: the fiber law is the material's, not the microstructure's: fit it to "
            "your tensile tests with espin fit and give its fitted.toml as the base config"
        )
    key = SHORT_NAMES.get(name, name if "." in name or name in DERIVED_KEYS else f"rve.{name}")
    if not (key.startswith("rve.") or key in DERIVED_KEYS):
        raise ConfigError(
            f"variable {name}: a design variable is a key of the mat, [rve] (or "
            f"{', '.join(DERIVED_KEYS)}); the loading and the solver are the test's, set them in the "
            "base config"
        )
    if key in _NOT_VARIABLES:
        raise ConfigError(f"variable {name}: not a design variable: {_NOT_VARIABLES[key]}")
    return DesignVariable(key, float(low), float(high), integer=key in _INTEGER_KEYS, log=log)


def parse_constraint(text: str | Constraint) -> Constraint:
    """A constraint from ``QUANTITY>=BOUND`` or ``QUANTITY<=BOUND`` (``porosity>=0.8``)."""
    if isinstance(text, Constraint):
        return text
    match = re.fullmatch(rf"\s*(\w+)\s*(>=|<=)\s*({_NUMBER})\s*", text)
    if match is None:
        raise ConfigError(
            f"constraint {text!r}: write QUANTITY>=BOUND or QUANTITY<=BOUND, QUANTITY one of "
            f"{', '.join(CONSTRAINT_QUANTITIES)}"
        )
    return Constraint(match[1], match[2], float(match[3]))


@dataclass(frozen=True)
class DesignSpace:
    """The variables and constraints of a design on a base config.

    Attributes
    ----------
    base : Config
        Every key not searched (fiber law, loading, RVE size and sampling).
    variables : tuple of DesignVariable
        At least one.
    constraints : tuple of Constraint
    """

    base: Config
    variables: tuple[DesignVariable, ...]
    constraints: tuple[Constraint, ...] = ()

    @classmethod
    def build(
        cls,
        base: Config,
        variables: Iterable[str | tuple[str, float, float] | DesignVariable] | Mapping[str, tuple[float, float]],
        constraints: Iterable[str | Constraint] = (),
    ) -> DesignSpace:
        """Parse and check the variables and constraints against ``base`` (both bounds of every
        variable must give a valid config) before any work."""
        if isinstance(variables, Mapping):
            variables = [(name, *bounds) for name, bounds in variables.items()]
        parsed = tuple(v if isinstance(v, DesignVariable) else parse_variable(v) for v in variables)
        if not parsed:
            raise ConfigError("variables: give at least one design variable with its bounds (eta=0.1:0.3)")
        keys = [v.key for v in parsed]
        if len(set(keys)) != len(keys):
            raise ConfigError(f"variables: each key once (got {', '.join(keys)})")
        space = cls(base, parsed, tuple(parse_constraint(c) for c in constraints))
        for variable in parsed:  # each key alone first, so that an unknown key is named as such
            try:
                apply_overrides(base, space.overrides({variable.key: float(variable.value(0.5))}))
            except ConfigError as err:
                raise ConfigError(f"variable {variable.key}: {err}") from None
        for variable in parsed:
            for end in (0.0, 1.0):
                unit = np.full(len(parsed), 0.5)
                unit[keys.index(variable.key)] = end
                try:
                    space.config(unit)
                except ConfigError as err:
                    raise ConfigError(
                        f"variable {variable.key}: bound {variable.value(end):g} is not allowed: {err}"
                    ) from None
        return space

    @property
    def dimension(self) -> int:
        """Number of variables."""
        return len(self.variables)

    def values(self, unit: Sequence[float] | np.ndarray) -> dict[str, float]:
        """Variable key -> value at one unit-cube point (integers rounded)."""
        return {v.key: float(v.value(u)) for v, u in zip(self.variables, unit)}

    def overrides(self, values: Mapping[str, float]) -> dict[str, Any]:
        """Dotted config overrides for variable values (derived keys resolved; integers as int)."""
        out: dict[str, Any] = {}
        for key, value in values.items():
            if key == "diameter_cv":
                out["rve.diameter_sd_um"] = round(value * self.base.rve.diameter_um, 12)
            elif key in _INTEGER_KEYS:
                out[key] = int(round(value))
            else:
                out[key] = round(float(value), 12)
        return out

    def config(self, unit: Sequence[float] | np.ndarray) -> Config:
        """The validated config at one unit-cube point."""
        return apply_overrides(self.base, self.overrides(self.values(unit)))

    def feasible(self, unit: np.ndarray) -> np.ndarray:
        """Whether each row of ``unit`` (n, d) meets every constraint (from its variable values)."""
        if not self.constraints:
            return np.ones(len(unit), dtype=bool)
        out = np.empty(len(unit), dtype=bool)
        for i, row in enumerate(unit):
            values = self.values(row)
            out[i] = all(c.holds(self.base, values) for c in self.constraints)
        return out

    def at_bounds(self, unit: Sequence[float] | np.ndarray, margin: float = 0.02) -> list[str]:
        """The variables within ``margin`` (a fraction of their range) of a bound at ``unit``:
        ``"rve.volume_fraction = 0.3 (upper bound)"``."""
        out = []
        for v, u in zip(self.variables, unit):
            if u <= margin:
                out.append(f"{v.key} = {v.value(0.0):g} (lower bound)")
            elif u >= 1.0 - margin:
                out.append(f"{v.key} = {v.value(1.0):g} (upper bound)")
        return out
