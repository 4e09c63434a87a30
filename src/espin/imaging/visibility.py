"""Fully visible fibers against partly hidden deeper ones.

An analyst measuring diameters by hand picks the fibers of the top of the mat: seen whole
(both edges), in focus and passing over, not under, the fibers they cross. Fibers deeper in
the mat are dimmer (fewer secondary electrons escape from below), blurred (out of focus),
interrupted where a higher fiber covers them, and read narrower where a neighbour covers an
edge. Per traced fiber, :func:`fiber_features` measures:

- ``brightness``: its plateau (the mean of the smoothed image over the middle half of its
  width, median along the fiber) above the image's dark level (its 0.5th percentile), over the
  same for the brightest fibers around it (the 90th percentile of the plateaus of the width
  samples within a quarter of the image diagonal, so that uneven illumination cancels);
- ``edge_sigma_px``: the blur of its edges [px], sigma of the Gaussian-blurred step whose
  steepest slope is that of its median profile (1 / (sqrt(2 pi) sigma) for a unit step);
- ``edge_contrast``: how free its weaker edge is: the drop of its profile from the plateau
  to the lowest level within w / 2 beyond that edge, over the plateau above the dark level
  (median along the fiber; 1 with background on both sides, near 0 for a trace along the
  rim of a wider fiber or between two fibers lying side by side);
- ``occluded``: of the junctions on its path, the fraction where the image is
  :data:`OCCLUSION_RATIO` times as bright as its own plateau or more (a brighter fiber covers
  it there);
- ``both_edges``: the fraction of its width sample points where both edges were found.

The rule (:func:`classify`): a fiber is visible when its brightness is at least a threshold,
both its edges are free (edge contrast at least :data:`MIN_EDGE_CONTRAST`) and it is covered
at no more than half of its junctions (:data:`OCCLUDED_FRACTION`). The
threshold comes from the image: a mixture of two normals is fitted to ln brightness
(:func:`espin.imaging.distributions.fit_normal_mixture`); when it has a smaller BIC than one
normal, its components are :data:`MIN_SEPARATION` times apart or more and the smaller holds
at least three fibers, the image shows two populations and the threshold is the geometric
mean of their two levels; else it shows one, and the threshold is :data:`SINGLE_THRESHOLD`.

Why these features and these numbers (benchmarks/bench_sem_visible.py: 14 renderings of
virtual mats, 570 traced fibers of the top layer or the one below; docs/sem.md): brightness
is 0.945 +- 0.044 on the top layer (5th-95th percentile 0.86-1.00) and 0.585 +- 0.072 one
layer down (0.48-0.68): the two differ by 6.0 pooled standard deviations. Edge blur (1.42 +-
0.14 against 1.74 +- 0.22 px) differs by 1.7, the fraction of both edges found (0.97 against
0.93) by less than 1, so both are reported, not used. Edge contrast (0.76 +- 0.13 against
0.70 +- 0.17) does not tell the layers apart either; it removes what is no whole fiber of the
top: on PLGA-1500_1, where brightness does not separate the layers, the 13 traces it removes
are mostly rims of thick fibers read as 1-um fibers. The covered fraction is 0.004 +- 0.036 on
top fibers and 0.52 +- 0.40 below: half of the deeper fibers show no covered junction (their
crossings are traced as their ends), so it can only veto. The threshold sits in the middle
(in ln) of the two levels rather than where the fitted components are equally likely: the
top component is narrow (sd 0.03-0.05 in ln) and top fibers in a shaded corner or under
noise fall below it; the equal-likelihood point lay at 0.87-0.90 on some renderings and
missed top fibers of brightness 0.79-0.86 (recall 0.965 against 0.994, with the tracer of
that time).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, stats
from scipy.spatial import cKDTree

from espin.imaging.distributions import MIN_COMPONENT, fit_normal_mixture
from espin.imaging.widths import WidthSamples, sample_counts

__all__ = [
    "Visibility",
    "classify",
    "fiber_features",
    "fiber_visibility",
    "OCCLUSION_RATIO",
    "OCCLUDED_FRACTION",
    "MIN_EDGE_CONTRAST",
    "MIN_SEPARATION",
    "SINGLE_THRESHOLD",
]

OCCLUSION_RATIO = 1.25
"""A junction at least this many times brighter (above the dark level) than a fiber's plateau
covers it: a fiber one layer down is 0.65 times as bright with the default dimming of
:func:`espin.imaging.synthetic.render_sem`, so a junction over it is 1 / 0.65 = 1.54 times;
two fibers of one layer cross at about 1. The geometric middle of 1 and 1.54."""
OCCLUDED_FRACTION = 0.5
"""A fiber covered at more than this fraction of its junctions is hidden, however bright. On
the benchmark's renderings brightness alone decides (the veto changed none of 570 fibers);
it is the analyst's rule where brightness does not separate the layers."""
MIN_SEPARATION = 1.2
"""The two components of ln brightness must be this factor apart to be two populations: on
the benchmark's renderings the layer below was 1.44-1.75 times dimmer than the top (1.44-1.47
with a dimming of 0.25 per layer), while the two components fitted to one population (images
where no deeper fiber was traced) were 1.11-1.13 apart, and BIC alone preferred them on both."""
MIN_EDGE_CONTRAST = 0.3
"""Both edges free: beside its weaker edge a visible fiber's profile drops by at least this
fraction of its plateau (above the dark level). On the benchmark's renderings top fibers
dropped by 0.76 +- 0.13, at least 0.425 (a deeper fiber touching one edge, 0.65 as bright:
0.35 before blur); on PLGA-1500_1 the traces along one bright rim of a thick fiber dropped by
0.08-0.22, and top fibers lying side by side with another by 0.17-0.29 (an analyst skips
both: an edge between two fibers is not a free edge)."""
SINGLE_THRESHOLD = 0.7
"""Brightness below which a fiber is hidden when the image shows one population: below the
top layer's 5th percentile (0.86; its lowest of 342 values were 0.70, 0.76, 0.77) and at
the 95th percentile of the layer below (0.68)."""
_REFERENCE_QUANTILE = 90.0  # percentile of the plateaus around a sample: the brightest fibers
_REFERENCE_RADIUS = 0.25  # of the image diagonal
_BLOCK_PAIRS = 2_000_000  # sample pairs whose distance is evaluated at once in _reference
_DARK_PERCENTILE = 0.5
_STEP = 0.25  # px, between the points of a profile


@dataclass(frozen=True, eq=False)
class Visibility:
    """Features and class of each traced fiber (NaN where a fiber has no width samples).

    Attributes
    ----------
    visible : (n,) bool
        Fully visible (a top fiber).
    brightness : (n,) float64
        Plateau over the brightest fibers' around it, both above the dark level (1: as bright).
    edge_sigma_px : (n,) float64 [px]
        Blur of its edges.
    edge_contrast : (n,) float64
        Drop from its plateau to the lower level beside its weaker edge, over the plateau
        above the dark level (1: background on both sides; 0: no edge).
    occluded : (n,) float64
        Fraction of its crossings where a brighter fiber covers it (NaN with no crossing).
    both_edges : (n,) float64
        Fraction of its width sample points with both edges found.
    threshold : float
        Brightness below which a fiber is hidden.
    rule : str
        How the threshold was found.
    """

    visible: np.ndarray
    brightness: np.ndarray
    edge_sigma_px: np.ndarray
    edge_contrast: np.ndarray
    occluded: np.ndarray
    both_edges: np.ndarray
    threshold: float
    rule: str


def fiber_features(
    grey: np.ndarray,
    paths: list[np.ndarray],
    samples: WidthSamples,
    junctions: np.ndarray,
    crossings: np.ndarray,
    width_px: float,
) -> dict[str, np.ndarray]:
    """The features of the module notes for each traced fiber.

    Parameters
    ----------
    grey : (rows, cols) float64
        The analysed grey image.
    paths : list of (n_i, 2) float64 [px]
        Fiber centre lines (row, col).
    samples : WidthSamples
        Valid width samples on them (``samples.fiber`` indexes ``paths``).
    junctions : (m, 2) float64 [px]
        Junction centres of the skeleton.
    crossings : (k, 2) float64 [px]
        Those and the other points where fibers overlap (as given to
        :func:`espin.imaging.widths.local_widths`).
    width_px : float [px]
        Typical fiber width w.

    Returns
    -------
    dict of (n,) float64
        ``brightness``, ``edge_sigma_px``, ``edge_contrast``, ``occluded``, ``both_edges``.
    """
    n, w = len(paths), float(width_px)
    smooth = ndimage.gaussian_filter(grey, max(1.0, w / 8.0))
    dark = float(np.percentile(smooth, _DARK_PERCENTILE))
    counts = sample_counts(paths, crossings, w)
    found = np.bincount(samples.fiber, minlength=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        both = np.where(counts > 0, found / counts, np.nan)
    if len(samples.fiber) == 0:
        nothing = np.full(n, np.nan)
        return {
            "brightness": nothing,
            "edge_sigma_px": nothing,
            "edge_contrast": nothing,
            "occluded": nothing,
            "both_edges": both,
        }
    sides, top = _side_profiles(smooth, samples, w)
    plateau = top[: len(samples.fiber)] - dark
    reference = _reference(plateau, samples.point, math.hypot(*grey.shape) * _REFERENCE_RADIUS)
    own = _per_fiber(plateau, samples.fiber, n)
    return {
        "brightness": _per_fiber(plateau / np.maximum(reference, 1e-12), samples.fiber, n),
        "edge_sigma_px": _edge_sigma(sides, top, samples.fiber, n),
        "edge_contrast": _edge_contrast(sides, top, dark, samples.fiber, n),
        "occluded": _occluded(smooth - dark, paths, junctions, own, w),
        "both_edges": both,
    }


def _reference(plateau: np.ndarray, point: np.ndarray, radius: float) -> np.ndarray:
    """The :data:`_REFERENCE_QUANTILE` percentile of the plateaus within ``radius`` of each
    sample point.

    Exact, by blocks of points against all the others (at most :data:`_BLOCK_PAIRS` distances
    at once): a neighbourhood holds a good part of the image, so neighbour lists would take
    memory quadratic in the number of samples (4 GB at 20,000)."""
    out = np.empty(len(point))
    block = max(1, _BLOCK_PAIRS // max(len(point), 1))
    for start in range(0, len(point), block):
        chunk = point[start : start + block]
        near = np.hypot(chunk[:, None, 0] - point[None, :, 0], chunk[:, None, 1] - point[None, :, 1]) <= radius
        out[start : start + block] = np.nanpercentile(
            np.where(near, plateau[None, :], np.nan), _REFERENCE_QUANTILE, axis=1
        )
    return out


def _side_profiles(smooth: np.ndarray, samples: WidthSamples, w: float) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's profile folded onto its two sides (t >= 0 from its centre, every 0.25 px,
    +inf beyond half its width + w / 2: the next fiber), and its plateau (mean over the middle
    half of its width).

    Returns
    -------
    sides : (2 n_samples, k) float64
        The right sides of all samples, then the left ones.
    top : (2 n_samples,) float64
        The plateau of the sample of each side.
    """
    reach = 0.5 * samples.width_px + 0.5 * w
    t = np.arange(int(np.ceil(reach.max() / _STEP)) + 1) * _STEP
    t = np.concatenate([-t[:0:-1], t])
    centre = samples.point + samples.centre_px[:, None] * samples.normal
    coords = centre[:, None, :] + t[None, :, None] * samples.normal[:, None, :]
    profile = ndimage.map_coordinates(smooth, coords.reshape(-1, 2).T, order=1, mode="nearest").reshape(
        len(centre), len(t)
    )
    middle = np.abs(t)[None, :] <= 0.25 * samples.width_px[:, None]
    top = np.nanmean(np.where(middle, profile, np.nan), axis=1)
    inside = np.where(np.abs(t)[None, :] <= reach[:, None], profile, np.inf)
    half = len(t) // 2
    return np.concatenate([inside[:, half:], inside[:, half::-1]]), np.concatenate([top, top])


def _edge_contrast(sides: np.ndarray, top: np.ndarray, dark: float, fiber: np.ndarray, n: int) -> np.ndarray:
    """Median over each fiber's samples of the weaker side's drop from the plateau to that
    side's lowest level, over the plateau above the dark level."""
    drop = (top - sides.min(axis=1)) / np.maximum(top - dark, 1e-12)
    weaker = np.minimum(*drop.reshape(2, -1))
    return _per_fiber(weaker, fiber, n)


def _edge_sigma(sides: np.ndarray, top: np.ndarray, fiber: np.ndarray, n: int) -> np.ndarray:
    """Blur sigma [px] of each fiber's edges: 1 / (sqrt(2 pi) s), s the steepest slope of the
    median of its sides, each scaled from its lowest level (0) to the plateau (1)."""
    out = np.full(n, np.nan)
    base = sides.min(axis=1)
    scale = np.maximum(top - base, 1e-12)
    unit = np.where(np.isfinite(sides), (sides - base[:, None]) / scale[:, None], np.nan)
    both = np.concatenate([fiber, fiber])
    for f in np.unique(fiber):
        with warnings.catch_warnings():  # offsets beyond every side's reach are NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            median = np.nanmedian(unit[both == f], axis=0)
        slope = -np.nanmin(np.diff(median)) / _STEP
        if slope > 0:
            out[f] = 1.0 / (math.sqrt(2.0 * math.pi) * slope)
    return out


def _per_fiber(values: np.ndarray, fiber: np.ndarray, n: int) -> np.ndarray:
    """Median of sample values per fiber (NaN for a fiber without samples)."""
    out = np.full(n, np.nan)
    for f in np.unique(fiber):
        out[f] = np.median(values[fiber == f])
    return out


def _occluded(
    bright: np.ndarray, paths: list[np.ndarray], crossings: np.ndarray, own: np.ndarray, w: float
) -> np.ndarray:
    """Fraction of each fiber's crossings (within w / 2 of its path) whose brightness (the
    image above the dark level, at the crossing centre) is :data:`OCCLUSION_RATIO` times its
    own plateau or more; NaN without a crossing."""
    out = np.full(len(paths), np.nan)
    if len(crossings) == 0:
        return out
    level = ndimage.map_coordinates(bright, crossings.T, order=1, mode="nearest")
    tree = cKDTree(crossings)
    for f, path in enumerate(paths):
        if not np.isfinite(own[f]):
            continue
        hits = sorted(set().union(*tree.query_ball_point(path, w / 2.0)))
        if hits:
            out[f] = float(np.mean(level[hits] >= OCCLUSION_RATIO * own[f]))
    return out


def classify(features: dict[str, np.ndarray]) -> Visibility:
    """Visible (top) fibers from their features, by the rule of the module notes.

    Parameters
    ----------
    features : dict of (n,) float64
        :func:`fiber_features`.

    Returns
    -------
    Visibility
    """
    brightness = np.asarray(features["brightness"], dtype=float)
    threshold, rule = _threshold(brightness[np.isfinite(brightness)])
    occluded = np.asarray(features["occluded"], dtype=float)
    covered = np.isfinite(occluded) & (occluded > OCCLUDED_FRACTION)
    contrast = np.asarray(features["edge_contrast"], dtype=float)
    with np.errstate(invalid="ignore"):
        visible = (brightness >= threshold) & (contrast >= MIN_EDGE_CONTRAST) & ~covered
    return Visibility(
        visible=visible,
        brightness=brightness,
        edge_sigma_px=np.asarray(features["edge_sigma_px"], dtype=float),
        edge_contrast=contrast,
        occluded=occluded,
        both_edges=np.asarray(features["both_edges"], dtype=float),
        threshold=threshold,
        rule=rule,
    )


def _threshold(brightness: np.ndarray) -> tuple[float, str]:
    """Brightness threshold and how it was found: the geometric mean of the two levels of a
    two-normal mixture of ln brightness, when the mixture has the smaller BIC, its
    components are :data:`MIN_SEPARATION` times apart or more and the smaller one holds
    :data:`espin.imaging.distributions.MIN_COMPONENT` fibers or more; else
    :data:`SINGLE_THRESHOLD`."""
    n = len(brightness)
    x = np.log(np.maximum(brightness, 1e-6))
    if n < 6 or np.ptp(x) == 0:
        return SINGLE_THRESHOLD, "one population (too few fibers for a mixture)"
    mixture = fit_normal_mixture(x)
    log_l_one = float(np.sum(stats.norm.logpdf(x, x.mean(), x.std())))
    bic_one = 2.0 * math.log(n) - 2.0 * log_l_one
    bic_two = 5.0 * math.log(n) - 2.0 * mixture.log_likelihood
    ratio = math.exp(mixture.mean_2 - mixture.mean_1)
    if bic_two < bic_one and ratio >= MIN_SEPARATION and mixture.smaller_share(n) >= MIN_COMPONENT:
        return float(math.exp(0.5 * (mixture.mean_1 + mixture.mean_2))), (
            f"two populations: brightness {math.exp(mixture.mean_1):.3g} and "
            f"{math.exp(mixture.mean_2):.3g} (mixture of ln brightness, BIC {bic_two:.1f} "
            f"against {bic_one:.1f} for one)"
        )
    return SINGLE_THRESHOLD, (
        f"one population (mixture of ln brightness: BIC {bic_two:.1f} "
        f"against {bic_one:.1f}, components {ratio:.3g} times apart)"
    )


def fiber_visibility(
    grey: np.ndarray,
    paths: list[np.ndarray],
    samples: WidthSamples,
    junctions: np.ndarray,
    crossings: np.ndarray,
    width_px: float,
) -> Visibility:
    """:func:`classify` of the :func:`fiber_features` (same parameters)."""
    return classify(fiber_features(grey, paths, samples, junctions, crossings, width_px))
