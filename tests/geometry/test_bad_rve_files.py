"""Damaged RVE files: every bad header, array or config is an RVEFileError naming the file and
the dataset, attribute or config key at fault (and exit code 3 on the command line)."""

from __future__ import annotations

import os
import re
import shutil

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from espin.cli import app
from espin.core.errors import RVEFileError
from espin.core.header import open_checked
from espin.core.version import __version__
from espin.geometry.rve import generate
from espin.geometry.rve_file import SCHEMA, load_rve, save_rve


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A tiny RVE (L = 20 D = 9 um, 2 layers, with cross-links), saved once for the module."""
    rve = generate("plla", rve__size_ratio=20, rve__layers=2)
    assert rve.crosslinks.n > 0 and rve.network.n_elements > 0
    return save_rve(rve, tmp_path_factory.mktemp("rve") / "rve.h5")


def damaged(saved, tmp_path, damage) -> str:
    """A copy of the saved RVE with ``damage(f)`` applied to the open file."""
    path = tmp_path / "damaged.h5"
    shutil.copy(saved, path)
    with h5py.File(path, "a") as f:
        damage(f)
    return path


# ------------------------------------------------------------------ ways to damage a file
def replace(name, change):
    """Replace dataset ``name`` by ``change(its values)``."""

    def damage(f):
        values = change(f[name][()].copy())
        del f[name]
        f[name] = values

    return damage


def at(index, value):
    """A change that sets one entry."""

    def change(a):
        a = a.astype(np.result_type(a, np.asarray(value)))
        a[index] = value
        return a

    return change


def set_attr(group, key, value):
    def damage(f):
        f[group].attrs[key] = value

    return damage


def del_attr(group, key):
    def damage(f):
        del f[group].attrs[key]

    return damage


def delete(name):
    def damage(f):
        del f[name]

    return damage


def edit_config(key, value):
    """Replace the first ``key = ...`` line of the stored TOML config (the [rve] section), or
    the first line ``key`` (a whole line) by ``value``."""
    line = key if " = " in key else None

    def damage(f):
        pattern = rf"^{re.escape(line)}$" if line else rf"^{key} = .*$"
        text, n = re.subn(
            pattern,
            value if line else f"{key} = {value}",
            f.attrs["config_toml"],
            count=1,
            flags=re.MULTILINE,
        )
        assert n == 1
        f.attrs["config_toml"] = text

    return damage


def both(*damages):
    def damage(f):
        for d in damages:
            d(f)

    return damage


def group_for_dataset(name):
    def damage(f):
        del f[name]
        f.create_group(name)

    return damage


def _soft_link_loop(f):
    """Two soft links pointing at each other, one in place of a dataset."""
    f["network/element_nodes"] = h5py.SoftLink("/network/loop")
    f["network/loop"] = h5py.SoftLink("/network/element_nodes")


def _huge_dataset(name):
    """A dataset whose header declares 2^50 x 2 float64 (16 PiB), with no data written."""

    def damage(f):
        f.create_dataset(name, shape=(2**50, 2), dtype="f8", chunks=(1024, 2))

    return damage


NAN, INF = float("nan"), float("inf")

CASES = {
    # header
    "schema_version_text": (set_attr("/", "schema_version", "abc"), ["schema_version", "'abc'"]),
    "schema_version_fraction": (set_attr("/", "schema_version", 1.9), ["schema_version", "1.9"]),
    "schema_version_float_1": (
        set_attr("/", "schema_version", 1.0),
        ["schema_version", "not an integer"],
    ),
    "schema_version_zero": (set_attr("/", "schema_version", 0), ["schema_version 0", "start at 1"]),
    "schema_version_negative": (set_attr("/", "schema_version", -5), ["schema_version -5"]),
    "schema_version_newer": (set_attr("/", "schema_version", 2), ["version 2", "upgrade espin"]),
    "schema_version_bool": (
        set_attr("/", "schema_version", True),
        ["schema_version", "not an integer"],
    ),
    "schema_version_array": (
        set_attr("/", "schema_version", [1, 1]),
        ["schema_version", "not an integer"],
    ),
    "schema_version_missing": (del_attr("/", "schema_version"), ["no schema_version"]),
    "schema_missing": (del_attr("/", "schema"), ["not an espin RVE file", "no schema"]),
    "schema_other": (
        set_attr("/", "schema", "espin.results"),
        ["not an espin RVE file", "espin.results"],
    ),
    "schema_array": (set_attr("/", "schema", ["espin.rve"]), ["not an espin RVE file", "array"]),
    "config_missing": (del_attr("/", "config_toml"), ["config_toml", "missing"]),
    "config_not_text": (set_attr("/", "config_toml", 3), ["config_toml", "not a string"]),
    "config_not_toml": (set_attr("/", "config_toml", "[[["), ["config_toml", "not valid TOML"]),
    "config_bad_value": (edit_config("layers", 0), ["config_toml", "rve.layers"]),
    "seed_missing": (del_attr("/", "seed"), ["root attribute seed", "missing"]),
    "seed_text": (set_attr("/", "seed", "one"), ["root attribute seed", "'one'"]),
    # the stored config against the arrays
    "config_layers": (edit_config("layers", 3), ["rve.layers = 3", "n_layers of mat = 2"]),
    "config_size_ratio": (edit_config("size_ratio", 21.0), ["rve.size_ratio", "size_um of mat"]),
    "config_size_um": (
        edit_config("size_ratio = 20.0", "size_um = 6.0"),
        ["rve.size_um = 6.0", "= 9.0"],
    ),
    "config_diameter": (
        both(edit_config("diameter_um", 0.5), edit_config("size_ratio", 18.0)),
        ["rve.diameter_um = 0.5", "thickness_um of mat = 0.45"],
    ),
    "config_merge_tolerance": (
        edit_config("merge_tolerance_ratio", 0.05),
        ["rve.merge_tolerance_ratio", "merge_tolerance_um of network"],
    ),
    "config_diameter_min": (
        both(
            replace("mat/fiber_diameter", lambda a: np.full_like(a, 0.01)),
            replace("network/element_diameter", lambda a: np.full_like(a, 0.01)),
        ),
        ["rve.diameter_min_um = 0.045", "mat/fiber_diameter = 0.01"],
    ),
    "config_seed": (edit_config("seed", 7), ["root attribute seed = 1", "rve.seed = 7"]),
    # mat
    "vertices_nan": (
        replace("mat/vertices", at((2, 1), NAN)),
        ["dataset mat/vertices", "nan at [2, 1]"],
    ),
    "vertices_inf": (
        replace("mat/vertices", at((0, 0), INF)),
        ["dataset mat/vertices", "not finite"],
    ),
    "vertices_outside": (
        replace("mat/vertices", at((3, 0), -1.0)),
        ["dataset mat/vertices", "-1.0 at [3, 0]", "square [0, L]^2"],
    ),
    "vertices_shape": (
        replace("mat/vertices", lambda a: np.c_[a, a[:, :1]]),
        ["dataset mat/vertices", "shape"],
    ),
    "vertices_text": (
        replace("mat/vertices", lambda a: np.array([b"x"] * len(a))),
        ["dataset mat/vertices", "strings"],
    ),
    "offsets_not_rising": (
        replace("mat/fiber_offsets", lambda a: at(2, a[1])(a)),
        ["dataset mat/fiber_offsets", "goes from"],
    ),
    "offsets_short": (
        replace("mat/fiber_offsets", lambda a: a[:-1]),
        ["dataset mat/fiber_offsets", "ends at"],
    ),
    "offsets_start": (
        replace("mat/fiber_offsets", at(0, 1)),
        ["dataset mat/fiber_offsets", "start with 0"],
    ),
    "offsets_float": (
        replace("mat/fiber_offsets", lambda a: a.astype(float)),
        ["dataset mat/fiber_offsets", "floats"],
    ),
    "offsets_beyond": (
        replace("mat/fiber_offsets", lambda a: at(-1, a[-1] + 5)(a)),
        ["dataset mat/fiber_offsets", "above"],
    ),
    "offsets_empty": (
        replace("mat/fiber_offsets", lambda a: a[:0]),
        ["dataset mat/fiber_offsets", "start with 0"],
    ),
    "fiber_layer_range": (
        replace("mat/fiber_layer", at(0, 2)),
        ["dataset mat/fiber_layer", "above the maximum 1"],
    ),
    "fiber_layer_negative": (
        replace("mat/fiber_layer", at(0, -1)),
        ["dataset mat/fiber_layer", "below the minimum 0"],
    ),
    "fiber_layer_length": (
        replace("mat/fiber_layer", lambda a: a[1:]),
        ["dataset mat/fiber_layer", "shape"],
    ),
    "diameter_zero": (
        replace("mat/fiber_diameter", at(1, 0.0)),
        ["dataset mat/fiber_diameter", "not > 0"],
    ),
    "diameter_negative": (
        replace("mat/fiber_diameter", lambda a: -a),
        ["dataset mat/fiber_diameter", "not > 0"],
    ),
    "diameter_nan": (
        replace("mat/fiber_diameter", at(0, NAN)),
        ["dataset mat/fiber_diameter", "not finite"],
    ),
    "size_negative": (set_attr("mat", "size_um", -5.4), ["attribute size_um of mat", "not > 0"]),
    "n_layers_zero": (
        set_attr("mat", "n_layers", 0),
        ["attribute n_layers of mat", "below the minimum 1"],
    ),
    "n_layers_text": (set_attr("mat", "n_layers", "2"), ["attribute n_layers of mat", "'2'"]),
    "thickness_missing": (
        del_attr("mat", "thickness_um"),
        ["attribute thickness_um of mat", "missing"],
    ),
    "mat_missing": (delete("mat"), ["no group mat"]),
    # cross-links
    "crosslink_segment_range": (
        replace("crosslinks/segment", lambda a: a * 100),
        ["dataset crosslinks/segment", "above"],
    ),
    "crosslink_segment_negative": (
        replace("crosslinks/segment", at((0, 0), -1)),
        ["dataset crosslinks/segment", "below"],
    ),
    "crosslink_fiber_range": (
        replace("crosslinks/fiber", at((0, 1), 99)),
        ["dataset crosslinks/fiber", "above"],
    ),
    "crosslink_layer_range": (
        replace("crosslinks/layer", at((0, 1), 2)),
        ["dataset crosslinks/layer", "above"],
    ),
    "crosslink_fiber_swapped": (
        replace("crosslinks/fiber", lambda a: a[:, ::-1].copy()),
        ["dataset crosslinks/fiber", "the fibers of crosslinks/segment"],
    ),
    "crosslink_layer_wrong": (
        replace("crosslinks/layer", lambda a: at((0, 0), 1 - a[0, 0])(a)),
        ["dataset crosslinks/layer", "the layers of crosslinks/fiber"],
    ),
    "crosslink_arc_negative": (
        replace("crosslinks/arc", at((0, 0), -0.1)),
        ["dataset crosslinks/arc", "below"],
    ),
    "crosslink_point_nan": (
        replace("crosslinks/point", at((0, 0), NAN)),
        ["dataset crosslinks/point", "not finite"],
    ),
    "crosslink_count": (
        replace("crosslinks/point", lambda a: a[1:]),
        ["dataset crosslinks/segment", "shape"],
    ),
    # network
    "node_position_inf": (
        replace("network/node_position", at((1, 1), -INF)),
        ["dataset network/node_position", "not finite"],
    ),
    "element_nodes_shape": (
        replace("network/element_nodes", lambda a: np.c_[a, a[:, :1]]),
        ["dataset network/element_nodes", "has shape", "(any, 2)"],
    ),
    "element_nodes_float": (
        replace("network/element_nodes", lambda a: a + 0.5),
        ["dataset network/element_nodes", "floats"],
    ),
    "element_nodes_text": (
        replace("network/element_nodes", lambda a: a.astype("S8")),
        ["dataset network/element_nodes", "strings"],
    ),
    "element_nodes_range": (
        replace("network/element_nodes", lambda a: a + 100),
        ["dataset network/element_nodes", "above"],
    ),
    "element_nodes_negative": (
        replace("network/element_nodes", at((4, 1), -3)),
        ["dataset network/element_nodes", "below"],
    ),
    "element_nodes_same": (
        replace("network/element_nodes", lambda a: at((0, 1), a[0, 0])(a)),
        ["dataset network/element_nodes", "zero distance"],
    ),
    "element_nodes_missing": (
        delete("network/element_nodes"),
        ["dataset network/element_nodes", "incomplete"],
    ),
    "element_nodes_group": (
        group_for_dataset("network/element_nodes"),
        ["dataset network/element_nodes", "not a dataset"],
    ),
    "contour_zero": (
        replace("network/element_contour_length", at(0, 0.0)),
        ["dataset network/element_contour_length", "not > 0"],
    ),
    "contour_negative": (
        replace("network/element_contour_length", lambda a: -a),
        ["dataset network/element_contour_length", "not > 0"],
    ),
    "contour_nan": (
        replace("network/element_contour_length", at(3, NAN)),
        ["dataset network/element_contour_length", "not finite"],
    ),
    "contour_below_chord": (
        replace("network/element_contour_length", lambda a: 0.5 * a),
        ["dataset network/element_contour_length", "shorter than the distance"],
    ),
    "element_diameter_zero": (
        replace("network/element_diameter", at(0, 0.0)),
        ["dataset network/element_diameter", "not > 0"],
    ),
    "element_diameter_negative": (
        replace("network/element_diameter", at(0, -0.45)),
        ["dataset network/element_diameter", "not > 0"],
    ),
    "element_diameter_nan": (
        replace("network/element_diameter", at(0, NAN)),
        ["dataset network/element_diameter", "not finite"],
    ),
    "element_diameter_wrong": (
        replace("network/element_diameter", lambda a: 2 * a),
        ["dataset network/element_diameter", "the diameters of network/element_fiber"],
    ),
    "element_layer_range": (
        replace("network/element_layer", at(0, 5)),
        ["dataset network/element_layer", "above"],
    ),
    "element_fiber_range": (
        replace("network/element_fiber", at(0, -1)),
        ["dataset network/element_fiber", "below"],
    ),
    "n_inner_range": (
        set_attr("network", "n_inner", 1000),
        ["attribute n_inner of network", "above"],
    ),
    "n_inner_negative": (
        set_attr("network", "n_inner", -1),
        ["attribute n_inner of network", "below"],
    ),
    "n_inner_float": (set_attr("network", "n_inner", 3.0), ["attribute n_inner of network", "3.0"]),
    "n_inner_zero": (set_attr("network", "n_inner", 0), ["attribute n_inner of network", "below"]),
    "config_volume_fraction_low": (edit_config("volume_fraction", "0.1"),
                                   ["stored config key rve.volume_fraction", "reached by its last fiber"]),
    "config_volume_fraction": (edit_config("volume_fraction", "0.9"),
                               ["stored config key rve.volume_fraction", "reached by its last fiber"]),
    "soft_link_loop": (both(delete("network/element_nodes"), _soft_link_loop),
                       ["dataset network/element_nodes", "cannot be reached"]),
    "huge_declared_shape": (both(delete("network/node_position"), _huge_dataset("network/node_position")),
                            ["dataset network/node_position", "declares"]),
    "n_merged_negative": (
        set_attr("network", "n_merged", -2),
        ["attribute n_merged of network", "below"],
    ),
    "merge_tolerance_zero": (
        set_attr("network", "merge_tolerance_um", 0.0),
        ["attribute merge_tolerance_um of network", "not > 0"],
    ),
    "merge_tolerance_nan": (
        set_attr("network", "merge_tolerance_um", NAN),
        ["attribute merge_tolerance_um of network", "not finite"],
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_damaged_file_is_a_clear_error(saved, tmp_path, case):
    damage, fragments = CASES[case]
    path = damaged(saved, tmp_path, damage)
    with pytest.raises(RVEFileError) as caught:
        load_rve(path)
    message = str(caught.value)
    assert message.startswith(f"{path}:") and "expected" in message, message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def _not_hdf5(path, saved):
    path.write_text("step,strain\n0,0.0\n")


def _empty(path, saved):
    path.write_bytes(b"")


def _directory(path, saved):
    path.mkdir()


def _truncated(path, saved):
    data = saved.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _missing(path, saved):
    pass


def _fifo(path, saved):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no named pipes on this platform")
    os.mkfifo(path)


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (_not_hdf5, "not HDF5"),
        (_empty, "empty"),
        (_directory, "directory"),
        (_truncated, "truncated"),
        (_missing, "no such file"),
        (_fifo, "not a regular file"),
    ],
    ids=["not_hdf5", "empty", "directory", "truncated", "missing", "fifo"],
)
def test_unreadable_file_is_a_clear_error(saved, tmp_path, make, fragment):
    path = tmp_path / "rve.h5"
    make(path, saved)
    with pytest.raises(RVEFileError, match=fragment) as caught:
        load_rve(path)
    assert str(path) in str(caught.value) and "expected an HDF5 RVE file" in str(caught.value)


def test_older_schema_version_names_the_espin_that_wrote_it(saved):
    # No older RVE schema exists yet: a reader of version 2 sees a version-1 file as older.
    with pytest.raises(
        RVEFileError,
        match=rf"version 1, written by espin {re.escape(__version__)}: "
        "regenerate",
    ):
        open_checked(saved, SCHEMA, 2, "RVE")


def test_other_storage_types_load_unchanged(saved, tmp_path):
    """Narrower integer and float types are read as int64 / float64, values unchanged."""
    path = damaged(
        saved,
        tmp_path,
        both(
            replace("network/element_nodes", lambda a: a.astype(np.uint32)),
            replace("mat/fiber_layer", lambda a: a.astype(np.int8)),
            replace("network/element_contour_length", lambda a: a.astype(np.float32)),
            replace("mat/vertices", lambda a: a.astype(np.float32)),
        ),
    )
    back, original = load_rve(path), load_rve(saved)
    assert back.network.element_nodes.dtype == np.int64
    assert np.array_equal(back.network.element_nodes, original.network.element_nodes)
    assert np.array_equal(back.mat.fiber_layer, original.mat.fiber_layer)
    assert np.allclose(
        back.network.element_contour_length, original.network.element_contour_length, rtol=1e-6
    )


@pytest.mark.parametrize(
    ("case", "fragment"),
    [
        ("schema_version_text", "schema_version"),
        ("diameter_nan", "mat/fiber_diameter"),
        ("config_layers", "rve.layers"),
    ],
)
def test_simulate_on_a_damaged_file_exits_3_without_traceback(saved, tmp_path, case, fragment):
    path = damaged(saved, tmp_path, CASES[case][0])
    result = CliRunner().invoke(
        app,
        [
            "simulate",
            str(path),
            "--max-strain",
            "0.01",
            "--steps",
            "1",
            "-o",
            str(tmp_path / "out"),
        ],
    )
    assert result.exit_code == 3, result.output
    assert "Traceback" not in result.output and fragment in result.output
    assert "damaged.h5" in result.output
    assert not (tmp_path / "out").exists()


def test_read_dataset_checks_booleans_and_scalars(tmp_path):
    """The helpers other readers use (results files): bool datasets and scalar datasets."""
    from espin.core.header import read_dataset

    with h5py.File(tmp_path / "x.h5", "w") as f:
        f["flags"] = np.array([True, False])
        f["count"] = np.array([1, 0])
        f["scalar"] = 2.5
    with h5py.File(tmp_path / "x.h5", "r") as f:
        flags = read_dataset(f, "flags", kind="bool", shape=(2,), meaning="flags")
        assert flags.dtype == bool and flags.tolist() == [True, False]
        assert read_dataset(f, "scalar", kind="float", shape=(), positive=True, meaning="s") == 2.5
        with pytest.raises(RVEFileError, match=r"x.h5: dataset count holds integers; expected"):
            read_dataset(f, "count", kind="bool", shape=(2,), meaning="flags")
        with pytest.raises(RVEFileError, match=r"dataset scalar holds 2.5, which is above"):
            read_dataset(f, "scalar", kind="float", shape=(), high=1.0, meaning="a fraction")
