"""SEM-like grey images rendered from a virtual mat, with their ground truth.

:func:`render_sem` draws the fibers of the top layers of a :class:`espin.geometry.mat.FiberMat` as bright
tubes of their true diameter on a dark background, the way a secondary-electron image shows an
electrospun mat, and returns what an ideal analyst would measure on it: the true diameters and
the fiber portions visible in the image (:func:`espin.geometry.statistics.window_tortuosity` on the same
window). It is the test bed of :func:`espin.imaging.measurement.measure`.

Image model (all documented parameters of :func:`render_sem`)
--------------------------------------------------------------
1. Layer ``k`` sits at height (k + 1/2) D, so the highest layers face the microscope. The
   ``layers`` top layers are drawn; the layer at depth ``j`` (0 = top) has brightness
   ``(1 - depth_dimming) ** j`` (fewer secondary electrons escape from below) and is blurred
   by a Gaussian of ``blur_px + j * depth_blur_px`` pixels (out of focus).
2. A fiber covers the pixels within D_f / 2 of its centreline, with a one-pixel anti-aliased
   edge; its profile is flat with edges up to 15 % brighter (the SEM edge effect).
   Fibers of one layer are fused (union); a layer hides the layers below it (alpha compositing).
3. The background (deeper layers, holes) has the grey level ``background``.
4. Uneven illumination: the image is multiplied by a linear ramp that falls from 1 at the
   upper-left corner to ``1 - illumination`` at the lower-right one.
5. Detector noise: Gaussian, standard deviation ``noise_sd`` (top-fiber brightness = 1);
   the image is clipped to [0, 1].
6. Optionally a microscope's data bar (``data_bar``), ``data_bar_fraction`` of the rows at
   the bottom or the top: a line of 11 tick marks (a Hitachi scale bar) next to the image,
   as far from the bar's edge as they are high, and a line of text (Pillow's default font,
   "SE 15.0kV x2.00k 30.0um") beyond it, white (1.0). Either a separate band (black
   background, the fibers hidden) or overlaid on the image (Hitachi; each glyph outlined in
   black, 1 px). The ground truth stays that of the whole window.

Image axes: column j grows with x, row i grows downwards (y decreases), so angles measured on
the image counter-clockwise from +x (y up) equal the mat's angles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from PIL import Image, ImageDraw, ImageFont
from scipy import ndimage
from scipy.spatial import cKDTree

from espin.core.errors import ConfigError
from espin.geometry.mat import FiberMat
from espin.geometry.statistics import VisibleFibers, window_tortuosity

__all__ = ["SyntheticSEM", "render_sem"]

_EDGE_BRIGHTENING = 0.15
_MAX_PAIRS = 4_000_000  # (segment, pixel) pairs evaluated at once while rasterizing
_DATA_BAR_KINDS = ("band", "overlaid")
_DATA_BAR_TEXT = "SE 15.0kV x2.00k 30.0um"
_N_TICKS = 11


@dataclass(frozen=True, eq=False)
class SyntheticSEM:
    """A rendered SEM-like image and its ground truth.

    Attributes
    ----------
    image : (rows, cols) float64
        Grey levels in [0, 1]; row 0 is the top of the window (largest y).
    um_per_px : float [um / px]
        Pixel size.
    origin : (2,) float64 [um]
        Lower-left corner of the imaged window in mat coordinates.
    side : float [um]
        Side of the square window.
    layers : (n_layers,) int64
        The layers drawn, top first.
    fiber : (n_fibers,) int64
        Mat indices of the drawn fibers that have a visible portion.
    diameter_um : (n_fibers,) float64 [um]
        True diameter of each of those fibers.
    visible : VisibleFibers
        Fiber portions of the drawn layers inside the window (``visible.fiber`` are mat
        indices): contour length, chord, tortuosity and orientation (rad) of each.
    label : (rows, cols) int64
        Mat index of the fiber seen at each pixel: the fiber of the highest drawn layer whose
        body covers at least half the pixel (the nearest one where fibers of that layer
        overlap); -1 where no drawn fiber does (the background). The data bar does not
        change it.
    fiber_layer : (n_mat_fibers,) int64
        Layer of every fiber of the mat (:attr:`espin.geometry.mat.FiberMat.fiber_layer`).
    data_bar_rows : tuple[int, int] or None
        Rows (start, stop) of the drawn data bar, None without one.
    """

    image: np.ndarray
    um_per_px: float
    origin: np.ndarray
    side: float
    layers: np.ndarray
    fiber: np.ndarray
    diameter_um: np.ndarray
    visible: VisibleFibers
    label: np.ndarray
    fiber_layer: np.ndarray
    data_bar_rows: tuple[int, int] | None = None

    def depth(self, fiber: np.ndarray) -> np.ndarray:
        """Depth of mat fibers below the top drawn layer (0 = top, 1 = the next, ...; -1 for a
        fiber of no drawn layer, or a negative index such as the background's label).

        Parameters
        ----------
        fiber : (n,) int
            Mat fiber indices.

        Returns
        -------
        (n,) int64
        """
        fiber = np.asarray(fiber, dtype=np.int64)
        layer = self.fiber_layer[np.clip(fiber, 0, None)]
        depth = self.layers[0] - layer
        return np.where((fiber >= 0) & (depth < len(self.layers)), depth, -1)

    def followed(self, paths: list[np.ndarray], junctions: np.ndarray, away_px: float) -> np.ndarray:
        """The mat fiber each traced centre line follows: the most frequent ``label`` at its
        points at least ``away_px`` from every junction (at all its points if none is).

        Parameters
        ----------
        paths : list of (n_i, 2) float64 [px]
            Centre lines (row, col) on this image.
        junctions : (m, 2) float64 [px]
            Junction centres (row, col): near them the label is the crossing fiber's.
        away_px : float [px]
            Points closer than this to a junction are left out (e.g. a fiber width).

        Returns
        -------
        (n,) int64
            Mat fiber indices (-1: the background, a path off every fiber); their
            :meth:`depth` is the truth of a visibility classification.
        """
        tree = cKDTree(junctions) if len(junctions) else None
        out = np.full(len(paths), -1, dtype=np.int64)
        for i, path in enumerate(paths):
            if len(path) == 0:
                continue
            far = path if tree is None else path[tree.query(path)[0] >= away_px]
            pixel = np.clip(np.round(far if len(far) else path).astype(np.int64), 0, np.array(self.label.shape) - 1)
            values, counts = np.unique(self.label[pixel[:, 0], pixel[:, 1]], return_counts=True)
            out[i] = values[np.argmax(counts)]
        return out


def render_sem(
    mat: FiberMat,
    *,
    um_per_px: float | None = None,
    origin: ArrayLike | None = None,
    side_um: float | None = None,
    layers: int = 3,
    noise_sd: float = 0.05,
    blur_px: float = 1.0,
    depth_blur_px: float = 1.0,
    depth_dimming: float = 0.35,
    illumination: float = 0.3,
    background: float = 0.08,
    min_chord_um: float | None = None,
    seed: int = 0,
    data_bar: str | None = None,
    data_bar_side: str = "bottom",
    data_bar_fraction: float = 0.07,
) -> SyntheticSEM:
    """Render the top layers of a mat as an SEM-like grey image, with its ground truth.

    Parameters
    ----------
    mat : FiberMat
        The virtual mat.
    um_per_px : float [um / px], optional
        Pixel size; default an eighth of the mean fiber diameter (8 px across a fiber).
        Adjusted slightly so the window holds a whole number of pixels.
    origin : (2,) array [um], optional
        Lower-left corner of the square window; default: the window is centred in the mat.
    side_um : float [um], optional
        Side of the window; default the whole mat side.
    layers : int
        Number of top layers drawn, >= 1 (at most the mat's layers).
    noise_sd : float
        Standard deviation of the additive Gaussian noise (top-fiber brightness 1), >= 0.
    blur_px : float [px]
        Gaussian blur of the top layer (the beam spot), >= 0.
    depth_blur_px : float [px]
        Extra blur per layer of depth (focus), >= 0.
    depth_dimming : float
        Brightness lost per layer of depth, in [0, 1).
    illumination : float
        Relative brightness lost from the upper-left to the lower-right corner, in [0, 1).
    background : float
        Grey level between the fibers, in [0, 1).
    min_chord_um : float [um], optional
        Shortest chord of a visible portion in the ground truth; default three mean diameters
        (what :func:`espin.imaging.measurement.measure` keeps by default).
    seed : int
        Seed of the noise.
    data_bar : {"band", "overlaid"}, optional
        Draw a microscope's data bar: a separate black band, or text overlaid on the image.
    data_bar_side : {"bottom", "top"}
        Where the data bar is.
    data_bar_fraction : float
        Height of the data bar over the image's, in [0.02, 0.25] (at least 12 rows).

    Returns
    -------
    SyntheticSEM
        The image (float64 in [0, 1]) and its ground truth.
    """
    diameter = float(np.mean(mat.fiber_diameter))
    side = float(mat.size) if side_um is None else float(side_um)
    if origin is None:
        origin = np.full(2, (float(mat.size) - side) / 2.0)
    origin = np.asarray(origin, dtype=float).reshape(2)
    pixel = diameter / 8.0 if um_per_px is None else float(um_per_px)
    _check_options(
        side, pixel, layers, noise_sd, blur_px, depth_blur_px, depth_dimming, illumination, background, mat.n_layers
    )
    _check_data_bar(data_bar, data_bar_side, data_bar_fraction)
    n_px = max(int(round(side / pixel)), 1)
    pixel = side / n_px
    drawn = np.arange(mat.n_layers - 1, mat.n_layers - 1 - layers, -1)

    canvas = np.full((n_px, n_px), float(background))
    label = np.full((n_px, n_px), -1, dtype=np.int64)
    for depth in range(layers - 1, -1, -1):
        cover, shade, seen = _rasterize_layer(mat, int(drawn[depth]), origin, side, pixel, n_px)
        label = np.where(seen >= 0, seen, label)
        sigma = blur_px + depth * depth_blur_px
        brightness = (1.0 - depth_dimming) ** depth
        alpha = ndimage.gaussian_filter(cover, sigma) if sigma > 0 else cover
        light = cover * shade * brightness
        light = ndimage.gaussian_filter(light, sigma) if sigma > 0 else light
        canvas = canvas * (1.0 - alpha) + light

    ramp = (np.arange(n_px)[:, None] + np.arange(n_px)[None, :]) / max(2 * (n_px - 1), 1)
    canvas *= 1.0 - illumination * ramp
    rng = np.random.default_rng(seed)
    canvas += rng.normal(0.0, noise_sd, canvas.shape) if noise_sd > 0 else 0.0
    image = np.clip(canvas, 0.0, 1.0)
    bar_rows = None
    if data_bar is not None:
        bar_rows = _draw_data_bar(image, data_bar, data_bar_side, data_bar_fraction)

    visible, fiber, diam = _ground_truth(
        mat, drawn, origin, side, 3.0 * diameter if min_chord_um is None else min_chord_um
    )
    return SyntheticSEM(
        image=image,
        um_per_px=pixel,
        origin=origin,
        side=side,
        layers=drawn,
        fiber=fiber,
        diameter_um=diam,
        visible=visible,
        data_bar_rows=bar_rows,
        label=label,
        fiber_layer=np.asarray(mat.fiber_layer, dtype=np.int64),
    )


def _check_options(
    side: float,
    pixel: float,
    layers: int,
    noise_sd: float,
    blur_px: float,
    depth_blur_px: float,
    depth_dimming: float,
    illumination: float,
    background: float,
    n_layers: int,
) -> None:
    checks = [
        ("side_um", side > 0, "> 0"),
        ("um_per_px", 0 < pixel <= side, f"in (0, side_um = {side:g}]"),
        ("layers", 1 <= layers <= n_layers, f"in [1, {n_layers}] (the mat's layers)"),
        ("noise_sd", noise_sd >= 0, ">= 0"),
        ("blur_px", blur_px >= 0, ">= 0"),
        ("depth_blur_px", depth_blur_px >= 0, ">= 0"),
        ("depth_dimming", 0 <= depth_dimming < 1, "in [0, 1)"),
        ("illumination", 0 <= illumination < 1, "in [0, 1)"),
        ("background", 0 <= background < 1, "in [0, 1)"),
    ]
    for name, ok, allowed in checks:
        if not ok:
            raise ConfigError(f"render_sem: {name} must be {allowed}")


def _check_data_bar(kind: str | None, side: str, fraction: float) -> None:
    if kind is not None and kind not in _DATA_BAR_KINDS:
        raise ConfigError(f"render_sem: data_bar must be one of {_DATA_BAR_KINDS} or None, got {kind!r}")
    if side not in ("bottom", "top"):
        raise ConfigError(f"render_sem: data_bar_side must be 'bottom' or 'top', got {side!r}")
    if not 0.02 <= fraction <= 0.25:
        raise ConfigError(f"render_sem: data_bar_fraction must be in [0.02, 0.25], got {fraction!r}")


def _draw_data_bar(image: np.ndarray, kind: str, side: str, fraction: float) -> tuple[int, int]:
    """Draw a data bar into ``image`` (in place) and return its rows (start, stop)."""
    n_rows, n_cols = image.shape
    height = min(max(int(round(fraction * n_rows)), 12), n_rows)
    start = n_rows - height if side == "bottom" else 0
    ink = _data_bar_ink(height, n_cols, side)
    band = image[start : start + height]
    if kind == "band":
        band[:] = 0.0
    else:
        band[ndimage.binary_dilation(ink, np.ones((3, 3), dtype=bool))] = 0.0
    band[ink] = 1.0
    return start, start + height


def _data_bar_ink(height: int, n_cols: int, side: str) -> np.ndarray:
    """The white pixels (height, n_cols) of a data bar: a line of tick marks ``tick`` rows high,
    ``tick`` rows from the bar's edge towards the image, and a line of text beyond it."""
    ink = np.zeros((height, n_cols), dtype=bool)
    tick = max(5, int(round(0.22 * height)))
    tick_width = max(1, tick // 4)
    spacing = max(int(0.4 * n_cols / (_N_TICKS - 1)), tick_width + 3)
    ticks = slice(tick, 2 * tick) if side == "bottom" else slice(height - 2 * tick, height - tick)
    for k in range(_N_TICKS):
        left = int(0.55 * n_cols) + k * spacing
        ink[ticks, left : left + tick_width] = True
    gap = max(1, tick // 2)
    text = _text_ink(height - 1 - 2 * tick - gap, n_cols // 2)
    text_top = 2 * tick + gap if side == "bottom" else 1
    ink[text_top : text_top + text.shape[0], 2 : 2 + text.shape[1]] = text
    return ink


def _text_ink(rows: int, cols: int) -> np.ndarray:
    """:data:`_DATA_BAR_TEXT` in Pillow's default font, at most ``rows`` x ``cols`` px, as
    a boolean array cropped to its ink rows."""
    size = max(int(rows / 0.8), 6)
    font = ImageFont.load_default(size=size)
    canvas = Image.new("L", (cols, 2 * size), 0)
    ImageDraw.Draw(canvas).text((0, 0), _DATA_BAR_TEXT, fill=255, font=font)
    ink = np.asarray(canvas) >= 128
    used = np.flatnonzero(ink.any(axis=1))
    return ink[used[0] : used[0] + min(rows, used[-1] + 1 - used[0])] if len(used) else ink[:0]


def _rasterize_layer(
    mat: FiberMat, layer: int, origin: np.ndarray, side: float, pixel: float, n_px: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coverage (0-1, anti-aliased), profile shade and fiber label (mat index of the nearest
    fiber where it covers at least half the pixel, else -1) of one layer's fibers on the
    pixel grid.

    Every (segment, nearby pixel) pair is evaluated at once, in chunks: the signed distance
    from the pixel centre to the fiber surface, d - D_f / 2, is reduced by minimum per pixel.
    """
    chosen = np.flatnonzero(mat.fiber_layer[mat.segment_fiber] == layer)
    seg = mat.segment_start[chosen]
    # Segment ends in pixels: column (x - x0) / pixel - 1/2, row (y_top - y) / pixel - 1/2.
    top = origin[1] + side

    def to_px(p: np.ndarray) -> np.ndarray:
        return np.column_stack([(p[:, 0] - origin[0]) / pixel - 0.5, (top - p[:, 1]) / pixel - 0.5])

    a, b = to_px(mat.vertices[seg]), to_px(mat.vertices[seg + 1])
    radius = mat.fiber_diameter[mat.segment_fiber[chosen]] / (2.0 * pixel)
    reach = radius + 1.0
    lo = np.floor(np.minimum(a, b) - reach[:, None]).astype(np.int64).clip(0, n_px - 1)
    hi = np.ceil(np.maximum(a, b) + reach[:, None]).astype(np.int64).clip(0, n_px - 1)
    inside = np.all(np.maximum(a, b) + reach[:, None] >= 0, axis=1) & np.all(
        np.minimum(a, b) - reach[:, None] <= n_px - 1, axis=1
    )
    a, b, radius, lo, hi = a[inside], b[inside], radius[inside], lo[inside], hi[inside]
    extent = hi - lo + 1
    count = extent[:, 0] * extent[:, 1]

    surface = np.full(n_px * n_px, np.inf)
    relative = np.full(n_px * n_px, np.inf)
    nearest = np.full(n_px * n_px, -1, dtype=np.int64)
    owner = mat.segment_fiber[chosen][inside]
    ends = np.cumsum(count)
    start = 0
    while start < len(count):
        stop = max(int(np.searchsorted(ends, ends[start] - count[start] + _MAX_PAIRS, "right")), start + 1)
        s = np.arange(start, stop)
        pair = np.repeat(s, count[s])
        k = np.arange(len(pair)) - np.repeat(ends[s] - count[s] - (ends[start] - count[start]), count[s])
        col = lo[pair, 0] + k % extent[pair, 0]
        row = lo[pair, 1] + k // extent[pair, 0]
        d = _point_segment_distance(np.column_stack([col, row]), a[pair], b[pair])
        flat = row * n_px + col
        gap = d - radius[pair]
        # the fiber nearest to each pixel of this chunk, kept where it beats the earlier chunks'
        order = np.lexsort((gap, flat))
        first = order[np.r_[True, flat[order][1:] != flat[order][:-1]]]
        better = gap[first] < surface[flat[first]]
        nearest[flat[first][better]] = owner[pair[first][better]]
        np.minimum.at(surface, flat, gap)
        np.minimum.at(relative, flat, d / radius[pair])
        start = stop
    cover = np.clip(0.5 - surface, 0.0, 1.0).reshape(n_px, n_px)
    rho = np.minimum(relative, 1.0).reshape(n_px, n_px)
    label = np.where(cover >= 0.5, nearest.reshape(n_px, n_px), -1)
    return cover, 1.0 + _EDGE_BRIGHTENING * rho**4, label


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points p to segments a-b, row by row (all (n, 2))."""
    ab = b - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    t = np.einsum("ij,ij->i", p - a, ab) / np.where(length2 > 0, length2, 1.0)
    foot = a + np.clip(t, 0.0, 1.0)[:, None] * ab
    return np.hypot(*(p - foot).T)


def _ground_truth(
    mat: FiberMat, drawn: np.ndarray, origin: np.ndarray, side: float, min_chord: float
) -> tuple[VisibleFibers, np.ndarray, np.ndarray]:
    """Visible portions of the drawn layers' fibers and the true diameter of those fibers."""
    chosen = np.flatnonzero(np.isin(mat.fiber_layer, drawn))
    counts = np.diff(mat.fiber_offsets)
    vertex_fiber = np.repeat(np.arange(mat.n_fibers), counts)
    offsets = np.concatenate([[0], np.cumsum(counts[chosen])]).astype(np.int64)
    vertices = mat.vertices[np.isin(vertex_fiber, chosen)]
    portions = window_tortuosity(vertices, offsets, origin, side, min_chord)
    visible = VisibleFibers(**{**portions.__dict__, "fiber": chosen[portions.fiber]})
    fiber = np.unique(visible.fiber)
    return visible, fiber, np.asarray(mat.fiber_diameter, dtype=float)[fiber]
