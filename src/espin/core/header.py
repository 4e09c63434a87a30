"""The header every espin HDF5 file carries, and how files are opened and checked.

Root attributes: ``schema``, ``schema_version``, the resolved config as ``config_toml``, the
``seed``, the versions of espin, numpy, scipy, h5py and Python, the ``units`` and the
creation time.
"""

from __future__ import annotations

import datetime as _dt
import platform
import tomllib
from pathlib import Path

import h5py
import numpy as np
import scipy

from espin.core.config import Config, config_from_dict, config_to_toml
from espin.core.errors import RVEFileError
from espin.core.version import __version__

__all__ = ["UNITS", "provenance", "write_header", "open_checked", "read_config"]

UNITS = "length um, stress MPa, force uN (MPa um^2), time s, angles rad"


def provenance() -> dict[str, str]:
    """Versions, units and creation time, as string attributes for a file's root."""
    return {
        "espin_version": __version__,
        "numpy_version": np.__version__,
        "scipy_version": scipy.__version__,
        "h5py_version": h5py.__version__,
        "python_version": platform.python_version(),
        "units": UNITS,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


def write_header(f: h5py.File, schema: str, version: int, config: Config) -> None:
    """Write the root attributes of an espin file of ``schema``."""
    f.attrs.update(provenance())
    f.attrs["schema"] = schema
    f.attrs["schema_version"] = version
    f.attrs["config_toml"] = config_to_toml(config)
    f.attrs["seed"] = config.rve.seed


def open_checked(path: Path, schema: str, version: int, what: str) -> h5py.File:
    """Open an espin file for reading after checking its schema and version.

    Raises
    ------
    RVEFileError
        If the file is missing or unreadable, of another schema, or of a newer version.
    """
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise RVEFileError(f"cannot open {what} file {path}: {err}") from None
    found = f.attrs.get("schema")
    if found != schema:
        f.close()
        raise RVEFileError(f"{path} is not an espin {what} file (schema {found!r})")
    stored = f.attrs.get("schema_version")
    if stored is None:
        f.close()
        raise RVEFileError(f"{path} has no schema_version: not a complete espin {what} file")
    stored = int(stored)
    if stored > version:
        f.close()
        raise RVEFileError(f"{path} has {what} schema version {stored}; this espin reads up to {version}")
    return f


def read_config(f: h5py.File, path: Path) -> Config:
    """The resolved config stored in a file's header."""
    return config_from_dict(tomllib.loads(f.attrs["config_toml"]), f"(stored in {path})")
