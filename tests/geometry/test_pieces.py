"""Crossing statistics of fiber portions (espin.geometry.pieces): which edge a point lies on,
U-turn fraction and straightness of portions that cross a window edge to edge."""

from __future__ import annotations

import math

import numpy as np
import pytest

from espin.geometry.pieces import border_edges, crossing_statistics, window_crossings, window_runs

LOWER, UPPER = np.zeros(2), np.array([4.0, 2.0])  # a 4 x 2 rectangle
BOTTOM, RIGHT, TOP, LEFT, INSIDE = 0, 1, 2, 3, -1


def test_border_edges_names_the_nearest_edge_within_the_tolerance():
    points = [(2.0, 0.0), (4.0, 1.0), (2.0, 2.0), (0.0, 1.0),  # on each edge
              (2.0, 0.05), (3.95, 1.0), (2.0, -0.05), (-0.05, 1.0),  # near, inside and outside
              (2.0, 1.0), (0.5, 0.5), (2.0, -0.5)]  # inside; beyond the tolerance outside
    edges = border_edges(np.array(points), LOWER, UPPER, 0.1)
    assert edges.tolist() == [BOTTOM, RIGHT, TOP, LEFT, BOTTOM, RIGHT, BOTTOM, LEFT,
                              INSIDE, INSIDE, INSIDE]


def test_border_edges_at_corners_takes_the_nearer_edge():
    # Within the tolerance of two edges: the nearer one; exactly at a corner, the first of
    # bottom, right, top, left.
    points = [(0.02, 0.05), (0.05, 0.02), (3.97, 1.95), (0.0, 0.0), (4.0, 2.0)]
    assert border_edges(np.array(points), LOWER, UPPER, 0.1).tolist() == [LEFT, BOTTOM, RIGHT,
                                                                          BOTTOM, RIGHT]


def test_border_edges_of_no_points():
    assert border_edges(np.zeros((0, 2)), LOWER, UPPER, 0.1).shape == (0,)


def test_crossing_statistics_counts_edge_to_edge_portions_only():
    first = np.array([(0.0, 1.0), (1.0, 0.0), (0.0, 0.5), (2.0, 1.0), (3.0, 2.0)])
    last = np.array([(4.0, 1.0), (3.0, 0.0), (2.0, 2.0), (4.0, 1.5), (2.0, 1.0)])
    # straight across; a U-turn through the bottom (contour 2 x chord); a corner cut from
    # left to top; two portions with an end inside the window (left out).
    contour = np.array([4.0, 4.0, math.hypot(2.0, 1.5), 3.0, 3.0])
    stats = crossing_statistics(first, last, contour, LOWER, UPPER, 1e-9)
    assert stats.n_crossing == 3
    assert stats.u_turn_fraction == pytest.approx(1 / 3)
    assert stats.straightness == pytest.approx((1.0 + 0.5 + 1.0) / 3)


def test_crossing_statistics_without_crossings_is_nan():
    empty = crossing_statistics(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), LOWER, UPPER, 0.1)
    assert empty.n_crossing == 0
    assert math.isnan(empty.u_turn_fraction) and math.isnan(empty.straightness)
    inside = crossing_statistics(np.array([(1.0, 1.0)]), np.array([(4.0, 1.0)]), np.array([3.0]),
                                 LOWER, UPPER, 0.1)
    assert inside.n_crossing == 0 and math.isnan(inside.u_turn_fraction)


def test_window_crossings_of_clipped_polylines():
    # In the window [0, 10]^2: a straight fiber across (left -> right), a V dipping in and
    # out of the top edge (a U-turn), a fiber ending inside, and a corner stub shorter than
    # the chord filter.
    fibers = [[(-5.0, 5.0), (15.0, 5.0)],
              [(2.0, 12.0), (4.0, 6.0), (6.0, 12.0)],
              [(-5.0, 2.0), (5.0, 2.0)],
              [(-0.5, 9.0), (1.0, 10.5)]]
    vertices = np.array([p for f in fibers for p in f])
    offsets = np.cumsum([0] + [len(f) for f in fibers])
    runs = window_runs(vertices, offsets, np.zeros(2), 10.0)
    stats = window_crossings(runs, np.zeros(2), 10.0, min_chord_um=1.0)
    assert stats.n_crossing == 2
    assert stats.u_turn_fraction == pytest.approx(0.5)
    # the V crosses y = 10 at x = 8/3 and 16/3, each arm 4 down and 4/3 across inside
    assert stats.straightness == pytest.approx((1.0 + (8 / 3) / (2 * math.hypot(4 / 3, 4.0))) / 2)
