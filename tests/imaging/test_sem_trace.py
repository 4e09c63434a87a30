"""Tracing fibers through crossings on exact masks: straight bands of known directions."""

from __future__ import annotations

import numpy as np
import pytest

from espin.imaging import trace
from espin.imaging.trace import trace_fibers

N, WIDTH = 320, 8.0  # image side and fiber width [px]


def _bands(*angles_deg: float) -> np.ndarray:
    """Mask of straight fibers WIDTH px wide through the image centre at the given angles."""
    rows, cols = np.mgrid[0:N, 0:N].astype(float) - (N - 1) / 2
    mask = np.zeros((N, N), dtype=bool)
    for a in np.radians(angles_deg):
        mask |= np.abs(rows * np.cos(a) + cols * np.sin(a)) <= WIDTH / 2
    return mask


def _long_paths(mask: np.ndarray) -> list[np.ndarray]:
    paths = trace_fibers(mask, WIDTH).paths
    return [p for p in paths if np.hypot(*(p[-1] - p[0])) > N / 3]


def _tortuosity(p: np.ndarray) -> float:
    return float(np.hypot(*np.diff(p, axis=0).T).sum() / np.hypot(*(p[-1] - p[0])))


def _axes_deg(paths: list[np.ndarray]) -> list[int]:
    """Axes of the end-to-end lines (x = col, y = -row), whole degrees in [0, 180), sorted."""
    axes = [np.degrees(np.arctan2(-(p[-1] - p[0])[0], (p[-1] - p[0])[1])) for p in paths]
    return sorted(int(round(a)) % 180 for a in axes)


def test_a_straight_fiber_is_traced_straight():
    (path,) = _long_paths(_bands(20.0))
    assert _tortuosity(path) < 1.002  # the 8-connected staircase would add up to 8 %
    assert np.hypot(*(path[-1] - path[0])) > 0.95 * N / np.cos(np.radians(20.0))


@pytest.mark.parametrize("angle_deg", [30.0, 60.0, 90.0])
def test_fibers_pass_straight_through_a_crossing(angle_deg):
    paths = _long_paths(_bands(0.0, angle_deg))
    assert len(paths) == 2
    assert _axes_deg(paths) == [0, round(angle_deg)]
    assert all(_tortuosity(p) < 1.002 for p in paths)


@pytest.mark.parametrize("angle_deg", [6.0, 10.0, 15.0])
def test_a_shallow_crossing_is_crossed_straight(monkeypatch, angle_deg):
    """At 6-15 deg the fibers share a stretch 6-18 w long: two junctions joined by a bridge.
    Each fiber keeps its own straight line through it, and the bridge is no fiber."""
    mask = _bands(0.0, angle_deg)
    traced = trace_fibers(mask, WIDTH)
    assert len(traced.paths) == 2
    assert _axes_deg(traced.paths) == [0, round(angle_deg)]
    assert all(_tortuosity(p) < 1.002 for p in traced.paths)
    # The shared stretch is reported (no width is measured there), around the crossing.
    assert len(traced.shared) > 2 * WIDTH
    assert np.hypot(*(traced.shared.mean(axis=0) - (N - 1) / 2)) < WIDTH
    # Paired junction by junction instead, one fiber jogs onto the other and one is cut.
    monkeypatch.setattr(trace, "_SHALLOW", 0.0)
    assert len(trace_fibers(mask, WIDTH).paths) == 3


def test_two_fibers_joined_by_a_bar_are_no_shallow_crossing():
    """An H: two parallel fibers and a bar between them. The outer branches at each end of the
    bar do not leave away from it, so nothing is paired across the bar; each fiber stays whole
    and straight."""
    rows, cols = np.mgrid[0:N, 0:N].astype(float) - (N - 1) / 2
    mask = (np.abs(cols + 40) <= WIDTH / 2) | (np.abs(cols - 40) <= WIDTH / 2)
    mask |= (np.abs(rows) <= WIDTH / 2) & (np.abs(cols) <= 40)
    traced = trace_fibers(mask, WIDTH)
    assert len(traced.shared) == 0
    long = _long_paths(mask)
    assert _axes_deg(long) == [90, 90]
    assert all(_tortuosity(p) < 1.002 for p in long)


def test_crossings_close_together_are_paired_by_straight_continuation():
    """Fibers at 0 and 20 deg cross in the centre, 30 px from a fiber at 80 deg: the skeleton
    junctions of the shallow X (a bridge about 3 w long) and of the third fiber form one
    cluster with five branch ends and more. Paired junction by junction, both fibers of the
    X switched (two traces at 10 deg); paired across the cluster by straight continuation,
    each keeps its line."""
    rows, cols = np.mgrid[0:N, 0:N].astype(float) - (N - 1) / 2
    mask = _bands(0.0, 20.0) | (np.abs(rows * np.cos(np.radians(80.0))
                                       + cols * np.sin(np.radians(80.0)) - 30.0) <= WIDTH / 2)
    paths = _long_paths(mask)
    assert _axes_deg(paths) == [0, 20, 80]
    assert all(_tortuosity(p) < 1.002 for p in paths)


def _ray(angle_deg: float, width: float) -> np.ndarray:
    """Mask of a straight fiber ``width`` px wide from the image centre out at ``angle_deg``
    (counter-clockwise from +col, row up)."""
    rows, cols = np.mgrid[0:N, 0:N].astype(float) - (N - 1) / 2
    a = np.radians(angle_deg)
    along = -rows * np.sin(a) + cols * np.cos(a)
    across = -rows * np.cos(a) - cols * np.sin(a)
    return (np.abs(across) <= width / 2) & (along >= -width / 2)


def test_a_fiber_continues_on_the_branch_of_its_own_width():
    """A thick fiber (12 px) from the left ends where a thin one (5 px) from the lower left
    bends by 30 deg into a thin branch to the right. By direction alone the thick one would
    continue straight onto the thin branch (a switch); the width difference (12 / 5) costs
    more than the bend, so the thin fiber is traced whole and the thick one ends."""
    mask = _ray(180.0, 12.0) | _ray(210.0, 5.0) | _ray(0.0, 5.0)
    paths = trace_fibers(mask, WIDTH).paths
    assert len(paths) == 2
    thin = max(paths, key=len)
    ends = sorted([thin[0].round().tolist(), thin[-1].round().tolist()], key=lambda p: p[1])
    # from the left edge, 92 px below the centre (tan 30 deg), to the right edge on the axis
    assert ends[0][1] == 0 and ends[0][0] == pytest.approx((N - 1) / 2 + (N - 1) / 2 * np.tan(
        np.radians(30.0)), abs=2)
    assert ends[1][1] == N - 1 and ends[1][0] == pytest.approx((N - 1) / 2, abs=1)
    thick = min(paths, key=len)
    assert max(thick[0][1], thick[-1][1]) < (N - 1) / 2  # ends before the junction


def test_branch_ends_are_matched_best_overall_not_greedily(monkeypatch):
    """Four ends: the cheapest pair (0, 1) leaves 2 and 3 too far apart to pair; the best
    matching takes (0, 2) and (1, 3), at a higher cost for one pair but lower in total."""
    cost = np.array([[np.inf, 0.1, 0.2, 0.9],
                     [0.1, np.inf, 0.9, 0.2],
                     [0.2, 0.9, np.inf, 0.8],
                     [0.9, 0.2, 0.8, np.inf]])
    limit = 0.5
    assert trace._best_matching(cost, cost <= limit, limit / 2) == [(0, 2), (1, 3)]
    # with more ends than the exhaustive search takes, the greedy fallback: cheapest first
    monkeypatch.setattr(trace, "_EXACT", 2)
    assert trace._best_matching(cost, cost <= limit, limit / 2) == [(0, 1)]
