"""What a design must achieve: target properties, in one or more loading directions, and ratios.

A target is a property of the bilinear fit of the tensile curve (modulus, yield stress,
post-yield modulus, yield strain; :mod:`espin.analysis.properties`) in a loading direction,
with a relative tolerance; a ratio target compares one property in two directions (an
anisotropy E_0 / E_90 = 3). A design meets its targets when every normalized error

    e = (achieved - target) / (tolerance * target)

lies in [-1, 1]; the search minimizes the mean of e^2.

On the command line a target is written ``NAME[@DIR]=VALUE[+-TOL%]`` (``E=200``,
``sigma_y=6.2+-3%``, ``E@90=70``) and a ratio ``NAME@DIR/NAME@DIR=VALUE[+-TOL%]``
(``E@0/E@90=3``); NAME is a property of :data:`PROPERTY_NAMES` or its symbol of
:data:`SYMBOLS`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from espin.core.errors import ConfigError

__all__ = ["PROPERTY_NAMES", "SYMBOLS", "DEFAULT_TOLERANCE", "PropertyTarget", "RatioTarget", "DesignTargets",
           "parse_target", "parse_targets"]

PROPERTY_NAMES = ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa", "yield_strain")
"""The properties a design can target (columns of the bilinear fit)."""
SYMBOLS = {"E": "modulus_MPa", "sigma_y": "yield_stress_MPa", "H": "post_yield_modulus_MPa", "eps_y": "yield_strain"}
"""Short names accepted for the properties."""
DEFAULT_TOLERANCE = 0.05
"""Relative tolerance of a target when none is given (5 %)."""


def _property(name: str) -> str:
    name = SYMBOLS.get(name, name)
    if name not in PROPERTY_NAMES:
        raise ConfigError(f"target: unknown property {name!r}; one of {', '.join(PROPERTY_NAMES)} "
                          f"or {', '.join(SYMBOLS)}")
    return name


def _check_number(what: str, value: float, low: float, high: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and low < value < high):
        raise ConfigError(f"{what}: must be in ({low:g}, {high:g}) (got {value:g})")
    return value


def _direction(value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and -180.0 <= value <= 180.0):
        raise ConfigError(f"target direction: an angle in degrees in [-180, 180] (got {value:g})")
    return value


@dataclass(frozen=True)
class PropertyTarget:
    """One property in one loading direction.

    Attributes
    ----------
    name : str
        A property of :data:`PROPERTY_NAMES` (its unit in its name; the yield strain is a
        fraction).
    value : float
        The target value (> 0).
    tolerance : float
        Relative tolerance (0.05: within 5 %).
    direction_deg : float [deg]
        Loading direction of the tensile test (0: along x, 90: across).
    """

    name: str
    value: float
    tolerance: float = DEFAULT_TOLERANCE
    direction_deg: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", _property(self.name))
        object.__setattr__(self, "value", _check_number(f"target {self.name}", self.value, 0.0, math.inf))
        object.__setattr__(self, "tolerance", _check_number(f"target {self.name} tolerance", self.tolerance, 0.0, 1.0))
        object.__setattr__(self, "direction_deg", _direction(self.direction_deg))

    @property
    def label(self) -> str:
        """``modulus_MPa@0`` style label."""
        return f"{self.name}@{self.direction_deg:g}"

    def achieved(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """The property achieved, from (name, direction) -> values (any shape)."""
        return np.asarray(properties[(self.name, self.direction_deg)], dtype=float)


@dataclass(frozen=True)
class RatioTarget:
    """A property in one direction over the same property in another (anisotropy).

    Attributes
    ----------
    name : str
        A property of :data:`PROPERTY_NAMES`.
    value : float
        Target of property(direction_deg) / property(over_direction_deg).
    tolerance : float
        Relative tolerance of the ratio.
    direction_deg, over_direction_deg : float [deg]
        The two loading directions.
    """

    name: str
    value: float
    tolerance: float = DEFAULT_TOLERANCE
    direction_deg: float = 0.0
    over_direction_deg: float = 90.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", _property(self.name))
        object.__setattr__(self, "value", _check_number(f"ratio target {self.name}", self.value, 0.0, math.inf))
        object.__setattr__(self, "tolerance",
                           _check_number(f"ratio target {self.name} tolerance", self.tolerance, 0.0, 1.0))
        object.__setattr__(self, "direction_deg", _direction(self.direction_deg))
        object.__setattr__(self, "over_direction_deg", _direction(self.over_direction_deg))
        if self.direction_deg == self.over_direction_deg:
            raise ConfigError(f"ratio target {self.name}: the two directions must differ "
                              f"(got {self.direction_deg:g} twice)")

    @property
    def label(self) -> str:
        """``modulus_MPa@0/modulus_MPa@90`` style label."""
        return f"{self.name}@{self.direction_deg:g}/{self.name}@{self.over_direction_deg:g}"

    def achieved(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """The ratio achieved, from (name, direction) -> values (any shape)."""
        return (np.asarray(properties[(self.name, self.direction_deg)], dtype=float)
                / np.asarray(properties[(self.name, self.over_direction_deg)], dtype=float))


Target = PropertyTarget | RatioTarget


@dataclass(frozen=True)
class DesignTargets:
    """The targets of one design run.

    Attributes
    ----------
    targets : tuple of PropertyTarget and RatioTarget
        At least one; no two with the same label.
    """

    targets: tuple[Target, ...]

    def __post_init__(self) -> None:
        if not self.targets:
            raise ConfigError("targets: give at least one target property")
        labels = [t.label for t in self.targets]
        if len(set(labels)) != len(labels):
            raise ConfigError(f"targets: each property and direction once (got {', '.join(labels)})")

    @property
    def directions(self) -> tuple[float, ...]:
        """The loading directions the targets need [deg], sorted."""
        out = set()
        for t in self.targets:
            out.add(t.direction_deg)
            if isinstance(t, RatioTarget):
                out.add(t.over_direction_deg)
        return tuple(sorted(out))

    @property
    def outputs(self) -> tuple[tuple[str, float], ...]:
        """The (property, direction) pairs the targets read, in a fixed order."""
        pairs = set()
        for t in self.targets:
            pairs.add((t.name, t.direction_deg))
            if isinstance(t, RatioTarget):
                pairs.add((t.name, t.over_direction_deg))
        return tuple(sorted(pairs, key=lambda p: (PROPERTY_NAMES.index(p[0]), p[1])))

    def errors(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """Normalized errors (achieved - target) / (tolerance target), last axis one per target."""
        return np.stack([(t.achieved(properties) - t.value) / (t.tolerance * t.value) for t in self.targets],
                        axis=-1)

    def objective(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """Mean squared normalized error (<= 1 for every target within its tolerance alone)."""
        return np.mean(self.errors(properties) ** 2, axis=-1)


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_SIDE = rf"(?P<{{p}}name>[A-Za-z_]+)(?:@(?P<{{p}}dir>{_NUMBER}))?"
_TARGET = re.compile(
    rf"^\s*{_SIDE.format(p='a')}\s*(?:/\s*{_SIDE.format(p='b')}\s*)?=\s*(?P<value>{_NUMBER})\s*"
    rf"(?:(?:\+-|±|\+/-)\s*(?P<tol>{_NUMBER})\s*%)?\s*$")


def parse_target(text: str) -> Target:
    """One target from its command-line form (module docstring).

    Raises
    ------
    ConfigError
        Naming the text and the form expected.
    """
    match = _TARGET.match(text)
    if match is None:
        raise ConfigError(f"target {text!r}: write NAME[@DIR]=VALUE[+-TOL%] (E=200, sigma_y@90=4+-3%) or "
                          "NAME@DIR/NAME@DIR=VALUE (E@0/E@90=3)")
    tolerance = DEFAULT_TOLERANCE if match["tol"] is None else float(match["tol"]) / 100.0
    value = float(match["value"])
    if match["bname"] is None:
        return PropertyTarget(match["aname"], value, tolerance, float(match["adir"] or 0.0))
    a, b = _property(match["aname"]), _property(match["bname"])
    if a != b:
        raise ConfigError(f"target {text!r}: a ratio compares one property in two directions (got {a} and {b})")
    if match["adir"] is None or match["bdir"] is None:
        raise ConfigError(f"target {text!r}: give both directions of a ratio, e.g. E@0/E@90=3")
    return RatioTarget(a, value, tolerance, float(match["adir"]), float(match["bdir"]))


def parse_targets(targets: Iterable[str | Target] | Mapping[str, float] | DesignTargets) -> DesignTargets:
    """Targets from command-line strings, target objects, or a mapping NAME -> value.

    Parameters
    ----------
    targets
        ``["E=200", "E@0/E@90=3"]``, ``{"modulus_MPa": 200, "yield_stress_MPa": 6}``, or
        :class:`PropertyTarget` / :class:`RatioTarget` objects.
    """
    if isinstance(targets, DesignTargets):
        return targets
    if isinstance(targets, Mapping):
        items: Sequence[str | Target] = [f"{name}={value:.17g}" for name, value in targets.items()]
    else:
        items = list(targets)
    return DesignTargets(tuple(parse_target(t) if isinstance(t, str) else t for t in items))
