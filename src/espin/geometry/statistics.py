"""Statistics of a virtual mat and its network, and their comparison with measured targets.

This module measures what docs/model.md section 2 lists and what the paper compares with SEM images (Fig. 10,
12; docs/model.md section 7): counts, the achieved volume fraction, cross-link densities against the
integral-geometry expectation, and samples of orientation, tortuosity, diameter and element
length, with Kolmogorov-Smirnov statistics against their targets: the orientation against the
config's own distribution, and diameter, tortuosity, orientation and the crossing statistics
against the measured targets of the config's ``[targets]`` section (:class:`TargetGrading`;
none without that section).

Measured as the targets were
----------------------------
A measured sample is compared with the mat's by the two-sample KS statistic, a distribution
by the one-sample one. When the targets give the contour lengths of the measured pieces
(``targets.contour_length_um``, as ``espin measure`` writes them), the mat is measured on
pieces of those lengths cut from its window portions, like the SEM tracer's pieces, and the
U-turn fraction and straightness of its edge-to-edge portions are measured for the targets
that give them. Both need :mod:`espin.geometry.pieces`, which stands on this module's window
clipping: :func:`espin.geometry.rve_folder.trace_window` measures them and hands them to
:func:`network_statistics` (:class:`TracedWindow`).

Tortuosity as an SEM image sees it
----------------------------------
A whole virtual fiber runs from border to border of the RVE; an SEM analyst instead traces the
part of a fiber that is visible in one image. :func:`window_tortuosity` therefore clips the
fibers to a square observation window (side ``Config.observation_window_um``, centred in the
RVE) and measures each visible portion: contour length / end-to-end (chord) length, and the
axis of the chord (the paper measured orientation "along the end-to-end line", section 2.2).
The same function serves traced SEM fibers, so simulated and measured mats are measured alike.

Straight fibers are a result, not a failure
-------------------------------------------
With the paper's Table 2 deposition parameters (max deviation 5 deg between segments of 5 D) the
virtual fibers are far straighter than the measured ones: whole fibers have a tortuosity of
about 1.006 and the portions visible in a 50 D window about 1.002, while the SEM half-normal
``halfnorm(loc=1, scale=0.14)`` has mean 1.112. The KS statistic of window tortuosity is then
about 0.95 (1 = disjoint distributions) against the paper's targets of the ``plla`` preset.
espin reports this honestly (docs/model.md sections 7-8): matching the measured tortuosity needs
other deposition parameters (a larger ``max_deviation_deg`` or segment length), and then the
material parameters must be fitted again.

Units: lengths um, areas um^2, angles rad inside (degrees in :meth:`NetworkStatistics.summary`
and on plots).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:  # pragma: no cover
    from espin.core.config import Config, TargetsConfig
    from espin.geometry.mat import FiberMat
    from espin.geometry.network import Network
    from espin.geometry.orientation import OrientationDistribution

__all__ = [
    "DEFAULT_MIN_CHORD_FRACTION",
    "VisibleFibers",
    "window_tortuosity",
    "Target",
    "tortuosity_target",
    "diameter_target",
    "TracedWindow",
    "Graded",
    "TargetGrading",
    "grade",
    "NetworkStatistics",
    "network_statistics",
    "ks_statistic",
    "ks_two_sample",
    "centred_window",
    "observation_window",
    "WHOLE_PORTIONS",
    "LENGTH_MATCHED",
    "NO_TARGETS",
]

DEFAULT_MIN_CHORD_FRACTION = 0.1
"""Default shortest chord of a visible fiber portion, as a fraction of the window side.

An SEM analyst does not measure stubs that merely clip a corner of the image. With espin's
default window (``output.window_ratio`` = 50 D) this is 5 D, a few fiber diameters (2.25 um for
``plla``, one deposition segment), and it scales with the image for traced SEM fibers whose
diameter is not known in advance.
"""


# --------------------------------------------------------------------------------------------
# Fibers seen through an observation window
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class VisibleFibers:
    """Fiber portions visible in a square observation window, one row per portion.

    A portion is a maximal connected piece of one fiber inside the closed window
    [origin, origin + side]^2. A fiber that leaves and re-enters the window gives several.

    Attributes
    ----------
    contour_length : (n,) float64 [um]
        Length of the polyline inside the window.
    chord_length : (n,) float64 [um]
        Distance between the portion's first and last point (> 0, >= ``min_chord``).
    tortuosity : (n,) float64
        ``contour_length / chord_length`` (>= 1).
    orientation : (n,) float64 [rad]
        Axis of the chord, counter-clockwise from +x, in [0, pi).
    fiber : (n,) int64
        Index of the fiber each portion belongs to.
    start : (n, 2) float64 [um]
        First point of each portion (where it enters the window, or a fiber end inside).
    end : (n, 2) float64 [um]
        Last point of each portion.
    origin : (2,) float64 [um]
        Lower-left corner of the window.
    side : float [um]
        Side of the window.
    min_chord : float [um]
        Portions with a shorter chord were dropped.
    """

    contour_length: np.ndarray
    chord_length: np.ndarray
    tortuosity: np.ndarray
    orientation: np.ndarray
    fiber: np.ndarray
    start: np.ndarray
    end: np.ndarray
    origin: np.ndarray
    side: float
    min_chord: float

    def __len__(self) -> int:
        return len(self.contour_length)


def _clip_segments(
    p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Liang-Barsky clipping of segments p0 -> p1 to the box [lo, hi], all at once.

    Returns the parameters (t0, t1) of the clipped piece p0 + t (p1 - p0), t0 <= t <= t1,
    and a mask of the segments that meet the closed box at all.
    """
    d = p1 - p0
    t0 = np.zeros(len(p0))
    t1 = np.ones(len(p0))
    hits = np.ones(len(p0), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(2):
            sides = ((-d[:, axis], p0[:, axis] - lo[axis]), (d[:, axis], hi[axis] - p0[:, axis]))
            for p, q in sides:
                # Crossing the boundary line p t = q: entering where p < 0, leaving where p > 0.
                r = q / p
                t0 = np.where(p < 0, np.maximum(t0, r), t0)
                t1 = np.where(p > 0, np.minimum(t1, r), t1)
                hits &= ~((p == 0) & (q < 0))  # parallel to this boundary and outside it
    hits &= t0 <= t1
    return t0, t1, hits


@dataclass(frozen=True)
class WindowPieces:
    """Fiber segments clipped to a square window, inside pieces only, grouped into runs.

    A run is a maximal portion: consecutive pieces of a fiber that meet at a vertex inside
    the closed window. Pieces are ordered by fiber and along each fiber.

    Attributes
    ----------
    fiber : (n,) int64
        Fiber of each piece.
    start, end : (n, 2) float64 [um]
        End points of each piece (exactly the vertices where a segment is not cut).
    length : (n,) float64 [um]
        Length of each piece.
    run_start : (n,) bool
        True where a piece starts a new run.
    run : (n,) int64
        Run of each piece, 0, 1, ...
    """

    fiber: np.ndarray
    start: np.ndarray
    end: np.ndarray
    length: np.ndarray
    run_start: np.ndarray
    run: np.ndarray


def clip_to_window(vertices: np.ndarray, fiber_offsets: np.ndarray, origin: np.ndarray, side: float) -> WindowPieces:
    """Clip every fiber segment to the square [origin, origin + side]^2 at once (Liang-Barsky)
    and group the inside pieces into runs (see :class:`WindowPieces`)."""
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    offsets = np.asarray(fiber_offsets, dtype=np.int64)
    lo = np.asarray(origin, dtype=float).reshape(2)
    hi = lo + float(side)
    # Segments: vertex i to i + 1 of the same fiber (robust to fibers with 0 or 1 vertex).
    vertex_fiber = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    seg = np.flatnonzero(vertex_fiber[:-1] == vertex_fiber[1:])
    p0, p1 = v[seg], v[seg + 1]
    t0, t1, hits = _clip_segments(p0, p1, lo, hi)
    d = p1 - p0
    # Exact end points where the segment is not cut, so shared vertices coincide bit for bit.
    a = np.where((t0 <= 0.0)[:, None], p0, p0 + t0[:, None] * d)
    b = np.where((t1 >= 1.0)[:, None], p1, p0 + t1[:, None] * d)
    piece = np.hypot(*(b - a).T)
    # A piece counts if it has length; a zero-length segment counts if its point is inside.
    idx = np.flatnonzero(hits & ((piece > 0.0) | (np.hypot(*d.T) == 0.0)))
    # A piece continues the previous inside piece if that is the previous segment (of the same
    # fiber, then) and their shared vertex lies in the closed window.
    vertex_in = np.all((v >= lo) & (v <= hi), axis=1)
    run_start = np.ones(len(idx), dtype=bool)
    if len(idx) > 1:
        run_start[1:] = ~((seg[idx[1:]] == seg[idx[:-1]] + 1) & vertex_in[seg[idx[1:]]])
    return WindowPieces(
        fiber=vertex_fiber[seg[idx]].astype(np.int64),
        start=a[idx],
        end=b[idx],
        length=piece[idx],
        run_start=run_start,
        run=np.cumsum(run_start) - 1,
    )


def window_tortuosity(
    vertices: ArrayLike,
    fiber_offsets: ArrayLike,
    origin: ArrayLike,
    side: float,
    min_chord: float | None = None,
) -> VisibleFibers:
    """Contour length, chord, tortuosity and orientation of fiber portions inside a window.

    Every segment is clipped to the square [origin, origin + side]^2 at once (Liang-Barsky);
    consecutive clipped pieces of a fiber that meet at a vertex inside the window form one
    portion (a run). This measures a mat the way the paper's SEM analysis does (section 2.2:
    tortuosity = contour / end-to-end length, orientation along the end-to-end line).

    Parameters
    ----------
    vertices : (n_vertices, 2) array [um]
        Polyline vertices of all fibers, one fiber after the other (CSR layout, as
        :class:`espin.geometry.mat.FiberMat`).
    fiber_offsets : (n_fibers + 1,) int array
        Fiber ``f`` has the vertices ``vertices[fiber_offsets[f]:fiber_offsets[f + 1]]``.
    origin : (2,) array [um]
        Lower-left corner of the window.
    side : float [um]
        Side of the square window, > 0.
    min_chord : float [um], optional
        Portions whose chord is shorter are dropped (an SEM analyst does not measure tiny
        stubs). Default ``DEFAULT_MIN_CHORD_FRACTION * side`` = side / 10 (5 D with espin's
        default 50 D window). Portions of zero chord (a corner touched at one point, a closed
        loop) are always dropped.

    Returns
    -------
    VisibleFibers
        One entry per visible portion, ordered by fiber and along each fiber.
    """
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    offsets = np.asarray(fiber_offsets, dtype=np.int64)
    lo = np.asarray(origin, dtype=float).reshape(2)
    side = float(side)
    if not side > 0.0:
        raise ValueError(f"window side must be > 0, got {side}")
    if min_chord is None:
        min_chord = DEFAULT_MIN_CHORD_FRACTION * side
    if min_chord < 0.0:
        raise ValueError(f"min_chord must be >= 0, got {min_chord}")
    if offsets.ndim != 1 or len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != len(v):
        raise ValueError("fiber_offsets must start at 0 and end at the number of vertices")
    pieces = clip_to_window(v, offsets, lo, side)
    run_start = pieces.run_start
    n_runs = int(run_start.sum())
    last = np.r_[run_start[1:], True] if len(run_start) else run_start

    contour = np.bincount(pieces.run, pieces.length, minlength=n_runs)
    start = pieces.start[run_start]
    end = pieces.end[last]
    chord_vec = end - start
    chord = np.hypot(*chord_vec.T)
    keep = (chord > 0.0) & (chord >= min_chord)
    chord_vec, chord, contour = chord_vec[keep], chord[keep], contour[keep]
    # Rounding may put a straight portion's contour a hair below its chord.
    contour = np.maximum(contour, chord)
    return VisibleFibers(
        contour_length=contour,
        chord_length=chord,
        tortuosity=contour / chord,
        orientation=np.mod(np.arctan2(chord_vec[:, 1], chord_vec[:, 0]), np.pi),
        fiber=pieces.fiber[run_start][keep],
        start=start[keep],
        end=end[keep],
        origin=lo,
        side=side,
        min_chord=float(min_chord),
    )


def centred_window(size: float, side: float) -> tuple[np.ndarray, float]:
    """Origin [um] and side [um] of a square window of ``side`` centred in [0, size]^2.

    The side is clipped to ``size``.
    """
    side = min(float(side), float(size))
    corner = (float(size) - side) / 2.0
    return np.array([corner, corner]), side


def observation_window(config: Config, size: float) -> tuple[np.ndarray, float, float]:
    """Origin [um], side [um] and shortest chord [um] of the window a mat of layer side
    ``size`` [um] is seen through: centred, of side ``config.observation_window_um``; the
    shortest chord is ``targets.min_chord_um`` when the config gives it, else
    ``DEFAULT_MIN_CHORD_FRACTION`` of the side."""
    origin, side = centred_window(size, config.observation_window_um)
    given = None if config.targets is None else config.targets.min_chord_um
    return origin, side, DEFAULT_MIN_CHORD_FRACTION * side if given is None else given


# --------------------------------------------------------------------------------------------
# Targets and goodness of fit
# --------------------------------------------------------------------------------------------
WHOLE_PORTIONS = "whole window portions"
"""Tortuosity measured on every maximal fiber portion in the window (:func:`window_tortuosity`)."""
LENGTH_MATCHED = "length-matched pieces"
"""Tortuosity measured on pieces of the targets' contour lengths (:class:`TracedWindow`)."""


@dataclass(frozen=True, eq=False)
class Target:
    """A measured target of one quantity: a sample, or a distribution.

    Attributes
    ----------
    label : str
        What it is, for reports: ``"halfnorm(loc=1, scale=0.14)"``, ``"sample of 523 values"``.
    sample : (n,) float64, optional
        The measured values (in the units the quantity is graded in).
    law : frozen ``scipy.stats`` distribution, optional
        The distribution, when no sample is given.
    """

    label: str
    sample: np.ndarray | None = None
    law: Any = None

    @property
    def mean(self) -> float:
        """Mean of the sample or the distribution."""
        return _mean(self.sample) if self.sample is not None else float(self.law.mean())

    @property
    def sd(self) -> float:
        """Standard deviation (population) of the sample or the distribution."""
        return _std(self.sample) if self.sample is not None else float(self.law.std())

    def quantile(self, q: float) -> float:
        """The ``q`` quantile of the sample or the distribution."""
        return float(np.quantile(self.sample, q)) if self.sample is not None else float(self.law.ppf(q))

    def ks(self, values: ArrayLike) -> float:
        """KS statistic of ``values`` against this target: two-sample against a sample,
        one-sample against a distribution (NaN for an empty sample)."""
        if self.sample is not None:
            return ks_two_sample(values, self.sample)
        return ks_statistic(values, self.law.cdf)


def _sample_target(values: list[float], scale: float = 1.0) -> Target:
    return Target(f"sample of {len(values):,} values", sample=np.asarray(values, dtype=float) * scale)


def tortuosity_target(targets: TargetsConfig | None) -> Target | None:
    """The tortuosity target of ``targets``: its sample, or ``halfnorm(loc=1, scale)``; None
    when it gives neither."""
    from scipy import stats

    if targets is None:
        return None
    if targets.tortuosity is not None:
        return _sample_target(targets.tortuosity)
    scale = targets.tortuosity_halfnorm_scale
    if scale is None:
        return None
    return Target(f"halfnorm(loc=1, scale={scale:g})", law=stats.halfnorm(loc=1.0, scale=scale))


def diameter_target(targets: TargetsConfig | None) -> Target | None:
    """The diameter target [um] of ``targets``: its sample, or the normal or lognormal of
    the given mean and sd (a point mass, given as a one-value sample, when sd = 0); None
    when it gives neither."""
    from scipy import stats

    if targets is None:
        return None
    if targets.diameter_um is not None:
        return _sample_target(targets.diameter_um)
    mean, sd = targets.diameter_mean_um, cast(float, targets.diameter_sd_um)  # given with the mean
    if mean is None:
        return None
    if sd == 0.0:
        return Target(f"fixed {mean:g} um", sample=np.array([mean]))
    if targets.diameter_distribution == "normal":
        return Target(f"normal({mean:g}, {sd:g}) um", law=stats.norm(loc=mean, scale=sd))
    sigma2 = math.log1p((sd / mean) ** 2)  # lognormal of that mean and sd
    law = stats.lognorm(s=math.sqrt(sigma2), scale=mean * math.exp(-sigma2 / 2.0))
    return Target(f"lognormal(mean {mean:g}, sd {sd:g}) um", law=law)


@dataclass(frozen=True, eq=False)
class TracedWindow:
    """A mat measured in its observation window as the SEM tracer measures, beyond the whole
    window portions: made by :func:`espin.geometry.rve_folder.trace_window` with
    :mod:`espin.geometry.pieces` (which stands on this module).

    Attributes
    ----------
    piece_tortuosity : (n,) float64, optional
        Tortuosity of pieces of the targets' contour lengths (None: not sampled).
    piece_orientation : (n,) float64 [rad], optional
        Axes of their chords, in [0, pi).
    n_crossing : int, optional
        Window portions that cross the window edge to edge (None: not measured).
    u_turn_fraction : float
        Of those, the fraction that leave through the edge they entered (NaN: none or not
        measured).
    straightness : float
        Their mean end-to-end over contour length (NaN: none or not measured).
    """

    piece_tortuosity: np.ndarray | None = None
    piece_orientation: np.ndarray | None = None
    n_crossing: int | None = None
    u_turn_fraction: float = math.nan
    straightness: float = math.nan


@dataclass(frozen=True, eq=False)
class Graded:
    """One quantity of a mat graded against its measured target.

    Attributes
    ----------
    target : Target
        The measured target.
    mat : (n,) float64
        The mat's values as graded (empty when they could not be measured).
    ks : float
        KS statistic of ``mat`` against ``target`` (0 same, 1 disjoint; NaN if ``mat`` is
        empty).
    """

    target: Target
    mat: np.ndarray
    ks: float


def _graded(target: Target | None, mat: np.ndarray) -> Graded | None:
    return None if target is None else Graded(target, mat, target.ks(mat))


@dataclass(frozen=True, eq=False)
class TargetGrading:
    """A mat against the measured targets of its config (``[targets]``).

    Attributes
    ----------
    targets : TargetsConfig, optional
        The config's targets; None: no measured targets, nothing graded.
    tortuosity : Graded, optional
        Tortuosity in the window: of the whole window portions, or of pieces of the targets'
        contour lengths (``tortuosity_sampling``).
    tortuosity_sampling : str, optional
        :data:`WHOLE_PORTIONS` or :data:`LENGTH_MATCHED` when tortuosity is graded.
    diameter : Graded, optional
        Fiber diameters [um], one per fiber.
    orientation : Graded, optional
        Chord axes [rad] of the same portions or pieces as the tortuosity, against the
        measured sample of ``targets.orientation_deg``.
    n_crossing : int, optional
        Window portions crossing the window edge to edge, when the U-turn fraction or the
        straightness is a target (None: not measured).
    u_turn_fraction, straightness : float
        The mat's (NaN: not measured, or no portion crossing).
    """

    targets: TargetsConfig | None = None
    tortuosity: Graded | None = None
    tortuosity_sampling: str | None = None
    diameter: Graded | None = None
    orientation: Graded | None = None
    n_crossing: int | None = None
    u_turn_fraction: float = math.nan
    straightness: float = math.nan


def grade(
    targets: TargetsConfig | None, window: VisibleFibers, diameter_um: np.ndarray, traced: TracedWindow | None = None
) -> TargetGrading:
    """Grade a mat against measured ``targets``.

    Parameters
    ----------
    targets : TargetsConfig, optional
        The config's ``[targets]``; None grades nothing.
    window : VisibleFibers
        The mat's whole portions in its observation window.
    diameter_um : (n_fibers,) float64 [um]
        Its fiber diameters.
    traced : TracedWindow, optional
        Its length-matched pieces and crossing statistics, needed when the targets give
        contour lengths or crossing statistics (without it those are not measured: empty
        samples, NaN).

    Returns
    -------
    TargetGrading
    """
    if targets is None:
        return TargetGrading()
    traced = TracedWindow() if traced is None else traced
    if targets.contour_length_um is None:
        sampling, tortuosity, orientation = WHOLE_PORTIONS, window.tortuosity, window.orientation
    else:
        sampling = LENGTH_MATCHED
        tortuosity = _or_empty(traced.piece_tortuosity)
        orientation = _or_empty(traced.piece_orientation)
    graded_tortuosity = _graded(tortuosity_target(targets), tortuosity)
    crossings = targets.u_turn_fraction is not None or targets.straightness is not None
    return TargetGrading(
        targets=targets,
        tortuosity=graded_tortuosity,
        tortuosity_sampling=None if graded_tortuosity is None else sampling,
        diameter=_graded(diameter_target(targets), diameter_um),
        orientation=None
        if targets.orientation_deg is None
        else _graded(_sample_target(targets.orientation_deg, math.pi / 180.0), orientation),
        n_crossing=traced.n_crossing if crossings else None,
        u_turn_fraction=traced.u_turn_fraction if crossings else math.nan,
        straightness=traced.straightness if crossings else math.nan,
    )


def _or_empty(x: np.ndarray | None) -> np.ndarray:
    return np.empty(0) if x is None else np.asarray(x, dtype=float)


def ks_statistic(sample: ArrayLike, cdf: Callable[[np.ndarray], np.ndarray]) -> float:
    """Kolmogorov-Smirnov statistic sup |F_n - F| of ``sample`` against the target ``cdf``.

    Only the statistic is returned (NaN for an empty sample): it measures the distance between
    the distributions on a scale from 0 to 1. A p-value would be misleading here: the samples
    are large and not independent draws (portions of the same mat), and a degenerate sample
    (all diameters equal, a fixed diameter) against a continuous target is not a sample of any
    continuous distribution at all.
    """
    from scipy import stats

    x = np.asarray(sample, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return math.nan
    return float(stats.kstest(x, cdf).statistic)


def ks_two_sample(sample: ArrayLike, target: ArrayLike) -> float:
    """Two-sample Kolmogorov-Smirnov statistic sup |F_n - G_m| of ``sample`` against a
    measured ``target`` sample (NaN if either is empty); see :func:`ks_statistic` for why
    only the statistic."""
    from scipy import stats

    x, y = _finite(sample), _finite(target)
    if len(x) == 0 or len(y) == 0:
        return math.nan
    return float(stats.ks_2samp(x, y).statistic)


# --------------------------------------------------------------------------------------------
# Network statistics
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class NetworkStatistics:
    """Statistics of a mat and its network (docs/model.md section 2) and the fit to measured
    targets (docs/model.md section 7).

    Cross-link conventions
    ----------------------
    A cross-link is an inner node of the network (merged cross-links count once).

    - ``crosslink_density_per_um``: cross-links met per um walked along a fiber, i.e. the
      number of (cross-link, fiber) incidences over the total fiber contour length. Each
      cross-link lies on two fibers (more if merged), so this is 2 n_crosslinks / total length
      when none are merged; its inverse is the mean spacing of cross-links along a fiber.
    - ``crosslink_density_per_um2``: cross-links per um^2 of one layer,
      n_crosslinks / (N_l L^2).
    - Integral-geometry expectation (docs/model.md section 2): isotropic stationary lines of length density
      L_A,k (um of fiber per um^2) in layer k cross L_A,k^2 / pi times per unit area within
      the layer and 2 L_A,k L_A,k+1 / pi times between adjacent layers. L_A,k is the achieved
      density (fiber length in layer k / L^2), so with equal layers the expected total is
      L^2 (N_l L_A^2 / pi + (N_l - 1) 2 L_A^2 / pi); the nominal L_A = 4 eta / (pi D) is
      ``nominal_length_density_per_um``. ``border`` seeding deviates by a percent or two.
      A cross-link is "within" when all elements at its node belong to one layer.
    - The formula counts pairs of a line with itself, which a finite mat cannot have (a
      fiber crossing itself makes no cross-link). Excluding them, independent isotropic
      straight fibers of lengths l_i cross within layer k
      (sum(l_i)^2 - sum(l_i^2)) / (pi L^2) times: ``expected_crosslinks_within_distinct``,
      lower by about 1 / (fibers per layer), 1.5 % within a ``plla`` layer. ``lines`` seeding
      matches this one to about 0.1 % over several seeds.

    Attributes
    ----------
    n_fibers, n_segments, n_elements : int
        Counts of the mat and network.
    n_inner_nodes, n_border_nodes, n_merged, n_dof : int
        Inner nodes (cross-links), border nodes (fiber ends), node candidates merged into
        another node, and degrees of freedom (2 per inner node).
    n_crosslinks_within_layer, n_crosslinks_between_layers : int
        Cross-links joining fibers of one layer / of adjacent layers.
    size_um, thickness_um : float [um]
        Layer side L and thickness D.
    n_layers : int
        Number of layers N_l.
    total_fiber_length_um : float [um]
        Sum of fiber contour lengths.
    layer_volume_fraction : (n_layers,) float64
        Achieved volume fraction of each layer.
    target_volume_fraction : float
        Configured eta.
    layer_length_density_per_um : (n_layers,) float64 [1/um]
        Fiber length per unit layer area L_A,k [um / um^2].
    nominal_length_density_per_um : float [1/um]
        4 eta / (pi D) with the configured eta and D.
    crosslink_density_per_um : float [1/um]
        Cross-links per um of fiber (see above).
    crosslink_density_per_um2 : float [1/um^2]
        Cross-links per um^2 of layer.
    expected_crosslinks_within, expected_crosslinks_between : float
        Integral-geometry expectation for the whole mat (docs/model.md section 2 formula).
    expected_crosslinks_within_distinct : float
        Within-layer expectation without self-pairs (see above).
    fiber_orientation : (n_fibers,) float64 [rad]
        Axis of each fiber's end-to-end chord, in [0, pi) (the paper measured orientation
        along the end-to-end line). With ``border`` seeding a few percent of the fibers are
        seeded nearly parallel to an edge and leave through the same edge, so their chord
        lies exactly along it: the histogram has spikes at 0 and 90 deg. That is the
        seeding's geometry; the window sample (``window.orientation``) is free of it.
    segment_orientation : (n_segments,) float64 [rad]
        Axis of each deposition segment, in [0, pi).
    segment_length_um : (n_segments,) float64 [um]
        Length of each segment (the weights of the orientation moments).
    fiber_tortuosity : (n_fibers,) float64
        Contour over end-to-end length of whole fibers.
    element_tortuosity : (n_elements,) float64
        lambda_r = L0 / l0 of the elements.
    diameter_um : (n_fibers,) float64 [um]
        Diameter of each fiber (one value per fiber, not length-weighted).
    element_length_um : (n_elements,) float64 [um]
        End-to-end length l0 of the elements.
    window : VisibleFibers
        Fiber portions (all layers pooled) visible in the observation window.
    orientation_target : OrientationDistribution
        The configured orientation distribution.
    ks_fiber_orientation : float
        KS statistic of ``fiber_orientation`` against ``orientation_target``.
    ks_window_orientation : float
        KS statistic of the visible portions' orientation against ``orientation_target``.
    grading : TargetGrading
        The mat against the measured targets of the config (none without ``[targets]``).
        Against the paper's targets (``plla``) the window tortuosity's KS statistic is about
        0.95 with the Table 2 parameters: the virtual fibers are far straighter than the
        measured ones (a result, not a failure; see the module docs); and with a fixed
        diameter the diameter sample is degenerate: its KS statistic still measures the
        distance to the target (0.5 + |Phi((D - mean) / sd) - 0.5|), but no p-value is
        meaningful.
    """

    n_fibers: int
    n_segments: int
    n_elements: int
    n_inner_nodes: int
    n_border_nodes: int
    n_merged: int
    n_dof: int
    n_crosslinks_within_layer: int
    n_crosslinks_between_layers: int
    size_um: float
    thickness_um: float
    n_layers: int
    total_fiber_length_um: float
    layer_volume_fraction: np.ndarray
    target_volume_fraction: float
    layer_length_density_per_um: np.ndarray
    nominal_length_density_per_um: float
    crosslink_density_per_um: float
    crosslink_density_per_um2: float
    expected_crosslinks_within: float
    expected_crosslinks_between: float
    expected_crosslinks_within_distinct: float
    fiber_orientation: np.ndarray
    segment_orientation: np.ndarray
    segment_length_um: np.ndarray
    fiber_tortuosity: np.ndarray
    element_tortuosity: np.ndarray
    diameter_um: np.ndarray
    element_length_um: np.ndarray
    window: VisibleFibers
    orientation_target: OrientationDistribution
    ks_fiber_orientation: float = math.nan
    ks_window_orientation: float = math.nan
    grading: TargetGrading = field(default_factory=TargetGrading)

    def orientation_moments(self) -> dict[str, float]:
        """Length-weighted orientation moments of the mat's segments against the target's.

        With n = (cos phi, sin phi) the segment axis and weights the segment lengths:
        ``cos2`` = <cos^2 phi>, ``cos4`` = <cos^4 phi> (the affine modulus along x goes as
        <cos^4>, the yield stress as <cos^2>; docs/model.md section 7), the orientation tensor
        <n (x) n> (``tensor_11``, ``tensor_12``; ``tensor_22`` = 1 - ``tensor_11``), the same
        moments of the target distribution ``target_*`` (by quadrature of its density), and
        ``tensor_deviation``, the Frobenius norm of the difference of the two tensors (0: the
        realization's second moments are the target's).
        """
        phi = self.segment_orientation
        w = self.segment_length_um / np.sum(self.segment_length_um)
        c, s = np.cos(phi), np.sin(phi)
        mat = {"cos2": float(np.sum(w * c * c)), "cos4": float(np.sum(w * c**4)), "tensor_12": float(np.sum(w * c * s))}
        theta = (np.arange(_MOMENT_POINTS) + 0.5) * np.pi / _MOMENT_POINTS
        density = self.orientation_target.pdf(theta)
        density = density / np.sum(density)
        ct, st = np.cos(theta), np.sin(theta)
        target = {
            "cos2": float(np.sum(density * ct * ct)),
            "cos4": float(np.sum(density * ct**4)),
            "tensor_12": float(np.sum(density * ct * st)),
        }
        d11, d12 = mat["cos2"] - target["cos2"], mat["tensor_12"] - target["tensor_12"]
        return {
            **mat,
            "tensor_11": mat["cos2"],
            **{f"target_{k}": v for k, v in target.items()},
            "target_tensor_11": target["cos2"],
            "tensor_deviation": float(np.sqrt(2.0 * d11 * d11 + 2.0 * d12 * d12)),
        }

    @property
    def n_crosslinks(self) -> int:
        """Number of cross-links (inner nodes)."""
        return self.n_inner_nodes

    @property
    def mean_volume_fraction(self) -> float:
        """Mean achieved volume fraction over the layers."""
        return float(np.mean(self.layer_volume_fraction))

    @property
    def expected_crosslinks(self) -> float:
        """Integral-geometry expectation of the number of cross-links in the mat."""
        return self.expected_crosslinks_within + self.expected_crosslinks_between

    @property
    def expected_crosslinks_distinct(self) -> float:
        """Expected cross-links without pairs of a fiber with itself."""
        return self.expected_crosslinks_within_distinct + self.expected_crosslinks_between

    @property
    def crosslink_ratio(self) -> float:
        """Cross-links found over the integral-geometry expectation (docs/model.md section 2 formula)."""
        e = self.expected_crosslinks
        return self.n_inner_nodes / e if e > 0 else math.nan

    @property
    def crosslink_ratio_distinct(self) -> float:
        """Cross-links found over the expectation without self-pairs."""
        e = self.expected_crosslinks_distinct
        return self.n_inner_nodes / e if e > 0 else math.nan

    def summary(self) -> dict[str, int | float | str | None]:
        """Flat, JSON-ready dict of the scalar results; units in the key names.

        Angles are in degrees. NaN (an empty sample) becomes None.
        """
        w = self.window
        order, director = _axial_order(self.fiber_orientation)
        out: dict[str, Any] = {
            "n_fibers": self.n_fibers,
            "n_segments": self.n_segments,
            "n_elements": self.n_elements,
            "n_inner_nodes": self.n_inner_nodes,
            "n_border_nodes": self.n_border_nodes,
            "n_merged_nodes": self.n_merged,
            "n_dof": self.n_dof,
            "n_layers": self.n_layers,
            "size_um": self.size_um,
            "thickness_um": self.thickness_um,
            "total_fiber_length_um": self.total_fiber_length_um,
            "volume_fraction_target": self.target_volume_fraction,
            "volume_fraction_mean": self.mean_volume_fraction,
            "volume_fraction_min": float(np.min(self.layer_volume_fraction)),
            "volume_fraction_max": float(np.max(self.layer_volume_fraction)),
            "length_density_mean_per_um": float(np.mean(self.layer_length_density_per_um)),
            "length_density_nominal_per_um": self.nominal_length_density_per_um,
            "n_crosslinks": self.n_crosslinks,
            "n_crosslinks_within_layer": self.n_crosslinks_within_layer,
            "n_crosslinks_between_layers": self.n_crosslinks_between_layers,
            "crosslink_density_per_um": self.crosslink_density_per_um,
            "crosslink_spacing_um": _inverse(self.crosslink_density_per_um),
            "crosslink_density_per_um2": self.crosslink_density_per_um2,
            "expected_crosslinks": self.expected_crosslinks,
            "expected_crosslinks_within_layer": self.expected_crosslinks_within,
            "expected_crosslinks_between_layers": self.expected_crosslinks_between,
            "crosslink_ratio_to_expected": self.crosslink_ratio,
            "expected_crosslinks_distinct": self.expected_crosslinks_distinct,
            "expected_crosslinks_within_layer_distinct": self.expected_crosslinks_within_distinct,
            "crosslink_ratio_to_expected_distinct": self.crosslink_ratio_distinct,
            "fiber_orientation_order": order,
            "fiber_orientation_director_deg": director,
            "fiber_tortuosity_mean": _mean(self.fiber_tortuosity),
            "fiber_tortuosity_max": _max(self.fiber_tortuosity),
            "element_tortuosity_mean": _mean(self.element_tortuosity),
            "element_tortuosity_max": _max(self.element_tortuosity),
            "element_length_mean_um": _mean(self.element_length_um),
            "element_length_min_um": _min(self.element_length_um),
            "diameter_mean_um": _mean(self.diameter_um),
            "diameter_sd_um": _std(self.diameter_um),
            "window_side_um": w.side,
            "window_min_chord_um": w.min_chord,
            "window_n_portions": len(w),
            "window_tortuosity_mean": _mean(w.tortuosity),
            "window_tortuosity_sd": _std(w.tortuosity),
            **{f"orientation_{k}": v for k, v in self.orientation_moments().items()},
            "orientation_target": self.orientation_target.label,
            "ks_fiber_orientation": self.ks_fiber_orientation,
            "ks_window_orientation": self.ks_window_orientation,
            **_grading_summary(self.grading),
        }
        return {k: _json_value(v) for k, v in out.items()}

    def format_table(self) -> str:
        """Plain-text table of :meth:`summary` for the command line."""
        s = self.summary()
        groups = [
            (
                "counts",
                [
                    "n_fibers",
                    "n_segments",
                    "n_elements",
                    "n_inner_nodes",
                    "n_border_nodes",
                    "n_merged_nodes",
                    "n_dof",
                    "n_layers",
                ],
            ),
            (
                "geometry",
                [
                    "size_um",
                    "thickness_um",
                    "total_fiber_length_um",
                    "volume_fraction_target",
                    "volume_fraction_mean",
                    "volume_fraction_min",
                    "volume_fraction_max",
                    "length_density_mean_per_um",
                    "length_density_nominal_per_um",
                ],
            ),
            (
                "cross-links",
                [
                    "n_crosslinks",
                    "n_crosslinks_within_layer",
                    "n_crosslinks_between_layers",
                    "crosslink_density_per_um",
                    "crosslink_spacing_um",
                    "crosslink_density_per_um2",
                    "expected_crosslinks",
                    "expected_crosslinks_within_layer",
                    "expected_crosslinks_between_layers",
                    "crosslink_ratio_to_expected",
                    "expected_crosslinks_distinct",
                    "expected_crosslinks_within_layer_distinct",
                    "crosslink_ratio_to_expected_distinct",
                ],
            ),
            (
                "fibers and elements",
                [
                    "fiber_orientation_order",
                    "fiber_orientation_director_deg",
                    "fiber_tortuosity_mean",
                    "fiber_tortuosity_max",
                    "element_tortuosity_mean",
                    "element_tortuosity_max",
                    "element_length_mean_um",
                    "element_length_min_um",
                    "diameter_mean_um",
                    "diameter_sd_um",
                ],
            ),
            (
                "observation window (as SEM)",
                [
                    "window_side_um",
                    "window_min_chord_um",
                    "window_n_portions",
                    "window_tortuosity_mean",
                    "window_tortuosity_sd",
                ],
            ),
            (
                "against the config's orientation distribution (KS statistic: 0 same, 1 disjoint)",
                ["orientation_target", "ks_fiber_orientation", "ks_window_orientation"],
            ),
            (
                "length-weighted orientation moments of the segments, x the 0 deg axis (and the target's)",
                [
                    "orientation_cos2",
                    "orientation_target_cos2",
                    "orientation_cos4",
                    "orientation_target_cos4",
                    "orientation_tensor_12",
                    "orientation_target_tensor_12",
                    "orientation_tensor_deviation",
                ],
            ),
            ("against measured targets (KS statistic: 0 same, 1 disjoint)", _graded_keys(self.grading)),
        ]
        width = max(len(k) for _, keys in groups for k in keys)
        lines: list[str] = []
        for title, keys in groups:
            lines.append(title)
            lines += [f"  {k:<{width}}  {_format_value(s[k])}" for k in keys] or [f"  {NO_TARGETS}"]
        return "\n".join(lines)


NO_TARGETS = "no measured targets in the config"
"""What the table says when the config has no ``[targets]`` section."""


def _grading_summary(g: TargetGrading) -> dict[str, Any]:
    """The summary entries of a grading: target against mat for each quantity (None where
    it is not graded)."""
    t = g.targets
    tort, dia, ori = g.tortuosity, g.diameter, g.orientation
    mat_tortuosity = np.empty(0) if tort is None else tort.mat
    return {
        "targets_source": None if t is None else t.source or "not given",
        "target_window_um": None if t is None else t.window_um,
        "target_tortuosity": None if tort is None else tort.target.label,
        "tortuosity_sampling": g.tortuosity_sampling,
        "target_tortuosity_mean": None if tort is None else tort.target.mean,
        "target_tortuosity_sd": None if tort is None else tort.target.sd,
        "mat_tortuosity_n": None if tort is None else len(mat_tortuosity),
        "mat_tortuosity_mean": _mean(mat_tortuosity),
        "mat_tortuosity_sd": _std(mat_tortuosity),
        "ks_window_tortuosity": math.nan if tort is None else tort.ks,
        "target_diameter": None if dia is None else dia.target.label,
        "target_diameter_mean_um": None if dia is None else dia.target.mean,
        "target_diameter_sd_um": None if dia is None else dia.target.sd,
        "ks_diameter": math.nan if dia is None else dia.ks,
        "target_orientation": None if ori is None else ori.target.label,
        "ks_measured_orientation": math.nan if ori is None else ori.ks,
        "target_u_turn_fraction": None if t is None else t.u_turn_fraction,
        "target_straightness": None if t is None else t.straightness,
        "mat_n_crossing": g.n_crossing,
        "mat_u_turn_fraction": g.u_turn_fraction,
        "mat_straightness": g.straightness,
    }


def _graded_keys(g: TargetGrading) -> list[str]:
    """Keys of the table's target rows: the source, and target against mat of each graded
    quantity."""
    t = g.targets
    if t is None:
        return []
    keys = ["targets_source"] + ["target_window_um", "window_side_um"] * (t.window_um is not None)
    if g.tortuosity is not None:
        keys += [
            "target_tortuosity",
            "tortuosity_sampling",
            "target_tortuosity_mean",
            "target_tortuosity_sd",
            "mat_tortuosity_n",
            "mat_tortuosity_mean",
            "mat_tortuosity_sd",
            "ks_window_tortuosity",
        ]
    if g.diameter is not None:
        keys += [
            "target_diameter",
            "target_diameter_mean_um",
            "target_diameter_sd_um",
            "diameter_mean_um",
            "diameter_sd_um",
            "ks_diameter",
        ]
    if g.orientation is not None:
        keys += ["target_orientation", "ks_measured_orientation"]
    if g.n_crossing is not None or t.u_turn_fraction is not None or t.straightness is not None:
        keys += ["mat_n_crossing"]
    if t.u_turn_fraction is not None:
        keys += ["target_u_turn_fraction", "mat_u_turn_fraction"]
    if t.straightness is not None:
        keys += ["target_straightness", "mat_straightness"]
    return keys


def network_statistics(
    mat: FiberMat,
    network: Network,
    config: Config,
    traced: TracedWindow | None = None,
) -> NetworkStatistics:
    """Statistics of a deposited mat and its network, compared with their targets.

    Parameters
    ----------
    mat : FiberMat
        The deposited fibers.
    network : Network
        The network built from ``mat``.
    config : Config
        The run configuration: the orientation target (``rve.orientation``), the target
        volume fraction and diameter, the measured targets (``targets``, optional), and the
        observation window (:func:`observation_window`: side
        ``Config.observation_window_um``, centred in the RVE, seeing all layers like an SEM
        image of a mat whose layers are statistically alike).
    traced : TracedWindow, optional
        The mat's length-matched pieces and crossing statistics, from
        :func:`espin.geometry.rve_folder.trace_window`; needed when the targets give contour
        lengths or crossing statistics, which are otherwise reported as not measured.

    Returns
    -------
    NetworkStatistics
        See its documentation for the conventions (cross-link densities, expectations, KS).
    """
    from espin.geometry.orientation import orientation_distribution

    L = float(mat.size)
    n_layers = int(mat.n_layers)
    area = L * L

    # Cross-links: incidences along fibers, and within / between layers from the elements
    # meeting at each inner node.
    n_inner = int(network.n_inner)
    en = np.asarray(network.element_nodes)
    incidences = np.count_nonzero(en < n_inner) / 2.0
    total_length = float(np.sum(mat.contour_length))
    layer_of_end = np.repeat(np.asarray(network.element_layer), 2)
    node_of_end = en.ravel()
    lo_layer = np.full(n_inner, np.iinfo(np.int64).max)
    hi_layer = np.full(n_inner, np.iinfo(np.int64).min)
    at_inner = node_of_end < n_inner
    np.minimum.at(lo_layer, node_of_end[at_inner], layer_of_end[at_inner])
    np.maximum.at(hi_layer, node_of_end[at_inner], layer_of_end[at_inner])
    n_within = int(np.count_nonzero(lo_layer == hi_layer))
    n_between = int(np.count_nonzero(lo_layer < hi_layer))

    layer_length = np.bincount(mat.fiber_layer, mat.contour_length, minlength=n_layers)
    la = layer_length / area
    expected_within = area * float(np.sum(la**2)) / np.pi
    layer_length_sq = np.bincount(mat.fiber_layer, mat.contour_length**2, minlength=n_layers)
    expected_within_distinct = float(np.sum(layer_length**2 - layer_length_sq)) / (np.pi * area)
    expected_between = area * 2.0 * float(np.sum(la[:-1] * la[1:])) / np.pi

    # Samples.
    seg_vec = mat.vertices[mat.segment_start + 1] - mat.vertices[mat.segment_start]
    segment_orientation = np.mod(np.arctan2(seg_vec[:, 1], seg_vec[:, 0]), np.pi)
    element_tortuosity = np.asarray(network.element_tortuosity, dtype=float)
    origin, side, min_chord = observation_window(config, L)
    window = window_tortuosity(mat.vertices, mat.fiber_offsets, origin, side, min_chord)
    diameter = np.asarray(mat.fiber_diameter, dtype=float)

    target = orientation_distribution(config.rve.orientation)
    D = config.rve.diameter_um
    eta = config.rve.volume_fraction
    return NetworkStatistics(
        n_fibers=int(mat.n_fibers),
        n_segments=int(mat.n_segments),
        n_elements=int(network.n_elements),
        n_inner_nodes=n_inner,
        n_border_nodes=int(network.n_border),
        n_merged=int(network.n_merged),
        n_dof=int(network.n_dof),
        n_crosslinks_within_layer=n_within,
        n_crosslinks_between_layers=n_between,
        size_um=L,
        thickness_um=float(mat.thickness),
        n_layers=n_layers,
        total_fiber_length_um=total_length,
        layer_volume_fraction=np.asarray(mat.layer_volume_fraction()),
        target_volume_fraction=float(eta),
        layer_length_density_per_um=la,
        nominal_length_density_per_um=4.0 * eta / (np.pi * D),
        crosslink_density_per_um=incidences / total_length if total_length > 0 else math.nan,
        crosslink_density_per_um2=n_inner / (n_layers * area),
        expected_crosslinks_within=expected_within,
        expected_crosslinks_between=expected_between,
        expected_crosslinks_within_distinct=expected_within_distinct,
        fiber_orientation=np.asarray(mat.orientation),
        segment_orientation=segment_orientation,
        segment_length_um=np.hypot(seg_vec[:, 0], seg_vec[:, 1]),
        fiber_tortuosity=np.asarray(mat.tortuosity),
        element_tortuosity=element_tortuosity,
        diameter_um=diameter,
        element_length_um=np.asarray(network.element_length, dtype=float),
        window=window,
        orientation_target=target,
        ks_fiber_orientation=ks_statistic(mat.orientation, target.cdf),
        ks_window_orientation=ks_statistic(window.orientation, target.cdf),
        grading=grade(config.targets, window, diameter, traced),
    )


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
_MOMENT_POINTS = 3600  # midpoints over [0, pi) for the target's orientation moments


def _axial_order(theta: np.ndarray) -> tuple[float, float]:
    """Order parameter |<exp(2 i theta)>| (0 isotropic, 1 aligned) and director [deg]."""
    theta = np.asarray(theta, dtype=float)
    if len(theta) == 0:
        return math.nan, math.nan
    z = np.mean(np.exp(2j * theta))
    return float(abs(z)), float(np.degrees(np.mod(np.angle(z) / 2.0, np.pi)))


def _finite(x: ArrayLike) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return x[np.isfinite(x)]


def _mean(x: np.ndarray) -> float:
    x = _finite(x)
    return float(np.mean(x)) if len(x) else math.nan


def _std(x: np.ndarray) -> float:
    x = _finite(x)
    if len(x) == 0:
        return math.nan
    return float(np.std(x)) if np.ptp(x) > 0 else 0.0  # exactly 0 for a fixed value


def _min(x: np.ndarray) -> float:
    x = _finite(x)
    return float(np.min(x)) if len(x) else math.nan


def _max(x: np.ndarray) -> float:
    x = _finite(x)
    return float(np.max(x)) if len(x) else math.nan


def _inverse(x: float) -> float:
    return 1.0 / x if x > 0 else math.nan


def _json_value(v: Any) -> int | float | str | None:
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        v = float(v)
        return v if math.isfinite(v) else None
    return v


def _format_value(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, int):
        return f"{v:,}"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)
