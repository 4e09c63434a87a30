"""Checking traced fibers against the ground truth of a rendered mat: switches and coverage.

A trace *switches* when it follows one true fiber into a crossing and leaves it on another
one: the measurement then joins two fibers into one (wrong orientation, tortuosity and
edge-to-edge count). :func:`check_traces` compares the traced centre lines of an image
rendered by :func:`espin.imaging.synthetic.render_sem` with the centre lines of the mat's
drawn fibers:

1. True centre lines: the window portions (:func:`espin.geometry.pieces.window_runs`) of the
   fibers of the drawn layers, in pixels as the renderer maps them (column = (x - x0) / pixel
   - 1/2, row = (y_top - y) / pixel - 1/2), sampled every :data:`STEP_PX`. True crossings:
   the intersections of two of them, with their acute angle.
2. The fiber a trace follows at each of its points: the nearest true centre line, if it is
   within w / 2 and every other fiber's is at least w / 2 farther (else the point is
   ambiguous: near a crossing, along a shallow one, between fused fibers), and the point is
   more than w from every true crossing. A fiber hidden under a top one has no label there,
   but its centre line is still the nearest one, so a trace that runs under a top fiber on a
   hidden one follows it.
3. The sequence of fibers a trace follows: maximal runs of points assigned to one fiber (at
   least w / 2 of them; ambiguous points in between are skipped), consecutive runs on the
   same fiber merged. Each change of fiber is a switch, placed at the crossing of the two
   fibers nearest to where it happens (none within 3 w: a jump between fibers that do not
   cross there, angle NaN).
4. Crossings passed: a true crossing that a trace comes within w / 2 of, running on at least
   1.5 w of arc on both sides, following one of the two crossing fibers on one side
   (plus every crossing where it switches). The switch rate is switches over crossings
   passed.
5. Coverage of a true fiber: the fraction of its visible length (its window portions with
   the ground truth's chord filter, ``SyntheticSEM.visible``) that its single longest trace
   covers: a point of the true centre line is covered by the trace nearest to it if that is
   within max(3 px, w / 2) and this fiber's centre line is the one nearest to the trace there.

On a real image there is no ground truth: :func:`junction_passes` lists the junctions of the
skeleton that traces pass through, with the trace's turn there, to look at (a switch shows as
a kink, or a change of width or brightness at the junction).

Coordinates are (row, col) pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from espin.geometry.mat import FiberMat
from espin.geometry.pieces import window_runs
from espin.imaging.synthetic import SyntheticSEM

__all__ = ["TraceCheck", "JunctionPasses", "check_traces", "junction_passes", "STEP_PX"]

STEP_PX = 0.5
"""Spacing [px] of the samples of the true centre lines."""
_ON_FIBER = 0.5  # a trace point follows a fiber within this * w of its centre line ...
_MARGIN = 0.5  # ... if every other fiber's centre line is at least this * w farther
_NEAR_CROSSING = 1.0  # points within this * w of a true crossing are ambiguous
_MIN_RUN = 0.5  # a run on one fiber counts if it has at least this * w points
_PASS = 0.5  # a trace passes through a crossing that it comes within this * w of ...
_BEYOND = 1.5  # ... and runs on for this * w of arc on both sides
_SWITCH_REACH = 3.0  # a switch is placed at a crossing of its two fibers within this * w
_COVER_PX = 3.0  # a true point is covered by a trace within max(this, w / 2) px of it
ANGLE_BINS_DEG = (10.0, 30.0, 60.0, 90.0)
"""Edges [deg] of the crossing-angle bins :meth:`TraceCheck.describe` reports."""


@dataclass(frozen=True, eq=False)
class TraceCheck:
    """Traces compared with a rendering's ground truth (see the module notes).

    Attributes
    ----------
    crossing_px : (n_crossings, 2) float64 [px]
        True crossings (row, col) of two drawn fibers inside the window.
    crossing_fibers : (n_crossings, 2) int64
        Mat indices of the two fibers of each.
    crossing_angle_deg : (n_crossings,) float64 [deg]
        Their acute crossing angle, in [0, 90].
    passes : (n_passes, 2) int64
        (trace, crossing) for each crossing a trace passes through.
    switches_px : (n_switches, 2) float64 [px]
        Where each change of fiber happens (row, col): the crossing of its two fibers (a
        switch), or where the trace leaves one fiber for the other if they do not cross
        there (a jump).
    switch_trace : (n_switches,) int64
        Trace of each switch.
    switch_fibers : (n_switches, 2) int64
        Fiber the trace leaves and fiber it continues on.
    switch_angle_deg : (n_switches,) float64 [deg]
        Crossing angle at each switch (NaN for a jump between fibers that do not cross).
    fiber : (n_fibers,) int64
        Mat indices of the fibers with a visible portion.
    fiber_depth : (n_fibers,) int64
        Their depth below the top drawn layer (0 = top).
    coverage : (n_fibers,) float64
        Fraction of each one's visible length covered by its longest trace, in [0, 1].
    n_traces : int
        Traces checked.
    """

    crossing_px: np.ndarray
    crossing_fibers: np.ndarray
    crossing_angle_deg: np.ndarray
    passes: np.ndarray
    switches_px: np.ndarray
    switch_trace: np.ndarray
    switch_fibers: np.ndarray
    switch_angle_deg: np.ndarray
    fiber: np.ndarray
    fiber_depth: np.ndarray
    coverage: np.ndarray
    n_traces: int

    @property
    def n_passed(self) -> int:
        """Crossings passed through by traces (a crossing passed by two traces counts twice)."""
        return len(self.passes)

    @property
    def at_crossing(self) -> np.ndarray:
        """(n_switches,) bool: the switch is at a crossing of its two fibers (else a jump
        between fibers that do not cross there)."""
        return np.isfinite(self.switch_angle_deg)

    @property
    def n_switches(self) -> int:
        """Switches at crossings, of all traces."""
        return int(self.at_crossing.sum())

    @property
    def n_jumps(self) -> int:
        """Changes of fiber away from a crossing of the two (through an ambiguous stretch:
        fused fibers, a segmented blob between fibers)."""
        return len(self.switch_trace) - self.n_switches

    @property
    def switch_rate(self) -> float:
        """Switches at crossings over crossings passed (NaN if none passed)."""
        return self.n_switches / self.n_passed if self.n_passed else float("nan")

    @property
    def median_coverage(self) -> float:
        """Median over the visible fibers of the fraction covered by the longest trace."""
        return float(np.median(self.coverage)) if len(self.coverage) else float("nan")

    def passed_by_angle(self, edges_deg: tuple[float, ...] = ANGLE_BINS_DEG) -> np.ndarray:
        """Crossings passed, counted in the angle bins [edges[k], edges[k + 1]) [deg]
        (the last bin closed)."""
        angle = self.crossing_angle_deg[self.passes[:, 1]]
        return np.histogram(angle, bins=np.asarray(edges_deg))[0]

    def switches_by_angle(self, edges_deg: tuple[float, ...] = ANGLE_BINS_DEG) -> np.ndarray:
        """Switches at crossings, counted in the same angle bins."""
        angle = self.switch_angle_deg[self.at_crossing]
        return np.histogram(angle, bins=np.asarray(edges_deg))[0]

    def describe(self) -> str:
        """A few lines: crossings passed by angle, switches, switch rate, coverage."""
        edges = ANGLE_BINS_DEG
        bins = ", ".join(
            f"{edges[k]:g}-{edges[k + 1]:g} deg: {p} ({s})"
            for k, (p, s) in enumerate(zip(self.passed_by_angle(), self.switches_by_angle()))
        )
        lines = [
            f"{self.n_traces} traces; {len(self.crossing_px)} true crossings, "
            f"{self.n_passed} passed by traces (switches): {bins}",
            f"switches at crossings {self.n_switches} (rate {self.switch_rate:.3f}); "
            f"jumps between fibers off crossings {self.n_jumps}",
            f"median coverage of a visible fiber by its longest trace "
            f"{self.median_coverage:.3f} ({len(self.fiber)} fibers; by depth "
            + ", ".join(
                f"{d}: {np.median(self.coverage[self.fiber_depth == d]):.3f}" for d in np.unique(self.fiber_depth)
            )
            + ")",
        ]
        for (r, c), (a, b), angle in zip(self.switches_px, self.switch_fibers, self.switch_angle_deg):
            lines.append(
                f"  switch at (row {r:.0f}, col {c:.0f}): fiber {a} -> {b}, crossing angle {angle:.0f} deg"
                if np.isfinite(angle)
                else f"  jump at (row {r:.0f}, col {c:.0f}): fiber {a} -> {b}"
            )
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class _TrueLines:
    """Samples of the drawn fibers' centre lines in the window, every STEP_PX."""

    points: np.ndarray  # (n, 2) float64 [px] (row, col)
    fiber: np.ndarray  # (n,) int64 mat index
    portion: np.ndarray  # (n,) int64 window portion (run) index
    polylines: list[np.ndarray]  # (m_r, 2) [px] of each portion
    run_fiber: np.ndarray  # (n_runs,) int64


def check_traces(paths: list[np.ndarray], image: SyntheticSEM, mat: FiberMat, width_px: float) -> TraceCheck:
    """Compare traced centre lines with the true fibers of a rendered mat.

    Parameters
    ----------
    paths : list of (n_i, 2) float64 [px]
        Traced centre lines (row, col), one point per pixel of arc length
        (:attr:`espin.imaging.trace.TracedFibers.paths`).
    image : SyntheticSEM
        The rendering the traces were found on.
    mat : FiberMat
        The mat it was rendered from.
    width_px : float [px]
        Typical fiber width w (the tracer's).

    Returns
    -------
    TraceCheck
    """
    w = float(width_px)
    lines = _true_lines(image, mat)
    crossing, pair, angle = _true_crossings(lines)
    tree = cKDTree(lines.points)
    crossing_tree = cKDTree(crossing) if len(crossing) else None
    passes, switches = [], []
    for t, path in enumerate(paths):
        follow = _followed_fiber(path, lines, tree, crossing_tree, w)
        runs = _fiber_runs(follow, w)
        found = _switches(t, path, runs, crossing, pair, angle, w)
        switches += found
        passes += _passes(t, path, follow, crossing, pair, w, {s[4] for s in found if s[4] >= 0})
    fiber, depth, coverage = _coverage(paths, image, lines, tree, w)
    where = np.array([s[2:4] for s in switches], dtype=float).reshape(-1, 2)
    return TraceCheck(
        crossing_px=crossing,
        crossing_fibers=pair,
        crossing_angle_deg=angle,
        passes=np.array(passes, dtype=np.int64).reshape(-1, 2),
        switches_px=where,
        switch_trace=np.array([s[0] for s in switches], dtype=np.int64),
        switch_fibers=np.array([s[1] for s in switches], dtype=np.int64).reshape(-1, 2),
        switch_angle_deg=np.array([s[5] for s in switches], dtype=float),
        fiber=fiber,
        fiber_depth=depth,
        coverage=coverage,
        n_traces=len(paths),
    )


def _to_px(xy: np.ndarray, image: SyntheticSEM) -> np.ndarray:
    """Mat coordinates (x, y) [um] -> pixel centres (row, col), as the renderer maps them."""
    top = image.origin[1] + image.side
    return np.column_stack(
        [(top - xy[:, 1]) / image.um_per_px - 0.5, (xy[:, 0] - image.origin[0]) / image.um_per_px - 0.5]
    )


def _true_lines(image: SyntheticSEM, mat: FiberMat) -> _TrueLines:
    """The window portions of the drawn layers' fibers, in pixels, sampled every STEP_PX."""
    runs = window_runs(mat.vertices, mat.fiber_offsets, image.origin, image.side)
    drawn = np.isin(mat.fiber_layer[runs.fiber], image.layers)
    points, fiber, portion = [], [], []
    polylines: list[np.ndarray] = []
    for r in np.flatnonzero(drawn):
        xy = runs.points[runs.first[r] : runs.last[r] + 1]
        px = _to_px(xy, image)
        arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(px, axis=0).T))]
        s = np.arange(0.0, arc[-1] + STEP_PX / 2, STEP_PX)
        points.append(np.column_stack([np.interp(s, arc, px[:, k]) for k in range(2)]))
        fiber.append(np.full(len(s), runs.fiber[r]))
        portion.append(np.full(len(s), len(polylines)))
        polylines.append(px)
    return _TrueLines(
        points=np.concatenate(points),
        fiber=np.concatenate(fiber),
        portion=np.concatenate(portion),
        polylines=polylines,
        run_fiber=runs.fiber[drawn],
    )


def _true_crossings(lines: _TrueLines) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intersections (row, col) of the segments of two different fibers' portions, the two
    fibers (sorted) and the acute angle [deg] of each."""
    seg_a = np.concatenate([p[:-1] for p in lines.polylines])
    seg_b = np.concatenate([p[1:] for p in lines.polylines])
    seg_fiber = np.concatenate([np.full(len(p) - 1, f) for p, f in zip(lines.polylines, lines.run_fiber)])
    lo, hi = np.minimum(seg_a, seg_b), np.maximum(seg_a, seg_b)
    # Candidate pairs: overlapping bounding boxes, whose centres are at most the sum of their
    # half-sides apart along each axis (Chebyshev distance, p = inf), found by a tree.
    centre, half = (lo + hi) / 2, np.max(hi - lo, axis=1) / 2
    pairs = cKDTree(centre).query_pairs(2 * half.max() + 1e-9, p=np.inf, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    keep = (seg_fiber[i] != seg_fiber[j]) & np.all(lo[i] <= hi[j], axis=1) & np.all(lo[j] <= hi[i], axis=1)
    i, j = i[keep], j[keep]
    p, r = seg_a[i], seg_b[i] - seg_a[i]
    q, s = seg_a[j], seg_b[j] - seg_a[j]
    cross = r[:, 0] * s[:, 1] - r[:, 1] * s[:, 0]
    ok = np.abs(cross) > 1e-12
    safe = np.where(ok, cross, 1.0)
    qp = q - p
    t = (qp[:, 0] * s[:, 1] - qp[:, 1] * s[:, 0]) / safe
    u = (qp[:, 0] * r[:, 1] - qp[:, 1] * r[:, 0]) / safe
    hit = ok & (t >= 0) & (t < 1) & (u >= 0) & (u < 1)
    point = p[hit] + t[hit, None] * r[hit]
    cos = np.abs(np.einsum("ij,ij->i", r[hit], s[hit])) / (np.hypot(*r[hit].T) * np.hypot(*s[hit].T))
    angle = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
    pair = np.sort(np.column_stack([seg_fiber[i[hit]], seg_fiber[j[hit]]]), axis=1)
    return point.reshape(-1, 2), pair.reshape(-1, 2).astype(np.int64), angle


def _followed_fiber(
    path: np.ndarray, lines: _TrueLines, tree: cKDTree, crossing_tree: cKDTree | None, w: float
) -> np.ndarray:
    """Mat index of the fiber a trace follows at each of its points, -1 where ambiguous."""
    k = min(len(lines.points), int(np.ceil(8.0 * (_ON_FIBER + _MARGIN) * w / STEP_PX)) + 8)
    distance, index = tree.query(path, k=k, distance_upper_bound=(_ON_FIBER + _MARGIN) * w)
    found = np.isfinite(distance)
    fib = np.where(found, lines.fiber[np.minimum(index, len(lines.fiber) - 1)], -1)
    nearest = fib[:, 0]
    other = np.where(found & (fib != nearest[:, None]), distance, np.inf).min(axis=1)
    follow = np.where(
        np.isfinite(distance[:, 0]) & (distance[:, 0] <= _ON_FIBER * w) & (other >= distance[:, 0] + _MARGIN * w),
        nearest,
        -1,
    )
    if crossing_tree is not None:
        near = crossing_tree.query(path, distance_upper_bound=_NEAR_CROSSING * w)[0]
        follow[np.isfinite(near)] = -1
    return follow


def _fiber_runs(follow: np.ndarray, w: float) -> list[tuple[int, int, int]]:
    """(fiber, first index, last index) of the runs of a trace on one fiber, ambiguous
    points skipped, runs shorter than _MIN_RUN w dropped, consecutive equal ones merged."""
    assigned = np.flatnonzero(follow >= 0)
    if len(assigned) == 0:
        return []
    values = follow[assigned]
    cut = np.flatnonzero(np.diff(values) != 0) + 1
    runs: list[tuple[int, int, int]] = []
    for idx in np.split(assigned, cut):
        if len(idx) >= _MIN_RUN * w:
            f = int(follow[idx[0]])
            if runs and runs[-1][0] == f:
                runs[-1] = (f, runs[-1][1], int(idx[-1]))
            else:
                runs.append((f, int(idx[0]), int(idx[-1])))
    return runs


def _switches(
    t: int,
    path: np.ndarray,
    runs: list[tuple[int, int, int]],
    crossing: np.ndarray,
    pair: np.ndarray,
    angles: np.ndarray,
    w: float,
) -> list[tuple]:
    """(trace, (from, to), row, col, crossing index or -1, angle [deg] or NaN) per switch."""
    out = []
    for (fa, _, end), (fb, start, _) in zip(runs[:-1], runs[1:]):
        middle = path[(end + start) // 2]
        mine = np.flatnonzero(np.all(pair == sorted((fa, fb)), axis=1))
        where, c, angle = middle, -1, float("nan")
        if len(mine):
            d = np.hypot(*(crossing[mine] - middle).T)
            if d.min() <= _SWITCH_REACH * w:
                c = int(mine[np.argmin(d)])
                where, angle = crossing[c], float(angles[c])
        out.append((t, (fa, fb), float(where[0]), float(where[1]), c, angle))
    return out


def _passes(
    t: int, path: np.ndarray, follow: np.ndarray, crossing: np.ndarray, pair: np.ndarray, w: float, switched: set[int]
) -> list[tuple[int, int]]:
    """(trace, crossing) for the crossings the trace passes through (module notes, 4)."""
    if len(crossing) == 0 or len(path) < 2:
        return []
    distance, index = cKDTree(path).query(crossing, distance_upper_bound=_PASS * w)
    beyond = _BEYOND * w
    out = set(switched)
    for c in np.flatnonzero(np.isfinite(distance)):
        i = int(index[c])
        if i < beyond or len(path) - 1 - i < beyond:
            continue
        before = follow[: i + 1][follow[: i + 1] >= 0]
        after = follow[i:][follow[i:] >= 0]
        sides = ([before[-1]] if len(before) else []) + ([after[0]] if len(after) else [])
        if np.isin(sides, pair[c]).any():
            out.add(int(c))
    return [(t, c) for c in sorted(out)]


def _coverage(
    paths: list[np.ndarray], image: SyntheticSEM, lines: _TrueLines, tree: cKDTree, w: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Visible fibers, their depth and the fraction of their visible length (portions with
    a chord of at least the ground truth's ``min_chord``) covered by their longest trace."""
    fibers = np.unique(image.visible.fiber)
    if not paths:
        return fibers, image.depth(fibers), np.zeros(len(fibers))
    points = np.concatenate(paths)
    owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(paths)])
    nearest = lines.fiber[tree.query(points)[1]]  # the true fiber nearest to each trace point
    trace_tree = cKDTree(points)
    reach = max(_COVER_PX, w / 2)
    min_chord = image.visible.min_chord / image.um_per_px
    coverage = np.zeros(len(fibers))
    for k, f in enumerate(fibers):
        portions = [
            r
            for r in np.flatnonzero(lines.run_fiber == f)
            if np.hypot(*(lines.polylines[r][-1] - lines.polylines[r][0])) >= min_chord
        ]
        samples = lines.points[np.isin(lines.portion, portions)]
        if len(samples) == 0:
            continue
        d, near = trace_tree.query(samples, distance_upper_bound=reach)
        ok = np.isfinite(d)
        near = near[ok]
        hit = owner[near[nearest[near] == f]]
        coverage[k] = np.bincount(hit).max() / len(samples) if len(hit) else 0.0
    return fibers, image.depth(fibers), coverage


@dataclass(frozen=True, eq=False)
class JunctionPasses:
    """Junctions of a skeleton that traces pass through (a real image: no ground truth).

    Attributes
    ----------
    trace : (n,) int64
        Trace passing through.
    junction : (n,) int64
        Junction passed (index into the junctions given).
    point_px : (n, 2) float64 [px]
        The junction centre (row, col).
    turn_deg : (n,) float64 [deg]
        Turn of the trace across the junction: the angle between its chords over the 2 w of
        arc before and after its point nearest to the junction (0 = straight through).
    """

    trace: np.ndarray
    junction: np.ndarray
    point_px: np.ndarray
    turn_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.trace)


def junction_passes(paths: list[np.ndarray], junctions: np.ndarray, width_px: float) -> JunctionPasses:
    """Junctions that traces pass through: within w / 2 of the trace, which runs on for at
    least 1.5 w of arc on both sides.

    Parameters
    ----------
    paths : list of (n_i, 2) float64 [px]
        Traced centre lines (row, col), one point per pixel of arc.
    junctions : (n_junctions, 2) float64 [px]
        Junction centres (row, col) (:attr:`espin.imaging.trace.TracedFibers.junctions`).
    width_px : float [px]
        Typical fiber width w.

    Returns
    -------
    JunctionPasses
    """
    w = float(width_px)
    rows = []
    for t, path in enumerate(paths):
        if len(path) < 2 or len(junctions) == 0:
            continue
        distance, index = cKDTree(path).query(junctions, distance_upper_bound=_PASS * w)
        for j in np.flatnonzero(np.isfinite(distance)):
            i = int(index[j])
            if i < _BEYOND * w or len(path) - 1 - i < _BEYOND * w:
                continue
            h = int(round(2 * w))
            before = path[i] - path[max(i - h, 0)]
            after = path[min(i + h, len(path) - 1)] - path[i]
            cos = before @ after / max(float(np.hypot(*before) * np.hypot(*after)), 1e-12)
            rows.append((t, int(j), float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))))
    trace = np.array([r[0] for r in rows], dtype=np.int64)
    junction = np.array([r[1] for r in rows], dtype=np.int64)
    return JunctionPasses(
        trace=trace,
        junction=junction,
        point_px=np.asarray(junctions, dtype=float)[junction].reshape(-1, 2),
        turn_deg=np.array([r[2] for r in rows], dtype=float),
    )
