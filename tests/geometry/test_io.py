"""RVE files and VTK exports: round trips, atomic writes, clear errors."""

from __future__ import annotations

import h5py
import meshio
import numpy as np
import pytest

from espin.core.atomic import atomic_write
from espin.core.errors import RVEFileError
from espin.geometry.rve_file import SCHEMA_VERSION, load_rve, save_rve
from espin.geometry.vtk import write_mat_vtu, write_network_vtu


def test_rve_round_trip(small_rve, tmp_path):
    path = save_rve(small_rve, tmp_path / "rve.h5")
    back = load_rve(path)
    assert back.config == small_rve.config
    for part in ("mat", "crosslinks", "network"):
        a, b = getattr(small_rve, part), getattr(back, part)
        for name, value in vars(a).items():
            if isinstance(value, np.ndarray):
                assert np.array_equal(value, getattr(b, name)), (part, name)
            else:
                assert value == getattr(b, name), (part, name)
    with h5py.File(path) as f:
        assert f.attrs["schema_version"] == SCHEMA_VERSION and f.attrs["seed"] == 1
        for key in ("espin_version", "numpy_version", "scipy_version", "units", "config_toml"):
            assert f.attrs[key]


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")

    def broken(tmp):
        tmp.write_bytes(b"half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(target, broken)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]


def test_a_full_disk_is_a_clear_error_and_keeps_the_old_file(tmp_path):
    import errno

    target = tmp_path / "out.bin"
    target.write_bytes(b"old")

    def full(tmp):
        tmp.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(RVEFileError, match=r"cannot write .*out.bin: No space left on device"):
        atomic_write(target, full)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]
    with pytest.raises(RVEFileError, match="cannot write"):
        atomic_write(tmp_path / "out.bin" / "below_a_file.bin", full)


def test_load_errors(tmp_path, small_rve):
    with pytest.raises(RVEFileError, match="cannot open"):
        load_rve(tmp_path / "missing.h5")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["schema"] = "something.else"
    with pytest.raises(RVEFileError, match="not an espin RVE file"):
        load_rve(other)
    newer = save_rve(small_rve, tmp_path / "newer.h5")
    with h5py.File(newer, "a") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(RVEFileError, match="schema version"):
        load_rve(newer)
    partial = save_rve(small_rve, tmp_path / "partial.h5")
    with h5py.File(partial, "a") as f:
        del f["network/element_nodes"]
    with pytest.raises(RVEFileError, match="incomplete"):
        load_rve(partial)


def test_vtk_exports(small_rve, tmp_path):
    mat, net = small_rve.mat, small_rve.network
    fibers = meshio.read(write_mat_vtu(mat, tmp_path / "fibers.vtu"))
    assert fibers.cells_dict["line"].shape == (mat.n_segments, 2)
    assert set(fibers.cell_data) >= {"layer", "fiber", "tortuosity", "diameter_um"}
    z = fibers.points[:, 2]
    assert np.allclose(np.unique(z), (np.arange(mat.n_layers) + 0.5) * mat.thickness)
    # Every file is centred on the RVE, so the fibers, the network and the steps overlay.
    assert np.allclose(fibers.points[:, :2].min(axis=0), -mat.size / 2) and np.allclose(
        fibers.points[:, :2].max(axis=0), mat.size / 2)
    centred = net.node_position - net.centre
    displacement = 0.1 * centred  # a uniform 10 % stretch about the centre
    stress = np.arange(net.n_elements, dtype=float)
    network = meshio.read(write_network_vtu(net, tmp_path / "net.vtu", displacement, {"stress_MPa": stress},
                                            field_data={"time_s": 2.5, "strain": 0.1}))
    assert np.allclose(network.points[:, :2], centred)
    assert np.allclose(network.point_data["displacement_um"][:, :2], displacement)
    assert np.allclose(network.cell_data["chord_strain"][0], 0.1)
    assert np.array_equal(network.cell_data["stress_MPa"][0], stress)
    text = (tmp_path / "net.vtu").read_text()
    assert 'Name="time_s" NumberOfTuples="1" format="ascii">2.5<' in text and 'Name="strain"' in text
    assert np.array_equal(network.cells_dict["line"], net.element_nodes)
