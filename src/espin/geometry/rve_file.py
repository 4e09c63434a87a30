"""RVE files (HDF5): the resolved config, seed, fibers, cross-links and network.

Layout (schema ``espin.geometry.rve``, version 1)::

    /                attrs: schema, schema_version, config_toml, seed, versions, units
    /mat             vertices (n_v, 2), fiber_offsets (n_f + 1), fiber_layer, fiber_diameter
                     attrs: size_um, thickness_um, n_layers
    /crosslinks      point (n, 2), segment (n, 2), fiber (n, 2), layer (n, 2), arc (n, 2)
    /network         node_position (n, 2), element_nodes (n_e, 2), element_contour_length,
                     element_diameter, element_layer, element_fiber
                     attrs: n_inner, n_merged, merge_tolerance_um
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from espin.core.atomic import atomic_write
from espin.core.errors import RVEFileError
from espin.core.header import open_checked, read_config, write_header
from espin.geometry.crosslinks import Crosslinks
from espin.geometry.mat import FiberMat
from espin.geometry.network import Network
from espin.geometry.rve import RVE

__all__ = ["save_rve", "load_rve", "SCHEMA", "SCHEMA_VERSION"]

SCHEMA = "espin.rve"
SCHEMA_VERSION = 1

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


def save_rve(rve: RVE, path: str | Path) -> Path:
    """Write an RVE to an HDF5 file, atomically (a temporary file renamed on success).

    Parameters
    ----------
    rve
        The RVE.
    path
        Destination ``.h5`` file.

    Returns
    -------
    Path
        The written file.
    """

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as f:
            write_header(f, SCHEMA, SCHEMA_VERSION, rve.config)
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
    """Read an RVE written by :func:`save_rve`.

    Raises
    ------
    RVEFileError
        If the file is missing, unreadable, not an espin RVE file, or of a newer schema.
    """
    path = Path(path)
    with open_checked(path, SCHEMA, SCHEMA_VERSION, "RVE") as f:
        try:
            config = read_config(f, path)
            g = f["mat"]
            mat = FiberMat(
                **{name: g[name][()] for name in _MAT},
                size=float(g.attrs["size_um"]),
                thickness=float(g.attrs["thickness_um"]),
                n_layers=int(g.attrs["n_layers"]),
            )
            crosslinks = Crosslinks(**{name: f["crosslinks"][name][()] for name in _CROSSLINKS})
            g = f["network"]
            network = Network(
                **{name: g[name][()] for name in _NETWORK},
                n_inner=int(g.attrs["n_inner"]),
                size=mat.size,
                thickness=mat.thickness,
                n_layers=mat.n_layers,
                n_merged=int(g.attrs["n_merged"]),
                merge_tolerance=float(g.attrs["merge_tolerance_um"]),
            )
        except KeyError as err:
            raise RVEFileError(f"{path} is incomplete: missing {err}") from None
    if not np.array_equal(network.element_nodes.shape, (network.n_elements, 2)):
        raise RVEFileError(f"{path}: network/element_nodes must have shape (n_elements, 2)")
    return RVE(config=config, mat=mat, crosslinks=crosslinks, network=network)
