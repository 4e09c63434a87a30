"""Cross-links: in-plane intersections of fibers in the same or adjacent layers (paper Fig. 5).

Segments are binned on a uniform grid. A segment of layer k is entered in the bins of the
layer pairs (k, k+1) and (k-1, k); within each bin every pair of entries is a candidate, kept
when the lower layer of the two is the pair's base (so each pair of layers is searched once),
the fibers differ, and the segments truly intersect. A pair found in several bins is counted
once. Everything is numpy over all segments at once: no loop over segments, no all-pairs test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from espin.geometry.mat import FiberMat

__all__ = ["Crosslinks", "find_crosslinks", "segment_pairs_in_cells"]


@dataclass(frozen=True, eq=False)
class Crosslinks:
    """Intersections of two segments of different fibers (same or adjacent layers).

    Attributes
    ----------
    point : (n, 2) float64 [um]
        Position of each cross-link in the layer plane.
    segment : (n, 2) int64
        The two segments (indices into the FiberMat's segments), lower index first.
    fiber : (n, 2) int64
        Their fibers.
    layer : (n, 2) int64
        Their layers.
    arc : (n, 2) float64 [um]
        Arc length from each fiber's start to the cross-link.
    """

    point: np.ndarray
    segment: np.ndarray
    fiber: np.ndarray
    layer: np.ndarray
    arc: np.ndarray

    @property
    def n(self) -> int:
        """Number of cross-links."""
        return len(self.point)

    @property
    def n_within_layer(self) -> int:
        """Cross-links between fibers of the same layer."""
        return int(np.count_nonzero(self.layer[:, 0] == self.layer[:, 1]))

    @property
    def n_between_layers(self) -> int:
        """Cross-links between fibers of adjacent layers."""
        return self.n - self.n_within_layer


def _cells_of_segments(p: np.ndarray, q: np.ndarray, cell: float, n_cells: int):
    """Grid cells overlapped by each segment's bounding box, as (segment, cell) entries.

    Also returns the integer cell coordinates of each box's lower-left corner.
    """
    lo = np.clip(np.floor(np.minimum(p, q) / cell).astype(np.int64), 0, n_cells - 1)
    hi = np.clip(np.floor(np.maximum(p, q) / cell).astype(np.int64), 0, n_cells - 1)
    width = hi[:, 0] - lo[:, 0] + 1
    count = width * (hi[:, 1] - lo[:, 1] + 1)
    seg = np.repeat(np.arange(len(p)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    ix = lo[seg, 0] + k % width[seg]
    iy = lo[seg, 1] + k // width[seg]
    return seg, iy * n_cells + ix, lo


def segment_pairs_in_cells(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All pairs of entries that share a key.

    Parameters
    ----------
    key : (m,) int64
        Bin of each entry.

    Returns
    -------
    order : (m,) int64
        Permutation sorting the entries by key.
    i, j : (n_pairs,) int64
        Positions in the sorted order of the two entries of each pair (i < j, same key).
    """
    order = np.argsort(key, kind="stable")
    key = key[order]
    idx = np.arange(len(key))
    boundary = np.flatnonzero(np.diff(key)) + 1
    sizes = np.diff(np.concatenate([[0], boundary, [len(key)]]))
    group_end = np.repeat(np.append(boundary, len(key)), sizes)
    partners = group_end - idx - 1
    i = np.repeat(idx, partners)
    offset = np.arange(partners.sum()) - np.repeat(np.cumsum(partners) - partners, partners)
    return order, i, i + 1 + offset


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _crossings_in_bins(seg, cell, lo, seg_fiber, seg_layer, base, n_cells, p, q):
    """Crossings among grid entries (segment, cell) of layers ``base`` and ``base + 1``.

    Pairs of entries in the same cell are filtered on the entries themselves before any
    coordinates are read: different fibers; same-layer pairs of layer base + 1 are left to the
    next layer pair; a pair sharing several cells is kept in the one cell that holds the
    lower-left corner of the overlap of the two bounding boxes. Returns the segment pairs
    (a < b) that intersect and the parameters t, u of the crossing along each.
    """
    order, i, j = segment_pairs_in_cells(cell)
    seg, cell = seg[order], cell[order]
    fiber, layer, lo_x, lo_y = seg_fiber[seg], seg_layer[seg], lo[seg, 0], lo[seg, 1]
    keep = fiber[i] != fiber[j]
    keep &= np.minimum(layer[i], layer[j]) == base
    keep &= np.maximum(lo_y[i], lo_y[j]) * n_cells + np.maximum(lo_x[i], lo_x[j]) == cell[i]
    a, b = seg[i[keep]], seg[j[keep]]
    a, b = np.minimum(a, b), np.maximum(a, b)
    r = q[a] - p[a]
    w = q[b] - p[b]
    d = p[b] - p[a]
    denom = _cross(r, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(d, w) / denom
        u = _cross(d, r) / denom
    hit = (denom != 0.0) & (t >= 0.0) & (t < 1.0) & (u >= 0.0) & (u < 1.0)
    return a[hit], b[hit], t[hit], u[hit]


def find_crosslinks(mat: FiberMat, cell_size: float | None = None) -> Crosslinks:
    """Find every cross-link of a mat (paper 3.1.1; docs/model.md section 2).

    A cross-link is an intersection in the plane of two segments of different fibers whose
    layers differ by at most one. A fiber crossing itself makes no cross-link. Each segment is
    taken as half-open (its end point belongs to the next segment), so a crossing exactly at
    a vertex counts once.

    Parameters
    ----------
    mat
        The deposited fibers.
    cell_size
        Side of the search grid's cells [um]; default the longest segment (at most 4 cells a
        segment).

    Returns
    -------
    Crosslinks
        Sorted by segment pair.
    """
    s = mat.segment_start
    p, q = mat.vertices[s], mat.vertices[s + 1]
    seg_fiber = mat.segment_fiber
    seg_layer = mat.fiber_layer[seg_fiber]
    if cell_size is None:
        cell_size = max(float(mat.segment_length.max(initial=0.0)), mat.size / 4096)
    n_cells = max(int(np.ceil(mat.size / cell_size)), 1)

    seg, cell, lo = _cells_of_segments(p, q, cell_size, n_cells)
    by_layer = np.argsort(seg_layer[seg], kind="stable")
    seg, cell = seg[by_layer], cell[by_layer]
    bounds = np.searchsorted(seg_layer[seg], np.arange(mat.n_layers + 1))
    found_a, found_b, found_t, found_u = [], [], [], []
    # One layer pair (k, k+1) at a time keeps the working arrays in cache.
    for k in range(mat.n_layers):
        rows = slice(bounds[k], bounds[min(k + 2, mat.n_layers)])
        a, b, t, u = _crossings_in_bins(seg[rows], cell[rows], lo, seg_fiber, seg_layer, k, n_cells, p, q)
        found_a.append(a)
        found_b.append(b)
        found_t.append(t)
        found_u.append(u)
    a, b = np.concatenate(found_a), np.concatenate(found_b)
    t, u = np.concatenate(found_t), np.concatenate(found_u)
    first = np.lexsort((b, a))
    a, b, t, u = a[first], b[first], t[first], u[first]
    r = q[a] - p[a]
    seg_len = mat.segment_length
    arc = mat.segment_arc_start
    return Crosslinks(
        point=p[a] + t[:, None] * r,
        segment=np.c_[a, b],
        fiber=np.c_[seg_fiber[a], seg_fiber[b]],
        layer=np.c_[seg_layer[a], seg_layer[b]],
        arc=np.c_[arc[a] + t * seg_len[a], arc[b] + u * seg_len[b]],
    )
