"""What a design must achieve: target properties, in one or more loading directions, and ratios.

A target is a property of the bilinear fit of the tensile curve (modulus, yield stress,
post-yield modulus, yield strain; :mod:`espin.analysis.properties`) in a loading direction,
with a relative tolerance; a ratio target compares one property in two directions (an
anisotropy E_0 / E_90 = 3). A curve target compares a whole stress-strain curve at a few strains (relative RMS
deviation). A design meets its targets when every normalized error

    e = (achieved - target) / (tolerance * target)   (a curve: RMS deviation / tolerance)

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
from numpy.typing import ArrayLike

from espin.core.errors import ConfigError

__all__ = [
    "PROPERTY_NAMES",
    "SYMBOLS",
    "DEFAULT_TOLERANCE",
    "STRESS_AT",
    "PropertyTarget",
    "RatioTarget",
    "CurveTarget",
    "DesignTargets",
    "parse_target",
    "parse_targets",
]

PROPERTY_NAMES = ("modulus_MPa", "yield_stress_MPa", "post_yield_modulus_MPa", "yield_strain")
"""The properties a design can target (columns of the bilinear fit)."""
SYMBOLS = {"E": "modulus_MPa", "sigma_y": "yield_stress_MPa", "H": "post_yield_modulus_MPa", "eps_y": "yield_strain"}
"""Short names accepted for the properties."""
DEFAULT_TOLERANCE = 0.05
"""Relative tolerance of a target when none is given (5 %)."""


def _property(name: str) -> str:
    name = SYMBOLS.get(name, name)
    if name not in PROPERTY_NAMES:
        raise ConfigError(
            f"target: unknown property {name!r}; one of {', '.join(PROPERTY_NAMES)} or {', '.join(SYMBOLS)}"
        )
    return name


def _check_number(what: str, value: float, low: float, high: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and low < value < high):
        raise ConfigError(f"{what}: must be in ({low:g}, {high:g}) (got {value:g})")
    return value


def _direction(value: float) -> float:
    """A loading direction in [0, 180) deg: a planar mat pulled at theta and theta + 180 (or
    -theta + 180) is the same test."""
    value = float(value)
    if not (math.isfinite(value) and -180.0 <= value <= 180.0):
        raise ConfigError(f"target direction: an angle in degrees in [-180, 180] (got {value:g})")
    return value % 180.0


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

    @property
    def outputs(self) -> tuple[tuple[str, float], ...]:
        """The (property, direction) it reads."""
        return ((self.name, self.direction_deg),)

    def achieved(self, properties: Mapping[tuple[str, float], ArrayLike]) -> np.ndarray:
        """The property achieved, from (name, direction) -> values (any shape)."""
        return np.asarray(properties[(self.name, self.direction_deg)], dtype=float)

    def error(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """Normalized error (achieved - target) / (tolerance target)."""
        return (self.achieved(properties) - self.value) / (self.tolerance * self.value)

    def meets(self, achieved: float) -> bool:
        """Whether an achieved value is within the tolerance."""
        return bool(abs(achieved - self.value) <= self.tolerance * self.value)


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
        object.__setattr__(
            self, "tolerance", _check_number(f"ratio target {self.name} tolerance", self.tolerance, 0.0, 1.0)
        )
        object.__setattr__(self, "direction_deg", _direction(self.direction_deg))
        object.__setattr__(self, "over_direction_deg", _direction(self.over_direction_deg))
        if self.direction_deg == self.over_direction_deg:
            raise ConfigError(
                f"ratio target {self.name}: the two directions must differ (got {self.direction_deg:g} twice)"
            )

    @property
    def label(self) -> str:
        """``modulus_MPa@0/modulus_MPa@90`` style label."""
        return f"{self.name}@{self.direction_deg:g}/{self.name}@{self.over_direction_deg:g}"

    @property
    def outputs(self) -> tuple[tuple[str, float], ...]:
        """The (property, direction) pairs it reads."""
        return ((self.name, self.direction_deg), (self.name, self.over_direction_deg))

    def achieved(self, properties: Mapping[tuple[str, float], ArrayLike]) -> np.ndarray:
        """The ratio achieved, from (name, direction) -> values (any shape)."""
        return np.asarray(properties[(self.name, self.direction_deg)], dtype=float) / np.asarray(
            properties[(self.name, self.over_direction_deg)], dtype=float
        )

    def error(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """Normalized error (achieved - target) / (tolerance target)."""
        return (self.achieved(properties) - self.value) / (self.tolerance * self.value)

    def meets(self, achieved: float) -> bool:
        """Whether an achieved value is within the tolerance."""
        return bool(abs(achieved - self.value) <= self.tolerance * self.value)


STRESS_AT = "stress_at_"
"""Prefix of the outputs of a curve target: the stress [MPa] at a strain (``stress_at_0.05``)."""


@dataclass(frozen=True)
class CurveTarget:
    """A whole stress-strain curve in one loading direction, compared at ``points`` strains.

    The curve's error is the root mean square of the stress differences at its strains over
    the largest target stress there; it is met when that relative RMS deviation is at most
    ``tolerance``. Each strain's stress is an output the search models.

    Attributes
    ----------
    strain : tuple of float
        The compared strains (> 0, increasing).
    stress_MPa : tuple of float [MPa]
        The target stress at each (> 0).
    tolerance : float
        Largest RMS deviation as a fraction of the largest target stress (0.05: 5 %).
    direction_deg : float [deg]
        Loading direction.
    source : str
        Where the curve came from.
    """

    strain: tuple[float, ...]
    stress_MPa: tuple[float, ...]
    tolerance: float = DEFAULT_TOLERANCE
    direction_deg: float = 0.0
    source: str = "curve"

    def __post_init__(self) -> None:
        strain, stress = np.asarray(self.strain, dtype=float), np.asarray(self.stress_MPa, dtype=float)
        if strain.ndim != 1 or strain.shape != stress.shape or len(strain) < 3:
            raise ConfigError(f"curve target {self.source}: at least 3 (strain, stress) points of equal count")
        if not (np.all(np.isfinite(strain)) and np.all(strain > 0) and np.all(np.diff(strain) > 0)):
            raise ConfigError(f"curve target {self.source}: strains must be positive and increasing")
        if not (np.all(np.isfinite(stress)) and np.all(stress > 0)):
            raise ConfigError(
                f"curve target {self.source}: stresses must be positive at the compared strains "
                "(leave out the toe's zero stresses with a strain range)"
            )
        object.__setattr__(self, "strain", tuple(map(float, strain)))
        object.__setattr__(self, "stress_MPa", tuple(map(float, stress)))
        object.__setattr__(
            self, "tolerance", _check_number(f"curve target {self.source} tolerance", self.tolerance, 0.0, 1.0)
        )
        object.__setattr__(self, "direction_deg", _direction(self.direction_deg))

    @classmethod
    def from_curve(
        cls,
        strain: ArrayLike,
        stress_MPa: ArrayLike,
        *,
        points: int = 12,
        strain_range: tuple[float, float] | None = None,
        tolerance: float = DEFAULT_TOLERANCE,
        direction_deg: float = 0.0,
        source: str = "curve",
    ) -> CurveTarget:
        """A target from a measured or wanted curve, interpolated at ``points`` evenly spaced
        strains over ``strain_range`` (default: from a ``points``-th of the last strain to it)."""
        x, y = np.asarray(strain, dtype=float), np.asarray(stress_MPa, dtype=float)
        if int(points) != points or points < 3:
            raise ConfigError(f"curve target {source}: points must be an integer >= 3 (got {points})")
        high = float(x.max())
        low, high = strain_range if strain_range is not None else (high / points, high)
        if not (0.0 < low < high <= x.max() + 1e-12):
            raise ConfigError(
                f"curve target {source}: strain range {low:g}:{high:g} must lie in (0, "
                f"{x.max():g}], the curve's strains"
            )
        grid = np.linspace(low, high, int(points))
        return cls(tuple(grid), tuple(np.interp(grid, x, y)), tolerance, direction_deg, source)

    @property
    def name(self) -> str:
        """``curve``."""
        return "curve"

    @property
    def value(self) -> float:
        """The target of the achieved RMS deviation: 0."""
        return 0.0

    @property
    def label(self) -> str:
        """``curve@0`` style label."""
        return f"curve@{self.direction_deg:g}"

    @property
    def outputs(self) -> tuple[tuple[str, float], ...]:
        """One (stress at strain, direction) output per compared strain."""
        return tuple((f"{STRESS_AT}{e:.6g}", self.direction_deg) for e in self.strain)

    def achieved(self, properties: Mapping[tuple[str, float], ArrayLike]) -> np.ndarray:
        """RMS stress deviation over the largest target stress (relative, any shape)."""
        target = np.asarray(self.stress_MPa)
        model = np.stack([np.asarray(properties[o], dtype=float) for o in self.outputs], axis=-1)
        return np.sqrt(np.mean((model - target) ** 2, axis=-1)) / target.max()

    def error(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """The achieved relative RMS deviation over the tolerance."""
        return self.achieved(properties) / self.tolerance

    def meets(self, achieved: float) -> bool:
        """Whether an achieved relative RMS deviation is within the tolerance."""
        return bool(achieved <= self.tolerance)


Target = PropertyTarget | RatioTarget | CurveTarget


@dataclass(frozen=True)
class DesignTargets:
    """The targets of one design run.

    Attributes
    ----------
    targets : tuple of PropertyTarget, RatioTarget and CurveTarget
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
        return tuple(sorted({d for t in self.targets for _, d in t.outputs}))

    @property
    def outputs(self) -> tuple[tuple[str, float], ...]:
        """The (output, direction) pairs the targets read, each once, in the targets' order."""
        return tuple(dict.fromkeys(o for t in self.targets for o in t.outputs))

    def errors(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """Normalized errors (1: at the tolerance), last axis one per target."""
        return np.stack([t.error(properties) for t in self.targets], axis=-1)

    def objective(self, properties: Mapping[tuple[str, float], np.ndarray]) -> np.ndarray:
        """Mean squared normalized error (<= 1 for every target within its tolerance alone)."""
        return np.mean(self.errors(properties) ** 2, axis=-1)


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_SIDE = rf"(?P<{{p}}name>[A-Za-z_]+)(?:@(?P<{{p}}dir>{_NUMBER}))?"
_TARGET = re.compile(
    rf"^\s*{_SIDE.format(p='a')}\s*(?:/\s*{_SIDE.format(p='b')}\s*)?=\s*(?P<value>{_NUMBER})\s*"
    rf"(?:(?:\+-|±|\+/-)\s*(?P<tol>{_NUMBER})\s*%)?\s*$"
)


def parse_target(text: str) -> Target:
    """One target from its command-line form (module docstring).

    Raises
    ------
    ConfigError
        Naming the text and the form expected.
    """
    match = _TARGET.match(text)
    if match is None:
        raise ConfigError(
            f"target {text!r}: write NAME[@DIR]=VALUE[+-TOL%] (E=200, sigma_y@90=4+-3%) or "
            "NAME@DIR/NAME@DIR=VALUE (E@0/E@90=3)"
        )
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
        :class:`PropertyTarget` / :class:`RatioTarget` / :class:`CurveTarget` objects.
    """
    if isinstance(targets, DesignTargets):
        return targets
    if isinstance(targets, Mapping):
        items: Sequence[str | Target] = [f"{name}={value:.17g}" for name, value in targets.items()]
    else:
        items = list(targets)
    return DesignTargets(tuple(parse_target(t) if isinstance(t, str) else t for t in items))
