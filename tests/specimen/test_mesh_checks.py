"""User meshes checked before any work: finite specimen coordinates, coincident nodes merged,
repeated cells, folds and pieces refused naming where, gauge marks on the specimen; a specimen's
memory estimated and refused beyond what is available."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

import espin
from espin.core.errors import ConfigError
from espin.specimen.mesh_checks import check_memory, specimen_memory
from espin.specimen.shapes import holed_strip, read_specimen, strip


def _write(path, p, cells, kind="quad"):
    meshio.write(path, meshio.Mesh(np.column_stack([p, np.zeros(len(p))]), [(kind, cells)]))
    return path


@pytest.fixture()
def plate():
    mesh = strip(20.0, 5.0, elements_across=2).mesh
    return mesh.p.T.copy(), mesh.t.T.copy()


@pytest.mark.parametrize("value, message", [(np.inf, "non-finite"), (np.nan, "non-finite"),
                                            (1e12, "beyond 10000 mm")])
def test_coordinates_that_are_not_a_specimen_are_refused(tmp_path, plate, value, message):
    p, t = plate
    p[3, 0] = value
    with pytest.raises(ConfigError, match=f"specimen mesh .*bad.vtu.*{message}"):
        read_specimen(_write(tmp_path / "bad.vtu", p, t))


def test_a_repeated_cell_is_refused(tmp_path, plate):
    p, t = plate
    with pytest.raises(ConfigError, match=r"1 cell\(s\) repeat another's nodes \(first: cell \d+ at"):
        read_specimen(_write(tmp_path / "twice.vtu", p, np.vstack([t, t[2:3, ::-1]])))


def test_a_fold_is_refused_not_flipped(tmp_path, plate):
    """A node pulled across its neighbours' edge inverts a cell: flipped, it would overlap them."""
    p, t = plate
    inner = np.flatnonzero((p[:, 0] > p[:, 0].min()) & (p[:, 0] < p[:, 0].max()) & (p[:, 1] > p[:, 1].min())
                           & (p[:, 1] < p[:, 1].max()))[0]
    p[inner, 0] += 8.0  # beyond the next column of nodes (5 mm apart)
    with pytest.raises(ConfigError, match="folds over itself|shared by 3 cells"):
        read_specimen(_write(tmp_path / "fold.vtu", p, t))


def test_coincident_interface_nodes_are_merged_and_said(tmp_path, plate):
    p, t = plate
    right = p[:, 0] >= p[:, 0].mean()
    # the right half's nodes written a second time: the two halves share no node in the file
    copy = np.flatnonzero(right)
    p2 = np.vstack([p, p[copy]])
    renumber = np.arange(len(p))
    renumber[copy] = len(p) + np.arange(len(copy))
    right_cells = np.all(right[t], axis=1)
    t2 = np.where(right_cells[:, None], renumber[t], t)
    specimen = read_specimen(_write(tmp_path / "halves.vtu", p2, t2))
    assert specimen.mesh.nvertices == len(p) and specimen.notes and "merged" in specimen.notes[0]
    assert np.count_nonzero(right_cells) and np.count_nonzero(~right_cells)


def test_a_mesh_in_two_pieces_is_refused_naming_them(tmp_path, plate):
    p, t = plate
    apart = np.vstack([p, p + [30.0, 0.0]])
    with pytest.raises(ConfigError, match=rf"in 2 pieces \({len(t)} cells in x -10..10, y -2.5..2.5 mm; {len(t)} "
                                          r"cells in x 20..40"):
        read_specimen(_write(tmp_path / "two.vtu", apart, np.vstack([t, t + len(p)])))


def test_gauge_marks_off_the_specimen_are_refused(tmp_path):
    """A plate with a slot along its centre line where the extensometer's marks would be."""
    holed = holed_strip(50.0, 10.0, 3.0, elements_across=4).mesh
    with pytest.raises(ConfigError, match=r"gauge mark\(s\) at \(.*\) mm .* are not on the specimen"):
        read_specimen(_write(tmp_path / "holed.vtu", holed.p.T, holed.t.T), gauge_length_mm=2.0)
    assert read_specimen(tmp_path / "holed.vtu", gauge_length_mm=20.0).gauge_length_mm == 20.0


def test_an_empty_mesh_file_is_refused(tmp_path):
    (tmp_path / "empty.vtu").write_bytes(b"")
    with pytest.raises(ConfigError, match="empty.vtu"):
        read_specimen(tmp_path / "empty.vtu")


def test_memory_is_estimated_and_refused_beyond_what_is_available():
    small = specimen_memory(100, 4)
    assert specimen_memory(200, 4) > small and specimen_memory(100, 4, rve_dof=1e4) > small
    assert check_memory("strip", 100, 4, available=2**40) == small
    with pytest.raises(ConfigError, match=r"strip: about 1,000,000 elements need about .* GiB of memory, "
                                          r"1 GiB is available; use fewer elements \(--elements-across\)"):
        check_memory("strip", 10**6, 4, available=2**30)


def test_a_huge_built_in_mesh_is_refused_before_it_is_built(monkeypatch):
    import espin.geometry.size_estimate as size_estimate

    monkeypatch.setattr(size_estimate, "available_memory", lambda: 2**30)
    with pytest.raises(ConfigError, match="elements_across = 10000: about .* elements need"):
        espin.specimen(None, "strip", model="neo_hookean", modulus_MPa=200.0, poisson_ratio=0.3,
                       elements_across=10000)


@pytest.mark.parametrize("option, value", [("thickness_mm", np.inf), ("thickness_mm", np.nan),
                                           ("surrogate_reach", np.inf), ("modulus_MPa", np.inf)])
def test_non_finite_specimen_options_are_refused(option, value):
    options = {"model": "neo_hookean", "modulus_MPa": 200.0, "poisson_ratio": 0.3, option: value}
    with pytest.raises(ConfigError, match=option):
        espin.specimen(None, "strip", **options)
