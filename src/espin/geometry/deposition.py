"""Virtual deposition of fiber layers (paper 3.1.1, Fig. 4; docs/model.md section 1).

A fiber starts at a point of the border of the square [0, L]^2 and walks inwards in segments
of length l_s until a segment leaves the square; that segment is trimmed at the border. Two
walks set the segment directions (``rve.walk``): the paper's turns each segment from the
previous one by a uniform random angle in [-theta_max, +theta_max] (the direction drifts
without bound); the smooth walk keeps the drawn axis as the fiber's mean direction and adds a
smooth stationary Gaussian deviation of rms ``waviness_deg`` and correlation length
``waviness_length_ratio`` D (the fiber bends smoothly but keeps its course). Fibers are laid
until the layer reaches its target volume fraction; the fiber that crosses the target is kept.

Two seedings choose the start point and the first axis:

* ``border`` (the paper): a start point uniform by arc length on the border, the axis drawn
  from the orientation distribution with the sense that points into the square (redrawn when
  parallel to the start edge).
* ``lines`` (a stationary line process): the axis drawn from the distribution, then an offset
  uniform across the width of the square measured perpendicular to it; the fiber starts where
  that line enters the square. For a uniform distribution this is the isotropic uniform random
  line measure, so the mat is homogeneous and isotropic up to the corners.

Two samplings draw them (``rve.sampling``): ``random`` (the paper), each fiber independently,
layer after layer, each layer from its own child stream of the seed, so a layer does not change
when others are added; and ``balanced`` (:mod:`espin.geometry.balanced`), the same law for each
fiber but the RVE's fibers drawn together from a low-discrepancy sequence (with ``border``
seeding: the axis and the third in which the fiber's chord lies given its axis), the layers filled
together, and each walk laid in the variant that balances the orientation content.

The walk is vectorized over a batch of fibers and over chunks of steps.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any, cast

import numpy as np
from scipy import special, stats

from espin.core.config import RVEConfig
from espin.geometry.balanced import BalancedSampler, axis_quantiles, orientation_content
from espin.geometry.mat import FiberMat
from espin.geometry.orientation import OrientationDistribution, orientation_distribution

__all__ = ["deposit", "deposit_layer", "lognormal_diameters"]

# Inward unit normals of the edges bottom (y = 0), right (x = L), top (y = L), left (x = 0).
_INWARD = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])
# Spawn keys of balanced sampling's walk and layer streams (the layers' keys are 0 ..
# layers - 1 <= 999, the sampler's scramble 1,000,000).
_BALANCED_WALKS_KEY = 1_000_001
# Candidate fibers walked at once by balanced sampling (each in 2^blocks variants): bounds
# the memory of large RVEs (points not used go back to the sequence).
_BALANCED_BATCH = 1024
# Blocks of a paper walk's turns whose signs balanced sampling chooses (2^blocks variants).
# One: the walk and its mirror image, the only choice that keeps each fiber's shape law
# exactly (geometry/balanced.py); 4 blocks (16 variants) made the tortuosity - 1 of 5 deg
# walks 20 % lower (issue 35). benchmarks/bench_balanced_sampling.py patches it to compare.
_TURN_BLOCKS = 1
# Strata of the chord quantile that balanced ``border`` seeding takes from the sequence (the
# quantile is drawn at random within its third): finer strata balance the orientation content
# better but make fibers close in axis and chord, hence merged cross-links, rarer. The exact
# quantile left 2-5 % fewer merges than random sampling (z -3.0 to -6.4 over 1,000 L/D 60 mats
# per arm), thirds leave none beyond 1.6 standard errors (issue 35; docs/geometry.md).
# benchmarks/bench_balanced_sampling.py patches it to compare.
_CHORD_STRATA = 3
_BALANCED_LAYERS_KEY = 1_000_002


def _border_starts(
    rng: np.random.Generator, n: int, side: float, dist: OrientationDistribution
) -> tuple[np.ndarray, np.ndarray]:
    """Start points uniform on the border and inward axes (``border`` seeding)."""
    start, edge = _border_points(rng.uniform(0.0, 4.0 * side, n), side)
    return start, _inward(rng, dist.sample(rng, n), edge, dist)


def _border_points(s: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray]:
    """Points at arc lengths ``s`` in [0, 4L) [um] along the border (counter-clockwise from
    the origin) and the index of their edge (bottom, right, top, left)."""
    n = len(s)
    edge = np.minimum((s // side).astype(np.int64), 3)
    along = s - edge * side
    start = np.empty((n, 2))
    start[edge == 0] = np.c_[along[edge == 0], np.zeros((edge == 0).sum())]
    start[edge == 1] = np.c_[np.full((edge == 1).sum(), side), along[edge == 1]]
    start[edge == 2] = np.c_[side - along[edge == 2], np.full((edge == 2).sum(), side)]
    start[edge == 3] = np.c_[np.zeros((edge == 3).sum()), side - along[edge == 3]]
    return start, edge


def _chord_starts(
    rng: np.random.Generator, theta: np.ndarray, u: np.ndarray, side: float, dist: OrientationDistribution
) -> tuple[np.ndarray, np.ndarray]:
    """Border starts and inward directions [rad] of fibers of axes ``theta`` [rad] whose
    straight chord through the square lies, by its law given the axis, in the same stratum
    (third, ``_CHORD_STRATA``) of cumulative probability as ``u`` (``border`` seeding under
    balanced sampling).

    Given the axis, a start uniform on the border gives a chord of length l uniform on
    (0, l_max) (the fiber cuts a corner; l_max = L / max(|cos|, |sin|)) with probability
    (1 + r) / 2 and l_max otherwise (it crosses to the opposite edge), r = min(|cos|, |sin|)
    / max(|cos|, |sin|). The chord is taken at a quantile drawn by ``rng`` uniformly within
    the stratum of ``u`` (its third), and the start among the
    border points of that chord by a uniform draw of ``rng``: one of the four corner-cutting
    starts (bottom and top weighted |cos|, left and right |sin|, the border length per unit
    of chord) or a point uniform on the two opposite-edge intervals. So the start is uniform
    on the border and independent of the axis, as under ``border`` seeding; axes parallel to
    their start edge are drawn again from ``dist``.
    """
    theta = theta.copy()
    u = (np.floor(_CHORD_STRATA * u) + rng.uniform(0.0, 1.0, len(u))) / _CHORD_STRATA
    start = np.empty((len(theta), 2))
    direction = np.empty(len(theta))
    todo = np.arange(len(theta))
    while todo.size:
        start[todo], direction[todo] = _chord_starts_once(theta[todo], u[todo], rng.uniform(0.0, 1.0, todo.size), side)
        edge_normal = np.where(
            (start[todo, 1] == 0.0) | (start[todo, 1] == side), np.sin(direction[todo]), np.cos(direction[todo])
        )
        parallel = np.abs(edge_normal) < 1e-12
        todo = todo[parallel]
        theta[todo] = dist.sample(rng, todo.size)
    return start, direction


def _chord_starts_once(theta: np.ndarray, u: np.ndarray, v: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_chord_starts` for axes in [0, pi), chord quantiles ``u`` and the uniform draws
    ``v`` in [0, 1) that choose the start among the chord's border points."""
    a, b = np.abs(np.cos(theta)), np.abs(np.sin(theta))
    hi, lo = np.maximum(a, b), np.minimum(a, b)
    crossing_mass = 0.5 * (1.0 - lo / hi)  # the chords l_max from edge to opposite edge
    x, y = np.empty(len(theta)), np.empty(len(theta))
    sense = np.empty(len(theta))  # +1: along (a, b); -1: against
    # Axis in [0, pi / 2] (mirrored in x below otherwise): chords of length l cut the
    # bottom-right corner from (L - l a, 0) or (L, l b), or the top-left one from
    # (0, L - l b) or (l a, L).
    cut = u < 1.0 - crossing_mass
    length = side / hi * u / (1.0 - crossing_mass)  # 1 - crossing_mass >= 1 / 2
    pick = v * 2.0 * (a + b)
    corner = [
        (pick < a, side - length * a, np.zeros_like(length), 1.0),
        ((pick >= a) & (pick < 2.0 * a), length * a, np.full_like(length, side), -1.0),
        ((pick >= 2.0 * a) & (pick < 2.0 * a + b), np.zeros_like(length), side - length * b, 1.0),
        (pick >= 2.0 * a + b, np.full_like(length, side), length * b, -1.0),
    ]
    for chosen, cx, cy, cs in corner:
        m = cut & chosen
        x[m], y[m], sense[m] = cx[m], cy[m], cs
    # Edge to opposite edge: steep axes from the bottom (x in [0, L (1 - r)]) or the top
    # (x in [L r, L]), flat ones from the left or the right edge (y likewise).
    across = ~cut
    forward = v < 0.5
    offset = side * (1.0 - lo / hi) * np.where(forward, 2.0 * v, 2.0 * v - 1.0)
    along = np.where(forward, offset, side - offset)
    rim = np.where(forward, 0.0, side)
    steep = b > a
    x[across] = np.where(steep, along, rim)[across]
    y[across] = np.where(steep, rim, along)[across]
    sense[across] = np.where(forward, 1.0, -1.0)[across]
    mirror = np.cos(theta) < 0.0
    x[mirror] = side - x[mirror]
    direction = np.arctan2(sense * b, sense * np.where(mirror, -a, a))
    return np.c_[x, y], direction


def _inward(rng: np.random.Generator, theta: np.ndarray, edge: np.ndarray, dist: OrientationDistribution) -> np.ndarray:
    """The sense of the axes ``theta`` [rad] that points into the square from ``edge``
    (axes parallel to the edge drawn again)."""
    normal = _INWARD[edge]
    while True:
        dot = np.cos(theta) * normal[:, 0] + np.sin(theta) * normal[:, 1]
        parallel = np.abs(dot) < 1e-12
        if not parallel.any():
            break
        theta[parallel] = dist.sample(rng, int(parallel.sum()))
    return np.where(dot > 0.0, theta, theta + np.pi)


def _line_starts(
    rng: np.random.Generator, n: int, side: float, dist: OrientationDistribution
) -> tuple[np.ndarray, np.ndarray]:
    """Entry points of stationary random lines (``lines`` seeding).

    Axes are drawn with density proportional to p(theta) w(theta), w = L (|cos| + |sin|) the
    width of the square across theta (by rejection from p), so that the fiber *length* per
    direction follows p: a line of axis theta crosses the square along L^2 / w on average.
    """
    theta = _width_weighted_axes(rng, n, dist) + np.pi * rng.integers(0, 2, n)  # random sense
    return _line_entries(theta, rng.uniform(0.0, 1.0, n), side)


def _line_entries(theta: np.ndarray, offset: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray]:
    """Entry points into the square of the lines of directions ``theta`` [rad] whose offsets
    across the square, perpendicular to them, are the fractions ``offset`` in [0, 1) of the
    square's width seen from that direction; and ``theta``."""
    d = np.c_[np.cos(theta), np.sin(theta)]
    normal = np.c_[-d[:, 1], d[:, 0]]
    centre = np.array([side / 2.0, side / 2.0])
    # Half-width of the square seen across the line direction: projection of the corners.
    half = 0.5 * side * (np.abs(normal[:, 0]) + np.abs(normal[:, 1]))
    # -half + (2 half) offset: the arithmetic of Generator.uniform(-half, half).
    point = centre + (-half + 2.0 * half * offset)[:, None] * normal
    # Entry parameter of the line into the square (slab method).
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (0.0 - point) / d
        t1 = (side - point) / d
    t_enter = np.nanmax(np.where(d != 0.0, np.minimum(t0, t1), -np.inf), axis=1)
    start = np.clip(point + t_enter[:, None] * d, 0.0, side)
    return start, theta


def _width_weighted_axes(rng: np.random.Generator, n: int, dist: OrientationDistribution) -> np.ndarray:
    """``n`` axes [rad] with density proportional to p(theta) (|cos theta| + |sin theta|):
    draws from p kept with probability (|cos| + |sin|) / sqrt(2)."""
    kept: list[np.ndarray] = []
    missing = n
    while missing > 0:
        theta = dist.sample(rng, int(1.2 * missing) + 8)
        width = np.abs(np.cos(theta)) + np.abs(np.sin(theta))
        accepted = theta[rng.uniform(0.0, np.sqrt(2.0), theta.size) < width][:missing]
        kept.append(accepted)
        missing -= accepted.size
    return np.concatenate(kept)


def _exit_distance(p: np.ndarray, u: np.ndarray, side: float) -> np.ndarray:
    """Distance from points ``p`` (inside) along unit vectors ``u`` to the border."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(u > 0.0, (side - p) / u, np.where(u < 0.0, -p / u, np.inf))
    return np.maximum(t.min(axis=1), 0.0)


class _PaperTurns:
    """The paper's walk: each segment turned from the previous one by a uniform angle in
    [-max_turn, max_turn] [rad]; the first segment follows the drawn axis. The state of a
    fiber is its last direction."""

    def __init__(self, max_turn: float) -> None:
        self.max_turn = max_turn

    def start(self, rng: np.random.Generator, start: np.ndarray, theta: np.ndarray, side: float) -> np.ndarray:
        return theta.copy()

    @staticmethod
    def mirrorable(start: np.ndarray, state: np.ndarray, side: float) -> np.ndarray:
        """Every fiber: the first segment follows the drawn axis in every variant."""
        return np.ones(len(state), dtype=bool)

    @property
    def variants(self) -> np.ndarray:
        """Turn signs of balanced sampling's variants: every sign pattern over
        ``_TURN_BLOCKS`` blocks, all +1 first (the turns are independent and symmetric, so
        negating any of them keeps the walk's law)."""
        return -np.array(list(itertools.product((-1.0, 1.0), repeat=_TURN_BLOCKS)))

    @staticmethod
    def block_steps(side: float, segment: float, n_blocks: int) -> int:
        """Steps per block of turns: the mean chord pi L / 4 in ``n_blocks`` parts."""
        return int(np.ceil(np.pi * side / 4.0 / segment / n_blocks))

    def directions(
        self, rng: np.random.Generator, state: np.ndarray, n_steps: int, first: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        turns = rng.uniform(-self.max_turn, self.max_turn, (len(state), n_steps))
        if first:
            turns[:, 0] = 0.0  # the first segment follows the drawn axis
        angles = state[:, None] + np.cumsum(turns, axis=1)
        return angles, angles[:, -1]

    @staticmethod
    def keep(state: np.ndarray, going: np.ndarray) -> np.ndarray:
        return state[going]


class _SmoothDeviation:
    """The smooth walk: segment k points along the fiber's mean axis theta plus a deviation
    rms * phi_k, phi a stationary Gaussian sequence of unit variance whose correlation at arc
    lag s = k l_s is a^k (1 + k (1 - a^2) / (1 + a^2)), a = exp(-segment / length) (the
    Matern-3/2 correlation (1 + s / length) exp(-s / length) as segments shrink): an AR(1)
    sequence psi filtered once more by the same AR(1), so that the direction turns smoothly
    (a continuous turning rate), unlike a random walk, and stays within a few rms of the
    mean axis. The state of a fiber is (mean axis, last psi, last phi).
    """

    def __init__(self, rms: float, length: float, segment: float) -> None:
        self.rms = rms
        self.a = float(np.exp(-segment / length))
        # phi = gain * sum_j a^j psi_(k-j) has unit variance with this gain; phi and psi
        # have correlation 1 / sqrt(1 + a^2) when stationary.
        self.gain = (1.0 - self.a**2) / np.sqrt(1.0 + self.a**2)
        self.coupling = 1.0 / np.sqrt(1.0 + self.a**2)

    def _stationary(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        psi = rng.normal(0.0, 1.0, n)
        phi = self.coupling * psi + np.sqrt(1.0 - self.coupling**2) * rng.normal(0.0, 1.0, n)
        return psi, phi

    def start(
        self, rng: np.random.Generator, start: np.ndarray, theta: np.ndarray, side: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # The first state is drawn from the stationary law, again while the first segment
        # would point out of the square (then the drawn axis itself, which points in).
        psi, phi = self._stationary(rng, len(theta))
        for _ in range(50):
            out = self._points_out(start, theta + self.rms * phi, side)
            if not out.any():
                break
            psi[out], phi[out] = self._stationary(rng, int(out.sum()))
        else:
            psi[out], phi[out] = 0.0, 0.0
        return theta, psi, phi

    def mirrorable(
        self, start: np.ndarray, state: tuple[np.ndarray, np.ndarray, np.ndarray], side: float
    ) -> np.ndarray:
        """Fibers whose mirror image also starts into the square: on that set, symmetric in
        the deviation, the image has the walk's law."""
        theta, _, phi = state
        return ~self._points_out(start, theta - self.rms * phi, side)

    @property
    def variants(self) -> np.ndarray:
        """Deviation signs (2, 1) of balanced sampling's variants: the walk and its mirror
        image (the Gaussian deviation negated as a whole keeps its law, in part it would not)."""
        return np.array([[1.0], [-1.0]])

    @staticmethod
    def block_steps(side: float, segment: float, n_blocks: int) -> int:
        """One block: the deviation is negated as a whole."""
        return int(np.ceil(4.0 * side / segment))

    @staticmethod
    def _points_out(start: np.ndarray, direction: np.ndarray, side: float) -> np.ndarray:
        ahead = start + 1e-9 * side * np.c_[np.cos(direction), np.sin(direction)]
        return ((ahead <= 0.0) | (ahead >= side)).any(axis=1)

    def directions(
        self, rng: np.random.Generator, state: tuple[np.ndarray, np.ndarray, np.ndarray], n_steps: int, first: bool
    ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        from scipy.signal import lfilter

        mean, psi, phi = state
        new = n_steps - 1 if first else n_steps  # the first segment takes the drawn state
        kicks = rng.normal(0.0, np.sqrt(1.0 - self.a**2), (len(mean), new))
        ar = [1.0, -self.a]
        psi_k = lfilter([1.0], ar, kicks, axis=1, zi=self.a * psi[:, None])[0]
        phi_k = lfilter([self.gain], ar, psi_k, axis=1, zi=self.a * phi[:, None])[0]
        if first:
            psi_k, phi_k = np.c_[psi, psi_k], np.c_[phi, phi_k]
        return mean[:, None] + self.rms * phi_k, (mean, psi_k[:, -1], phi_k[:, -1])

    @staticmethod
    def keep(
        state: tuple[np.ndarray, np.ndarray, np.ndarray], going: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return state[0][going], state[1][going], state[2][going]


def _walk_model(rve: RVEConfig) -> _PaperTurns | _SmoothDeviation:
    """The direction model of ``rve.walk`` (docs/model.md section 1)."""
    if rve.walk == "smooth":
        # The config fills the keys of its walk (WALK_DEFAULTS).
        return _SmoothDeviation(
            np.radians(cast(float, rve.waviness_deg)),
            cast(float, rve.waviness_length_ratio) * rve.diameter_um,
            rve.segment_length_um,
        )
    return _PaperTurns(np.radians(cast(float, rve.max_deviation_deg)))


def _walk(
    rng: np.random.Generator,
    start: np.ndarray,
    theta: np.ndarray,
    side: float,
    segment: float,
    model: _PaperTurns | _SmoothDeviation,
    signs: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Walks of segments ``segment`` from ``start`` along first axes ``theta``, directions from
    ``model``, until they leave the square; the leaving segment is trimmed at the border.

    With ``signs`` (n_variants, n_blocks) of +-1, each fiber is walked once per variant, all
    on the same draws: variant v turns by ``signs[v, b]`` times the drawn turn (the change of
    direction from one segment to the next, the first one measured from the axis) in the
    b-th block of ``model.block_steps(side, segment, n_blocks)`` steps (the last block runs to
    the end). Variant 0 must be all +1 (the walk as drawn); a fiber that
    ``model.mirrorable`` refuses is walked as drawn in every variant.

    Returns
    -------
    vertices : (n_vertices, 2) float64 [um]
        Vertices of all fibers, fiber after fiber (with ``signs``, variant after variant).
    counts : (n,) or (n_variants n,) int64
        Number of vertices of each fiber (segments + 1).
    """
    n = len(start)
    signs = np.ones((1, 1)) if signs is None else np.asarray(signs, dtype=float)
    rows = len(signs) * n
    drawn_for = np.arange(rows) % n  # the fiber whose draws a row follows
    chunk = int(np.ceil(1.5 * side / segment)) + 2
    pieces_fiber = [np.arange(rows)]
    pieces_vertex = [start[drawn_for]]
    active = np.arange(rows)
    pos = start[drawn_for]
    drawn = np.arange(n)  # fibers whose directions are still drawn (a variant is inside)
    state: Any = model.start(rng, start, theta, side)  # the model's own, passed back to it
    if len(signs) > 1:
        row_signs = np.where(model.mirrorable(start, state, side)[drawn_for, None], np.repeat(signs, n, axis=0), 1.0)
        block = max(model.block_steps(side, segment, signs.shape[1]), 1)
        drawn_last = theta.copy()  # direction before the next drawn segment
        row_last = theta[drawn_for]
    step = 0
    first = True
    while active.size:
        drawn_angles, state = model.directions(rng, state, chunk, first)
        first = False
        angles = drawn_angles[np.searchsorted(drawn, drawn_for[active])]
        if len(signs) > 1:
            turned = active >= n  # variant 0 takes the drawn angles as they are
            turns = np.diff(np.c_[drawn_last, drawn_angles], axis=1)[np.searchsorted(drawn, drawn_for[active[turned]])]
            blocks = np.minimum((step + np.arange(chunk)) // block, signs.shape[1] - 1)
            angles[turned] = row_last[active[turned], None] + np.cumsum(
                row_signs[active[turned]][:, blocks] * turns, axis=1
            )
            row_last[active] = angles[:, -1]
            drawn_last = drawn_angles[:, -1]
        step += chunk
        steps = segment * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
        path = pos[:, None, :] + np.cumsum(steps, axis=1)
        outside = cast(np.ndarray, ((path < 0.0) | (path > side)).any(axis=2))  # numpy types it bool | array
        exited = outside.any(axis=1)
        k = np.where(exited, outside.argmax(axis=1), chunk)  # index of the leaving vertex
        keep = np.arange(chunk)[None, :] < k[:, None]
        pieces_fiber.append(np.repeat(active, k))
        pieces_vertex.append(path[keep])
        # Trim the leaving segment at the border.
        e = np.flatnonzero(exited)
        ke = k[e]
        before = np.where(ke[:, None] > 0, path[e, np.maximum(ke - 1, 0)], pos[e])
        u = np.c_[np.cos(angles[e, ke]), np.sin(angles[e, ke])]
        t = np.minimum(_exit_distance(before, u, side), segment)
        pieces_fiber.append(active[e])
        pieces_vertex.append(np.clip(before + t[:, None] * u, 0.0, side))
        # Fibers still inside carry on from their last vertex.
        going = ~exited
        pos = path[going, -1]
        active = active[going]
        still = np.isin(drawn, drawn_for[active])
        state = model.keep(state, still)
        if len(signs) > 1:
            drawn_last = drawn_last[still]
        drawn = drawn[still]
    fiber = np.concatenate(pieces_fiber)
    order = np.argsort(fiber, kind="stable")
    return np.concatenate(pieces_vertex)[order], np.bincount(fiber, minlength=rows)


def _diameters(rng: np.random.Generator, n: int, rve: RVEConfig) -> np.ndarray:
    """``n`` fiber diameters [um] from ``rve.diameter_distribution``, truncated below at
    ``rve.diameter_min_um``."""
    if rve.diameter_sd_um == 0.0:
        return np.full(n, rve.diameter_um)
    # Unfrozen scipy calls and special functions: freezing a scipy distribution costs ~1 ms,
    # more than the draws of a layer (the geometry calibration deposits ~1e5 layers).
    if rve.diameter_distribution == "normal":
        lower = (cast(float, rve.diameter_min_um) - rve.diameter_um) / rve.diameter_sd_um
        return stats.truncnorm.rvs(
            lower, np.inf, loc=rve.diameter_um, scale=rve.diameter_sd_um, size=n, random_state=rng
        )
    return _diameter_quantiles(rve, rng.uniform(0.0, 1.0, n))


def _diameter_quantiles(rve: RVEConfig, u: np.ndarray) -> np.ndarray:
    """Fiber diameters [um] at cumulative probabilities ``u`` of ``rve.diameter_distribution``
    truncated below at ``rve.diameter_min_um`` (the inverse distribution function)."""
    if rve.diameter_sd_um == 0.0:
        return np.full(len(u), rve.diameter_um)
    if rve.diameter_distribution == "normal":
        lower = (cast(float, rve.diameter_min_um) - rve.diameter_um) / rve.diameter_sd_um
        return stats.truncnorm.ppf(u, lower, np.inf, loc=rve.diameter_um, scale=rve.diameter_sd_um)
    sigma, median = _lognormal_parameters(rve.diameter_um, rve.diameter_sd_um)
    # Inverse CDF over [low, 1): the truncated law exactly.
    low = special.ndtr(np.log(cast(float, rve.diameter_min_um) / median) / sigma)
    return median * np.exp(sigma * special.ndtri(low + (1.0 - low) * u))


def _lognormal_parameters(mean_um: float, sd_um: float) -> tuple[float, float]:
    """sigma of ln D and the median [um] of the lognormal of this mean and sd."""
    sigma = float(np.sqrt(np.log1p((sd_um / mean_um) ** 2)))
    return sigma, mean_um * float(np.exp(-(sigma**2) / 2.0))


def lognormal_diameters(mean_um: float, sd_um: float) -> Any:
    """The lognormal law (``scipy.stats.lognorm``, frozen) of mean ``mean_um`` and standard
    deviation ``sd_um`` [um]: sigma^2 = ln(1 + (sd / mean)^2), median mean / sqrt(1 + cv^2)."""
    sigma, median = _lognormal_parameters(mean_um, sd_um)
    return stats.lognorm(s=sigma, scale=median)


def deposit_layer(rve: RVEConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Deposit one layer of random sampling until its volume fraction reaches
    ``rve.volume_fraction``.

    Parameters
    ----------
    rve
        Deposition parameters (resolved seeding).
    rng
        Random stream of this layer.

    Returns
    -------
    vertices : (n_vertices, 2) float64 [um]
        Vertices of the layer's fibers, fiber after fiber.
    counts : (n_fibers,) int64
        Vertices per fiber.
    diameters : (n_fibers,) float64 [um]
        Fiber diameters.
    """
    dist = orientation_distribution(rve.orientation)
    target, expected = _layer_target(rve)
    batch = int(1.1 * expected) + 4
    parts_v, parts_c, parts_d = [], [], []
    volume = 0.0
    while True:
        vertices, counts, diameter = _random_fibers(rve, rng, batch, dist)
        ends = np.cumsum(counts)
        cum_volume = volume + np.cumsum(_fiber_volumes(vertices, counts, diameter))
        reached = np.flatnonzero(cum_volume >= target)
        n_keep = reached[0] + 1 if reached.size else batch
        parts_v.append(vertices[: ends[n_keep - 1]])
        parts_c.append(counts[:n_keep])
        parts_d.append(diameter[:n_keep])
        volume = cum_volume[n_keep - 1]
        if reached.size:
            break
        batch = max(int(1.1 * expected * (target - volume) / target) + 4, 4)
    return np.concatenate(parts_v), np.concatenate(parts_c), np.concatenate(parts_d)


def _layer_target(rve: RVEConfig) -> tuple[float, float]:
    """Fiber volume of a full layer [um^3] and the expected number of fibers in it."""
    target = rve.volume_fraction * rve.side_um**2 * rve.diameter_um
    # Mean chord of isotropic lines in a square is pi L / 4 (Cauchy-Crofton).
    return target, target / (np.pi * rve.diameter_um**2 / 4.0 * np.pi * rve.side_um / 4.0)


def _fiber_volumes(vertices: np.ndarray, counts: np.ndarray, diameter: np.ndarray) -> np.ndarray:
    """Volume [um^3] of each fiber: cross-section times contour (the sum of its segments;
    the step from one fiber to the next is not a segment)."""
    seg = np.diff(vertices, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    ends = np.cumsum(counts)
    return np.pi * diameter**2 / 4.0 * (cum[ends - 1] - cum[ends - counts])


def _balanced_layers(
    rve: RVEConfig, progress: Callable[[int, int], None] | None
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """All layers of a mat of balanced sampling, deposited together: fiber after fiber, the
    sampler's next fiber goes to a layer drawn uniformly among those not yet full, until
    every layer reaches ``rve.volume_fraction`` (the fiber that crosses it is kept).
    ``progress(done, layers)`` is called after each batch of candidates with the fiber volume
    laid so far in layers' worth.

    The RVE's fibers are then a prefix of the sampler's sequence (balanced), and a layer's
    fibers are scattered through it: fibers of one layer are no closer in the sequence than
    fibers of different layers, so the sequence's even spreading does not change how often
    fibers of a layer cross (consecutive points of the sequence are never alike).

    Returns
    -------
    list of (vertices, counts, diameters), one per layer
        As :func:`deposit_layer`.
    """
    dist = orientation_distribution(rve.orientation)
    target, expected = _layer_target(rve)
    sampler = BalancedSampler(rve.seed)
    walks = np.random.default_rng(np.random.SeedSequence(rve.seed, spawn_key=(_BALANCED_WALKS_KEY,)))
    chooser = np.random.default_rng(np.random.SeedSequence(rve.seed, spawn_key=(_BALANCED_LAYERS_KEY,)))
    volume = np.zeros(rve.layers)
    open_layers = list(range(rve.layers))
    kept: list[list[tuple[np.ndarray, float]]] = [[] for _ in range(rve.layers)]
    while open_layers:
        batch = min(int(1.1 * expected * len(open_layers)) + 4, _BALANCED_BATCH)
        vertices, counts, diameter = _balanced_fibers(rve, walks, batch, dist, sampler)
        ends = np.concatenate([[0], np.cumsum(counts)])
        fiber_volume = _fiber_volumes(vertices, counts, diameter)
        n_keep = batch
        for j in range(batch):
            layer = open_layers[int(chooser.integers(len(open_layers)))]
            kept[layer].append((vertices[ends[j] : ends[j + 1]], diameter[j]))
            volume[layer] += fiber_volume[j]
            if volume[layer] >= target:
                open_layers.remove(layer)
                if not open_layers:
                    n_keep = j + 1
                    break
        if progress is not None:
            # The layers fill together: report the fiber volume laid, in layers' worth.
            progress(
                rve.layers - len(open_layers)
                if not open_layers
                else min(int(np.minimum(volume, target).sum() / target), rve.layers - 1),
                rve.layers,
            )
        sampler.accept(n_keep)
    return [
        (
            np.concatenate([v for v, _ in fibers]),
            np.array([len(v) for v, _ in fibers]),
            np.array([d for _, d in fibers]),
        )
        for fibers in kept
    ]


def _random_fibers(
    rve: RVEConfig, rng: np.random.Generator, n: int, dist: OrientationDistribution
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` candidate fibers drawn independently (the paper): vertices, counts, diameters."""
    seed_fibers = _border_starts if rve.seeding == "border" else _line_starts
    start, theta = seed_fibers(rng, n, rve.side_um, dist)
    diameter = _diameters(rng, n, rve)
    vertices, counts = _walk(rng, start, theta, rve.side_um, rve.segment_length_um, _walk_model(rve))
    return vertices, counts, diameter


def _balanced_fibers(
    rve: RVEConfig, rng: np.random.Generator, n: int, dist: OrientationDistribution, sampler: BalancedSampler
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` candidate fibers of balanced sampling (geometry/balanced.py): axis, start (the
    chord's third given the axis, :func:`_chord_starts`, or the line's offset) and diameter
    at the sampler's next points, each walk's variant (its mirror image, ``model.variants``)
    chosen by herding."""
    side = rve.side_um
    u = sampler.points(n)
    if rve.seeding == "border":
        start, theta = _chord_starts(rng, axis_quantiles(dist, u[:, 0], width_weighted=False), u[:, 1], side, dist)
    else:
        theta = axis_quantiles(dist, u[:, 0], width_weighted=True) + np.pi * rng.integers(0, 2, n)
        start, theta = _line_entries(theta, u[:, 1], side)
    diameter = _diameter_quantiles(rve, u[:, 2])
    model = _walk_model(rve)
    variants = model.variants
    vertices, counts = _walk(rng, start, theta, side, rve.segment_length_um, model, signs=variants)
    ends = np.concatenate([[0], np.cumsum(counts)])
    content = orientation_content(vertices, counts, np.tile(diameter, len(variants)))
    chosen = sampler.herd(content.reshape(len(variants), n, -1)) * n + np.arange(n)
    kept_counts = counts[chosen]
    first = np.repeat(ends[chosen] - np.concatenate([[0], np.cumsum(kept_counts)[:-1]]), kept_counts)
    return vertices[first + np.arange(kept_counts.sum())], kept_counts, diameter


def deposit(
    rve: RVEConfig,
    progress: Callable[[int, int], None] | None = None,
) -> FiberMat:
    """Deposit all layers of a virtual mat (paper 3.1.1).

    Parameters
    ----------
    rve
        Deposition parameters; ``rve.seed`` seeds the random streams (random sampling: one
        child stream per layer, so adding layers leaves the others unchanged; balanced
        sampling: the sequence's scramble, the walks and the layers' draw), so the same
        parameters give the same mat.
    progress
        Called as ``progress(layers_done, n_layers)`` after each layer.

    Returns
    -------
    FiberMat
        The fibers as polylines.
    """
    if rve.sampling == "balanced":
        per_layer = _balanced_layers(rve, progress)
    else:
        per_layer = []
        for k, child in enumerate(np.random.SeedSequence(rve.seed).spawn(rve.layers)):
            per_layer.append(deposit_layer(rve, np.random.default_rng(child)))
            if progress is not None:
                progress(k + 1, rve.layers)
    vertices = [v for v, _, _ in per_layer]
    counts = [c for _, c, _ in per_layer]
    diameters = [d for _, _, d in per_layer]
    layers = [np.full(len(c), k, dtype=np.int64) for k, c in enumerate(counts)]
    counts_all = np.concatenate(counts)
    return FiberMat(
        vertices=np.concatenate(vertices),
        fiber_offsets=np.concatenate([[0], np.cumsum(counts_all)]).astype(np.int64),
        fiber_layer=np.concatenate(layers),
        fiber_diameter=np.concatenate(diameters),
        size=rve.side_um,
        thickness=rve.diameter_um,
        n_layers=rve.layers,
    )
