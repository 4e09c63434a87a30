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
