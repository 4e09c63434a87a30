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

from espin.mat import FiberMat

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
    """Grid cells overlapped by each segment's bounding box, as (segment, cell) entries."""
    lo = np.clip(np.floor(np.minimum(p, q) / cell).astype(np.int64), 0, n_cells - 1)
    hi = np.clip(np.floor(np.maximum(p, q) / cell).astype(np.int64), 0, n_cells - 1)
    width = hi[:, 0] - lo[:, 0] + 1
    count = width * (hi[:, 1] - lo[:, 1] + 1)
    seg = np.repeat(np.arange(len(p)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    ix = lo[seg, 0] + k % width[seg]
    iy = lo[seg, 1] + k // width[seg]
    return seg, iy * n_cells + ix


def segment_pairs_in_cells(
    key: np.ndarray, item: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All pairs of items that share a key (each unordered pair once per shared key).

    Parameters
    ----------
    key : (m,) int64
        Bin of each entry.
    item : (m,) int64
        Item of each entry.

    Returns
    -------
    a, b : (n_pairs,) int64
        Items of each pair.
    pair_key : (n_pairs,) int64
        The key they share.
    """
    order = np.argsort(key, kind="stable")
    key, item = key[order], item[order]
    idx = np.arange(len(key))
    boundary = np.flatnonzero(np.diff(key)) + 1
    group_end = np.repeat(np.append(boundary, len(key)), np.diff(np.concatenate([[0], boundary, [len(key)]])))
    partners = group_end - idx - 1
    first = np.repeat(idx, partners)
    offset = np.arange(partners.sum()) - np.repeat(np.cumsum(partners) - partners, partners)
    return item[first], item[first + 1 + offset], key[first]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def find_crosslinks(mat: FiberMat, cell_size: float | None = None) -> Crosslinks:
    """Find every cross-link of a mat (paper 3.1.1; SPEC 2).

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

    seg, cell = _cells_of_segments(p, q, cell_size, n_cells)
    # Enter every segment in the bins of layer pairs (k, k+1) (base k) and (k-1, k) (base k-1).
    layer = seg_layer[seg]
    upper = layer > 0
    base = np.concatenate([layer, layer[upper] - 1])
    seg = np.concatenate([seg, seg[upper]])
    cell = np.concatenate([cell, cell[upper]])
    a, b, key = segment_pairs_in_cells(base * (n_cells * n_cells) + cell, seg)
    # A same-layer pair of layer k meets in the bins of bases k and k - 1: keep base k only.
    pair_base = key // (n_cells * n_cells)
    keep = (seg_fiber[a] != seg_fiber[b]) & (np.minimum(seg_layer[a], seg_layer[b]) == pair_base)
    a, b = np.minimum(a[keep], b[keep]), np.maximum(a[keep], b[keep])

    r = q[a] - p[a]
    w = q[b] - p[b]
    d = p[b] - p[a]
    denom = _cross(r, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(d, w) / denom
        u = _cross(d, r) / denom
    hit = (denom != 0.0) & (t >= 0.0) & (t < 1.0) & (u >= 0.0) & (u < 1.0)
    code = np.unique(a[hit] * mat.n_segments + b[hit])
    a, b = code // mat.n_segments, code % mat.n_segments

    r = q[a] - p[a]
    w = q[b] - p[b]
    d = p[b] - p[a]
    denom = _cross(r, w)
    t = _cross(d, w) / denom
    u = _cross(d, r) / denom
    seg_len = mat.segment_length
    arc = mat.segment_arc_start
    return Crosslinks(
        point=p[a] + t[:, None] * r,
        segment=np.c_[a, b],
        fiber=np.c_[seg_fiber[a], seg_fiber[b]],
        layer=np.c_[seg_layer[a], seg_layer[b]],
        arc=np.c_[arc[a] + t * seg_len[a], arc[b] + u * seg_len[b]],
    )
