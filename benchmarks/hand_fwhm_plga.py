"""Hand FWHM check of fiber diameters on the real SEM image PLGA-1500_1.

Independent of espin (espin is not imported): the positions and fiber axes in
``benchmarks/data/plga_hand_fwhm.csv`` were chosen by eye on fully visible top fibers
(see docs/sem_hand_check.md). For each position this script takes an intensity profile
across the fiber, perpendicular to the recorded axis, and measures the full width at
half maximum by the rule written in that page:

* profile: bilinear samples (``scipy.ndimage.map_coordinates``, order 1) every 0.25 px
  over +-60 px, mean of 7 parallel profiles 1 px apart along the axis, then a light
  Gaussian smoothing (sigma 1 px);
* plateau: median of the central half of the fiber (between the two edges); the bright
  edge of the SE image is therefore not taken as the fiber level;
* local background on each side: minimum of the profile within 15 px outside that edge;
* half-way level on each side = (plateau + that side's background) / 2; the edge is the
  first crossing of that level walking outwards from the fiber centre (linear
  interpolation); width = distance between the two crossings. The edges start at the
  steepest rise/fall within 45 px of the recorded centre and the rule is iterated 5 times.

Run: ``python benchmarks/hand_fwhm_plga.py [path/to/PLGA-1500_1.tif]``. Prints each width,
the CSV value, and mean, SD, standard error and n (all positions, and without the
positions whose note says "dimmer").
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

PIXEL_UM = 0.06592  # um per pixel
DATA_BAR_ROW = 880  # rows 880 and below are the microscope's data bar
HALF_LEN = 60.0  # px, half length of the profile
STEP = 0.25  # px between samples along the profile
N_PAR = 7  # parallel profiles, 1 px apart along the fiber axis
SMOOTH = 1.0  # px, sigma of the light Gaussian smoothing
BG_WIN = 15.0  # px searched outside each edge for the local background
EDGE_WIN = 45.0  # px searched either side of the centre for the first edge guess

HERE = Path(__file__).parent
CSV = HERE / "data" / "plga_hand_fwhm.csv"
IMAGE = Path(__file__).parents[2] / "shared" / "data" / "sem" / "PLGA-1500_1.tif"


def load(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("L"), dtype=float)[:DATA_BAR_ROW]


def profile(img: np.ndarray, row: float, col: float, axis_deg: float):
    """Mean profile across the fiber. axis_deg: angle of the fiber axis from the +col
    direction towards +row (image x to the right, y down)."""
    a = np.deg2rad(axis_deg)
    ax = np.array([np.sin(a), np.cos(a)])  # (drow, dcol) along the fiber
    nx = np.array([ax[1], -ax[0]])  # (drow, dcol) across the fiber
    t = np.arange(-HALF_LEN, HALF_LEN + STEP / 2, STEP)
    offs = np.arange(N_PAR) - (N_PAR - 1) / 2
    rows = row + offs[:, None] * ax[0] + t[None, :] * nx[0]
    cols = col + offs[:, None] * ax[1] + t[None, :] * nx[1]
    vals = ndimage.map_coordinates(img, [rows.ravel(), cols.ravel()], order=1, mode="nearest")
    return t, vals.reshape(rows.shape).mean(axis=0)


def crossing(t, p, i0, level, direction):
    """First crossing of ``level`` walking from index i0 in ``direction`` (-1 or +1)."""
    i = i0
    while 0 <= i + direction < len(p):
        j = i + direction
        if p[j] < level <= p[i]:
            return t[i] + (level - p[i]) * (t[j] - t[i]) / (p[j] - p[i])
        i = j
    return np.nan


def fwhm(img: np.ndarray, row: float, col: float, axis_deg: float) -> float:
    """Width (px) between the two half-way crossings of the profile at (row, col)."""
    t, raw = profile(img, row, col, axis_deg)
    p = ndimage.gaussian_filter1d(raw, SMOOTH / STEP)
    d = np.gradient(p)
    left = (t >= -EDGE_WIN) & (t <= -2)
    right = (t >= 2) & (t <= EDGE_WIN)
    lo = t[left][np.argmax(d[left])]
    hi = t[right][np.argmin(d[right])]
    for _ in range(5):
        if not np.isfinite(lo + hi):
            return np.nan
        w = hi - lo
        plateau = np.median(p[(t > lo + 0.25 * w) & (t < hi - 0.25 * w)])
        bg_lo = p[(t >= lo - BG_WIN) & (t <= lo)].min()
        bg_hi = p[(t >= hi) & (t <= hi + BG_WIN)].min()
        mid = int(np.argmin(np.abs(t - 0.5 * (lo + hi))))
        lo = crossing(t, p, mid, 0.5 * (plateau + bg_lo), -1)
        hi = crossing(t, p, mid, 0.5 * (plateau + bg_hi), +1)
    return hi - lo


def summary(label: str, w_um: np.ndarray) -> None:
    n = len(w_um)
    sd = w_um.std(ddof=1)
    print(f"{label}: n = {n}, mean = {w_um.mean():.3f} um, SD = {sd:.3f} um, "
          f"SE = {sd / np.sqrt(n):.3f} um, range {w_um.min():.3f}-{w_um.max():.3f} um")


def main() -> None:
    img = load(Path(sys.argv[1]) if len(sys.argv) > 1 else IMAGE)
    with open(CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    widths, dim = [], []
    print(f"{'id':>4} {'row':>6} {'col':>7} {'axis':>6} {'width px':>9} {'width um':>9} {'csv um':>7}")
    for r in rows:
        w = fwhm(img, float(r["row"]), float(r["col"]), float(r["axis_deg"]))
        widths.append(w)
        dim.append("dimmer" in r["note"])
        print(f"{r['id']:>4} {float(r['row']):6.1f} {float(r['col']):7.1f} {float(r['axis_deg']):6.1f} "
              f"{w:9.2f} {w * PIXEL_UM:9.3f} {float(r['width_um']):7.3f}")
    w_um = np.array(widths) * PIXEL_UM
    dim = np.array(dim)
    summary("all positions", w_um)
    summary("without the dimmer fibers", w_um[~dim])


if __name__ == "__main__":
    main()
