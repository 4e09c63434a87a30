"""Deposition parameters whose mat, measured like an SEM image, matches measured distributions.

:func:`calibrate_geometry` takes measured (or typed-in) distributions of fiber diameter,
orientation and tortuosity (:class:`espin.geometry_targets.GeometryTargets`) and a base
config, and returns a config whose virtual mat, measured the same way (portions of fibers
visible in the same square observation window, :func:`espin.statistics.window_tortuosity`),
matches them. The other keys of the base config are kept.

Method (docs/geometry_calibration.md)
-------------------------------------
1. **Diameters** are set directly: a normal with the sample's mean and sd, truncated below at
   ``rve.diameter_min_um`` as the deposition draws it; when the truncation matters the
   parent normal is solved for so that the *truncated* distribution has the target mean and
   sd.
2. **Tortuosity.** The visible tortuosity depends on the walk (segment length l_s and largest
   turn theta_max) through, mainly, its persistence length
   ``l_p = -l_s / ln(sin theta_max / theta_max)`` relative to the window: pairs along a curve
   of constant l_p give nearly the same distribution, so only one combination is identifiable.
   One parameter is searched with the other fixed (default: ``max_deviation_deg`` at the base
   segment length), minimizing the Kolmogorov-Smirnov distance between the visible tortuosity
   of generated mats and the target: a coarse grid, then a bounded scalar refinement. Mats are
   small RVEs (side twice the window) over fixed seeds (common random numbers), so the
   objective is deterministic. With ``fit="both"`` the search is repeated over a grid of
   segment lengths and the whole valley is reported; of the points whose KS lies within the
   sampling spread (1 / sqrt(n)) of the best, the one nearest the base segment length is
   kept, since the window cannot tell them apart.
3. **Orientation**: uniform, or an axial von Mises fitted to the sample (uniform when a
   Rayleigh test on the doubled angles does not reject isotropy at 1 %). The deposition walk
   widens the visible distribution (a fiber forgets its direction over about l_p / 4), so the
   deposition kappa is raised until the visible order parameter, measured in the RVE of the
   written config, matches the target's; where even kappa = 700 cannot, the closest is kept
   and a warning says so.

New deposition parameters change the network and thus the mechanics: the fiber parameters
must be fitted again (``espin fit``) before stresses of the calibrated mat mean anything.

Units: um, degrees at the edge (configs, reports); radians inside.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from espin.config import Config, RVEConfig, config_from_dict, config_to_toml
from espin.errors import ConfigError
from espin.geometry_targets import GeometryTargets, MeasurementError

__all__ = [
    "MECHANICS_NOTE",
    "DistributionMatch",
    "ValleyPoint",
    "VirtualMeasurement",
    "GeometryCalibration",
    "calibrate_geometry",
    "persistence_ratio",
    "fit_axial_von_mises",
    "truncated_normal_parameters",
]

log = logging.getLogger(__name__)

SCHEMA = "espin.geometry_calibration"
SCHEMA_VERSION = 1
MECHANICS_NOTE = (
    "New deposition parameters change the network and so the mechanics: fit the fiber "
    "parameters again (espin fit) before using stresses of the calibrated mat."
)
ISOTROPY_P_VALUE = 0.01
"""A measured orientation sample is taken as uniform unless a Rayleigh test rejects it here."""
KAPPA_MAX = 700.0
"""Largest von Mises concentration a config accepts."""
DEVIATION_RANGE_DEG = (0.0, 85.0)
"""Search range of ``rve.max_deviation_deg`` [deg]."""
DEVIATION_GRID_STEP_DEG = 5.0
SEGMENT_RATIO_MIN = 0.5
"""Shortest segment searched [D]: shorter ones multiply the deposition cost."""
SEGMENT_RATIO_MAX_FRACTION = 1.0 / 3.0
"""Longest segment searched, as a fraction of the window side: longer segments make every
visible portion a few straight pieces."""
VALLEY_SEGMENT_RATIOS = (1.0, 2.0, 3.0, 5.0, 8.0, 12.0)
"""Segment lengths [D] at which ``fit="both"`` searches the deviation."""
SEARCH_SIDE_OVER_WINDOW = 2.0
"""Side of the search RVE over the window side (the window sits in its central quarter)."""
Fit = Literal["deviation", "segment", "both"]


# --------------------------------------------------------------------------------------------
# small models
# --------------------------------------------------------------------------------------------
def persistence_ratio(segment_ratio: float, max_deviation_deg: float) -> float:
    """Persistence length of the deposition walk over D, ``-l_s / ln(sin t / t)``.

    Consecutive segments turn by a uniform angle in [-t, t], so the direction correlation
    after n segments is E[cos]^n = (sin t / t)^n = exp(-n l_s / l_p).

    Parameters
    ----------
    segment_ratio : float
        Segment length over D.
    max_deviation_deg : float [deg]
        Largest turn t between consecutive segments.

    Returns
    -------
    float
        l_p / D (infinite for straight fibers).
    """
    t = math.radians(max_deviation_deg)
    if t == 0.0:
        return math.inf
    return -segment_ratio / math.log(math.sin(t) / t)


def _mean_resultant(theta_rad: np.ndarray) -> tuple[float, float]:
    """Axial order |<exp(2 i theta)>| and director [rad] of axes ``theta_rad``."""
    z = np.mean(np.exp(2j * np.asarray(theta_rad)))
    return float(abs(z)), float(np.mod(np.angle(z) / 2.0, np.pi))


def _kappa_from_order(order: float) -> float:
    """Von Mises kappa of the doubled angle whose mean resultant length is ``order``."""
    from scipy import optimize, special

    def a1(k: float) -> float:
        return float(special.i1e(k) / special.i0e(k))

    if order <= 0.0:
        return 0.0
    if a1(KAPPA_MAX) <= order:
        return KAPPA_MAX
    return float(optimize.brentq(lambda k: a1(k) - order, 0.0, KAPPA_MAX, xtol=1e-10))


def fit_axial_von_mises(orientation_deg: np.ndarray) -> tuple[float, float, float]:
    """Axial von Mises fit and isotropy test of measured fiber axes.

    Parameters
    ----------
    orientation_deg : (n,) array [deg]
        Fiber axes in [0, 180).

    Returns
    -------
    mean_deg : float [deg]
        Maximum-likelihood mean axis, in [0, 180).
    kappa : float
        Maximum-likelihood concentration of p ~ exp(kappa cos 2(theta - mean)), <= 700.
    p_isotropy : float
        Rayleigh test of the doubled angles (Zar's approximation): the probability of an
        order at least this large from a uniform distribution.
    """
    n = len(orientation_deg)
    order, director = _mean_resultant(np.radians(orientation_deg))
    r = n * order
    p = math.exp(math.sqrt(1.0 + 4.0 * n + 4.0 * (n * n - r * r)) - (1.0 + 2.0 * n))
    return math.degrees(director) % 180.0, _kappa_from_order(order), min(p, 1.0)


def truncated_normal_parameters(
    mean_um: float, sd_um: float, lower_um: float | None = None
) -> tuple[float, float]:
    """Parent normal (mu, sigma) whose truncation below ``lower_um`` has this mean and sd.

    Parameters
    ----------
    mean_um, sd_um : float [um]
        Target mean and standard deviation of the diameters.
    lower_um : float [um], optional
        Truncation; default 0.1 mu, the config's default ``diameter_min_um``.

    Returns
    -------
    (mu, sigma) : float [um]
        ``rve.diameter_um`` and ``rve.diameter_sd_um``.

    Raises
    ------
    MeasurementError
        If no truncated normal has this mean and sd (the sd is too large for the mean).
    """
    from scipy import optimize, stats

    if sd_um == 0.0:
        return mean_um, 0.0

    def moments(params: np.ndarray) -> np.ndarray:
        mu, sigma = params[0], math.exp(params[1])
        low = 0.1 * mu if lower_um is None else lower_um
        law = stats.truncnorm((low - mu) / sigma, np.inf, loc=mu, scale=sigma)
        return np.array([law.mean() - mean_um, law.std() - sd_um]) / sd_um

    start = np.array([mean_um, math.log(sd_um)])
    if np.max(np.abs(moments(start))) < 1e-9:
        return mean_um, sd_um
    sol = optimize.root(moments, start, method="hybr")
    mu, sigma = float(sol.x[0]), math.exp(sol.x[1])
    if not sol.success or np.max(np.abs(moments(sol.x))) > 1e-6 or mu <= 0.0:
        raise MeasurementError(
            f"no normal truncated at diameter_min_um has mean {mean_um:g} um and sd {sd_um:g} um "
            "(the sd is too large for the mean); give a smaller diameter sd"
        )
    return mu, sigma


# --------------------------------------------------------------------------------------------
# the virtual SEM
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class VirtualMeasurement:
    """How generated mats are measured: window, seeds and layers (common random numbers).

    Attributes
    ----------
    window_um : float [um]
        Side of the square observation window, centred in the layer.
    min_chord_um : float [um]
        Visible portions with a shorter chord are dropped (as by the SEM tracer).
    seeds : tuple of int
        ``rve.seed`` of each generated mat; the same for every evaluation.
    layers : int
        Layers per mat; all layers are measured through the window and pooled.
    """

    window_um: float
    min_chord_um: float
    seeds: tuple[int, ...]
    layers: int

    def measure(self, rve: dict[str, Any], side_um: float) -> dict[str, np.ndarray]:
        """Visible fiber portions of mats with deposition ``rve`` in layers of ``side_um``.

        Returns
        -------
        dict
            ``tortuosity`` (n,), ``orientation_deg`` (n,) [deg] of the chords and
            ``diameter_um`` (n,) [um] of the fibers they belong to, pooled over the seeds.
        """
        from espin.deposition import deposit
        from espin.statistics import centred_window, window_tortuosity

        parts: dict[str, list[np.ndarray]] = {"tortuosity": [], "orientation_deg": [], "diameter_um": []}
        for seed in self.seeds:
            cfg = _validated_rve(rve | {"size_um": side_um, "layers": self.layers, "seed": seed})
            mat = deposit(cfg)
            origin, side = centred_window(mat.size, self.window_um)
            seen = window_tortuosity(mat.vertices, mat.fiber_offsets, origin, side, self.min_chord_um)
            parts["tortuosity"].append(seen.tortuosity)
            parts["orientation_deg"].append(np.degrees(seen.orientation))
            parts["diameter_um"].append(mat.fiber_diameter[seen.fiber])
        return {k: np.concatenate(v) for k, v in parts.items()}


def _validated_rve(data: dict[str, Any]) -> RVEConfig:
    """An RVEConfig from plain data, with the sizes given one way only."""
    data = dict(data)
    for chosen, other in (("size_um", "size_ratio"), ("size_ratio", "size_um"),
                          ("segment_ratio", "segment_um"), ("segment_um", "segment_ratio")):
        if chosen in data and other in data:
            data.pop(other)
    return config_from_dict({"rve": data}, "(geometry calibration)").rve


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DistributionMatch:
    """How one visible distribution of the calibrated mat matches its target.

    Attributes
    ----------
    quantity : str
        ``"tortuosity"``, ``"orientation_deg"`` or ``"diameter_um"``.
    target : str
        The target: a measured sample or a named distribution.
    n_target : int or None
        Size of the measured sample (None for a typed-in distribution).
    n_virtual : int
        Visible fiber portions of the virtual mats.
    ks : float
        Kolmogorov-Smirnov distance (0 same, 1 disjoint).
    p_value : float or None
        Two-sample KS p-value against a measured sample; None against a typed-in
        distribution (the virtual sample is large and its portions are not independent, so a
        p-value against an exact distribution would mislead).
    summary : tuple of (name, target value, virtual value)
        Mean / sd / median (orientation: director [deg] and order |<exp 2i theta>|).
    """

    quantity: str
    target: str
    n_target: int | None
    n_virtual: int
    ks: float
    p_value: float | None
    summary: tuple[tuple[str, float, float], ...]


@dataclass(frozen=True)
class ValleyPoint:
    """Best deviation found at one segment length (``fit="both"``): the identifiability curve.

    Attributes
    ----------
    segment_ratio : float
        Segment length over D.
    max_deviation_deg : float [deg]
        Deviation of least tortuosity KS at this segment length.
    persistence_ratio : float
        Persistence length of the walk over D.
    ks : float
        Tortuosity KS distance reached.
    """

    segment_ratio: float
    max_deviation_deg: float
    persistence_ratio: float
    ks: float


@dataclass(frozen=True, eq=False)
class GeometryCalibration:
    """Result of :func:`calibrate_geometry`.

    Attributes
    ----------
    config : Config
        The calibrated configuration (base config with the found deposition parameters and
        ``output.window_ratio`` set to the observation window). ``espin generate`` and
        ``espin simulate`` take it as it is.
    base : Config
        The base configuration.
    targets : GeometryTargets
        What was matched.
    parameters : dict
        The found values by config key, and ``fitted`` (the keys that were searched).
    matches : tuple of DistributionMatch
        Per targeted distribution, measured on mats of ``config`` (its layer side, unless the
        window does not fit: then the search RVE), pooled over the seeds.
    valley : tuple of ValleyPoint
        Best deviation per segment length (``fit="both"`` only).
    search : dict
        Window, RVE sides, seeds, layers, evaluations and wall time [s].
    warnings : tuple of str
        What the user must know (targets out of reach, window larger than the layer...).
    """

    config: Config
    base: Config
    targets: GeometryTargets
    parameters: dict[str, Any]
    matches: tuple[DistributionMatch, ...]
    valley: tuple[ValleyPoint, ...] = ()
    search: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def match(self, quantity: str) -> DistributionMatch:
        """The match of one quantity (``tortuosity``, ``orientation_deg``, ``diameter_um``)."""
        for m in self.matches:
            if m.quantity == quantity:
                return m
        raise KeyError(f"{quantity} was not a target")

    @property
    def report(self) -> dict[str, Any]:
        """JSON-ready description of the calibration (units in the key names)."""
        from espin import __version__

        return {
            "schema": SCHEMA,
            "schema_version": SCHEMA_VERSION,
            "espin_version": __version__,
            "source": self.targets.source,
            "parameters": _finite_or_none(self.parameters),
            "matches": [_match_json(m) for m in self.matches],
            "valley": [_finite_or_none(v.__dict__) for v in self.valley],
            "search": self.search,
            "warnings": list(self.warnings),
            "note": MECHANICS_NOTE,
        }

    def format_table(self) -> str:
        """Plain-text report for the command line."""
        s = self.search
        lines = [f"targets: {self.targets.source}; observation window {s['window_um']:.4g} um "
                 f"({s['window_source']}), chords >= {s['min_chord_um']:.3g} um", "parameters"]
        fitted = set(self.parameters["fitted"])
        for key, value in self.parameters.items():
            if key == "fitted":
                continue
            shown = json.dumps(value) if isinstance(value, dict) else f"{value:.6g}" \
                if isinstance(value, float) else str(value)
            lines.append(f"  {key:<24} {shown}{'   (fitted)' if key in fitted else ''}")
        lines.append("match in the observation window (KS distance: 0 same, 1 disjoint; "
                     "p: two-sample KS against a measured sample)")
        for m in self.matches:
            n_target = "-" if m.n_target is None else f"{m.n_target:,}"
            p = "-" if m.p_value is None else f"{m.p_value:.3g}"
            lines.append(f"  {m.quantity:<16} KS {m.ks:.4f}  p {p:<8} target {m.target} "
                         f"(n {n_target}), virtual n {m.n_virtual:,}")
            for name, target, virtual in m.summary:
                lines.append(f"      {name:<14} target {target:<10.4g} virtual {virtual:.4g}")
        if self.valley:
            lines.append("tortuosity valley (segment length and deviation are only identifiable "
                         "together, through the persistence length)")
            lines.append(f"  {'segment_ratio':>13} {'max_deviation_deg':>17} "
                         f"{'persistence / D':>15} {'KS':>7}")
            for v in self.valley:
                lines.append(f"  {v.segment_ratio:>13.3g} {v.max_deviation_deg:>17.2f} "
                             f"{v.persistence_ratio:>15.1f} {v.ks:>7.4f}")
        lines.append(f"search: {len(s['seeds'])} seeds x {s['layers']} layers, RVE side "
                     f"{s['search_side_um']:.4g} um (search) / {s['check_side_um']:.4g} um "
                     f"(match), {s['evaluations']} evaluations, {s['elapsed_s']:.1f} s")
        lines += [f"  {n}" for n in s["notes"]]
        lines += [f"warning: {w}" for w in self.warnings]
        lines.append(f"note: {MECHANICS_NOTE}")
        return "\n".join(lines)

    def write(self, path: str | Path) -> dict[str, Path]:
        """Write the calibrated config and the report.

        Parameters
        ----------
        path
            A ``.toml`` file: the config there and the report beside it as
            ``<stem>.calibration.json``. Anything else is a folder: ``config.toml``,
            ``calibration.json`` and ``calibration.txt`` in it.

        Returns
        -------
        dict
            The files written, by kind.
        """
        from espin.io.atomic import atomic_write_bytes

        path = Path(path)
        if path.suffix == ".toml":
            files = {"config": path, "report": path.with_name(f"{path.stem}.calibration.json")}
        else:
            files = {"config": path / "config.toml", "report": path / "calibration.json",
                     "table": path / "calibration.txt"}
        header = "".join(f"# {line}\n" for line in self._header_lines())
        atomic_write_bytes(files["config"], (header + config_to_toml(self.config)).encode("utf-8"))
        report = json.dumps(self.report, indent=2, allow_nan=False) + "\n"
        atomic_write_bytes(files["report"], report.encode("utf-8"))
        if "table" in files:
            atomic_write_bytes(files["table"], (self.format_table() + "\n").encode("utf-8"))
        return files

    def _header_lines(self) -> list[str]:
        from espin import __version__

        lines = [f"Written by espin {__version__} calibrate-geometry from {self.targets.source}.",
                 "Deposition parameters fitted to the measured geometry (observation window "
                 f"{self.search['window_um']:.4g} um):"]
        lines += [f"  {m.quantity}: KS {m.ks:.4f}" for m in self.matches]
        lines += ["New deposition parameters change the mechanics: fit the fiber parameters",
                  "again (espin fit) before using stresses of this mat."]
        return lines


def _finite_or_none(d: dict[str, Any]) -> dict[str, Any]:
    """``d`` with non-finite floats (an infinite persistence length) as None, for JSON."""
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in d.items()}


def _match_json(m: DistributionMatch) -> dict[str, Any]:
    out = _finite_or_none(m.__dict__)
    out["summary"] = [{"statistic": n, "target": t, "virtual": v} for n, t, v in m.summary]
    return out


# --------------------------------------------------------------------------------------------
# targets as comparable distributions
# --------------------------------------------------------------------------------------------
def _compare(quantity: str, virtual: np.ndarray, sample: np.ndarray | None,
             cdf: Callable[[np.ndarray], np.ndarray] | None, label: str,
             target_summary: tuple[tuple[str, float], ...]) -> DistributionMatch:
    """KS distance (and p-value against a sample) of ``virtual`` against its target."""
    from scipy import stats

    if sample is not None:
        test = stats.ks_2samp(virtual, sample)
        ks, p = float(test.statistic), float(test.pvalue)
    else:
        ks, p = float(stats.kstest(virtual, cdf).statistic), None
    virtual_summary = dict(_summary(quantity, virtual))
    rows = tuple((name, float(t), float(virtual_summary[name])) for name, t in target_summary)
    return DistributionMatch(quantity, label, None if sample is None else len(sample), len(virtual),
                             ks, p, rows)


def _summary(quantity: str, x: np.ndarray) -> tuple[tuple[str, float], ...]:
    if quantity == "orientation_deg":
        order, director = _mean_resultant(np.radians(x))
        return (("director_deg", math.degrees(director)), ("order", order))
    return (("mean", float(np.mean(x))), ("sd", float(np.std(x))), ("median", float(np.median(x))))


def _distribution_summary(law: Any) -> tuple[tuple[str, float], ...]:
    """Summary of a frozen scipy distribution (mean, sd, median)."""
    return (("mean", float(law.mean())), ("sd", float(law.std())), ("median", float(law.median())))


@dataclass(frozen=True)
class _Target:
    """One targeted distribution: a sample, or a cdf with its summary."""

    quantity: str
    sample: np.ndarray | None
    cdf: Callable[[np.ndarray], np.ndarray] | None
    label: str
    summary: tuple[tuple[str, float], ...]

    def ks_noise(self, n_virtual: int) -> float:
        """Typical sampling spread of a KS distance against this target, 1 / sqrt(n_eff)."""
        n = max(n_virtual, 1)
        n_eff = n if self.sample is None else n * len(self.sample) / (n + len(self.sample))
        return 1.0 / math.sqrt(n_eff)

    def ks(self, virtual: np.ndarray) -> float:
        from scipy import stats

        if len(virtual) == 0:
            return 1.0
        if self.sample is not None:
            return float(stats.ks_2samp(virtual, self.sample).statistic)
        return float(stats.kstest(virtual, self.cdf).statistic)

    def compare(self, virtual: np.ndarray) -> DistributionMatch:
        return _compare(self.quantity, virtual, self.sample, self.cdf, self.label, self.summary)


def _sample_target(quantity: str, sample: np.ndarray, source: str) -> _Target:
    return _Target(quantity, sample, None, f"measured sample ({source})", _summary(quantity, sample))


def _tortuosity_target(targets: GeometryTargets) -> _Target:
    if targets.tortuosity is not None:
        return _sample_target("tortuosity", targets.tortuosity, targets.source)
    law = targets.tortuosity_distribution()
    return _Target("tortuosity", None, law.cdf, f"halfnorm(loc=1, scale={targets.tortuosity_scale:g})",
                   _distribution_summary(law))


def _diameter_target(targets: GeometryTargets) -> _Target:
    if targets.diameter_um is not None:
        return _sample_target("diameter_um", targets.diameter_um, targets.source)
    from scipy import stats

    mean, sd = targets.diameter_mean_um, targets.diameter_sd_um or 0.0
    if sd == 0.0:
        return _Target("diameter_um", None, lambda x: (np.asarray(x) >= mean).astype(float),
                       f"fixed {mean:g} um", (("mean", mean), ("sd", 0.0), ("median", mean)))
    law = stats.norm(mean, sd)
    return _Target("diameter_um", None, law.cdf, f"normal({mean:g}, {sd:g}) um",
                   _distribution_summary(law))


def _orientation_spec(targets: GeometryTargets) -> tuple[str | dict[str, Any], _Target, list[str]]:
    """The target orientation as a config value, its comparison target, and notes."""
    from espin.config import VonMises
    from espin.orientation import orientation_distribution

    notes: list[str] = []
    if targets.orientation_deg is not None:
        mean, kappa, p = fit_axial_von_mises(targets.orientation_deg)
        spec: str | dict[str, Any] = "uniform"
        if p < ISOTROPY_P_VALUE:
            spec = {"von_mises": {"mean_deg": round(mean, 2), "kappa": round(kappa, 4)}}
        notes.append(f"orientation sample: Rayleigh p = {p:.3g} -> "
                     f"{'von Mises' if spec != 'uniform' else 'uniform'}")
        return spec, _sample_target("orientation_deg", targets.orientation_deg, targets.source), notes
    if targets.orientation_uniform:
        spec = "uniform"
    else:
        spec = {"von_mises": {"mean_deg": targets.orientation_mean_deg,
                              "kappa": targets.orientation_kappa}}
    law = orientation_distribution(spec if spec == "uniform" else VonMises.model_validate(spec))
    # Summary of the exact distribution: director and order I1/I0(kappa).
    from scipy import special

    if spec == "uniform":
        summary: tuple[tuple[str, float], ...] = (("order", 0.0),)
    else:
        k = targets.orientation_kappa
        summary = (("director_deg", targets.orientation_mean_deg),
                   ("order", float(special.i1e(k) / special.i0e(k))))
    return spec, _Target("orientation_deg", None, lambda x: law.cdf(np.radians(x)), law.label,
                         summary), notes


# --------------------------------------------------------------------------------------------
# searches
# --------------------------------------------------------------------------------------------
class _Objective:
    """Visible-tortuosity KS of a walk (segment_ratio, max_deviation_deg), cached."""

    def __init__(self, measurement: VirtualMeasurement, rve: dict[str, Any], side_um: float,
                 target: _Target, progress: Callable[[str], None] | None) -> None:
        self.measurement, self.rve, self.side_um = measurement, rve, side_um
        self.target, self.progress = target, progress
        self.cache: dict[tuple[float, float], float] = {}
        self.n_virtual = 0

    def __call__(self, segment_ratio: float, max_deviation_deg: float) -> float:
        key = (round(segment_ratio, 6), round(max_deviation_deg, 6))
        if key not in self.cache:
            walk = {"segment_ratio": key[0], "max_deviation_deg": key[1]}
            seen = self.measurement.measure(self.rve | walk, self.side_um)
            self.cache[key] = self.target.ks(seen["tortuosity"])
            self.n_virtual = len(seen["tortuosity"])
            if self.progress is not None:
                self.progress(f"segment_ratio {key[0]:.3g}, max_deviation_deg {key[1]:.2f}: "
                              f"KS {self.cache[key]:.4f}")
        return self.cache[key]


def _grid_then_refine(f: Callable[[float], float], grid: np.ndarray, xatol: float) -> tuple[float, float]:
    """Minimize ``f`` over a grid, then refine in the bracket around the best grid point."""
    from scipy import optimize

    values = [f(x) for x in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    best_x, best_f = float(grid[i]), float(values[i])
    if hi > lo:
        res = optimize.minimize_scalar(f, bounds=(lo, hi), method="bounded",
                                       options={"xatol": xatol})
        if res.fun < best_f:
            best_x, best_f = float(res.x), float(res.fun)
    return best_x, best_f


def _search_deviation(objective: _Objective, segment_ratio: float) -> tuple[float, float]:
    lo, hi = DEVIATION_RANGE_DEG
    grid = np.arange(lo, hi + 1e-9, DEVIATION_GRID_STEP_DEG)
    x, ks = _grid_then_refine(lambda d: objective(segment_ratio, d), grid, xatol=0.05)
    return round(x, 1), ks


def _search_segment(objective: _Objective, max_deviation_deg: float, largest: float) -> tuple[float, float]:
    grid = np.linspace(math.log(SEGMENT_RATIO_MIN), math.log(largest), 13)
    x, ks = _grid_then_refine(lambda u: objective(math.exp(u), max_deviation_deg), grid, xatol=0.005)
    return float(f"{math.exp(x):.3g}"), ks


def _at_bound(value: float, low: float, high: float, tol: float) -> bool:
    return value <= low + tol or value >= high - tol


def _correct_kappa(measurement: VirtualMeasurement, rve: dict[str, Any], side_um: float,
                   mean_deg: float, kappa: float, order: float,
                   progress: Callable[[str], None] | None) -> tuple[float, str | None, int]:
    """Deposition kappa whose visible order matches ``order`` (the target's).

    Returns the kappa, a warning if the order is out of reach, and the evaluations made.
    """
    from scipy import optimize

    def visible_order(k: float) -> float:
        spec = {"von_mises": {"mean_deg": mean_deg, "kappa": k}}
        seen = measurement.measure(rve | {"orientation": spec}, side_um)
        value = _mean_resultant(np.radians(seen["orientation_deg"]))[0]
        if progress is not None:
            progress(f"orientation kappa {k:.4g}: visible order {value:.3f} (target {order:.3f})")
        return value

    calls = [0]

    def counted(k: float) -> float:
        calls[0] += 1
        return visible_order(k)

    if counted(kappa) >= order:
        return kappa, None, calls[0]
    highest = counted(KAPPA_MAX)
    if highest < order:
        return KAPPA_MAX, (
            f"the visible orientation order {order:.3f} is out of reach: even kappa = {KAPPA_MAX:g} "
            f"at deposition gives {highest:.3f}, because the deposition walk forgets its direction "
            "over about a quarter of its persistence length; kappa set to its maximum"
        ), calls[0]
    root = optimize.brentq(lambda u: counted(math.exp(u)) - order,
                           math.log(max(kappa, 1e-3)), math.log(KAPPA_MAX), xtol=0.01)
    return float(f"{math.exp(root):.4g}"), None, calls[0]


# --------------------------------------------------------------------------------------------
# the calibration
# --------------------------------------------------------------------------------------------
def _resolve_base(base: Config | str | Path | None) -> Config:
    from espin.rve import resolve_config

    return resolve_config(base)


def _base_rve_data(base: Config) -> dict[str, Any]:
    """The base config's rve keys as given (derived values re-resolve when others change)."""
    return base.rve.model_dump(mode="json", exclude_none=True, exclude_unset=True)


def _check_options(fit: str, segment_ratio: float | None, max_deviation_deg: float | None,
                   seeds: int, min_portions: int, window_um: float | None) -> None:
    if fit not in ("deviation", "segment", "both"):
        raise ConfigError(f"fit must be deviation, segment or both, got {fit!r}")
    if fit in ("deviation", "both") and max_deviation_deg is not None:
        raise ConfigError("max_deviation_deg is searched with fit = deviation or both: do not fix it")
    if fit in ("segment", "both") and segment_ratio is not None:
        raise ConfigError("segment_ratio is searched with fit = segment or both: do not fix it")
    if segment_ratio is not None and not (math.isfinite(segment_ratio) and segment_ratio > 0):
        raise ConfigError(f"segment_ratio must be > 0, got {segment_ratio!r}")
    if max_deviation_deg is not None and not 0.0 <= max_deviation_deg < 90.0:
        raise ConfigError(f"max_deviation_deg must be in [0, 90), got {max_deviation_deg!r}")
    if not 1 <= seeds <= 1000:
        raise ConfigError(f"seeds must be in [1, 1000], got {seeds!r}")
    if not 50 <= min_portions <= 10**6:
        raise ConfigError(f"min_portions must be in [50, 1000000], got {min_portions!r}")
    if window_um is not None and not (math.isfinite(window_um) and window_um > 0):
        raise ConfigError(f"window_um must be > 0, got {window_um!r}")


def _window(targets: GeometryTargets, window_um: float | None, config: Config) -> tuple[float, str]:
    if targets.window_um is not None and window_um is not None:
        raise ConfigError(
            "the observation window comes from field_of_view_um of the measurement; "
            "do not give window_um as well"
        )
    if targets.window_um is not None:
        w, h = targets.field_of_view_um
        return targets.window_um, f"square of equal mean chord to the {w:g} x {h:g} um field of view"
    if window_um is not None:
        return float(window_um), "window_um"
    return config.output.window_ratio * config.rve.diameter_um, \
        f"default {config.output.window_ratio:g} D"


def _layers_per_seed(measurement: VirtualMeasurement, rve: dict[str, Any], side_um: float,
                     min_portions: int) -> int:
    """Layers per mat so that all seeds together show at least ``min_portions`` portions."""
    probe = VirtualMeasurement(measurement.window_um, measurement.min_chord_um,
                               measurement.seeds[:1], 2)
    per_layer = max(len(probe.measure(rve, side_um)["tortuosity"]) / 2.0, 1.0)
    return int(np.clip(math.ceil(min_portions / (len(measurement.seeds) * per_layer)), 1, 500))


def calibrate_geometry(
    targets_or_path: GeometryTargets | str | Path,
    base: Config | str | Path | None = None,
    *,
    fit: Fit = "deviation",
    segment_ratio: float | None = None,
    max_deviation_deg: float | None = None,
    segment_ratios: tuple[float, ...] = VALLEY_SEGMENT_RATIOS,
    window_um: float | None = None,
    correct_orientation: bool = True,
    seeds: int = 8,
    seed: int = 0,
    min_portions: int = 1000,
    progress: Callable[[str], None] | None = None,
) -> GeometryCalibration:
    """Find deposition parameters whose mat, measured in the same window, matches the targets.

    Parameters
    ----------
    targets_or_path
        :class:`GeometryTargets`, a ``fibers.csv`` or a folder written by ``espin measure``.
    base
        Config, preset name or TOML whose other keys are kept (default ``plla``).
    fit
        Walk parameter(s) searched to match the tortuosity: ``"deviation"``
        (``rve.max_deviation_deg``, default), ``"segment"`` (``rve.segment_ratio``) or
        ``"both"`` (deviation searched at several segment lengths; the valley is reported,
        and of the equally good points the one nearest the base segment length is kept).
    segment_ratio
        Fixed segment length over D when it is not searched (default: the base's).
    max_deviation_deg : float [deg]
        Fixed largest turn when it is not searched (default: the base's).
    segment_ratios
        Segment lengths over D at which ``fit="both"`` searches the deviation (those longer
        than a third of the window are skipped).
    window_um : float [um]
        Observation window side when the targets carry no field of view (default
        ``output.window_ratio`` D of the calibrated diameter, 50 D).
    correct_orientation
        Raise the deposition kappa of an aligned target so that the visible orientation
        matches (the walk widens it).
    seeds
        Mats per evaluation (fixed seeds: common random numbers).
    seed
        Seeds the list of mat seeds.
    min_portions
        Fewest visible fiber portions per evaluation (sets the layers per mat).
    progress
        Called with a short message after each evaluation.

    Returns
    -------
    GeometryCalibration
        The calibrated config, the per-distribution match and the search record.

    Raises
    ------
    EspinError
        ConfigError or MeasurementError for bad options or targets, before any work.
    """
    started = time.perf_counter()
    _check_options(fit, segment_ratio, max_deviation_deg, seeds, min_portions, window_um)
    targets = (targets_or_path if isinstance(targets_or_path, GeometryTargets)
               else GeometryTargets.from_path(targets_or_path))
    if targets.is_empty:
        raise MeasurementError(
            "no targets: give measured fibers (diameter_um, orientation_deg or tortuosity "
            "columns) or typed-in diameter, orientation or tortuosity"
        )
    base_config = _resolve_base(base)
    rve = _base_rve_data(base_config)
    parameters: dict[str, Any] = {}
    warnings: list[str] = []
    notes: list[str] = []

    # 1. Diameters.
    if targets.has_diameter:
        rve |= _diameter_keys(targets, base_config)
        parameters |= {f"rve.{k}": rve[k] for k in ("diameter_um", "diameter_sd_um")}
    calibrated_d = _validated_rve(rve).diameter_um

    # 2. The window and how mats are measured.
    draft = config_from_dict(_with_section(base_config, rve, {}), "(geometry calibration)")
    window, window_source = _window(targets, window_um, draft)
    min_chord = targets.min_chord_um
    if min_chord is None:
        from espin.statistics import DEFAULT_MIN_CHORD_FRACTION

        min_chord = DEFAULT_MIN_CHORD_FRACTION * window
    seed_list = tuple(int(s) for s in np.random.SeedSequence(seed).generate_state(seeds))
    search_side = SEARCH_SIDE_OVER_WINDOW * window
    base_side = draft.rve.side_um
    check_side = base_side if window <= base_side else search_side
    if window > base_side:
        warnings.append(
            f"the observation window ({window:.4g} um) is larger than the layer of the config "
            f"({base_side:.4g} um): the calibration measured layers of {search_side:.4g} um, while "
            "espin generate with this config measures its whole layer (a smaller window)"
        )
    measurement = VirtualMeasurement(window, float(min_chord), seed_list, 1)
    if targets.has_orientation:
        orientation, orientation_target, found = _orientation_spec(targets)
        notes += found
        rve["orientation"] = orientation
    layers = _layers_per_seed(measurement, rve, search_side, min_portions)
    measurement = VirtualMeasurement(window, float(min_chord), seed_list, layers)
    evaluations = 0

    # 3. Tortuosity: the walk.
    valley: list[ValleyPoint] = []
    if targets.has_tortuosity:
        objective = _Objective(measurement, rve, search_side, _tortuosity_target(targets), progress)
        largest_segment = SEGMENT_RATIO_MAX_FRACTION * window / calibrated_d
        if largest_segment <= SEGMENT_RATIO_MIN:
            raise ConfigError(
                f"the observation window ({window:.4g} um) is too small to measure tortuosity: "
                f"it must exceed {SEGMENT_RATIO_MIN / SEGMENT_RATIO_MAX_FRACTION:g} D"
            )
        start = _validated_rve(rve)
        sr = segment_ratio if segment_ratio is not None else start.segment_length_um / calibrated_d
        dev = max_deviation_deg if max_deviation_deg is not None else start.max_deviation_deg
        sr, dev, valley, problem = _fit_walk(objective, fit, sr, dev, largest_segment, segment_ratios)
        if problem:
            warnings.append(problem)
        rve |= {"segment_ratio": float(sr), "max_deviation_deg": float(dev)}
        rve.pop("segment_um", None)
        parameters |= {"rve.segment_ratio": float(sr), "rve.max_deviation_deg": float(dev),
                       "persistence_ratio": persistence_ratio(sr, dev)}
        evaluations += len(objective.cache)

    # 4. Orientation: correct the deposition kappa for the widening by the walk.
    if targets.has_orientation:
        spec = rve["orientation"]
        if isinstance(spec, dict) and correct_orientation:
            vm = spec["von_mises"]
            order = dict(orientation_target.summary)["order"]
            kappa, problem, n = _correct_kappa(measurement, rve, check_side, vm["mean_deg"],
                                               vm["kappa"], order, progress)
            evaluations += n
            spec = {"von_mises": {"mean_deg": vm["mean_deg"], "kappa": kappa}}
            rve["orientation"] = spec
            if problem:
                warnings.append(problem)
        parameters["rve.orientation"] = spec

    # 5. The written config and its match, measured on mats of that config.
    output = {"window_ratio": float(f"{window / calibrated_d:.6g}")}
    config = config_from_dict(_with_section(base_config, rve, output), "(calibrated)")
    parameters["output.window_ratio"] = output["window_ratio"]
    parameters["fitted"] = _fitted(targets, fit)
    seen = measurement.measure(_base_rve_data(config), check_side)
    evaluations += 1
    matches = []
    if targets.has_tortuosity:
        matches.append(_tortuosity_target(targets).compare(seen["tortuosity"]))
    if targets.has_orientation:
        matches.append(orientation_target.compare(seen["orientation_deg"]))
    if targets.has_diameter:
        matches.append(_diameter_target(targets).compare(seen["diameter_um"]))
    search = {
        "window_um": window, "window_source": window_source, "min_chord_um": float(min_chord),
        "seeds": list(seed_list), "layers": layers, "search_side_um": search_side,
        "check_side_um": check_side, "evaluations": evaluations,
        "elapsed_s": time.perf_counter() - started, "notes": notes,
    }
    for w in warnings:
        log.info("calibration warning: %s", w)
    return GeometryCalibration(config, base_config, targets, parameters, tuple(matches),
                               tuple(valley), search, tuple(warnings))


def _diameter_keys(targets: GeometryTargets, base: Config) -> dict[str, float]:
    """``diameter_um`` and ``diameter_sd_um`` whose truncated normal has the target moments."""
    sample = targets.diameter_um
    if sample is not None:
        mean, sd = float(np.mean(sample)), float(np.std(sample, ddof=1))
    else:
        mean, sd = targets.diameter_mean_um, targets.diameter_sd_um or 0.0
    explicit_min = base.rve.diameter_min_um if "diameter_min_um" in base.rve.model_fields_set else None
    mu, sigma = truncated_normal_parameters(mean, sd, explicit_min)
    return {"diameter_um": float(f"{mu:.4g}"), "diameter_sd_um": float(f"{sigma:.4g}")}


def _fit_walk(objective: _Objective, fit: str, segment_ratio: float, max_deviation_deg: float,
              largest_segment: float, segment_ratios: tuple[float, ...]
              ) -> tuple[float, float, list[ValleyPoint], str | None]:
    """Search the walk parameter(s) named by ``fit``; the other keeps its given value.

    Returns the segment ratio, the deviation [deg], the valley (``fit="both"``) and a warning
    when the result sits at the end of its search range.
    """
    sr, dev = segment_ratio, max_deviation_deg
    if fit == "deviation":
        dev, _ = _search_deviation(objective, sr)
        if _at_bound(dev, *DEVIATION_RANGE_DEG, 0.5):
            return sr, dev, [], (f"max_deviation_deg = {dev:g} is at the end of its search range "
                                 f"{DEVIATION_RANGE_DEG}: try fit = segment or both")
        return sr, dev, [], None
    if fit == "segment":
        sr, _ = _search_segment(objective, dev, largest_segment)
        if _at_bound(sr, SEGMENT_RATIO_MIN, largest_segment, 0.05 * sr):
            return sr, dev, [], (
                f"segment_ratio = {sr:g} is at the end of its search range [{SEGMENT_RATIO_MIN:g}, "
                f"{largest_segment:.3g}]: the target is out of reach at max_deviation_deg = "
                f"{dev:g}; try fit = deviation or both")
        return sr, dev, [], None
    usable = [r for r in segment_ratios if SEGMENT_RATIO_MIN <= r <= largest_segment]
    if not usable:
        raise ConfigError(
            f"segment_ratios must hold values in [{SEGMENT_RATIO_MIN:g}, {largest_segment:.3g}] "
            f"(up to a third of the window), got {list(segment_ratios)}"
        )
    valley = []
    for s in usable:
        d, ks = _search_deviation(objective, s)
        valley.append(ValleyPoint(s, d, persistence_ratio(s, d), ks))
    # Points within the sampling spread of the best KS are equally good: keep the one whose
    # segment length is closest to the given (base) one.
    tie = min(v.ks for v in valley) + objective.target.ks_noise(objective.n_virtual)
    best = min((v for v in valley if v.ks <= tie),
               key=lambda v: abs(math.log(v.segment_ratio / segment_ratio)))
    return best.segment_ratio, best.max_deviation_deg, valley, None


def _fitted(targets: GeometryTargets, fit: str) -> list[str]:
    keys = []
    if targets.has_diameter:
        keys += ["rve.diameter_um", "rve.diameter_sd_um"]
    if targets.has_tortuosity:
        keys += {"deviation": ["rve.max_deviation_deg"], "segment": ["rve.segment_ratio"],
                 "both": ["rve.segment_ratio", "rve.max_deviation_deg"]}[fit]
    if targets.has_orientation:
        keys.append("rve.orientation")
    return keys


def _with_section(base: Config, rve: dict[str, Any], output: dict[str, Any]) -> dict[str, Any]:
    """The base config's given keys with the rve and output keys replaced."""
    data = base.model_dump(mode="json", exclude_none=True, exclude_unset=True)
    data["rve"] = rve
    data["output"] = data.get("output", {}) | output
    return data
