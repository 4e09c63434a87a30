"""RVE files (HDF5): the resolved config, seed, fibers, cross-links and network.

Layout (schema ``espin.rve``, version 1; float64 values, int64 indices)::

    /                attrs: schema, schema_version, config_toml, seed, versions, units
    /mat             vertices (n_v, 2), fiber_offsets (n_f + 1), fiber_layer (n_f),
                     fiber_diameter (n_f)
                     attrs: size_um, thickness_um, n_layers
    /crosslinks      point (n, 2), segment (n, 2), fiber (n, 2), layer (n, 2), arc (n, 2)
    /network         node_position (n_nodes, 2), element_nodes (n_e, 2), element_contour_length,
                     element_diameter, element_layer, element_fiber (n_e each)
                     attrs: n_inner, n_merged, merge_tolerance_um

The array meanings are those of :class:`~espin.geometry.mat.FiberMat`,
:class:`~espin.geometry.crosslinks.Crosslinks` and :class:`~espin.geometry.network.Network`;
:func:`load_rve` lists the checks a file must pass.
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

import h5py
import numpy as np

from espin.core.atomic import atomic_write
from espin.core.config import Config
from espin.core.errors import RVEFileError
from espin.core.header import (
    file_error,
    open_checked,
    read_attr,
    read_config,
    read_dataset,
    write_header,
)
from espin.geometry.crosslinks import Crosslinks
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network
from espin.geometry.rve import RVE

__all__ = ["save_rve", "load_rve", "SCHEMA", "SCHEMA_VERSION"]

SCHEMA = "espin.rve"
SCHEMA_VERSION = 1

_RTOL = 1e-6
"""Relative tolerance of the length checks: positions may lie this fraction of L outside the
square, L0 this fraction below l0, and config lengths may differ from the arrays' by this
fraction. It covers rounding (of mean node positions) and float32 storage (6e-8)."""

_MAT = ("vertices", "fiber_offsets", "fiber_layer", "fiber_diameter")
_CROSSLINKS = ("point", "segment", "fiber", "layer", "arc")
_NETWORK = (
    "node_position",
    "element_nodes",
    "element_contour_length",
    "element_diameter",
    "element_layer",
    "element_fiber",
)


def save_rve(rve: RVE, path: str | Path, run_id: str | None = None) -> Path:
    """Write an RVE to an HDF5 file, atomically (a temporary file renamed on success).

    Parameters
    ----------
    rve
        The RVE.
    path
        Destination ``.h5`` file.
    run_id
        The run writing it (stored as the ``run_id`` attribute), if any.

    Returns
    -------
    Path
        The written file.
    """

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as f:
            write_header(f, SCHEMA, SCHEMA_VERSION, rve.config, run_id)
            g = f.create_group("mat")
            for name in _MAT:
                g.create_dataset(name, data=getattr(rve.mat, name))
            g.attrs.update(size_um=rve.mat.size, thickness_um=rve.mat.thickness, n_layers=rve.mat.n_layers)
            g = f.create_group("crosslinks")
            for name in _CROSSLINKS:
                g.create_dataset(name, data=getattr(rve.crosslinks, name))
            g = f.create_group("network")
            for name in _NETWORK:
                g.create_dataset(name, data=getattr(rve.network, name))
            g.attrs.update(
                n_inner=rve.network.n_inner,
                n_merged=rve.network.n_merged,
                merge_tolerance_um=rve.network.merge_tolerance,
            )

    return atomic_write(path, write)


def load_rve(path: str | Path) -> RVE:
    """Read an RVE written by :func:`save_rve`, checking every array before it is used.

    Each dataset must have the type and shape of the layout (module notes) and finite values
    in range: indices within the arrays they point into, positive lengths and diameters,
    positions within the square (to 1e-6 L), fiber offsets from 0 rising by at least 2 (a
    fiber has two vertices or more) to ``n_vertices``. Derived arrays must agree with the
    fibers they come from (cross-link fibers and layers, element layers and diameters), every
    element must have a positive end-to-end length l0 and a contour length L0 >= l0, and the
    stored config must agree with the arrays (``rve.layers``, the side L, the diameter D,
    the merge tolerance, the smallest diameter).

    Parameters
    ----------
    path
        An ``.h5`` file.

    Returns
    -------
    RVE

    Raises
    ------
    RVEFileError
        If the file is missing, unreadable, not an espin RVE file, of another schema version,
        or holds anything that breaks the rules above; the message names the file, the
        dataset, attribute or config key, and the expected format.
    """
    path = Path(path)
    with open_checked(path, SCHEMA, SCHEMA_VERSION, "RVE") as f:
        config = read_config(f, path)
        mat = _read_mat(f)
        crosslinks = _read_crosslinks(f, mat)
        network = _read_network(f, mat)
    _check_config(path, config, mat, network)
    return RVE(config=config, mat=mat, crosslinks=crosslinks, network=network, path=path)


def _read_positions(f: h5py.File, name: str, size: float, meaning: str) -> np.ndarray:
    """An (n, 2) dataset of positions [um] in the square [0, size]^2 (to _RTOL size)."""
    positions = read_dataset(f, name, kind="float", shape=(None, 2), meaning=meaning)
    slack = _RTOL * size
    outside = np.argwhere((positions < -slack) | (positions > size + slack))
    if len(outside):
        i, j = (int(k) for k in outside[0])
        raise file_error(
            f.filename,
            f"dataset {name}",
            f"holds {float(positions[i, j])!r} at [{i}, {j}], outside the layer",
            f"{meaning} in the square [0, L]^2, L = {size!r}",
        )
    return positions


def _read_mat(f: h5py.File) -> FiberMat:
    size = read_attr(f, "mat", "size_um", kind="float", positive=True, meaning="layer side L [um]")
    thickness = read_attr(f, "mat", "thickness_um", kind="float", positive=True, meaning="layer thickness D [um]")
    n_layers = read_attr(f, "mat", "n_layers", kind="int", low=1, meaning="number of layers")
    vertices = _read_positions(f, "mat/vertices", size, "(n_vertices, 2) vertex positions [um]")
    offsets = read_dataset(
        f,
        "mat/fiber_offsets",
        kind="int",
        shape=(None,),
        low=0,
        high=len(vertices),
        meaning="(n_fibers + 1,) start of each fiber",
    )
    _check_offsets(f.filename, offsets, len(vertices))
    n_fibers = len(offsets) - 1
    return FiberMat(
        vertices=vertices,
        fiber_offsets=offsets,
        fiber_layer=read_dataset(
            f,
            "mat/fiber_layer",
            kind="int",
            shape=(n_fibers,),
            low=0,
            high=n_layers - 1,
            meaning="(n_fibers,) layer of each fiber",
        ),
        fiber_diameter=read_dataset(
            f,
            "mat/fiber_diameter",
            kind="float",
            shape=(n_fibers,),
            positive=True,
            meaning="(n_fibers,) fiber diameters [um]",
        ),
        size=size,
        thickness=thickness,
        n_layers=n_layers,
    )


def _check_offsets(path: str, offsets: np.ndarray, n_vertices: int) -> None:
    expected = (
        f"fiber_offsets[0] = 0, rising by at least 2 (a fiber has two vertices or "
        f"more), fiber_offsets[-1] = n_vertices = {n_vertices}"
    )
    where = "dataset mat/fiber_offsets"
    if len(offsets) == 0 or offsets[0] != 0:
        raise file_error(path, where, "does not start with 0", expected)
    short = np.flatnonzero(np.diff(offsets) < 2)
    if short.size:
        i = int(short[0])
        raise file_error(path, where, f"goes from {offsets[i]} to {offsets[i + 1]} at [{i}]", expected)
    if offsets[-1] != n_vertices:
        raise file_error(path, where, f"ends at {offsets[-1]}", expected)


def _read_crosslinks(f: h5py.File, mat: FiberMat) -> Crosslinks:
    point = _read_positions(f, "crosslinks/point", mat.size, "(n, 2) cross-link positions [um]")
    n = len(point)
    crosslinks = Crosslinks(
        point=point,
        segment=read_dataset(
            f,
            "crosslinks/segment",
            kind="int",
            shape=(n, 2),
            low=0,
            high=mat.n_segments - 1,
            meaning="(n, 2) segment indices",
        ),
        fiber=read_dataset(
            f,
            "crosslinks/fiber",
            kind="int",
            shape=(n, 2),
            low=0,
            high=mat.n_fibers - 1,
            meaning="(n, 2) fiber indices",
        ),
        layer=read_dataset(
            f,
            "crosslinks/layer",
            kind="int",
            shape=(n, 2),
            low=0,
            high=mat.n_layers - 1,
            meaning="(n, 2) layer indices",
        ),
        arc=read_dataset(
            f, "crosslinks/arc", kind="float", shape=(n, 2), low=0.0, meaning="(n, 2) arc lengths along the fibers [um]"
        ),
    )
    _check_same(
        f.filename,
        "crosslinks/fiber",
        crosslinks.fiber,
        mat.segment_fiber[crosslinks.segment],
        "the fibers of crosslinks/segment",
    )
    _check_same(
        f.filename,
        "crosslinks/layer",
        crosslinks.layer,
        mat.fiber_layer[crosslinks.fiber],
        "the layers of crosslinks/fiber",
    )
    return crosslinks


def _read_network(f: h5py.File, mat: FiberMat) -> Network:
    nodes = _read_positions(f, "network/node_position", mat.size, "(n_nodes, 2) node positions [um]")
    elements = read_dataset(
        f,
        "network/element_nodes",
        kind="int",
        shape=(None, 2),
        low=0,
        high=len(nodes) - 1,
        meaning="(n_elements, 2) node indices",
    )
    n_e = len(elements)
    network = Network(
        node_position=nodes,
        n_inner=read_attr(
            f,
            "network",
            "n_inner",
            kind="int",
            low=1,
            high=len(nodes),
            meaning="number of inner nodes (the free ones: at least 1), at most n_nodes",
        ),
        element_nodes=elements,
        element_contour_length=read_dataset(
            f,
            "network/element_contour_length",
            kind="float",
            shape=(n_e,),
            positive=True,
            meaning="(n_elements,) contour lengths L0 [um]",
        ),
        element_diameter=read_dataset(
            f,
            "network/element_diameter",
            kind="float",
            shape=(n_e,),
            positive=True,
            meaning="(n_elements,) diameters [um]",
        ),
        element_layer=read_dataset(
            f,
            "network/element_layer",
            kind="int",
            shape=(n_e,),
            low=0,
            high=mat.n_layers - 1,
            meaning="(n_elements,) layer indices",
        ),
        element_fiber=read_dataset(
            f,
            "network/element_fiber",
            kind="int",
            shape=(n_e,),
            low=0,
            high=mat.n_fibers - 1,
            meaning="(n_elements,) fiber indices",
        ),
        size=mat.size,
        thickness=mat.thickness,
        n_layers=mat.n_layers,
        n_merged=read_attr(f, "network", "n_merged", kind="int", low=0, meaning="number of merged node candidates"),
        merge_tolerance=read_attr(
            f, "network", "merge_tolerance_um", kind="float", positive=True, meaning="merge tolerance [um]"
        ),
    )
    _check_elements(f.filename, network, mat)
    return network


def _check_elements(path: str, network: Network, mat: FiberMat) -> None:
    """Elements agree with their fibers, have l0 > 0 and L0 >= l0 (to rounding)."""
    fiber = network.element_fiber
    _check_same(
        path,
        "network/element_layer",
        network.element_layer,
        mat.fiber_layer[fiber],
        "the layers of network/element_fiber",
    )
    _check_same(
        path,
        "network/element_diameter",
        network.element_diameter,
        mat.fiber_diameter[fiber],
        "the diameters of network/element_fiber",
    )
    chord = network.element_length
    where = "dataset network/element_nodes"
    expected = "two distinct nodes at distinct positions for each element"
    zero = np.flatnonzero(chord <= 0)
    if zero.size:
        i = int(zero[0])
        raise file_error(
            path, where, f"joins nodes {network.element_nodes[i].tolist()} at zero distance at [{i}]", expected
        )
    short = np.flatnonzero(network.element_contour_length < chord * (1.0 - _RTOL))
    if short.size:
        i = int(short[0])
        raise file_error(
            path,
            "dataset network/element_contour_length",
            f"holds {float(network.element_contour_length[i])!r} at [{i}], shorter "
            f"than the distance {float(chord[i])!r} between the element's nodes",
            "contour lengths L0 >= the end-to-end length l0 (tortuosity >= 1)",
        )


def _check_same(path: str, name: str, found: np.ndarray, wanted: np.ndarray, what: str) -> None:
    """Raise if ``found`` (dataset ``name``) differs from ``wanted`` (derived from ``what``)."""
    differ = np.argwhere(found != wanted)
    if len(differ):
        at = tuple(int(i) for i in differ[0])
        raise file_error(
            path,
            f"dataset {name}",
            f"holds {found[at].item()!r} at [{', '.join(map(str, at))}] where {what} give {wanted[at].item()!r}",
            f"{name} to agree with {what}",
        )


def _fiber_volume_fraction(mat: FiberMat, fiber: int) -> float:
    """The share of its layer's volume (L^2 times the layer thickness) that one fiber fills."""
    return float(np.pi * mat.fiber_diameter[fiber] ** 2 / 4 * mat.contour_length[fiber] / (mat.size**2 * mat.thickness))


def _check_config(path: Path, config: Config, mat: FiberMat, network: Network) -> None:
    """The stored config must be the one the arrays were generated from."""
    rve = config.rve
    side_key = "rve.size_um" if rve.size_um is not None else "rve.size_ratio * rve.diameter_um"
    pairs = (
        ("rve.layers", rve.layers, "attribute n_layers of mat", mat.n_layers),
        (side_key, rve.side_um, "attribute size_um of mat", mat.size),
        ("rve.diameter_um", rve.diameter_um, "attribute thickness_um of mat", mat.thickness),
        (
            "rve.merge_tolerance_ratio * rve.diameter_um",
            rve.merge_tolerance_um,
            "attribute merge_tolerance_um of network",
            network.merge_tolerance,
        ),
    )
    for key, stored, where, found in pairs:
        if not np.isclose(stored, found, rtol=_RTOL, atol=0.0):
            raise _config_error(path, key, stored, where, found)
    thinnest = float(mat.fiber_diameter.min(initial=np.inf))
    diameter_min = cast(float, rve.diameter_min_um)  # the config sets it when not given
    if thinnest < diameter_min * (1.0 - _RTOL):
        raise _config_error(
            path, "rve.diameter_min_um", diameter_min, "the smallest of dataset mat/fiber_diameter", thinnest
        )
    layer = mat.layer_volume_fraction()
    for k in range(mat.n_layers):  # deposition stops at the fiber that reaches the target
        in_layer = np.flatnonzero(mat.fiber_layer == k)
        last = in_layer[-1] if in_layer.size else None
        before = layer[k] - (0.0 if last is None else _fiber_volume_fraction(mat, last))
        if not (layer[k] >= rve.volume_fraction * (1 - _RTOL) and before < rve.volume_fraction * (1 + _RTOL)):
            raise _config_error(
                path,
                "rve.volume_fraction",
                rve.volume_fraction,
                f"the volume fraction of layer {k} of mat (reached by its last fiber)",
                layer[k],
            )


def _config_error(path: Path, key: str, stored: float, where: str, found: float) -> RVEFileError:
    return file_error(
        path,
        f"stored config key {key}",
        f"= {stored!r} disagrees with the arrays: {where} = {found!r}",
        "the config the RVE was generated from: regenerate the RVE, or restore the root attribute config_toml",
    )
