"""Tracing fibers through crossings: skeleton -> graph of branches and junctions -> fibers.

The algorithm (CT-FIRE-like, written with numpy / scipy.ndimage / scipy.sparse.csgraph):

1. Skeletonize the fiber mask (padded by replication, so skeletons run out to the image edge).
2. Junction pixels have three or more skeleton neighbours (8-connectivity); touching junction
   pixels form one junction. The remaining skeleton pixels split into branches, simple chains
   ordered end to end by one depth-first search.
3. Spurs (branches with a free end and shorter than one fiber width w) are pruned, and
   junctions joined by a branch shorter than 2.5 w are merged (into groups at most 2.5 w wide):
   two fibers crossing at a shallow angle give two nearby skeleton junctions, and are one
   crossing.
4. Shallow crossings first: two fibers crossing at a few degrees share a stretch of
   skeleton (up to 20 w), two three-way junctions joined by a bridge; each outer branch is
   paired with the one at the far junction that continues it on a straight line, and the
   bridge belongs to neither fiber (paired junction by junction, one fiber jogs onto the other
   one's branch and the other is cut).
   Then the other junctions, in clusters: junctions joined by a branch at most 3 w long
   (clusters at most 3.5 w across) are paired as one crossing, and those inner branches
   belong to no fiber (an X at 15-40 deg has two skeleton junctions about 2-4 w apart; a
   third fiber crossing nearby adds more). The direction of each outer branch is fitted on its pixels
   between 0.75 w and 2.75 w from its junction's centre (the skeleton bends towards a
   junction closer in). Continuing branch a on branch c costs the larger of the bend (pi
   minus the angle between their outgoing directions) and the angles between each direction
   and the line joining the two branches' points 2 w out (so a side step onto a parallel
   neighbour costs as a bend), plus 1 rad per unit of the log ratio of their widths beyond
   0.15 (median local widths 1.25-3.5 w out: a fiber keeps its width; a switch usually joins
   a fiber to a thinner, deeper one). A pair is allowed if its geometric cost is at most
   ``max_bend_deg``; the pairs of a cluster are the matching of least total cost, an end left
   unpaired costing ``max_bend_deg`` / 2 (the best assignment, not the cheapest pair first:
   greedily, the cheapest pair can leave the other two ends of an X to be paired wrongly or
   not at all). So a fiber passes straight through a crossing, and a branch whose best
   continuation costs more than ``max_bend_deg`` ends there (a fiber that dives under another
   one; better to end a trace than to switch fibers).
5. Paired branches are chained into fibers. Near a junction, the skeleton pixels within w / 2
   of its centre are dropped and the fiber crosses the junction on a straight line. At the
   open ends of a fiber the skeleton does not follow it: at an unpaired end at a junction it
   bends towards the junction centre, so the pixels within w of the centre are dropped; at a
   free end inside the image it curls into the end cap, so the last w / 2 is dropped.
6. Gap joining: a fiber broken at a crossing (a shallow crossing split into two junctions, an
   end taken by the other fiber, a fiber hidden under another one) leaves two open ends that
   face each other. Pairs of open ends at most 8 w apart, neither on the image border, whose
   total turn (end direction -> straight gap -> other end) is at most ``max_bend_deg`` are
   joined across the gap, smallest turn first; a join is refused if the joined, smoothed path
   turns by more than ``max_bend_deg`` between chords of 2 w or 4 w around the gap (a U-turn
   on a larger scale than the end directions see).
7. Each fiber's pixel chain is resampled every pixel along its arc length and smoothed by a
   Gaussian-weighted local linear fit of sigma w / 2 (at least 2 px; the Gaussian filter
   inside the chain, a local line at its ends): a digital chain overestimates the length of
   a straight line by up to 8 % (the staircase), the smoothed curve by well under 1 %.
8. A smoothed fiber is cut where it turns by more than 1.5 ``max_bend_deg`` between the
   chords over the arc length w before and after a point: a tracing artefact (a U-turn where
   two fibers reach the image border together, a jog onto a neighbour through a shallow
   crossing), not a bend of a fiber.

Coordinates are (row, col) pixels; nothing here knows the scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

__all__ = ["TracedFibers", "trace_fibers"]

_MERGE = 2.5
_SIGMA = 0.5  # smoothing sigma of a traced path, in widths (at least 2 px)
_END_JUNCTION = 1.0  # an unpaired end at a junction loses the pixels within this * w of it
_END_FREE = 0.5  # a free end inside the image loses this * w of arc (the end cap)
_GAP = 8.0  # open fiber ends at most this * w apart may be joined across a straight gap,
_JOIN_TURN = 1.0  # ... if their total turn is at most this * max_bend,
_GUARD_SHORT, _GUARD = 2.0, 4.0  # ... and the joined path turns by at most
_GUARD_LIMIT = 1.0  # this * max_bend between chords of these many widths around the gap
_CLUSTER = 3.0  # junctions joined by a branch at most this * w long are paired as one ...
_CLUSTER_SPREAD = 3.5  # ... cluster at most this * w across
_ANCHOR = 2.0  # a branch's anchor point for the continuation cost lies this * w out
_WIDTH_COST = 1.0  # [rad] per unit log ratio of the widths of two branches paired
_WIDTH_FROM, _WIDTH_TO = 1.25, 3.5  # widths compared between these many w from the junction
_WIDTH_SLACK = 0.15  # log ratio of widths that costs nothing
_UNPAIRED = 0.5  # an end left unpaired at a junction costs this * max_bend
_EXACT = 10  # the branch ends of a cluster are matched exhaustively up to this many
_SHALLOW = 20.0  # bridges of shallow crossings up to this * w long are crossed straight
_TURN = 1.5  # a fiber is cut where it turns by more than _TURN * max_bend within +- w
_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


@dataclass(frozen=True, eq=False)
class TracedFibers:
    """Fibers traced on a skeleton.

    Attributes
    ----------
    paths : list of (n_i, 2) float64 [px]
        Smoothed centre line of each fiber, (row, col), one point per pixel of arc length.
    junctions : (n_junctions, 2) float64 [px]
        Junction centres (row, col) after merging.
    skeleton : (rows, cols) bool
        The skeleton that was traced.
    shared : (n_shared, 2) float64 [px]
        Skeleton pixels two fibers share: the bridges of shallow crossings and the branches
        inside junction clusters. Like the junctions, no place to measure one fiber's width.
    """

    paths: list[np.ndarray]
    junctions: np.ndarray
    skeleton: np.ndarray
    shared: np.ndarray


@dataclass
class _Graph:
    """Branches (ordered pixel chains) and the junction each branch end touches (-1: none)."""

    branches: list[np.ndarray]
    ends: np.ndarray  # (n_branches, 2) int64 junction id at the first / last pixel
    junction_centre: np.ndarray  # (n_junctions, 2) float64
    skeleton_shape: tuple[int, int] = (0, 0)


def trace_fibers(mask: np.ndarray, width_px: float, max_bend_deg: float = 35.0) -> TracedFibers:
    """Trace fibers through crossings on a fiber mask (see the module notes).

    Parameters
    ----------
    mask : (rows, cols) bool
        Fiber pixels.
    width_px : float [px]
        Typical fiber width w; scales pruning, merging, direction fits and smoothing.
    max_bend_deg : float [deg]
        Largest bending angle at which two branches meeting at a junction are joined.

    Returns
    -------
    TracedFibers
    """
    from skimage.morphology import skeletonize

    w = float(width_px)
    pad = int(np.ceil(w))
    skeleton = skeletonize(np.pad(mask, pad, mode="edge"))[pad:-pad, pad:-pad]
    graph = _skeleton_graph(skeleton)
    graph = _prune_spurs(graph, w)
    graph = _merge_junctions(graph, w)
    partner, bridges = _pair_shallow_crossings(graph, w, np.radians(max_bend_deg))
    width = 2.0 * ndimage.distance_transform_edt(np.pad(mask, pad, mode="edge"))[pad:-pad, pad:-pad] - 1.0
    partner, inner = _pair_branches(graph, w, np.radians(max_bend_deg), partner, bridges, width)
    chains = _chain_fibers(graph, partner, w, bridges | inner)
    if _GAP > 0:
        smooth = _join_gaps(chains, w, np.radians(max_bend_deg), skeleton.shape)
    else:
        smooth = [_smoothed(c, w) for c, _ in chains]
    paths = [piece for path in smooth for piece in _split_at_turns(path, w, np.radians(_TURN * max_bend_deg))]
    shared = [graph.branches[b] for b in np.flatnonzero(bridges | inner)]
    return TracedFibers(
        paths=paths,
        junctions=graph.junction_centre,
        skeleton=skeleton,
        shared=np.concatenate(shared).astype(float) if shared else np.zeros((0, 2)),
    )


# --------------------------------------------------------------------------------------------
# skeleton -> graph
# --------------------------------------------------------------------------------------------
def _skeleton_graph(skeleton: np.ndarray) -> _Graph:
    count = ndimage.convolve(skeleton.astype(np.int8), np.ones((3, 3), np.int8), mode="constant")
    junction_px = skeleton & (count - 1 >= 3)
    junction_label, n_junctions = ndimage.label(junction_px, structure=np.ones((3, 3)))
    centre = np.array(ndimage.center_of_mass(junction_px, junction_label, np.arange(1, n_junctions + 1))).reshape(-1, 2)
    branches = _ordered_chains(skeleton & ~junction_px)
    shape = np.array(skeleton.shape)
    ends = np.full((len(branches), 2), -1, dtype=np.int64)
    for i, chain in enumerate(branches):
        for side, pixel in enumerate((chain[0], chain[-1])):
            near = pixel + _NEIGHBOURS
            near = near[np.all((near >= 0) & (near < shape), axis=1)]
            labels = junction_label[near[:, 0], near[:, 1]]
            labels = labels[labels > 0]
            if len(labels):
                # A one-pixel branch may touch two junctions: give it both.
                ends[i, side] = (labels.max() if side == 0 else labels.min()) - 1
    return _Graph(branches=branches, ends=ends, junction_centre=centre, skeleton_shape=skeleton.shape)


def _ordered_chains(chain_px: np.ndarray) -> list[np.ndarray]:
    """Pixels of each 8-connected chain (no pixel has > 2 neighbours), in order along it.

    One depth-first search from a virtual root linked to one end of every chain visits the
    chains one after the other, each from end to end (a closed loop from any pixel).
    """
    rows, cols = np.nonzero(chain_px)
    n = len(rows)
    if n == 0:
        return []
    index = np.full(chain_px.shape, -1, dtype=np.int64)
    index[rows, cols] = np.arange(n)
    src, dst = [], []
    for dr, dc in _NEIGHBOURS[4:]:  # each undirected neighbour pair once
        r, c = rows + dr, cols + dc
        ok = (r >= 0) & (r < chain_px.shape[0]) & (c >= 0) & (c < chain_px.shape[1])
        j = np.full(n, -1)
        j[ok] = index[r[ok], c[ok]]
        src.append(np.flatnonzero(j >= 0))
        dst.append(j[j >= 0])
    head, tail = np.concatenate(src), np.concatenate(dst)
    adjacency = sparse.coo_matrix((np.ones(len(head)), (head, tail)), shape=(n, n)).tocsr()
    adjacency = adjacency + adjacency.T
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    n_comp, comp = csgraph.connected_components(adjacency, directed=False)
    # One start per chain: its lowest-degree pixel (an end; any pixel of a loop).
    order = np.lexsort((degree, comp))
    first = order[np.r_[True, comp[order[1:]] != comp[order[:-1]]]]
    root = sparse.coo_matrix((np.ones(n_comp), (np.full(n_comp, n), first)), shape=(n + 1, n + 1))
    graph = sparse.bmat([[adjacency, None], [None, sparse.csr_matrix((1, 1))]]).tocsr() + root
    visit = csgraph.depth_first_order(graph, n, directed=False, return_predecessors=False)[1:]
    cuts = np.flatnonzero(np.isin(visit, first))
    return [np.column_stack([rows[v], cols[v]]) for v in np.split(visit, cuts[1:])]


# --------------------------------------------------------------------------------------------
# graph clean-up
# --------------------------------------------------------------------------------------------
def _branch_length(chain: np.ndarray) -> float:
    return float(np.hypot(*np.diff(chain, axis=0).T).sum()) + 1.0


def _prune_spurs(graph: _Graph, w: float) -> _Graph:
    """Drop branches with one free end, attached to a junction, shorter than w."""
    length = np.array([_branch_length(b) for b in graph.branches])
    free = (graph.ends < 0).sum(axis=1) == 1
    keep = ~(free & (length < w))
    return _Graph(
        [b for b, k in zip(graph.branches, keep) if k], graph.ends[keep], graph.junction_centre, graph.skeleton_shape
    )


def _merge_junctions(graph: _Graph, w: float) -> _Graph:
    """Merge junctions joined by a branch shorter than 2.5 w into one, at their mean centre.

    Shortest bridges first; a merge is refused if it would make a group wider than 2.5 w (so a
    row of nearby crossings does not collapse into one junction).
    """
    n = len(graph.junction_centre)
    length = np.array([_branch_length(b) for b in graph.branches])
    candidate = np.flatnonzero(
        np.all(graph.ends >= 0, axis=1) & (length < _MERGE * w) & (graph.ends[:, 0] != graph.ends[:, 1])
    )
    group = _group_junctions(graph, candidate[np.argsort(length[candidate])], _MERGE * w)
    _, group = np.unique(group, return_inverse=True)
    count = np.bincount(group, minlength=group.max(initial=-1) + 1)
    centre = (
        np.column_stack([np.bincount(group, graph.junction_centre[:, k]) / count for k in range(2)])
        if n
        else graph.junction_centre
    )
    ends = np.where(graph.ends >= 0, group[np.maximum(graph.ends, 0)] if n else -1, -1)
    # Bridges (and short loops) inside a merged junction are dropped.
    inner = np.all(ends >= 0, axis=1) & (ends[:, 0] == ends[:, 1]) & (length < 2 * _MERGE * w)
    return _Graph([b for b, k in zip(graph.branches, ~inner) if k], ends[~inner], centre, graph.skeleton_shape)


# --------------------------------------------------------------------------------------------
# pairing and chaining
# --------------------------------------------------------------------------------------------
def _outgoing_direction(chain: np.ndarray, centre: np.ndarray, w: float) -> np.ndarray:
    """Unit direction (row, col) in which a branch leaves a junction centre."""
    distance = np.hypot(*(chain - centre).T)
    near = chain[(distance >= 0.75 * w) & (distance <= 2.75 * w)]
    if len(near) < 3:
        near = chain[np.argsort(distance)[-max(len(chain) // 2, 1) :]]
    d = near.mean(axis=0) - centre
    if len(near) >= 3:
        axis = np.linalg.svd(near - near.mean(axis=0), full_matrices=False)[2][0]
        d = axis if axis @ d >= 0 else -axis
    norm = np.hypot(*d)
    return d / norm if norm > 0 else d


def _pair_shallow_crossings(graph: _Graph, w: float, max_bend: float) -> tuple[np.ndarray, np.ndarray]:
    """Pair the branches of two fibers crossing at a shallow angle: (partner, bridges).

    Two fibers crossing at a small angle share a stretch of skeleton longer than the merge
    distance: two three-way junctions joined by a bridge branch, two outer branches at each.
    Paired at each junction on its own, one fiber follows the bridge and may leave on the other
    fiber's branch (a jog), the other is cut. Here each outer branch is paired with the outer
    branch at the far junction that continues it straight: the pairing whose larger deviation
    is smaller, at most ``max_bend``, where the deviation of a pair is its bend or twice the
    angle between either branch and the line joining points 2 w out on both (so two branches
    parallel but offset are no pair). The fibers cross the shared stretch on straight lines,
    and the bridge belongs to neither. Bridges up to _SHALLOW w long are considered (two
    fibers w wide crossing at 6 deg share about 18 w).

    Returns
    -------
    partner : (n_branches, 2) int64
        As :func:`_pair_branches`, for the branches paired here (-1 elsewhere).
    bridges : (n_branches,) bool
        The bridges crossed this way.
    """
    partner = np.full(graph.ends.shape, -1, dtype=np.int64)
    bridges = np.zeros(len(graph.branches), dtype=bool)
    at: dict[int, list[int]] = {}  # junction -> its branch ends (2 b + side)
    for b in range(len(graph.branches)):
        for side in (0, 1):
            if graph.ends[b, side] >= 0:
                at.setdefault(int(graph.ends[b, side]), []).append(2 * b + side)
    for bridge, chain in enumerate(graph.branches):
        j1, j2 = (int(j) for j in graph.ends[bridge])
        if j1 < 0 or j2 < 0 or j1 == j2 or len(at[j1]) != 3 or len(at[j2]) != 3 or _branch_length(chain) > _SHALLOW * w:
            continue
        outer1 = [e for e in at[j1] if e // 2 != bridge]
        outer2 = [e for e in at[j2] if e // 2 != bridge]
        ends = outer1 + outer2
        if (
            len(ends) != 4
            or len({e // 2 for e in ends}) != 4
            or np.any(partner.flat[ends] >= 0)
            or bridges[[e // 2 for e in ends]].any()
        ):
            continue
        axis = graph.junction_centre[j2] - graph.junction_centre[j1]
        u, anchor = {}, {}
        for e, j in zip(ends, (j1, j1, j2, j2)):
            b, side = divmod(e, 2)
            oriented = graph.branches[b] if side == 0 else graph.branches[b][::-1]
            u[e] = _outgoing_direction(oriented, graph.junction_centre[j], w)
            anchor[e] = oriented[min(int(round(2 * w)), len(oriented) - 1)]
        # The outer branches leave away from the bridge on both sides (an X, not a loop).
        if min(-(u[e] @ axis) for e in outer1) <= 0 or min(u[e] @ axis for e in outer2) <= 0:
            continue

        def deviation(a: int, c: int, u: dict[int, np.ndarray] = u, anchor: dict[int, np.ndarray] = anchor) -> float:
            """Bend from a (at j1) to c (at j2), or twice the larger angle between their
            directions and the line joining them (on one straight line they are all 0)."""
            line = anchor[c] - anchor[a]
            line = line / max(float(np.hypot(*line)), 1e-12)
            return max(
                float(np.arccos(np.clip(-(u[a] @ u[c]), -1.0, 1.0))),
                2.0 * float(np.arccos(np.clip(-(u[a] @ line), -1.0, 1.0))),
                2.0 * float(np.arccos(np.clip(u[c] @ line, -1.0, 1.0))),
            )

        options = [((outer1[0], outer2[0]), (outer1[1], outer2[1])), ((outer1[0], outer2[1]), (outer1[1], outer2[0]))]
        worst = [max(deviation(*p) for p in pairs) for pairs in options]
        best = int(np.argmin(worst))
        if worst[best] > max_bend:
            continue
        for a, c in options[best]:
            partner.flat[a], partner.flat[c] = c, a
        bridges[bridge] = True
    return partner, bridges


def _pair_branches(
    graph: _Graph, w: float, max_bend: float, partner: np.ndarray, bridges: np.ndarray, width: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pair the branch ends at every junction cluster: (partner, inner).

    partner[b, side] = (branch, side) index 2 b' + s' joined at that end, or -1. Junctions
    joined by a branch at most _CLUSTER w long form one cluster (at most _CLUSTER_SPREAD w
    across); those inner branches belong to no fiber (``inner``), a fiber crosses the cluster
    on a straight line. The outer ends of a cluster are matched by :func:`_best_matching` on
    :func:`_continuation_cost` plus :func:`_width_cost` (``width``: the local width [px] on
    the skeleton, 2 d - 1 with d the distance to the background). Ends already paired in
    ``partner`` and the ``bridges`` are left out.
    """
    partner = partner.copy()
    cluster, inner = _junction_clusters(graph, w, partner, bridges)
    by_cluster: dict[int, list[int]] = {}
    for b in range(len(graph.branches)):
        if bridges[b] or inner[b]:
            continue
        for side in (0, 1):
            j = int(graph.ends[b, side])
            if j >= 0 and partner[b, side] < 0:
                by_cluster.setdefault(int(cluster[j]), []).append(2 * b + side)
    for ends in by_cluster.values():
        if len(ends) < 2:
            continue
        u, anchor, thick = {}, {}, {}
        for e in ends:
            b, side = divmod(e, 2)
            oriented = graph.branches[b] if side == 0 else graph.branches[b][::-1]
            centre = graph.junction_centre[graph.ends[b, side]]
            u[e] = _outgoing_direction(oriented, centre, w)
            anchor[e] = oriented[min(int(round(_ANCHOR * w)), len(oriented) - 1)]
            thick[e] = _width_near(width, oriented, centre, w)
        bend = np.full((len(ends), len(ends)), np.inf)  # the geometric part of the cost
        cost = np.full((len(ends), len(ends)), np.inf)
        for i, a in enumerate(ends):
            for k in range(i + 1, len(ends)):
                c = ends[k]
                if a // 2 != c // 2:
                    bend[i, k] = bend[k, i] = _continuation_cost(u[a], u[c], anchor[a], anchor[c])
                    cost[i, k] = cost[k, i] = bend[i, k] + _width_cost(thick[a], thick[c])
        for i, k in _best_matching(cost, bend <= max_bend, _UNPAIRED * max_bend):
            partner.flat[ends[i]], partner.flat[ends[k]] = ends[k], ends[i]
    return partner, inner


def _group_junctions(graph: _Graph, branches: np.ndarray, max_spread: float) -> np.ndarray:
    """Group of every junction after joining the two junctions of each of ``branches`` in
    turn, a join refused if the group would be more than ``max_spread`` [px] across."""
    group = np.arange(len(graph.junction_centre))
    for b in branches:
        ga, gb = group[graph.ends[b]]
        if ga == gb:
            continue
        members = graph.junction_centre[(group == ga) | (group == gb)]
        spread = np.hypot(*(members[:, None, :] - members[None, :, :]).transpose(2, 0, 1))
        if spread.max() <= max_spread:
            group[group == gb] = ga
    return group


def _junction_clusters(
    graph: _Graph, w: float, partner: np.ndarray, bridges: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Cluster of every junction, and the inner branches (joining two junctions of one
    cluster, at most _CLUSTER w long); shortest branches first, a merge refused if the
    cluster would be more than _CLUSTER_SPREAD w across."""
    n = len(graph.junction_centre)
    length = np.array([_branch_length(b) for b in graph.branches])
    short = np.all(graph.ends >= 0, axis=1) & (length <= _CLUSTER * w) & ~bridges & np.all(partner < 0, axis=1)
    group = _group_junctions(graph, np.flatnonzero(short)[np.argsort(length[short])], _CLUSTER_SPREAD * w)
    ends = np.maximum(graph.ends, 0)
    inner = short & (group[ends[:, 0]] == group[ends[:, 1]]) if n else short
    return group, inner


def _continuation_cost(ua: np.ndarray, uc: np.ndarray, anchor_a: np.ndarray, anchor_c: np.ndarray) -> float:
    """How far branch c is from continuing branch a straight through a junction [rad].

    The bend (pi minus the angle between their outgoing directions ``ua``, ``uc``) or the
    angle between either direction and the line joining their anchor points (_ANCHOR w out
    on each), whichever is largest: 0 on one straight line; a side step between two parallel
    branches (a fiber continuing on a neighbour) costs as a bend.
    """
    line = anchor_c - anchor_a
    norm = float(np.hypot(*line))
    if norm < 1e-9:
        return float(np.arccos(np.clip(-(ua @ uc), -1.0, 1.0)))
    line = line / norm
    return max(
        float(np.arccos(np.clip(-(ua @ uc), -1.0, 1.0))),
        float(np.arccos(np.clip(-(ua @ line), -1.0, 1.0))),
        float(np.arccos(np.clip(uc @ line, -1.0, 1.0))),
    )


def _width_near(width: np.ndarray, oriented: np.ndarray, centre: np.ndarray, w: float) -> float:
    """Median local width [px] of a branch's pixels _WIDTH_FROM w to _WIDTH_TO w from a
    junction centre (all its pixels if none are there)."""
    distance = np.hypot(*(oriented - centre).T)
    px = oriented[(distance >= _WIDTH_FROM * w) & (distance <= _WIDTH_TO * w)]
    px = (px if len(px) else oriented).astype(np.int64)
    return float(np.median(width[px[:, 0], px[:, 1]]))


def _width_cost(a: float, c: float) -> float:
    """Cost [rad] of joining branches of widths a and c [px]: _WIDTH_COST times the log of
    their ratio beyond _WIDTH_SLACK (a fiber keeps its width, up to the scatter of the local
    widths; a deeper one looks thinner in the mask)."""
    excess = abs(np.log(max(a, 1.0) / max(c, 1.0))) - _WIDTH_SLACK
    return float(_WIDTH_COST * max(excess, 0.0))


def _best_matching(cost: np.ndarray, allowed: np.ndarray, unpaired: float) -> list[tuple[int, int]]:
    """Pairs (i, k), each one ``allowed``, that minimize the total ``cost`` (symmetric
    matrices), an item left unpaired costing ``unpaired``. Exhaustive for up to _EXACT
    items, greedy (cheapest first) above."""
    n = len(cost)
    if n > _EXACT:
        order = np.dstack(np.unravel_index(np.argsort(cost, axis=None), cost.shape))[0]
        taken, pairs = set(), []
        for i, k in order:
            if i < k and allowed[i, k] and cost[i, k] < 2 * unpaired and i not in taken and k not in taken:
                taken |= {i, k}
                pairs.append((int(i), int(k)))
        return pairs

    memo: dict[tuple[int, ...], tuple[float, list[tuple[int, int]]]] = {}

    def best(free: tuple[int, ...]) -> tuple[float, list[tuple[int, int]]]:
        if free in memo:
            return memo[free]
        if len(free) < 2:
            return unpaired * len(free), []
        first, rest = free[0], free[1:]
        total, pairs = best(rest)
        total += unpaired
        for m, k in enumerate(rest):
            if allowed[first, k]:
                sub, sub_pairs = best(rest[:m] + rest[m + 1 :])
                if sub + cost[first, k] < total:
                    total, pairs = sub + cost[first, k], [(first, k)] + sub_pairs
        memo[free] = total, pairs
        return total, pairs

    return best(tuple(range(n)))[1]


def _chain_fibers(graph: _Graph, partner: np.ndarray, w: float, bridges: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Follow branches through their paired ends: (pixel chain, open?) of each fiber.

    The ends of an open chain are trimmed (:func:`_trim_open_ends`); a closed loop is not.
    """
    n = len(graph.branches)
    used = bridges.copy()  # a bridge of a shallow crossing belongs to neither fiber
    starts = [2 * b + s for b in range(n) for s in (0, 1) if partner[b, s] < 0]
    paths = []
    for start in starts + [2 * b for b in range(n)]:  # open chains first, then loops
        if used[start // 2]:
            continue
        pieces, end = [], start
        while not used[end // 2]:
            b, side = divmod(end, 2)
            used[b] = True
            pieces.append(_trimmed(graph, b, side, w))
            nxt = partner[b, 1 - side]
            if nxt < 0:
                break
            end = int(nxt)
        chain = np.concatenate(pieces).astype(float)
        if partner[b, 1 - side] < 0:  # an open chain: trim both of its ends
            first_b, first_side = divmod(start, 2)
            chain = _trim_open_ends(chain, graph.ends[first_b, first_side], graph.ends[b, 1 - side], graph, w)
            paths.append((chain, True))
        else:
            paths.append((chain, False))
    return paths


def _end_direction(chain: np.ndarray, w: float) -> np.ndarray:
    """Unit direction (row, col) in which a chain leaves its last point, fitted over 2 w."""
    distance = np.hypot(*(chain - chain[-1]).T)
    near = chain[distance <= 2.0 * w]
    d = chain[-1] - near.mean(axis=0)
    if len(near) >= 3:
        axis = np.linalg.svd(near - near.mean(axis=0), full_matrices=False)[2][0]
        d = axis if axis @ d >= 0 else -axis
    norm = np.hypot(*d)
    return d / norm if norm > 0 else d


def _max_turn(path: np.ndarray, h: int, around: float, radius: float) -> float:
    """Largest turn between the chords h points before and after, at points near index around."""
    n = len(path)
    if n < 2 * h + 1:
        return 0.0
    before = path[h : n - h] - path[: n - 2 * h]
    after = path[2 * h :] - path[h : n - h]
    cos = np.einsum("ij,ij->i", before, after) / np.maximum(np.hypot(*before.T) * np.hypot(*after.T), 1e-12)
    index = np.arange(h, n - h)
    near = np.abs(index - around) <= radius
    return float(np.arccos(np.clip(cos[near], -1.0, 1.0)).max(initial=0.0))


def _join_gaps(chains: list, w: float, max_bend: float, shape: tuple) -> list[np.ndarray]:
    """Join open fiber chains whose ends face each other across a straight gap; smooth all.

    A fiber broken at a crossing (a shallow crossing split into two junctions, an end stolen
    by the other fiber) leaves two open ends that face each other: candidates are pairs of
    ends at most _GAP w apart, neither on the image border, whose total turn (end direction
    to gap, gap to the other end's reverse direction) is at most ``max_bend``; smallest turn
    first. A join is kept only if the smoothed joined path turns by at most ``max_bend``
    between chords of 2 w and _GUARD w around the gap (no U-turn through a gap).
    """
    open_ids = [i for i, (c, o) in enumerate(chains) if o and len(c) >= 2]
    size = np.array(shape)
    ends = []  # (chain, side, point, outgoing direction)
    for i in open_ids:
        c = chains[i][0]
        for side, oriented in ((0, c[::-1]), (1, c)):
            p = oriented[-1]
            if np.any(p <= 1) or np.any(p >= size - 2):
                continue
            ends.append((i, side, p, _end_direction(oriented, w)))
    candidates = []
    for a in range(len(ends)):
        for b in range(a + 1, len(ends)):
            ia, sa, pa, da = ends[a]
            ib, sb, pb, db = ends[b]
            if ia == ib:
                continue
            g = pb - pa
            gap = np.hypot(*g)
            if gap > _GAP * w:
                continue
            if gap < 1e-9:
                turn = np.arccos(np.clip(-(da @ db), -1, 1))
            else:
                u = g / gap
                turn = np.arccos(np.clip(da @ u, -1, 1)) + np.arccos(np.clip(-(db @ u), -1, 1))
            if turn <= _JOIN_TURN * max_bend:
                candidates.append((turn, gap, a, b))
    # Union of chains: each chain is a sequence of (chain id, reversed?) pieces.
    seq = {i: [(i, False)] for i in range(len(chains))}
    owner = {i: i for i in range(len(chains))}
    free = {(ends[k][0], ends[k][1]) for k in range(len(ends))}

    def assemble(pieces):
        return np.concatenate([chains[i][0][::-1] if r else chains[i][0] for i, r in pieces])

    for _turn, gap, a, b in sorted(candidates):
        ia, sa = ends[a][:2]
        ib, sb = ends[b][:2]
        if (ia, sa) not in free or (ib, sb) not in free:
            continue
        ga, gb = owner[ia], owner[ib]
        if ga == gb:
            continue
        A, B = seq[ga], seq[gb]
        # orient A so that the end (ia, sa) is last, B so that (ib, sb) is first
        last_a = A[-1][0] == ia and (A[-1][1] == (sa == 0))
        A_or = A if last_a else [(i, not r) for i, r in A[::-1]]
        first_b = B[0][0] == ib and (B[0][1] == (sb == 1))
        B_or = B if first_b else [(i, not r) for i, r in B[::-1]]
        joined = A_or + B_or
        path = _smoothed(assemble(joined), w)
        # the gap starts at the arc length of A (one smoothed point per pixel of arc)
        arc_a = float(np.hypot(*np.diff(assemble(A_or), axis=0).T).sum())
        if (
            max(_max_turn(path, max(int(round(k * w)), 2), arc_a + gap / 2, _GUARD * w) for k in (_GUARD_SHORT, _GUARD))
            > _GUARD_LIMIT * max_bend
        ):
            continue
        free -= {(ia, sa), (ib, sb)}
        seq[ga] = joined
        for i, _ in B:
            owner[i] = ga
        del seq[gb]
    return [_smoothed(assemble(pieces), w) for pieces in seq.values()]


def _trim_open_ends(chain: np.ndarray, j_first: int, j_last: int, graph: _Graph, w: float) -> np.ndarray:
    """Drop the end pixels of an open fiber chain where the skeleton does not follow the fiber.

    At an unpaired end at a junction the skeleton bends towards the junction centre within
    about w of it (the same zone the direction fit leaves out); at a free end the skeleton
    curls into the end cap over about w / 2. Ends on the image border (the skeleton was run
    out to the border) are kept. A chain shorter than the trims is left whole.
    """
    shape = np.array(graph.skeleton_shape)
    arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(chain, axis=0).T))]
    keep = np.ones(len(chain), dtype=bool)
    for end, j, distance_from_end in ((0, j_first, arc), (-1, j_last, arc[-1] - arc)):
        pixel = chain[end]
        if j >= 0:
            keep &= np.hypot(*(chain - graph.junction_centre[j]).T) > _END_JUNCTION * w
        elif np.all(pixel > 0) and np.all(pixel < shape - 1):
            keep &= distance_from_end >= _END_FREE * w
    kept = np.flatnonzero(keep)
    if len(kept) < 2:
        return chain
    return chain[kept[0] : kept[-1] + 1]


def _trimmed(graph: _Graph, b: int, side: int, w: float) -> np.ndarray:
    """Branch b oriented from its end ``side``, without pixels within w / 2 of its junctions."""
    chain = graph.branches[b] if side == 0 else graph.branches[b][::-1]
    ends = graph.ends[b] if side == 0 else graph.ends[b][::-1]
    keep = np.ones(len(chain), dtype=bool)
    for j in ends[ends >= 0]:
        keep &= np.hypot(*(chain - graph.junction_centre[j]).T) > w / 2.0
    return chain[keep] if keep.any() else chain[len(chain) // 2 : len(chain) // 2 + 1]


def _smoothed(chain: np.ndarray, w: float) -> np.ndarray:
    """Resample a pixel chain every pixel of arc length and smooth it (sigma max(2, w / 2)).

    The smoothing is a Gaussian-weighted local linear fit (:func:`_local_linear`): the Gaussian
    filter inside the chain, and near an end a local line, so a straight chain stays straight
    up to its end points (a point reflection about a noisy end pixel put a kink there).
    """
    step = np.hypot(*np.diff(chain, axis=0).T)
    arc = np.r_[0.0, np.cumsum(step)]
    n = max(int(np.ceil(arc[-1])) + 1, 2)
    s = np.linspace(0.0, arc[-1], n)
    points = np.column_stack([np.interp(s, arc, chain[:, k]) for k in range(2)])
    return _local_linear(points, max(2.0, _SIGMA * w))


def _local_linear(points: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian-weighted local linear fit of a curve sampled every pixel, at every sample.

    Inside the curve this is the Gaussian filter; near an end, where the kernel is cut off, the
    local line keeps a straight curve straight (no reflection about a noisy end pixel).
    """
    n = len(points)
    half = int(np.ceil(3 * sigma))
    k = np.arange(-half, half + 1, dtype=float)
    g = np.exp(-0.5 * (k / sigma) ** 2)
    ones = np.ones(n)

    def conv(x: np.ndarray, kern: np.ndarray) -> np.ndarray:  # sum_k kern[k] x[i + k]
        return np.convolve(x, kern[::-1], mode="full")[half : half + n]

    s0, s1, s2 = conv(ones, g), conv(ones, k * g), conv(ones, k * k * g)
    out = np.empty_like(points)
    for c in range(points.shape[1]):
        t0, t1 = conv(points[:, c], g), conv(points[:, c], k * g)
        det = s0 * s2 - s1 * s1
        out[:, c] = np.where(det > 1e-9, (s2 * t0 - s1 * t1) / np.where(det > 1e-9, det, 1.0), t0 / s0)
    return out


def _split_at_turns(path: np.ndarray, w: float, max_bend: float) -> list[np.ndarray]:
    """Cut a smoothed path where it turns by more than ``max_bend`` within w on either side.

    The chord directions over the arc length w before and after each point are compared; at a
    local maximum of that turn above ``max_bend`` (1.5 times the pairing limit) the path is
    cut, cuts at least w apart. A fiber does not bend that sharply, so such a turn is a
    tracing artefact: a U-turn where two fibers meet at the image border (the padded
    skeleton joins them), or a jog onto a neighbouring fiber through a shallow crossing.
    """
    h = max(int(round(w)), 2)
    n = len(path)
    if n < 2 * h + 1:
        return [path]
    before = path[h : n - h] - path[: n - 2 * h]
    after = path[2 * h :] - path[h : n - h]
    cos = np.einsum("ij,ij->i", before, after) / np.maximum(np.hypot(*before.T) * np.hypot(*after.T), 1e-12)
    turn = np.arccos(np.clip(cos, -1.0, 1.0))
    cuts: list[int] = []
    for i in np.argsort(-turn):
        if turn[i] <= max_bend:
            break
        if all(abs(i - c) > h for c in cuts):
            cuts.append(int(i))
    if not cuts:
        return [path]
    return [piece for piece in np.split(path, np.sort(np.array(cuts)) + h) if len(piece) >= 2]
