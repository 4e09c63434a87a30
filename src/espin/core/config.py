"""The run configuration: one validated model for every section of a run.

A run is described by one TOML file (or a preset name such as ``plla``) with the sections
``rve``, ``fiber``, ``loading``, ``solver`` and ``output``, and optionally ``targets``
(statistics measured on SEM images that the generated mat is graded against). Every key that
carries a unit names it (``diameter_um``, ``strain_rate_per_s``); angles are degrees here and
radians inside the code. Unknown keys and out-of-range values raise :class:`ConfigError`, which names the key and
the allowed range, before any work starts.

Units inside espin: length um, stress MPa, force uN (= MPa um^2), time s, angles rad.
"""

from __future__ import annotations

import copy
import hashlib
import math
import re
import tomllib
from collections.abc import Iterator, Mapping
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal, cast

import tomli_w
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    model_validator,
)

from espin.core.errors import ConfigError, InputError

__all__ = [
    "dotted_overrides",
    "Config",
    "RVEConfig",
    "FiberConfig",
    "LoadingConfig",
    "SolverConfig",
    "OutputConfig",
    "TargetsConfig",
    "StressLateral",
    "VonMises",
    "Histogram",
    "LoadSegment",
    "HoldSegment",
    "PRESETS",
    "load_config",
    "config_from_dict",
    "config_to_toml",
    "write_config",
    "apply_overrides",
    "config_digest",
    "referenced_files",
]

PRESETS = ("plla", "plla-bonded")


MAX_SEED = 2**63 - 1
"""Largest seed: seeds are stored as 64-bit signed integers in the HDF5 files."""
MAX_MODULUS_MPA = 1e6
"""Largest fiber modulus or flow resistance [MPa] (1 TPa, the order of carbon nanotubes)."""
MAX_RATE_PER_S = 1e3
"""Largest strain rate [1/s] (impact testing; electrospun mats are tested near 1e-3 1/s)."""
MAX_HOLD_S = 1e9
"""Longest hold [s] (about 30 years)."""
MAX_CONFIG_BYTES = 2**20
"""Largest config file read [bytes]; a run's config is a few kB."""


class _Section(BaseModel):
    """Base of every section: unknown keys are errors, values are validated on assignment.

    Values are taken as they are typed, not coerced (strict): ``true`` is not the integer 1,
    ``"0.45"`` is not a number, ``5.0`` is not a count of layers; and every number must be
    finite (no ``inf`` or ``nan``).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, strict=True, allow_inf_nan=False)


# --------------------------------------------------------------------------------------------
# rve
# --------------------------------------------------------------------------------------------
class VonMisesParams(_Section):
    mean_deg: Annotated[float, Field(ge=0.0, lt=180.0)] = 0.0
    """Mean fiber axis [deg], in [0, 180)."""
    kappa: Annotated[float, Field(ge=0.0, le=700.0)] = 1.0
    """Concentration of p(theta) ~ exp(kappa cos 2(theta - mean)), in [0, 700]."""


class VonMises(_Section):
    """Axial von Mises orientation distribution ``{von_mises = {mean_deg, kappa}}``."""

    von_mises: VonMisesParams


class HistogramParams(_Section):
    edges_deg: list[float]
    """Bin edges [deg], strictly increasing, within [0, 180]."""
    weights: list[Annotated[float, Field(ge=0.0)]]
    """Relative weight of each bin (>= 0, not all zero); len(weights) = len(edges_deg) - 1."""

    @model_validator(mode="after")
    def _check(self) -> HistogramParams:
        e = self.edges_deg
        if len(e) < 2 or any(b <= a for a, b in zip(e, e[1:])) or e[0] < 0 or e[-1] > 180:
            raise ValueError("edges_deg must be strictly increasing within [0, 180], at least 2")
        if len(self.weights) != len(e) - 1:
            raise ValueError("weights must have len(edges_deg) - 1 entries")
        if sum(self.weights) <= 0:
            raise ValueError("weights must not all be zero")
        return self


class Histogram(_Section):
    """User orientation histogram ``{histogram = {edges_deg, weights}}`` over [0, 180) deg."""

    histogram: HistogramParams


def _tagged_union(key: str, choices: dict[str, str], description: str) -> tuple[Any, Any]:
    """A union routed by shape: a plain string, or a one-key table naming the variant.

    Returns the discriminator and a before-validator that rejects any other shape with one
    clear message listing the allowed forms (instead of one error per union member).
    """

    def tag(value: Any) -> str | None:
        if isinstance(value, str):
            return "plain"
        if isinstance(value, dict) and len(value) == 1:
            return choices.get(next(iter(value)))
        if isinstance(value, BaseModel):
            return type(value).__name__
        return None

    def check(value: Any) -> Any:
        if tag(value) is None:
            raise ValueError(f"{key} must be {description}")
        return value

    return Discriminator(tag), BeforeValidator(check)


_orientation_tag, _orientation_check = _tagged_union(
    "rve.orientation",
    {"von_mises": "VonMises", "histogram": "Histogram"},
    '"uniform", {von_mises = {mean_deg, kappa}} or {histogram = {edges_deg, weights}}',
)
Orientation = Annotated[
    Annotated[Literal["uniform"], Tag("plain")]
    | Annotated[VonMises, Tag("VonMises")]
    | Annotated[Histogram, Tag("Histogram")],
    _orientation_tag,
    _orientation_check,
]


WALK_DEFAULTS: dict[str, dict[str, float]] = {
    "paper": {"max_deviation_deg": 5.0},
    "smooth": {"waviness_deg": 10.0, "waviness_length_ratio": 20.0},
}
"""Default keys of each deposition walk (``rve.walk``); a walk's keys are refused with the
other walk."""


class RVEConfig(_Section):
    """Geometry of the virtual mat (paper Table 2, docs/model.md sections 0-2)."""

    diameter_um: Annotated[float, Field(ge=1e-3, le=1000.0)] = 0.45
    """Mean fiber diameter D [um], in [0.001, 1000]. Also the layer thickness."""
    diameter_sd_um: Annotated[float, Field(ge=0.0)] = 0.0
    """Standard deviation of the diameter distribution [um], in [0, diameter_um] (a
    coefficient of variation up to 1; measured mats: 0.1-0.6)."""
    diameter_distribution: Literal["normal", "lognormal"] = "normal"
    """Family of the fiber diameters: "normal" (the paper: a normal of mean diameter_um and
    sd diameter_sd_um, truncated below at diameter_min_um) or "lognormal" (mean diameter_um
    and sd diameter_sd_um, truncated below at diameter_min_um; how SEM diameters of
    electrospun mats are usually reported)."""
    diameter_min_um: Annotated[float, Field(gt=0.0)] | None = None
    """Truncation of the diameter distribution [um], > 0 and < diameter_um; default 0.1 D."""
    volume_fraction: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.19
    """Target volume fraction eta of each layer, in (0, 1)."""
    size_ratio: Annotated[float, Field(gt=0.0, le=1e5)] | None = None
    """Layer side over D (L_tilde), > segment_ratio and <= 1e5. Give this or size_um (default
    200)."""
    size_um: Annotated[float, Field(gt=0.0, le=1e6)] | None = None
    """Layer side L [um], <= 1e6 (1 m); alternative to size_ratio."""
    segment_ratio: Annotated[float, Field(gt=0.0)] | None = None
    """Segment length over D (ls_tilde), > 0. Give this or segment_um (default 5)."""
    segment_um: Annotated[float, Field(gt=0.0)] | None = None
    """Segment length l_s [um]; alternative to segment_ratio."""
    walk: Literal["paper", "smooth"] = "paper"
    """How a fiber's direction changes along it (docs/model.md section 1): "paper" (each
    segment turned from the previous one by a uniform angle up to max_deviation_deg, so the
    direction drifts without bound) or "smooth" (the direction meanders around the fiber's
    own mean axis: a deviation of rms waviness_deg, correlated over waviness_length_ratio D)."""
    max_deviation_deg: Annotated[float, Field(ge=0.0, lt=90.0)] | None = None
    """Largest turn between consecutive segments [deg], in [0, 90); walk = "paper" only
    (default 5)."""
    waviness_deg: Annotated[float, Field(ge=0.0, le=45.0)] | None = None
    """Root-mean-square deviation of a fiber's direction from its mean axis [deg], in
    [0, 45]; walk = "smooth" only (default 10)."""
    waviness_length_ratio: Annotated[float, Field(gt=0.0, le=1e4)] | None = None
    """Correlation length of that deviation over D, in (0, 1e4]: the arc length over which the
    direction forgets its deviation; walk = "smooth" only (default 20)."""
    layers: Annotated[int, Field(ge=1, le=1000)] = 15
    """Number of layers N_l, in [1, 1000]."""
    orientation: Orientation = "uniform"
    """Fiber axis distribution: "uniform", {von_mises = {...}} or {histogram = {...}}."""
    seeding: Literal["border", "lines"] | None = None
    """"border" (paper) or "lines" (stationary); default: border if uniform, else lines."""
    sampling: Literal["random", "balanced"] = "random"
    """How the fibers are drawn (docs/geometry.md): "random" (the paper: each fiber's axis,
    start and diameter independent) or "balanced" (the same law for each fiber, but the RVE's
    fibers take consecutive points of a scrambled Sobol' sequence, the layers are filled
    together, and of each walk's variants of equal law (turns negated in part; smooth walk:
    its mirror image) the one that balances the orientation content is kept; plla: 8 times
    less scatter of modulus and yield stress across realizations)."""
    merge_tolerance_ratio: Annotated[float, Field(gt=0.0, le=0.1)] = 0.1
    """Node candidates closer than this times D along a fiber are merged into one node, in
    (0, 0.1]. Default 0.1 (docs/model.md section 2): shorter elements between close
    cross-links stall Newton on wavy mats, in shear and on unloading, while from 1e-3 to 0.1
    the plla curve moves by < 0.01 % (docs/geometry.md)."""
    seed: Annotated[int, Field(ge=0, le=MAX_SEED)] = 1
    """Random seed, an integer in [0, 2^63 - 1]."""

    @model_validator(mode="after")
    def _resolve(self) -> RVEConfig:
        if self.size_ratio is not None and self.size_um is not None:
            raise ValueError("give rve.size_ratio or rve.size_um, not both")
        if self.segment_ratio is not None and self.segment_um is not None:
            raise ValueError("give rve.segment_ratio or rve.segment_um, not both")
        updates: dict[str, Any] = {}
        if self.size_ratio is None and self.size_um is None:
            updates["size_ratio"] = 200.0
        if self.segment_ratio is None and self.segment_um is None:
            updates["segment_ratio"] = 5.0
        if self.diameter_min_um is None:
            updates["diameter_min_um"] = round(0.1 * self.diameter_um, 12)
        if self.seeding is None:
            updates["seeding"] = "border" if self.orientation == "uniform" else "lines"
        other_walk = {"paper": ("waviness_deg", "waviness_length_ratio"), "smooth": ("max_deviation_deg",)}[self.walk]
        wrong = [key for key in other_walk if getattr(self, key) is not None]
        if wrong:
            raise ValueError(
                f"rve.{wrong[0]} does not apply to rve.walk = {self.walk!r}: "
                + (
                    "max_deviation_deg is the paper walk's key"
                    if self.walk == "smooth"
                    else "waviness_deg and waviness_length_ratio are the smooth walk's keys"
                )
            )
        updates |= {key: value for key, value in WALK_DEFAULTS[self.walk].items() if getattr(self, key) is None}
        for key, value in updates.items():
            object.__setattr__(self, key, value)
        if self.diameter_sd_um > self.diameter_um:
            raise ValueError(
                f"rve.diameter_sd_um must be in [0, rve.diameter_um = {self.diameter_um:g}] "
                "(a coefficient of variation up to 1)"
            )
        if cast(float, self.diameter_min_um) >= self.diameter_um:  # set above when not given
            raise ValueError(f"rve.diameter_min_um must be > 0 and < rve.diameter_um = {self.diameter_um}")
        if self.side_um <= self.segment_length_um:
            raise ValueError(
                "the layer side must exceed the segment length: rve.size_ratio (or size_um) "
                f"must be > rve.segment_ratio; got side {self.side_um:g} um, "
                f"segment {self.segment_length_um:g} um"
            )
        return self

    @property
    def side_um(self) -> float:
        """Layer side L [um]."""
        # The validator gives size_ratio its default when neither is given.
        return self.size_um if self.size_um is not None else cast(float, self.size_ratio) * self.diameter_um

    @property
    def segment_length_um(self) -> float:
        """Segment length l_s [um]."""
        if self.segment_um is not None:
            return self.segment_um
        return cast(float, self.segment_ratio) * self.diameter_um  # its default when neither is given

    @property
    def merge_tolerance_um(self) -> float:
        """Distance below which cross-links are merged [um]."""
        return self.merge_tolerance_ratio * self.diameter_um


# --------------------------------------------------------------------------------------------
# fiber
# --------------------------------------------------------------------------------------------
class FiberConfig(_Section):
    """Fiber constitutive law (paper Eq. 4-5, Table 3, docs/model.md section 3)."""

    taut_modulus_MPa: Annotated[float, Field(gt=0.0, le=MAX_MODULUS_MPA)] = 3000.0
    """Modulus of a straight (recruited) fiber E_t [MPa], > slack_modulus_MPa and <= 1e6."""
    slack_modulus_MPa: Annotated[float, Field(gt=0.0, le=MAX_MODULUS_MPA)] = 3.0
    """Modulus of a wrinkled fiber, and in compression, E_b [MPa], in (0, 1e6]."""
    flow_rate_per_s: Annotated[float, Field(ge=0.0, le=MAX_RATE_PER_S)] = 1e-8
    """Plastic flow rate coefficient a_p [1/s], in [0, 1e3] (0 = elastic)."""
    flow_resistance_MPa: Annotated[float, Field(ge=1e-6, le=MAX_MODULUS_MPA)] = 5.0
    """Initial resistance to flow b_p [MPa], in [1e-6, 1e6]."""
    hardening_exponent: Annotated[float, Field(ge=0.0, le=100.0)] = 0.5
    """Post-yield hardening exponent c_p, in [0, 100]."""
    bending_modulus_MPa: Annotated[float, Field(ge=0.0, le=MAX_MODULUS_MPA)] = 0.0
    """Modulus E of an opt-in bending stiffness E I (I = pi D^4 / 64) of each fiber across its
    nodes [MPa], in [0, 1e6]; 0 (default): no bending, the paper's model. The physical value
    is the fiber's Young's modulus (E_t); it makes compression-dominated states (lateral
    ``free``, large prescribed contraction) solvable (docs/model.md section 3)."""
    fused_crossing_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    """Fraction phi of fused (bonded) crossings, in [0, 1]; 0 (default): every crossing a pin,
    the paper's model. A fused crossing resists the relative rotation of its fibers with
    springs E I / lbar, E = ``bending_modulus_MPa`` (required > 0 with phi > 0): the mat gains
    lateral stiffness (docs/model.md section 3)."""
    fused_crossing_stiffness_ratio: Annotated[float, Field(gt=0.0, le=1e4)] = 1.0
    """Rotational stiffness c of a fused crossing relative to a fiber joint of the same two
    elements (springs c E I / lbar), in (0, 1e4]; 1 (default): the weld as compliant as the
    fiber bent over one element, larger: a stiffer weld (docs/model.md section 3)."""
    compression_limit: Annotated[float, Field(ge=0.0, le=0.9)] = 0.0
    """Compression limit lambda_c of the fiber segments, in [0, 0.9]; 0 (default): none, the
    paper's model. An element compressed below lambda_c times its deposited chord meets a
    contact force A E_t (1 - lambda_c / lambda) that grows without bound as it shortens
    (docs/model.md section 3); 0.5 keeps fused-crossing mats under lateral ``free`` solvable."""

    @model_validator(mode="after")
    def _check(self) -> FiberConfig:
        if self.taut_modulus_MPa <= self.slack_modulus_MPa:
            raise ValueError(f"fiber.taut_modulus_MPa must be > fiber.slack_modulus_MPa (= {self.slack_modulus_MPa:g})")
        if self.fused_crossing_fraction > 0 and self.bending_modulus_MPa == 0:
            raise ValueError(
                "fiber.fused_crossing_fraction > 0 needs fiber.bending_modulus_MPa > 0 (the fibers' "
                "Young's modulus E of the bond stiffness E I / lbar; plla: the taut modulus, 3000)"
            )
        return self


# --------------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------------
class LoadSegment(_Section):
    """Drive the load parameter to ``to_strain`` at ``rate_per_s`` in ``steps`` steps."""

    to_strain: Annotated[float, Field(gt=-1.0, le=10.0)]
    """Target strain (engineering for uniaxial, lambda - 1 for biaxial / pure shear,
    gamma for simple shear), in (-1, 10]."""
    rate_per_s: Annotated[float, Field(gt=0.0, le=MAX_RATE_PER_S)] = 5e-3
    """Magnitude of the strain rate [1/s], in (0, 1e3]."""
    steps: Annotated[int, Field(ge=1, le=100000)] | None = None
    """Number of load steps, in [1, 100000]; default 1 per percent of strain (at least 1)."""


class HoldSegment(_Section):
    """Hold the deformation for ``hold_s`` seconds (relaxation) in ``steps`` steps."""

    hold_s: Annotated[float, Field(gt=0.0, le=MAX_HOLD_S)]
    """Hold time [s], in (0, 1e9]."""
    steps: Annotated[int, Field(ge=1, le=100000)] = 10
    """Number of time steps, in [1, 100000]."""


def _segment_tag(value: Any) -> str:
    if isinstance(value, BaseModel):
        return type(value).__name__
    return "HoldSegment" if isinstance(value, dict) and "hold_s" in value else "LoadSegment"


Segment = Annotated[
    Annotated[LoadSegment, Tag("LoadSegment")] | Annotated[HoldSegment, Tag("HoldSegment")],
    Discriminator(_segment_tag),
]
"""A program segment: a hold if it has ``hold_s``, else a load segment."""


class PoissonLateral(_Section):
    poisson_ratio: Annotated[float, Field(ge=-1.0, le=50.0)]
    """Prescribed lateral contraction F'22 = 1 - nu * strain, nu in [-1, 50]."""


class TransverseCSVLateral(_Section):
    transverse_csv: Annotated[Path, Field(strict=False)]
    """CSV with columns axial_strain, transverse_strain (measured transverse strain)."""


class StressLateral(_Section):
    stress_MPa: Annotated[float, Field(ge=-MAX_MODULUS_MPA, le=MAX_MODULUS_MPA)]
    """Lateral stress held [MPa], in [-1e6, 1e6]: F'22 adjusts so that the lateral component
    of ``output.stress_measure`` (nominal P'22 or Kirchhoff tau'22) equals it; F'12 = 0."""


_lateral_tag, _lateral_check = _tagged_union(
    "loading.lateral",
    {"poisson_ratio": "PoissonLateral", "transverse_csv": "TransverseCSVLateral", "stress_MPa": "StressLateral"},
    '"fixed", "free", {poisson_ratio = nu}, {transverse_csv = path} or {stress_MPa = s}',
)
Lateral = Annotated[
    Annotated[Literal["fixed", "free"], Tag("plain")]
    | Annotated[PoissonLateral, Tag("PoissonLateral")]
    | Annotated[TransverseCSVLateral, Tag("TransverseCSVLateral")]
    | Annotated[StressLateral, Tag("StressLateral")],
    _lateral_tag,
    _lateral_check,
]


class LoadingConfig(_Section):
    """Macroscopic loading program (docs/model.md section 6)."""

    test: Literal["uniaxial", "equibiaxial", "pure_shear", "simple_shear", "path"] = "uniaxial"
    """Kind of test."""
    direction_deg: Annotated[float, Field(ge=0.0, lt=180.0)] = 0.0
    """Loading axis of the uniaxial test [deg] from +x, in [0, 180)."""
    lateral: Lateral = "fixed"
    """Lateral condition of the uniaxial test."""
    program: Annotated[list[Segment], Field(min_length=1)] | None = None
    """Sequence of load / unload / hold segments (at least one); default one monotonic
    segment."""
    max_strain: Annotated[float, Field(gt=-1.0, le=10.0)] = 0.30
    """Shorthand for one monotonic segment: its target strain, in (-1, 10]."""
    strain_rate_per_s: Annotated[float, Field(gt=0.0, le=MAX_RATE_PER_S)] = 5e-3
    """Shorthand: strain rate [1/s], in (0, 1e3] (plla: 6 mm/min over an assumed 20 mm gauge)."""
    steps: Annotated[int, Field(ge=1, le=100000)] = 30
    """Shorthand: number of load steps, in [1, 100000]."""
    path_csv: Annotated[Path, Field(strict=False)] | None = None
    """For test = "path": CSV with columns time_s, F11, F12, F21, F22."""

    @model_validator(mode="after")
    def _check(self) -> LoadingConfig:
        shorthand = sorted(self.model_fields_set & {"max_strain", "strain_rate_per_s", "steps"})
        if self.program is not None and shorthand:
            raise ValueError(
                f"loading.program replaces the shorthand loading.{', loading.'.join(shorthand)}: give one or the other"
            )
        if self.test != "uniaxial" and self.lateral != "fixed":
            raise ValueError(
                f'loading.lateral applies to uniaxial tests only (loading.test = "{self.test}" '
                "prescribes the whole in-plane deformation)"
            )
        if self.test == "path" and self.path_csv is None:
            raise ValueError('loading.path_csv is required when loading.test = "path"')
        if self.test != "path" and self.path_csv is not None:
            raise ValueError('loading.path_csv is only allowed with loading.test = "path"')
        return self

    @property
    def segments(self) -> list[LoadSegment | HoldSegment]:
        """The loading program, with the shorthand expanded into one segment."""
        if self.program is not None:
            return list(self.program)
        return [LoadSegment(to_strain=self.max_strain, rate_per_s=self.strain_rate_per_s, steps=self.steps)]


# --------------------------------------------------------------------------------------------
# targets
# --------------------------------------------------------------------------------------------
MAX_SAMPLE_VALUES = 100_000
"""Most values of one measured sample in ``[targets]``."""


def _sample_check(low: float, low_open: bool, high: float | None = None) -> BeforeValidator:
    """Validator of a measured sample: a list of 1 to MAX_SAMPLE_VALUES finite numbers in
    the range from ``low`` (excluded if ``low_open``) to ``high`` (excluded), with one error
    for the whole list that gives the range and the first value out of it."""
    bound = (
        f"{'>' if low_open else '>='} {low:g}" if high is None else f"in {'(' if low_open else '['}{low:g}, {high:g})"
    )

    def check(value: Any) -> Any:
        if not isinstance(value, list):
            return value  # the strict list type refuses it
        if not 1 <= len(value) <= MAX_SAMPLE_VALUES:
            raise ValueError(f"must hold 1 to {MAX_SAMPLE_VALUES:,} values, got {len(value):,}")
        for index, x in enumerate(value):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise ValueError(f"values must be numbers {bound}; value {index} is {x!r}")
        bad = [
            i
            for i, x in enumerate(value)
            if not (math.isfinite(x) and ((x > low if low_open else x >= low) and (high is None or x < high)))
        ]
        if bad:
            raise ValueError(
                f"values must be finite and {bound}; value {bad[0]} is "
                f"{value[bad[0]]!r} ({len(bad):,} of {len(value):,} out of range)"
            )
        return [float(x) for x in value]

    return BeforeValidator(check)


class TargetsConfig(_Section):
    """Statistics measured on SEM images that a generated mat is graded against.

    Each quantity is given as a measured sample (graded by the two-sample Kolmogorov-Smirnov
    statistic) or as a distribution (one-sample KS), not both; any may be left out. The mat
    is seen through its observation window (``output.window_ratio``), docs/configuration.md.
    """

    source: Annotated[str, Field(max_length=500)] | None = None
    """What the targets were measured on, for reports (at most 500 characters), e.g.
    "PLGA-1500_1.tif, espin measure"."""
    diameter_um: Annotated[list[float], _sample_check(0.0, True)] | None = None
    """Measured fiber diameters [um], one per fiber, each > 0."""
    orientation_deg: Annotated[list[float], _sample_check(0.0, False, 180.0)] | None = None
    """Measured axes of the chords of visible fiber pieces [deg] from +x, each in [0, 180)."""
    tortuosity: Annotated[list[float], _sample_check(1.0, False)] | None = None
    """Measured contour / chord length of visible fiber pieces, each >= 1."""
    contour_length_um: Annotated[list[float], _sample_check(0.0, True)] | None = None
    """Contour lengths of those same pieces [um], each > 0, one per tortuosity value: the
    mat is then measured on pieces of these lengths, as the SEM tracer cut them."""
    diameter_mean_um: Annotated[float, Field(gt=0.0)] | None = None
    """Mean of a diameter distribution [um], > 0; with diameter_sd_um, instead of
    diameter_um."""
    diameter_sd_um: Annotated[float, Field(ge=0.0)] | None = None
    """Standard deviation of that distribution [um], >= 0 (0: one fixed diameter)."""
    diameter_distribution: Literal["normal", "lognormal"] | None = None
    """Family of that distribution: "normal" or "lognormal" (of that mean and sd); default
    normal."""
    tortuosity_halfnorm_scale: Annotated[float, Field(gt=0.0)] | None = None
    """Scale of a half-normal tortuosity distribution from 1, halfnorm(loc=1, scale), > 0
    (mean 1 + 0.798 scale); instead of tortuosity."""
    window_um: Annotated[float, Field(gt=0.0)] | None = None
    """Side of the square observation window the statistics refer to [um], > 0 (the mat's
    window is output.window_ratio D; both are reported)."""
    min_chord_um: Annotated[float, Field(ge=0.0)] | None = None
    """Shortest chord of a measured piece [um], >= 0; the mat's pieces and window portions
    with a shorter chord are left out too (default a tenth of the mat's window)."""
    u_turn_fraction: Annotated[float, Field(ge=0.0, le=1.0)] | None = None
    """Of the fiber portions that cross the observation window edge to edge, the fraction
    that leave through the edge they entered, in [0, 1]."""
    straightness: Annotated[float, Field(gt=0.0, le=1.0)] | None = None
    """Of those portions, the mean end-to-end over contour length, in (0, 1]."""

    @model_validator(mode="after")
    def _check(self) -> TargetsConfig:
        law = [
            key
            for key in ("diameter_mean_um", "diameter_sd_um", "diameter_distribution")
            if getattr(self, key) is not None
        ]
        if self.diameter_um is not None and law:
            raise ValueError(f"give targets.diameter_um (a sample) or targets.{law[0]} (a distribution), not both")
        if law and (self.diameter_mean_um is None or self.diameter_sd_um is None):
            raise ValueError("a diameter distribution needs both targets.diameter_mean_um and targets.diameter_sd_um")
        if self.tortuosity is not None and self.tortuosity_halfnorm_scale is not None:
            raise ValueError(
                "give targets.tortuosity (a sample) or targets.tortuosity_halfnorm_scale (a distribution), not both"
            )
        if self.contour_length_um is not None and self.tortuosity is None:
            raise ValueError(
                "targets.contour_length_um needs targets.tortuosity (the contour "
                "lengths are those of the measured pieces)"
            )
        if (
            self.contour_length_um is not None
            and self.tortuosity is not None
            and len(self.contour_length_um) != len(self.tortuosity)
        ):
            raise ValueError(
                "targets.contour_length_um must hold one contour length per targets.tortuosity "
                f"value (the lengths of those pieces): got {len(self.contour_length_um):,} "
                f"lengths and {len(self.tortuosity):,} tortuosities"
            )
        if self.diameter_mean_um is not None and self.diameter_distribution is None:
            object.__setattr__(self, "diameter_distribution", "normal")
        return self


# --------------------------------------------------------------------------------------------
# solver, output
# --------------------------------------------------------------------------------------------
class SolverConfig(_Section):
    """Equilibrium solver (docs/model.md section 4)."""

    linear: Literal["auto", "superlu", "pardiso"] = "auto"
    """Sparse linear solver: auto (pardiso if installed, else superlu), superlu, pardiso."""
    rtol: Annotated[float, Field(gt=0.0, lt=1.0)] = 1e-6
    """Relative tolerance: max |residual| <= rtol max|T_e| + atol E_t mean(A_e), in (0, 1)."""
    atol: Annotated[float, Field(gt=0.0, lt=1.0)] = 1e-8
    """Absolute tolerance, in units of E_t mean(A_e), in (0, 1)."""
    max_iterations: Annotated[int, Field(ge=1, le=10000)] | None = None
    """Newton iterations per load step before the step is cut, in [1, 10000]. Default 200,
    or 500 under mixed control (lateral free), where buckling chains need hundreds."""
    max_cuts: Annotated[int, Field(ge=0, le=60)] = 12
    """Times a load step may be halved before the solve fails, in [0, 60]."""
    max_move_ratio: Annotated[float, Field(ge=0.0, le=1e6)] = 0.0
    """Trust region of Newton's method: the largest non-affine move of any node per iteration,
    in fiber diameters (a longer step is shortened along its direction), in [0, 1e6]; 0
    (default): none. It changes the path of the iterations, not the equilibrium they reach;
    0.5 keeps Newton from wandering through the floppy states of lateral ``free``
    (docs/model.md section 4)."""
    time_rtol: Annotated[float, Field(ge=1e-8, lt=1.0)] | Literal["off"] = 1e-3
    """Local error of the plastic update per time step, relative to the fiber stresses, in
    [1e-8, 1): load steps are split into as many time steps as it takes (docs/model.md
    section 4). "off": one time step per load step, halved only when Newton fails."""
    kinematics: Literal["equilibrium", "affine"] = "equilibrium"
    """How the cross-links move: "equilibrium" (default, the paper's model: they move until
    the fiber forces balance) or "affine" (every node at x = F X, no equilibrium solve: the
    classical affine network model, an upper bound of the stiffness; docs/model.md
    section 4)."""


class OutputConfig(_Section):
    """What is reported and written."""

    stress_measure: Literal["nominal", "paper", "kirchhoff"] = "nominal"
    """Stress on curves, plots and properties: "nominal" P, "paper" (the paper's Eq. 17 as
    printed) or "kirchhoff" (P F^T = det F times Cauchy, per reference volume: what the
    authors' code reports); all three are written (docs/model.md section 5)."""
    yield_threshold: Annotated[float, Field(gt=0.0, lt=1.0)] = 1e-3
    """An element counts as yielded when lambda_p - 1 exceeds this, in (0, 1)."""
    window_ratio: Annotated[float, Field(gt=0.0, le=1e6)] = 50.0
    """Side of the square observation window (an SEM field) over D, for the visible
    tortuosity statistic; clipped to the layer side. In (0, 1e6]."""
    figures: bool = True
    """Write PNG figures."""
    vtk: bool = True
    """Write VTK files for ParaView."""


class Config(_Section):
    """A whole run: ``rve``, ``fiber``, ``loading``, ``solver``, ``output``, and optionally
    ``targets`` (measured statistics the mat is graded against; None: none)."""

    rve: RVEConfig = RVEConfig()
    fiber: FiberConfig = FiberConfig()
    loading: LoadingConfig = LoadingConfig()
    solver: SolverConfig = SolverConfig()
    output: OutputConfig = OutputConfig()
    targets: TargetsConfig | None = None

    @model_validator(mode="after")
    def _check(self) -> Config:
        if isinstance(self.loading.lateral, StressLateral) and self.output.stress_measure == "paper":
            raise ValueError(
                "loading.lateral = {stress_MPa = ...} holds the lateral component of "
                'output.stress_measure, which must be "nominal" or "kirchhoff" (the paper\'s '
                "Eq. 17 is no stress conjugate to F, so no lateral stretch is defined by it)"
            )
        if self.solver.kinematics == "affine" and self.fiber.bending_modulus_MPa > 0.0:
            raise ValueError(
                'fiber.bending_modulus_MPa must be 0 with solver.kinematics = "affine" (bending '
                "resists the non-affine motion of the nodes, which affine kinematics leaves out)"
            )
        if self.solver.kinematics == "affine" and self.fiber.compression_limit > 0.0:
            raise ValueError(
                'fiber.compression_limit must be 0 with solver.kinematics = "affine" (it stops '
                "the non-affine collapse of short elements, which affine kinematics leaves out)"
            )
        return self

    @property
    def observation_window_um(self) -> float:
        """Side of the observation window [um] (window_ratio D, at most the layer side)."""
        return min(self.output.window_ratio * self.rve.diameter_um, self.rve.side_um)


# --------------------------------------------------------------------------------------------
# reading and writing
# --------------------------------------------------------------------------------------------
_PYDANTIC_TAG = re.compile(r"^(constrained-\w+|\w+\[.*\])$")
"""Names pydantic gives the members of a union (``constrained-float``, ``literal['off']``)."""
_UNION_TAGS = {
    "plain",
    "VonMises",
    "Histogram",
    "PoissonLateral",
    "TransverseCSVLateral",
    "LoadSegment",
    "HoldSegment",
}


def _format_validation_error(err: ValidationError, source: str) -> ConfigError:
    lines = []
    for e in err.errors(include_url=False):
        loc = ".".join(str(p) for p in e["loc"] if str(p) not in _UNION_TAGS and not _PYDANTIC_TAG.match(str(p)))
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = "unknown key"
        got = e.get("input")
        shown = "" if isinstance(got, dict) or e["type"] == "extra_forbidden" else f" (got {_shown(got)})"
        lines.append(f"{loc or '<top>'}: {msg}{shown}")
    # Unions report every alternative; keep each distinct line once.
    unique = list(dict.fromkeys(lines))
    return ConfigError(f"invalid configuration {source}:\n  " + "\n  ".join(unique))


def _shown(value: Any) -> str:
    """``value`` as an error message shows it: a long list (a measured sample) or string by
    its length."""
    if isinstance(value, list) and len(value) > 10:
        return f"a list of {len(value):,} values"
    if isinstance(value, str) and len(value) > 80:
        return f"a string of {len(value):,} characters"
    return repr(value)


def config_from_dict(data: dict[str, Any], source: str = "") -> Config:
    """Validate a nested dict (as read from TOML) into a :class:`Config`.

    Raises
    ------
    ConfigError
        Naming each offending key and its allowed range.
    """
    try:
        return Config.model_validate(_plain(data))
    except ValidationError as err:
        raise _format_validation_error(err, source) from None


def _plain(value: Any) -> Any:
    """``value`` with numpy scalars turned into the Python numbers they hold (a sweep's grid
    or an optimizer hands out ``numpy.int64`` and ``numpy.float64``), tables and lists walked."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if type(value).__module__ == "numpy" and hasattr(value, "item"):
        return value.item()
    return value


def _preset_dict(name: str) -> dict[str, Any]:
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; available presets: {', '.join(PRESETS)}")
    text = resources.files("espin.core.presets").joinpath(f"{name}.toml").read_text("utf-8")
    return tomllib.loads(text)


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        exists = path.exists()
    except OSError as err:
        raise ConfigError(f"config file {str(path)[:80]}...: {err.strerror}") from None
    if not exists:
        raise ConfigError(f"config file not found: {path}")
    if not path.is_file():
        raise ConfigError(f"config file {path} is not a regular file (a TOML file is expected)")
    size = path.stat().st_size
    if size > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"config file {path} has {size:,} bytes; a TOML config is expected, at most {MAX_CONFIG_BYTES:,} bytes"
        )
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except OSError as err:
        raise ConfigError(f"cannot read config file {path}: {err.strerror or err}") from None
    except UnicodeDecodeError as err:
        raise ConfigError(f"config file {path} is not UTF-8 text (byte {err.start}): a TOML file is expected") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"config file {path} is not valid TOML: {err}") from None
    except RecursionError:
        raise ConfigError(f"config file {path} nests arrays or tables too deeply to be a config") from None


_ALTERNATIVES = (
    ("rve", {"size_ratio"}, {"size_um"}),
    ("rve", {"segment_ratio"}, {"segment_um"}),
    ("loading", {"program"}, {"max_strain", "strain_rate_per_s", "steps"}),
    ("targets", {"diameter_um"}, {"diameter_mean_um", "diameter_sd_um", "diameter_distribution"}),
    ("targets", {"tortuosity", "contour_length_um"}, {"tortuosity_halfnorm_scale"}),
)
"""Keys that are given instead of each other: (section, one group, the other group)."""


def _drop_alternatives(data: dict[str, Any], overrides: dict[str, Any]) -> None:
    """Remove from ``data`` the keys that an override is given instead of (a resolved file
    holds ``size_ratio``; ``--set rve.size_um=...`` replaces it, as ``--set loading.program``
    replaces the shorthand ``max_strain`` / ``steps`` / ``strain_rate_per_s``, and a measured
    sample in ``targets`` replaces the distribution of the same quantity, and back)."""
    for section, one, other in _ALTERNATIVES:
        table = data.get(section)
        if not isinstance(table, dict):
            continue
        given = {d.split(".")[1] for d in overrides if d.count(".") >= 1 and d.split(".")[0] == section}
        for chosen, replaced in ((one, other), (other, one)):
            if given & chosen:
                for key in replaced - given:
                    table.pop(key, None)


def _drop_derived(data: dict[str, Any], overrides: dict[str, Any]) -> None:
    """Remove from ``data`` a value that equals the default derived from a key an override
    changes, so that it is derived again: a resolved file (``espin config plla``) holds
    ``diameter_min_um = 0.1 D`` and ``seeding = "border"`` (from ``orientation = "uniform"``),
    and ``--set rve.diameter_um`` or ``--set rve.orientation`` must act as on the preset; and
    ``--set rve.walk`` drops the keys of the other walk (``max_deviation_deg`` of the paper
    walk, ``waviness_*`` of the smooth one) unless they are set too."""
    rve = data.get("rve")
    if not isinstance(rve, dict):
        return
    given = set(overrides)
    if (
        "rve.diameter_um" in given
        and "rve.diameter_min_um" not in given
        and "diameter_um" in rve
        and rve.get("diameter_min_um") == round(0.1 * rve["diameter_um"], 12)
    ):
        rve.pop("diameter_min_um")
    walk = overrides.get("rve.walk")
    if walk in WALK_DEFAULTS:  # another walk: the keys of the old one go
        for key in {k for w, keys in WALK_DEFAULTS.items() if w != walk for k in keys}:
            if f"rve.{key}" not in given:
                rve.pop(key, None)
    changes_orientation = any(key == "rve.orientation" or key.startswith("rve.orientation.") for key in given)
    derived_seeding = "border" if rve.get("orientation", "uniform") == "uniform" else "lines"
    if changes_orientation and "rve.seeding" not in given and rve.get("seeding") == derived_seeding:
        rve.pop("seeding")


def _apply_dotted(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``data`` with each ``section.key[.sub...]`` override set along its path.

    A value replaces what is at its full path; deeper paths reach inside tables, e.g.
    ``rve.orientation.von_mises.kappa`` (a non-table on the way, such as ``"uniform"``, is
    replaced by a table); and the keys it is given instead of (``size_um`` for
    ``size_ratio``, the loading shorthand for ``program``, and back) are removed.
    """
    out = copy.deepcopy(data)
    _drop_alternatives(out, overrides)
    _drop_derived(out, overrides)
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        if len(parts) < 2 or parts[0] not in Config.model_fields or not all(parts):
            raise ConfigError(
                f"override key {dotted!r} must be section.key (or section.key.sub...) with "
                f"section one of {', '.join(Config.model_fields)}"
            )
        node = out
        for part in parts[:-1]:
            if not isinstance(node.get(part), dict):
                node[part] = {}
            node = node[part]
        node[parts[-1]] = value
    return out


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except OSError:  # e.g. a name too long for the file system
        return False


def _beside(data: dict[str, Any], folder: Path) -> dict[str, Any]:
    """``data`` with the relative table paths of its ``loading`` section made relative to
    ``folder`` (the config file's), so a config and its tables can move together."""
    loading = data.get("loading")
    if not isinstance(loading, dict):
        return data
    loading = dict(loading)
    if isinstance(loading.get("path_csv"), str) and not Path(loading["path_csv"]).is_absolute():
        loading["path_csv"] = str(folder / loading["path_csv"])
    lateral = loading.get("lateral")
    if (
        isinstance(lateral, dict)
        and isinstance(lateral.get("transverse_csv"), str)
        and not Path(lateral["transverse_csv"]).is_absolute()
    ):
        loading["lateral"] = {**lateral, "transverse_csv": str(folder / lateral["transverse_csv"])}
    return {**data, "loading": loading}


def load_config(source: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Read a run configuration from a preset name or a TOML file.

    Parameters
    ----------
    source
        A preset name (``"plla"``), a path to a TOML file, or None for the built-in
        defaults (the ``plla`` values, without its measured ``targets``).
    overrides
        Dotted keys and values applied on top, e.g. ``{"rve.layers": 5}``.

    Returns
    -------
    Config
        The validated configuration.
    """
    if source is None:
        data: dict[str, Any] = {}
        label = "(defaults)"
    elif isinstance(source, str) and source in PRESETS:
        data = _preset_dict(source)
        label = f"(preset {source})"
    else:
        path = Path(source)
        if not path.suffix and not _exists(path):
            raise ConfigError(f"{str(source)[:80]!r} is neither a preset ({', '.join(PRESETS)}) nor an existing file")
        data = _beside(_read_toml(path), path.parent)
        label = f"({path})"
    if overrides:
        data = _apply_dotted(data, overrides)
    return config_from_dict(data, label)


def dotted_overrides(keywords: Mapping[str, Any]) -> dict[str, Any]:
    """Overrides given as Python keywords, ``section__key=value`` (or ``**{"section.key": value}``),
    as the dotted keys ``section.key`` every other function of the package takes."""
    return {key.replace("__", "."): value for key, value in keywords.items()}


def apply_overrides(config: Config, overrides: dict[str, Any]) -> Config:
    """Return ``config`` with dotted-key ``overrides`` applied, validated again."""
    # Only what was given: derived values (seeding, diameter_min_um, ...) are resolved anew.
    data = _apply_dotted(config.model_dump(mode="json", exclude_none=True, exclude_unset=True), overrides)
    return config_from_dict(data, "(with overrides)")


def config_to_dict(config: Config) -> dict[str, Any]:
    """The resolved configuration as plain TOML-ready data (None values left out; the
    loading shorthand left out when a program is given)."""
    data = config.model_dump(mode="json", exclude_none=True)
    if config.loading.program is not None:
        for key in ("max_strain", "strain_rate_per_s", "steps"):
            data["loading"].pop(key)
    return data


def config_to_toml(config: Config) -> str:
    """The resolved configuration as TOML text; reading it back gives the same run."""
    return tomli_w.dumps(config_to_dict(config))


def write_config(config: Config, path: str | Path) -> Path:
    """Write the resolved configuration to a TOML file (atomically)."""
    from espin.core.atomic import atomic_write_bytes

    return atomic_write_bytes(Path(path), config_to_toml(config).encode("utf-8"))


def referenced_files(node: Any, name: str = "") -> Iterator[tuple[str, Path]]:
    """(dotted config key, path) of every file a config (or a part of it) references
    (``loading.path_csv``, ``loading.lateral.transverse_csv``)."""
    if isinstance(node, Path):
        yield name, node
    elif isinstance(node, BaseModel):
        for field_name in type(node).model_fields:
            yield from referenced_files(getattr(node, field_name), f"{name}.{field_name}" if name else field_name)
    elif isinstance(node, (list, tuple)):
        for index, item in enumerate(node):
            yield from referenced_files(item, f"{name}[{index}]")


def config_digest(config: Config, cache: dict[Path, str] | None = None) -> str:
    """SHA-256 (hex) of the config's TOML and of the bytes of every file it references.

    A config that references no file has the digest of its TOML alone. ``cache`` keeps file
    digests by path across calls (one plan of tasks).

    Raises
    ------
    ConfigError
        If a referenced file is missing or unreadable (naming the key and the path, never the
        file's contents).
    InputError
        If it is not a regular file (a folder, a pipe, a device).
    """
    cache = {} if cache is None else cache
    text = config_to_toml(config)
    for name, path in referenced_files(config):
        if path not in cache:
            cache[path] = _file_digest(name, path)
        text += f"\n# {name}: sha256 {cache[path]}"
    return hashlib.sha256(text.encode()).hexdigest()


def _file_digest(name: str, path: Path) -> str:
    """SHA-256 of a referenced file's bytes (only a regular file is opened: a pipe or a
    device would block or never end)."""
    if path.exists() and not path.is_file():
        raise InputError(f"{name}: {path} is not a regular file (a CSV table is expected)")
    try:
        with open(path, "rb") as fh:
            return hashlib.file_digest(fh, "sha256").hexdigest()
    except FileNotFoundError:
        raise ConfigError(f"{name}: the file it references does not exist: {path}") from None
    except OSError as err:
        raise ConfigError(f"{name}: cannot read the file it references, {path}: {err.strerror}") from None
