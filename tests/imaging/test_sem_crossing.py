"""espin measure: the long-range shape of traced fibers, the edges their ends lie on, the
U-turn fraction and straightness of those traced edge to edge, against the ground truth of
rendered virtual mats, and how they travel through fibers.csv, measurement.toml and
GeometryTargets."""

from __future__ import annotations

import dataclasses
import math
import tomllib

import numpy as np
import pytest

import espin.geometry.rve
from espin.core.errors import SEMError
from espin.core.parallel import TaskPool
from espin.geometry.fibers_csv import EDGE_COLUMNS, read_fibers_csv
from espin.geometry.pieces import window_crossings, window_runs
from espin.geometry.targets import GeometryTargets, MeasurementError
from espin.imaging.measurement import _edge_crossings, measure
from espin.imaging.synthetic import render_sem

D = 0.45  # um, plla diameter


def _line(start: tuple[float, float], stop: tuple[float, float]) -> np.ndarray:
    """Points (row, col) every pixel from start to stop."""
    n = int(np.ceil(math.dist(start, stop))) + 1
    return np.linspace(start, stop, n)


def _contour(path: np.ndarray) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def test_edges_of_traced_ends_and_their_crossing_statistics():
    shape, w = (100, 200), 10.0  # rows, cols; fiber width [px]
    across = _line((50.0, 0.0), (50.0, 199.0))  # left -> right
    u_turn = np.concatenate([_line((0.0, 20.0), (40.0, 40.0)), _line((40.0, 40.0), (0.0, 60.0))[1:]])
    pulled_back = _line((80.0, 0.0), (80.0, 184.0))  # its right end 1.5 w short of the edge
    along_top = _line((7.0, 80.0), (7.0, 150.0))  # 0.7 w below the top edge, heading along it
    near_bottom = _line((98.0, 150.0), (60.0, 199.0))  # 1 px above the bottom, heading away
    paths = [across, u_turn, pulled_back, along_top, near_bottom]
    contour = np.array([_contour(p) for p in paths])
    edges, stats = _edge_crossings(paths, contour, shape, w)
    bottom, right, top, left, inside = 0, 1, 2, 3, -1
    assert edges.tolist() == [[left, right], [top, top], [left, right], [inside, inside],
                              [bottom, right]]
    assert stats.n_crossing == 4
    assert stats.u_turn_fraction == pytest.approx(1 / 4)
    # The pulled-back fiber is continued straight to the edge: still straight.
    assert stats.straightness == pytest.approx((1.0 + 40.0 / contour[1] + 1.0 + 1.0) / 4)


def _mat(seed: int, size_ratio: float, **overrides):
    return espin.geometry.rve.generate("plla", rve__size_ratio=size_ratio, rve__layers=4,
                                       rve__seed=seed, **overrides).mat


def _true_crossings(mat, image):
    """window_crossings of the drawn layers' fibers in the rendered window, with the chord
    filter of the measurement (3 D)."""
    chosen = np.flatnonzero(np.isin(mat.fiber_layer, image.layers))
    counts = np.diff(mat.fiber_offsets)
    vertex_fiber = np.repeat(np.arange(mat.n_fibers), counts)
    offsets = np.concatenate([[0], np.cumsum(counts[chosen])]).astype(np.int64)
    runs = window_runs(mat.vertices[np.isin(vertex_fiber, chosen)], offsets, image.origin,
                       image.side)
    return window_crossings(runs, image.origin, image.side, min_chord_um=3 * D)


def _pooled(stats) -> tuple[int, int, float]:
    """Crossings, U-turns and straightness pooled over images (weighted by crossings)."""
    n = sum(s.n_crossing for s in stats)
    u_turns = sum(round(s.n_crossing * s.u_turn_fraction) for s in stats if s.n_crossing)
    straightness = sum(s.n_crossing * s.straightness for s in stats if s.n_crossing) / n
    return n, u_turns, straightness


@pytest.fixture(scope="module")
def straight():
    """Straight fibers (lines seeding) crossing at all angles: 60 D windows, 8 px per D."""
    out = []
    for seed in (1, 2, 3):
        mat = _mat(seed, 100, rve__max_deviation_deg=0.0, rve__seeding="lines")
        image = render_sem(mat, side_um=60 * D, seed=seed)
        out.append((image, measure(image.image, um_per_px=image.um_per_px)))
    return out


@pytest.mark.slow
def test_straight_fibers_make_no_u_turns(straight):
    for _, m in straight:
        f = m.fibers
        both = (f["start_edge"] != "") & (f["end_edge"] != "")
        assert m.n_crossing == int(both.sum()) >= 5
        assert m.u_turn_fraction == 0.0
    n, _, straightness = _pooled([m for _, m in straight])
    assert n >= 25
    # Not above 0.99: jogs onto another fiber at crossings (bends up to --max-bend-deg) cost
    # long traces several per cent; 12 such images pool to 0.977 (docs/sem.md).
    assert straightness > 0.97


def _curling_window(seed: int):
    """espin measure of a rendered 100 D window of a mat with 40 deg turns, and the window's
    true crossings (module level: the test runs its seeds on worker processes)."""
    mat = _mat(seed, 110, rve__max_deviation_deg=40.0)
    image = render_sem(mat, side_um=100 * D, seed=seed)
    return measure(image.image, um_per_px=image.um_per_px), _true_crossings(mat, image)


@pytest.mark.slow
def test_curling_fibers_u_turn_as_often_as_the_truth():
    """Paper walk of 40 deg turns per segment (persistence about 60 D) in 100 D windows: a
    fifth of the true portions crossing edge to edge leave through the edge they entered."""
    with TaskPool(workers=2) as pool:  # five independent images: on both cores
        outcomes = sorted(pool.map(_curling_window, range(1, 6)), key=lambda outcome: outcome.index)
    assert all(outcome.ok for outcome in outcomes), [outcome.traceback for outcome in outcomes]
    measured, truth = [outcome.value[0] for outcome in outcomes], [outcome.value[1] for outcome in outcomes]
    n, u_turns, straightness = _pooled(measured)
    n_true, u_true, _ = _pooled(truth)
    p = u_true / n_true
    assert n >= 25 and n_true >= 400
    # The traced crossings are a subsample of n of the n_true true ones; were they drawn at
    # random, their U-turn fraction would scatter about p with this sd (binomial, finite
    # population): allow 3 of it. About 0.07 for 30 of 450 at p = 0.2.
    sd = math.sqrt(p * (1 - p) * (1 / n - 1 / n_true))
    assert u_turns / n == pytest.approx(p, abs=3 * sd)
    assert u_turns / n > 2 * sd  # clearly above 0, which straight fibers read
    # Curled: below the straight fibers (above the truth: the curliest fibers are broken
    # by the tracer more often, docs/sem.md).
    assert straightness < 0.95


@pytest.mark.slow
def test_edges_travel_through_fibers_csv_and_measurement_toml(straight, tmp_path):
    _, m = straight[0]
    files = m.write(tmp_path / "out")
    table = read_fibers_csv(files["fibers"])
    for column in EDGE_COLUMNS:
        assert table[column].tolist() == m.fibers[column].tolist()
    assert set(table["start_edge"]) <= {"", "bottom", "right", "top", "left"}
    crossing = tomllib.loads(files["summary"].read_text())["crossing"]
    assert crossing["n_crossing"] == m.n_crossing
    assert crossing["u_turn_fraction"] == m.u_turn_fraction
    assert crossing["straightness"] == pytest.approx(m.straightness)
    assert ("edge to edge", f"{m.n_crossing} fibers traced across the image; U-turn fraction "
            f"0.000, straightness {m.straightness:.4f}") in m.table_rows()
    none = dataclasses.replace(m, n_crossing=0, u_turn_fraction=math.nan, straightness=math.nan)
    assert ("edge to edge", "no fiber traced across the image") in none.table_rows()


def test_bad_edge_name_in_fibers_csv(tmp_path):
    path = tmp_path / "fibers.csv"
    path.write_text("tortuosity,start_edge,end_edge\n1.1,top,\n1.2,left,north\n")
    with pytest.raises(SEMError, match="column end_edge, data row 2: 'north' is not an edge"):
        read_fibers_csv(path)


def _measure_folder(m, folder, crossing: str | None = None):
    """``m`` written to ``folder``, its ``[crossing]`` table replaced by ``crossing`` (TOML
    lines) or, with None, left out (a file written before espin measure reported it)."""
    files = m.write(folder)
    toml = files["summary"].read_text()
    files["summary"].write_text(toml[:toml.index("[crossing]")]
                                + ("" if crossing is None else f"[crossing]\n{crossing}\n"))
    return files


@pytest.mark.slow
def test_geometry_targets_read_the_crossing_statistics(straight, tmp_path):
    _, m = straight[0]
    files = m.write(tmp_path / "out")
    for targets in (GeometryTargets.from_folder(tmp_path / "out"),
                    GeometryTargets.from_measurement(m)):
        assert targets.n_crossing == m.n_crossing
        assert targets.u_turn_fraction == m.u_turn_fraction
        assert targets.straightness == pytest.approx(m.straightness)
    # A table on its own, or a measurement.toml without [crossing], has none.
    assert GeometryTargets.from_csv(files["fibers"]).u_turn_fraction is None
    _measure_folder(m, tmp_path / "old", None)
    old = GeometryTargets.from_folder(tmp_path / "old")
    assert (old.n_crossing, old.u_turn_fraction, old.straightness) == (None, None, None)


@pytest.mark.slow
def test_no_crossing_fiber_gives_none(straight, tmp_path):
    _, m = straight[0]
    _measure_folder(m, tmp_path / "out", "n_crossing = 0\nu_turn_fraction = nan\nstraightness = nan")
    targets = GeometryTargets.from_folder(tmp_path / "out")
    assert (targets.n_crossing, targets.u_turn_fraction, targets.straightness) == (0, None, None)


@pytest.mark.parametrize("line, match", [
    ("u_turn_fraction = 1.5", "u_turn_fraction must be in \\[0, 1\\], got 1.5"),
    ("straightness = 0.0", "straightness must be in \\(0, 1\\], got 0.0"),
    ("n_crossing = -1", "n_crossing must be an integer >= 0"),
    ("n_crossing = 'many'", "n_crossing must be a number"),
])
@pytest.mark.slow
def test_bad_crossing_values_name_the_file(straight, tmp_path, line, match):
    _, m = straight[0]
    _measure_folder(m, tmp_path / "out", line)
    with pytest.raises(MeasurementError, match=f"measurement.toml: {match}"):
        GeometryTargets.from_folder(tmp_path / "out")
