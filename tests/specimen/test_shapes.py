"""Specimen meshes: exact areas, positive elements, grips and edges, refinement, bad input, meshio round trips."""

from __future__ import annotations

import math

import meshio
import numpy as np
import pytest
import skfem
from scipy.integrate import quad

from espin.core.errors import ConfigError
from espin.specimen.shapes import (SHAPES, Specimen, dogbone, dogbone_half_width, holed_strip, notched_strip,
                                   read_specimen, strip)


def element_areas(mesh: skfem.Mesh) -> np.ndarray:
    """Signed area of every element (shoelace; exact for bilinear quads), mm^2."""
    x = mesh.p[:, mesh.t]
    return 0.5 * np.sum(x[0] * np.roll(x[1], -1, axis=0) - np.roll(x[0], -1, axis=0) * x[1], axis=0)


def facet_x(mesh: skfem.Mesh, facets: np.ndarray) -> np.ndarray:
    return mesh.p[0, mesh.facets[:, facets]]


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize("n", [1, 2, 4, 8])
def test_mesh_is_valid_with_grips_and_edge(name, n):
    specimen = SHAPES[name](elements_across=n)
    mesh = specimen.mesh
    assert isinstance(mesh, skfem.MeshQuad) and specimen.name == name
    assert np.all(element_areas(mesh) > 0)
    half = specimen.grip_length_mm / 2
    assert mesh.p[0].min() == pytest.approx(-half, abs=1e-12) and mesh.p[0].max() == pytest.approx(half, abs=1e-12)
    assert mesh.p[1].min() == pytest.approx(-mesh.p[1].max(), abs=1e-12)  # centred on y = 0
    left, right, edge = (mesh.boundaries[k] for k in ("grip_left", "grip_right", "edge"))
    assert left.size and right.size and edge.size
    np.testing.assert_allclose(facet_x(mesh, left), -half, atol=1e-12)
    np.testing.assert_allclose(facet_x(mesh, right), half, atol=1e-12)
    # The grip faces are whole: their facets cover the full width at the ends.
    for facets in (left, right):
        y = mesh.p[1, mesh.facets[:, facets]]
        assert np.sum(np.abs(y[1] - y[0])) == pytest.approx(np.ptp(y), rel=1e-12)
    everything = np.concatenate([left, right, edge])
    assert np.array_equal(np.sort(everything), np.sort(mesh.boundary_facets()))
    assert len(np.unique(everything)) == everything.size
    assert not np.any(np.all(np.abs(np.abs(facet_x(mesh, edge)) - half) < 1e-12, axis=0))
    assert specimen.n_elements == mesh.nelements and name in repr(specimen)


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_refinement_increases_elements(name):
    counts = [SHAPES[name](elements_across=n).n_elements for n in (2, 4, 8)]
    assert counts[0] < counts[1] < counts[2]


def test_strip_area_gauge_and_element_size():
    specimen = strip(40.0, 8.0, elements_across=4)
    assert element_areas(specimen.mesh).sum() == pytest.approx(40.0 * 8.0, rel=1e-12)
    assert (specimen.grip_length_mm, specimen.gauge_length_mm, specimen.gauge_width_mm) == (40.0, 20.0, 8.0)
    assert specimen.mesh.boundaries["grip_left"].size == 4
    assert specimen.n_elements == 4 * 20  # square elements 2 x 2 mm
    sized = strip(40.0, 8.0, element_size_mm=1.0)
    assert sized.n_elements == 8 * 40 and sized.dimensions["element_size"] == 1.0


def test_holed_strip_area_converges_to_the_exact_area():
    exact = 50.0 * 10.0 - math.pi * 3.0**2 / 4
    errors = [element_areas(holed_strip(elements_across=n).mesh).sum() - exact for n in (2, 4, 8)]
    assert all(e > 0 for e in errors)  # the hole is a polygon inscribed in the circle
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-3 * exact
    specimen = holed_strip()
    assert (specimen.gauge_length_mm, specimen.gauge_width_mm) == (50.0, 10.0)
    r = np.hypot(*specimen.mesh.p)
    assert r.min() == pytest.approx(1.5, rel=1e-12)  # hole nodes on the circle, none inside it


def _iso_5a_half_width(x: float) -> float:
    """Independent profile: narrow part, arc r = 12.5 tangent to it, arc r = 8 tangent to the 12.5 mm end."""
    u = abs(x)
    c1 = np.array([12.5, 2.0 + 12.5])  # centre of the arc tangent to the narrow part
    c2x = 12.5 + math.sqrt(20.5**2 - (20.5 - 4.25) ** 2)
    c2 = np.array([c2x, 6.25 - 8.0])  # centre of the arc tangent to the wide end
    inflection = c1 + 12.5 / 20.5 * (c2 - c1)  # the arcs touch on the line of centres
    if u <= 12.5:
        return 2.0
    if u <= inflection[0]:
        return c1[1] - math.sqrt(12.5**2 - (u - c1[0]) ** 2)
    if u <= c2x:
        return c2[1] + math.sqrt(8.0**2 - (u - c2x) ** 2)
    return 6.25


def test_dogbone_profile_is_the_iso_527_2_5a_reading():
    x = np.linspace(-25.0, 25.0, 20001)
    h = dogbone_half_width(x)
    np.testing.assert_allclose(h, [_iso_5a_half_width(v) for v in x], atol=1e-12)
    assert h.min() == 2.0 and h.max() == pytest.approx(6.25, abs=1e-12)
    assert np.max(np.abs(np.diff(h))) < 0.8 * (x[1] - x[0])  # continuous: slopes are below tan(37.6 deg) = 0.77
    assert np.max(np.abs(np.diff(np.diff(h) / np.diff(x)))) < 5e-3  # tangent arcs: no kink (slopes reach 0.6)
    np.testing.assert_allclose(dogbone_half_width(x, scale=2.0), 2.0 * dogbone_half_width(x / 2.0), atol=1e-12)


def test_dogbone_area_and_nodes_follow_the_profile():
    breaks = [12.5, 12.5 + 12.5 / 20.5 * 12.497, 24.997]
    exact = 4 * quad(_iso_5a_half_width, 0.0, 25.0, points=breaks, epsabs=1e-12, limit=200)[0]
    errors = []
    for n in (2, 4, 8):
        specimen = dogbone(elements_across=n)
        errors.append(abs(element_areas(specimen.mesh).sum() - exact))
        x, y = specimen.mesh.p[:, np.unique(specimen.mesh.facets[:, specimen.mesh.boundaries["edge"]])]
        np.testing.assert_allclose(np.abs(y), [_iso_5a_half_width(v) for v in x], atol=1e-12)  # nodes on the profile
    assert errors[0] > errors[1] > errors[2] and errors[2] < 5e-3 * exact
    specimen = dogbone(scale=0.5)
    assert (specimen.grip_length_mm, specimen.gauge_length_mm, specimen.gauge_width_mm) == (25.0, 10.0, 2.0)
    assert specimen.dimensions["narrow_width"] == 2.0 and specimen.dimensions["overall_length"] == 37.5


def _u_notch_area(depth: float, radius: float) -> float:
    if depth >= radius:
        return 2 * radius * (depth - radius) + math.pi * radius**2 / 2
    return radius**2 * math.acos((radius - depth) / radius) - (radius - depth) * math.sqrt(2 * radius * depth
                                                                                           - depth**2)


@pytest.mark.parametrize("depth, radius", [(2.0, 1.0), (0.5, 1.0), (6.0, 0.5)])
def test_notched_strip_area_converges_to_the_exact_area(depth, radius):
    exact = 50.0 * 10.0 - _u_notch_area(depth, radius)
    errors = []
    for n in (2, 4, 8):
        mesh = notched_strip(notch_depth_mm=depth, notch_radius_mm=radius, elements_across=n).mesh
        errors.append(element_areas(mesh).sum() - exact)
        assert np.all(element_areas(mesh) > 0)
        assert mesh.p[1, np.abs(mesh.p[0]) < 1e-12].min() == -5.0
        assert mesh.p[1, np.abs(mesh.p[0]) < 1e-12].max() == pytest.approx(5.0 - depth, abs=1e-12)
    assert all(e > 0 for e in errors) and errors[0] > errors[1] > errors[2] and errors[2] < 1e-3 * exact


@pytest.mark.parametrize("build, kwargs, name", [
    (strip, {"length_mm": 0.0}, "length_mm"),
    (strip, {"width_mm": -1.0}, "width_mm"),
    (strip, {"element_size_mm": 0.0}, "element_size_mm"),
    (strip, {"elements_across": 0}, "elements_across"),
    (strip, {"elements_across": 2.5}, "elements_across"),
    (dogbone, {"scale": float("nan")}, "scale"),
    (dogbone, {"elements_across": True}, "elements_across"),
    (holed_strip, {"hole_diameter_mm": 10.0}, "hole_diameter_mm"),
    (holed_strip, {"hole_diameter_mm": 0.0}, "hole_diameter_mm"),
    (holed_strip, {"length_mm": 8.0}, "length_mm"),
    (notched_strip, {"notch_depth_mm": 10.0}, "notch_depth_mm"),
    (notched_strip, {"notch_radius_mm": 0.0}, "notch_radius_mm"),
    (notched_strip, {"elements_across": -3}, "elements_across"),
])
def test_bad_input_names_the_parameter(build, kwargs, name):
    with pytest.raises(ConfigError, match=name):
        build(**kwargs)


def _write(path, points, cells, **extra):
    meshio.write(path, meshio.Mesh(points, cells, **extra), **({"file_format": "gmsh22"} if path.suffix == ".msh"
                                                               else {}))


@pytest.mark.parametrize("suffix", [".vtu", ".msh"])
def test_read_specimen_round_trip_of_quads(tmp_path, suffix):
    generated = holed_strip(elements_across=4)
    path = tmp_path / f"holed{suffix}"
    points = np.column_stack([generated.mesh.p.T + [100.0, 3.0], np.zeros(generated.mesh.p.shape[1])])
    _write(path, points, [("quad", generated.mesh.t.T)])
    specimen = read_specimen(path, gauge_length_mm=20.0)
    assert isinstance(specimen, Specimen) and isinstance(specimen.mesh, skfem.MeshQuad)
    assert specimen.name == path.name and specimen.mesh.nvertices == generated.mesh.nvertices
    assert (specimen.grip_length_mm, specimen.gauge_length_mm, specimen.gauge_width_mm) == pytest.approx((50, 20, 10))
    assert specimen.x_centre == pytest.approx(100.0)
    for name in ("grip_left", "grip_right", "edge"):
        assert specimen.mesh.boundaries[name].size == generated.mesh.boundaries[name].size
    np.testing.assert_allclose(facet_x(specimen.mesh, specimen.mesh.boundaries["grip_right"]), 125.0)


def test_read_specimen_of_triangles(tmp_path):
    generated = strip(20.0, 5.0, elements_across=2)
    t = generated.mesh.t
    path = tmp_path / "triangles.vtu"
    _write(path, generated.mesh.p.T, [("triangle", np.hstack([t[[0, 1, 2]], t[[0, 2, 3]]]).T)])
    specimen = read_specimen(path)
    assert isinstance(specimen.mesh, skfem.MeshTri) and specimen.n_elements == 2 * generated.n_elements
    assert np.abs(element_areas(specimen.mesh)).sum() == pytest.approx(100.0)
    assert specimen.mesh.boundaries["grip_left"].size == 2 and specimen.mesh.boundaries["grip_right"].size == 2


def test_read_specimen_reorients_clockwise_quads(tmp_path):
    t = strip(20.0, 5.0, elements_across=2).mesh.t.copy()
    t[:, ::2] = t[::-1, ::2]  # every other quad clockwise
    path = tmp_path / "clockwise.vtu"
    _write(path, strip(20.0, 5.0, elements_across=2).mesh.p.T, [("quad", t.T)])
    areas = element_areas(read_specimen(path).mesh)
    assert np.all(areas > 0) and areas.sum() == pytest.approx(100.0)


def test_read_specimen_uses_named_grip_lines(tmp_path):
    generated = strip(20.0, 5.0, elements_across=2)
    p, t = generated.mesh.p, generated.mesh.t
    left = np.flatnonzero(p[0] == p[0].min())
    right = np.flatnonzero(p[0] == p[0].max())
    left = left[np.argsort(p[1, left])][:2]  # only the lower half of the left face is gripped
    right = right[np.argsort(p[1, right])]
    lines = np.vstack([left, np.column_stack([right[:-1], right[1:]])])
    tags = [np.full(len(t.T), 3), np.array([1, 2, 2])]
    path = tmp_path / "named.msh"
    _write(path, p.T, [("quad", t.T), ("line", lines)],
           cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
           field_data={"grip_left": np.array([1, 1]), "grip_right": np.array([2, 1]), "mat": np.array([3, 2])})
    mesh = read_specimen(path).mesh
    assert mesh.boundaries["grip_left"].size == 1 and mesh.boundaries["grip_right"].size == 2
    assert mesh.boundaries["edge"].size == len(mesh.boundary_facets()) - 3


def test_read_specimen_says_what_is_wrong(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        read_specimen(tmp_path / "missing.vtu")
    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    _write(tmp_path / "lines.vtu", square, [("line", np.array([[0, 1], [1, 2]]))])
    with pytest.raises(ConfigError, match="triangle' or 'quad"):
        read_specimen(tmp_path / "lines.vtu")
    diamond = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    _write(tmp_path / "diamond.vtu", diamond, [("quad", np.array([[0, 1, 2, 3]]))])
    with pytest.raises(ConfigError, match="no boundary facet at the smallest x"):
        read_specimen(tmp_path / "diamond.vtu")
    bent = square + [0.0, 0.0, 0.5] * np.arange(4)[:, None]
    _write(tmp_path / "bent.vtu", bent, [("quad", np.array([[0, 1, 2, 3]]))])
    with pytest.raises(ConfigError, match="not planar"):
        read_specimen(tmp_path / "bent.vtu")
    with pytest.raises(ConfigError, match="gauge_width_mm"):
        read_specimen(tmp_path / "diamond.vtu", gauge_width_mm=-1.0)
