"""Networks made elsewhere: read a fiber network that espin did not generate.

Two formats: a plain HDF5 file, and the text of the model's original authors.

The plain format (HDF5)
-----------------------
::

    /          attrs: side_um (L), layer_thickness_um (D), layers
    /nodes     position_um (n, 2) float: reference positions in the square [0, L]^2
               border (n,) bool: the node follows x = F X (a fiber end on the border)
    /segments  nodes (m, 2) int: the two nodes (0-based) of each segment
               diameter_um (m,), l0_um (m,): the reference end-to-end length
               tortuosity (m,): lamr = L0 / l0 >= 1 (contour over end-to-end length)
               plastic_stretch (m,), optional: lamp > 0 at the start of the test (default 1)

Consecutive segments that share a node make one fiber. It is recognised by its ``/segments``
group (an espin RVE file has ``/network`` instead).

The authors' mesh format
------------------------
The text file of the model's original authors (``danielcaballero88/Nanofibrous_Mesh_Processor``,
e.g. ``malla_i_s.txt``), in sections that start with a line ``*Name``:

* ``*Parametros``: the side L of the square [um], the fiber diameter D [um] (the layer
  thickness) and the number of layers, one per line;
* ``*Coordenadas``: the number of nodes, then one line per node ``id type X Y x y``: ``id``
  0, 1, 2, ... in order, ``type`` 1 for a border node and 2 for a cross-link, the reference
  position X, Y [um] relative to the centre of the square and the current one (not used);
* ``*Fibras`` (the segments): their number, then one line per segment
  ``id d l0 lamr lamp broken n0 n1``: diameter [um], reference end-to-end length l0 [um],
  tortuosity lamr = L0 / l0 >= 1, plastic stretch lamp > 0, ``F`` (``T``: broken, refused)
  and its two nodes. Consecutive segments that share a node make one fiber.

The network's reference volume is L^2 x layers x D, as for a generated one. Its segments keep
their tortuosity and plastic stretch; l0 must equal the distance of the nodes (to 1e-6 of it
plus 1e-7 of the side: the text's rounding).
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from espin.core.errors import ConfigError, InputError
from espin.geometry.network import Network

__all__ = ["is_network_file", "network_from_segments", "read_network"]

_LENGTH_RTOL = 1e-6
"""Relative tolerance of l0 against the distance of a segment's nodes, and of node positions
outside the square (8-digit text)."""

_POSITION_RTOL = 1e-7
"""Rounding of a position in the text, relative to the side (8 significant digits)."""

MAX_NETWORK_BYTES = 256 * 2**20
"""Largest network file read [bytes]."""


def is_network_file(path: str | Path) -> bool:
    """Whether ``path`` is a network file this module reads: an HDF5 file with a
    ``/segments`` group, or text starting with ``*Parametros``."""
    path = Path(path)
    if not path.is_file() or path.suffix.lower() == ".toml":
        return False
    if h5py.is_hdf5(path):
        try:
            with h5py.File(path, "r") as f:
                return "segments" in f and "nodes" in f
        except OSError:
            return False
    with open(path, encoding="latin-1") as fh:
        head = fh.read(4096).lstrip()
    return head.startswith("*Parametros")


def network_from_segments(
    position: np.ndarray,
    border: np.ndarray,
    nodes: np.ndarray,
    diameter: np.ndarray,
    tortuosity: np.ndarray,
    plastic_stretch: np.ndarray,
    *,
    size: float,
    thickness: float,
    n_layers: int,
    what: str,
) -> Network:
    """A :class:`Network` from nodes and segments (inner nodes are numbered first).

    Parameters
    ----------
    position : (n, 2) float64 [um]
        Reference positions in the square [0, size]^2.
    border : (n,) bool
        Whether each node follows x = F X (a fiber end on the border).
    nodes : (m, 2) int64
        The two nodes of each segment.
    diameter : (m,) float64 [um]
    tortuosity : (m,) float64
        lamr = L0 / l0 >= 1.
    plastic_stretch : (m,) float64
        lamp > 0 at the start of a test.
    size, thickness : float [um]
        Side of the square and thickness of a layer.
    n_layers : int
    what : str
        The file, for messages.

    Raises
    ------
    InputError
        Naming ``what`` and the first offending node or segment.
    """
    n = len(position)
    if not (size > 0 and thickness > 0 and n_layers >= 1):
        raise InputError(
            f"{what}: side {size:g} um, thickness {thickness:g} um and {n_layers} layers: the side "
            "and thickness must be > 0 and the layers >= 1"
        )
    bad = np.flatnonzero((nodes < 0).any(1) | (nodes >= n).any(1) | (nodes[:, 0] == nodes[:, 1]))
    if bad.size:
        raise InputError(
            f"{what}: segment {bad[0]} joins nodes {nodes[bad[0]].tolist()}; a segment joins two "
            f"different nodes among the {n}"
        )
    for name, values, low in (("diameter", diameter, 0.0), ("plastic stretch", plastic_stretch, 0.0)):
        bad = np.flatnonzero(~(values > low))
        if bad.size:
            raise InputError(f"{what}: segment {bad[0]} has {name} {values[bad[0]]:.6g}; it must be > {low:g}")
    bad = np.flatnonzero(~(tortuosity >= 1.0))
    if bad.size:
        raise InputError(
            f"{what}: segment {bad[0]} has tortuosity {tortuosity[bad[0]]:.6g}; it must be >= 1 "
            "(contour over end-to-end length)"
        )
    slack = _LENGTH_RTOL * size
    outside = np.flatnonzero(~np.all((position >= -slack) & (position <= size + slack), axis=1))
    if outside.size:
        raise InputError(
            f"{what}: node {outside[0]} lies at {position[outside[0]].tolist()} um, outside the "
            f"square of side {size:g} um"
        )
    used = np.bincount(nodes.ravel(), minlength=n) > 0
    if not used.all():
        raise InputError(f"{what}: node {int(np.argmin(used))} belongs to no segment")
    order = np.r_[np.flatnonzero(~border), np.flatnonzero(border)]
    renumber = np.empty(n, np.int64)
    renumber[order] = np.arange(n)
    element_nodes = renumber[nodes]
    node_position = position[order]
    chord = np.hypot(*(node_position[element_nodes[:, 1]] - node_position[element_nodes[:, 0]]).T)
    new_fiber = np.r_[True, nodes[1:, 0] != nodes[:-1, 1]]
    return Network(
        node_position=node_position,
        n_inner=int((~border).sum()),
        element_nodes=element_nodes,
        element_contour_length=tortuosity * chord,
        element_diameter=diameter,
        element_layer=np.zeros(len(nodes), np.int64),
        element_fiber=np.cumsum(new_fiber) - 1,
        size=float(size),
        thickness=float(thickness),
        n_layers=int(n_layers),
        n_merged=0,
        merge_tolerance=0.0,
        element_plastic_stretch=plastic_stretch,
    )


def _sections(path: Path, text: str) -> dict[str, list[str]]:
    """Non-blank lines of each ``*Name`` section."""
    sections: dict[str, list[str]] = {}
    current = None
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("*"):
            current = stripped[1:].strip()
            sections[current] = []
        elif stripped and current is not None:
            sections[current].append(stripped)
    for name in ("Parametros", "Coordenadas", "Fibras"):
        if name not in sections:
            raise InputError(
                f"{path}: no *{name} section; expected the authors' mesh format (the *Parametros, "
                "*Coordenadas and *Fibras sections, docs/mechanics.md)"
            )
    return sections


def _table(path: Path, section: str, lines: list[str], columns: int) -> list[list[str]]:
    """The records of a section that starts with their count."""
    try:
        count = int(lines[0])
    except (IndexError, ValueError):
        raise InputError(f"{path}: *{section} must start with the number of records") from None
    records = [line.split() for line in lines[1 : 1 + count]]
    if len(records) < count:
        raise InputError(f"{path}: *{section} announces {count} records but holds {len(records)}")
    short = next((k for k, r in enumerate(records) if len(r) < columns), None)
    if short is not None:
        raise InputError(f"{path}: *{section} record {short} has {len(records[short])} fields, expected {columns}")
    return records


def _numbers(path: Path, section: str, records: list[list[str]], columns: list[int]) -> np.ndarray:
    try:
        values = np.array([[float(r[c]) for c in columns] for r in records], dtype=float).reshape(
            len(records), len(columns)
        )
    except ValueError:
        raise InputError(f"{path}: *{section} holds a field that is not a number") from None
    if not np.all(np.isfinite(values)):
        raise InputError(f"{path}: *{section} holds a value that is not finite")
    return values


def _read_authors(path: Path) -> Network:
    if path.stat().st_size > MAX_NETWORK_BYTES:
        raise InputError(f"{path}: larger than {MAX_NETWORK_BYTES // 2**20} MiB; is this a network?")
    sections = _sections(path, path.read_text(encoding="latin-1"))
    parameters = sections["Parametros"]
    try:
        size, thickness, n_layers = float(parameters[0]), float(parameters[1]), int(parameters[2])
    except (IndexError, ValueError):
        raise InputError(
            f"{path}: *Parametros must hold the side [um], the diameter [um] and the number of layers, one per line"
        ) from None
    node_records = _table(path, "Coordenadas", sections["Coordenadas"], 4)
    node = _numbers(path, "Coordenadas", node_records, [0, 1, 2, 3])
    if not np.array_equal(node[:, 0], np.arange(len(node))):
        raise InputError(f"{path}: *Coordenadas: node ids must be 0, 1, 2, ... in order")
    kind = node[:, 1]
    if not np.isin(kind, (1.0, 2.0)).all():
        raise InputError(f"{path}: *Coordenadas: node type must be 1 (border) or 2 (cross-link)")
    segment_records = _table(path, "Fibras", sections["Fibras"], 8)
    segment = _numbers(path, "Fibras", segment_records, [1, 2, 3, 4, 6, 7])
    broken = [k for k, r in enumerate(segment_records) if r[5].upper() not in ("F", ".FALSE.")]
    if broken:
        raise InputError(f"{path}: *Fibras: segment {broken[0]} is marked broken; espin reads intact networks")
    nodes = segment[:, 4:6].astype(np.int64)
    position = node[:, 2:4] + size / 2.0
    network = network_from_segments(
        position,
        kind == 1.0,
        nodes,
        segment[:, 0],
        segment[:, 2],
        segment[:, 3],
        size=size,
        thickness=thickness,
        n_layers=n_layers,
        what=str(path),
    )
    _check_l0(path, "*Fibras", segment[:, 1], position[nodes[:, 1]] - position[nodes[:, 0]], size)
    return network


def _dataset(f: h5py.File, path: Path, name: str, kind: str, columns: int | None, count: int | None) -> np.ndarray:
    """A dataset of the plain format, checked: its type (``float``, ``int``, or ``bool``: also
    integers 0 / 1), its shape ((count,) or (count, columns); count None: any) and finite values."""
    if name not in f or not isinstance(f[name], h5py.Dataset):
        raise InputError(f"{path}: no dataset /{name} (the plain network format, docs/mechanics.md)")
    data = f[name][()]
    if kind == "float":
        ok = np.issubdtype(data.dtype, np.floating) or np.issubdtype(data.dtype, np.integer)
    elif kind == "int":
        ok = np.issubdtype(data.dtype, np.integer)
    else:
        ok = data.dtype == bool or (np.issubdtype(data.dtype, np.integer) and bool(np.isin(data, (0, 1)).all()))
    rows = data.shape[0] if data.ndim and count is None else count
    expected = (rows,) + ((columns,) if columns else ())
    if not ok or data.shape != expected:
        want = f"({'n' if count is None else count}{', ' + str(columns) if columns else ''}) {kind}"
        raise InputError(f"{path}: /{name} is {data.dtype} of shape {data.shape}; expected {want}")
    if kind == "float" and not np.all(np.isfinite(data)):
        raise InputError(f"{path}: /{name} holds a value that is not finite")
    return data.astype(bool if kind == "bool" else np.int64 if kind == "int" else float)


def _read_plain(path: Path) -> Network:
    with h5py.File(path, "r") as f:
        try:
            size, thickness = float(f.attrs["side_um"]), float(f.attrs["layer_thickness_um"])
            n_layers = int(f.attrs["layers"])
        except (KeyError, TypeError, ValueError):
            raise InputError(
                f"{path}: the root needs the attributes side_um, layer_thickness_um and layers (numbers)"
            ) from None
        position = _dataset(f, path, "nodes/position_um", "float", 2, None)
        border = _dataset(f, path, "nodes/border", "bool", None, len(position))
        nodes = _dataset(f, path, "segments/nodes", "int", 2, None)
        m = len(nodes)
        diameter = _dataset(f, path, "segments/diameter_um", "float", None, m)
        l0 = _dataset(f, path, "segments/l0_um", "float", None, m)
        tortuosity = _dataset(f, path, "segments/tortuosity", "float", None, m)
        plastic = (
            _dataset(f, path, "segments/plastic_stretch", "float", None, m)
            if "segments/plastic_stretch" in f
            else np.ones(m)
        )
    network = network_from_segments(
        position,
        border,
        nodes,
        diameter,
        tortuosity,
        plastic,
        size=size,
        thickness=thickness,
        n_layers=n_layers,
        what=str(path),
    )
    _check_l0(path, "/segments/l0_um", l0, position[nodes[:, 1]] - position[nodes[:, 0]], size)
    return network


def _check_l0(path: Path, where: str, l0: np.ndarray, vector: np.ndarray, size: float) -> None:
    """l0 is the distance of each segment's nodes (to the rounding of text)."""
    chord = np.hypot(*vector.T)
    off = np.flatnonzero(~(np.abs(l0 - chord) <= _LENGTH_RTOL * chord + _POSITION_RTOL * size))
    if off.size:
        k = off[0]
        raise InputError(
            f"{path}: {where}: segment {k} has l0 {l0[k]:.8g} um but its nodes lie "
            f"{chord[k]:.8g} um apart; l0 is the reference end-to-end length"
        )


def read_network(path: str | Path) -> Network:
    """Read a network file (module docstring).

    Raises
    ------
    ConfigError
        If the file does not exist.
    InputError
        If it is not a network in a known format, naming the file and what is wrong.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"network file not found: {path}")
    return _read_plain(path) if h5py.is_hdf5(path) else _read_authors(path)
