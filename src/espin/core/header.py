"""The header every espin HDF5 file carries, and how files are opened and their content checked.

Root attributes: ``schema``, ``schema_version``, the resolved config as ``config_toml``, the
``seed``, the versions of espin, numpy, scipy, h5py and Python, the ``units``, the
creation time and, for a file written into a run's folder, the ``run_id`` of its ``run.json``.

Schema versions are whole numbers from 1, stored as an integer attribute. A reader accepts
exactly the version it was written for: a ``schema_version`` that is not an integer (a float,
even ``1.0``, a string, an array), that is < 1, newer, or older (no older schema exists yet,
so there is nothing to migrate) is refused with :class:`RVEFileError`, naming the espin
version that wrote the file (its ``espin_version`` attribute).

Readers check what they read with :func:`read_dataset` and :func:`read_attr`: type, shape,
finiteness and range, before the values are used. Every failure is an :class:`RVEFileError`
whose message names the file, the dataset or attribute, what is wrong and what is expected.
"""

from __future__ import annotations

import datetime as _dt
import platform
import tomllib
from pathlib import Path
from typing import Literal, TypeGuard, overload

import h5py
import numpy as np
import scipy

from espin.core.config import Config, config_from_dict, config_to_toml
from espin.core.errors import ConfigError, RVEFileError
from espin.core.version import __version__

__all__ = [
    "UNITS",
    "Kind",
    "file_error",
    "open_checked",
    "provenance",
    "read_attr",
    "read_config",
    "read_dataset",
    "write_header",
]

UNITS = "length um, stress MPa, force uN (MPa um^2), time s, angles rad"

Kind = Literal["float", "int", "bool"]
"""What a dataset or attribute holds: ``"float"`` (floats or integers, read as float64),
``"int"`` (integers only, read as int64) or ``"bool"``."""

_DTYPE_KINDS = {"float": "fiu", "int": "iu", "bool": "b"}
_KIND_TEXT = {"float": "number", "int": "integer", "bool": "boolean"}
_CAST = {"float": np.float64, "int": np.int64, "bool": np.bool_}


def provenance() -> dict[str, str]:
    """Versions, units and creation time, as string attributes for a file's root."""
    return {
        "espin_version": __version__,
        "numpy_version": np.__version__,
        "scipy_version": scipy.__version__,
        "h5py_version": h5py.__version__,
        "python_version": platform.python_version(),
        "units": UNITS,
        "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


def write_header(f: h5py.File, schema: str, version: int, config: Config, run_id: str | None = None) -> None:
    """Write the root attributes of an espin file of ``schema``; ``run_id``, the run that
    wrote it (its folder's ``run.json``), when it has one."""
    f.attrs.update(provenance())
    f.attrs["schema"] = schema
    f.attrs["schema_version"] = version
    f.attrs["config_toml"] = config_to_toml(config)
    f.attrs["seed"] = config.rve.seed
    if run_id is not None:
        f.attrs["run_id"] = run_id


def file_error(path: str | Path, where: str, problem: str, expected: str) -> RVEFileError:
    """The error for ``where`` (a dataset, attribute or key) of file ``path``.

    The message reads ``"{path}: {where} {problem}; expected {expected}"`` (without
    ``where`` when it is empty: a problem of the whole file).
    """
    subject = f"{path}: {where}" if where else f"{path}:"
    return RVEFileError(f"{subject} {problem}; expected {expected}")


def open_checked(path: Path, schema: str, version: int, what: str) -> h5py.File:
    """Open an espin file for reading after checking its schema and version.

    Parameters
    ----------
    path
        The file.
    schema
        The schema it must have (root attribute ``schema``).
    version
        The schema version this espin reads (root attribute ``schema_version``).
    what
        What the file is, for messages (``"RVE"``, ``"results"``).

    Returns
    -------
    h5py.File
        Open for reading; the caller closes it.

    Raises
    ------
    RVEFileError
        If the path is missing, a directory, empty, not HDF5 or truncated, of another schema,
        or of a schema version other than ``version`` (see the module notes).
    """
    f = _open(Path(path), what)
    try:
        _check_schema(f, path, schema, version, what)
    except BaseException:
        f.close()
        raise
    return f


def _open(path: Path, what: str) -> h5py.File:
    expected = f"an HDF5 {what} file written by espin"
    if path.is_dir():
        raise file_error(path, "", f"cannot open {what} file: it is a directory", expected)
    if path.exists() and not path.is_file():
        raise file_error(path, "", f"cannot open {what} file: not a regular file (a pipe or a device)", expected)
    if path.is_file() and path.stat().st_size == 0:
        raise file_error(path, "", f"cannot open {what} file: it is empty", expected)
    try:
        return h5py.File(path, "r")
    except FileNotFoundError:
        raise file_error(path, "", f"cannot open {what} file: no such file", expected) from None
    except OSError as err:
        raise file_error(
            path, "", f"cannot open {what} file: not HDF5, or damaged or truncated ({err})", expected
        ) from None


def _check_schema(f: h5py.File, path: Path, schema: str, version: int, what: str) -> None:
    found = _root_attr(f, path, "schema")
    if not (isinstance(found, str) and found == schema):
        problem = "has no schema attribute" if found is None else f"has schema {_show(found)}"
        raise file_error(path, "", f"is not an espin {what} file: it {problem}", f"schema {schema!r}")
    stored = _root_attr(f, path, "schema_version")
    expected = f"schema_version {version}, the {what} schema this espin ({__version__}) reads"
    if stored is None:
        raise file_error(path, "", f"has no schema_version: not a complete espin {what} file", expected)
    if not _is_integer(stored):
        raise file_error(path, "schema_version", f"{_show(stored)} is not an integer", expected)
    stored = int(stored)
    if stored < 1:
        raise file_error(path, "schema_version", f"{stored} is invalid (versions start at 1)", expected)
    if stored != version:
        writer = _root_attr(f, path, "espin_version")
        writer = "an unknown espin version" if writer is None else f"espin {writer}"
        advice = "upgrade espin" if stored > version else "regenerate the file with this espin"
        raise file_error(path, "", f"has {what} schema version {stored}, written by {writer}: {advice}", expected)


def _root_attr(f: h5py.File, path: Path, name: str) -> object:
    """A root attribute, None if absent; unreadable ones are an :class:`RVEFileError`."""
    try:
        return f.attrs.get(name)
    except (OSError, RuntimeError, TypeError, ValueError) as err:
        raise file_error(path, f"root attribute {name}", f"cannot be read ({err})", "an espin file header") from None


def _is_integer(value: object) -> TypeGuard[int | np.integer]:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _show(value: object) -> str:
    """A value as a message shows it (numpy scalars as their Python value)."""
    return repr(value.item() if isinstance(value, np.generic) else value)


def read_config(f: h5py.File, path: Path) -> Config:
    """The resolved config stored in a file's header, checked against its ``seed`` attribute.

    Raises
    ------
    RVEFileError
        If ``config_toml`` is missing, not TOML or not a valid config, or ``seed`` is missing,
        not an integer >= 0 or disagrees with the config's ``rve.seed``.
    """
    expected = "the resolved config as a TOML string (as `espin config` prints it)"
    text = _root_attr(f, path, "config_toml")
    if not isinstance(text, str):
        problem = "is missing" if text is None else f"is not a string ({type(text).__name__})"
        raise file_error(path, "root attribute config_toml", problem, expected)
    try:
        config = config_from_dict(tomllib.loads(text), f"(stored in {path})")
    except tomllib.TOMLDecodeError as err:
        raise file_error(path, "root attribute config_toml", f"is not valid TOML ({err})", expected) from None
    except ConfigError as err:
        raise file_error(path, "root attribute config_toml", f"is not a valid config: {err}", expected) from None
    seed = read_attr(f, "/", "seed", kind="int", low=0, meaning="the RVE's random seed")
    if seed != config.rve.seed:
        raise file_error(
            path,
            "root attribute seed",
            f"= {seed} disagrees with the stored config's rve.seed = {config.rve.seed}",
            "the two to be equal",
        )
    return config


MAX_DATASET_BYTES = 16 * 2**30
"""Largest dataset read [bytes]: a 16 GiB array is about 500 million elements, far beyond any
mat the memory estimate admits; a header declaring more is damaged or crafted."""


def read_dataset(
    f: h5py.File,
    name: str,
    *,
    kind: Kind,
    shape: tuple[int | None, ...],
    meaning: str,
    low: float | None = None,
    high: float | None = None,
    positive: bool = False,
    finite: bool = True,
) -> np.ndarray:
    """A dataset, checked before and after it is read.

    Its type and shape are checked from the file's metadata, before any data is read; then
    its values: finite (floats), ``>= low``, ``<= high``, ``> 0`` if ``positive``.

    Parameters
    ----------
    f
        The open file.
    name
        Path of the dataset in the file, e.g. ``"network/element_nodes"``.
    kind
        ``"float"`` (floats or integers; returned as float64), ``"int"`` (integers only,
        returned as int64) or ``"bool"``.
    shape
        The expected shape; ``None`` for a dimension of any length.
    meaning
        What the dataset holds, with its units, for messages (e.g. ``"node indices"``).
    low, high
        Inclusive bounds of the values (e.g. ``low=0, high=n_nodes - 1`` for indices).
    positive
        The values must be > 0.
    finite
        Float values must be finite (no NaN, no infinity).

    Returns
    -------
    numpy.ndarray
        The values, as float64, int64 or bool.

    Raises
    ------
    RVEFileError
        Naming the file and the dataset: missing, not a dataset, of another type or shape,
        unreadable, or with a value outside the rules (the first such value and its index).
    """
    path = f.filename
    expected = _expected(meaning, kind, shape, low, high, positive, finite)
    try:
        ds = f.get(name)
    except (RuntimeError, KeyError, OSError, ValueError) as err:  # e.g. a loop of soft links
        raise file_error(path, f"dataset {name}", f"cannot be reached ({err})", expected) from None
    if not isinstance(ds, h5py.Dataset):
        problem = "is missing (an incomplete file)" if ds is None else "is not a dataset"
        raise file_error(path, f"dataset {name}", problem, expected)
    if ds.dtype.kind not in _DTYPE_KINDS[kind]:
        raise file_error(path, f"dataset {name}", f"holds {_dtype_text(ds.dtype)}", expected)
    if not _shape_matches(ds.shape, shape):
        raise file_error(path, f"dataset {name}", f"has shape {ds.shape}", expected)
    if ds.size * ds.dtype.itemsize > MAX_DATASET_BYTES:
        raise file_error(
            path,
            f"dataset {name}",
            f"declares {ds.size * ds.dtype.itemsize:,} bytes, more than the {MAX_DATASET_BYTES:,} an espin file holds",
            expected,
        )
    try:
        raw = np.asarray(ds[()])
    except (OSError, RuntimeError, ValueError, TypeError) as err:
        raise file_error(path, f"dataset {name}", f"cannot be read: damaged file? ({err})", expected) from None
    _check_values(raw, path, f"dataset {name}", expected, kind, low, high, positive, finite)
    return raw.astype(_CAST[kind])


@overload
def read_attr(
    f: h5py.File,
    group: str,
    name: str,
    *,
    kind: Literal["int"],
    meaning: str,
    low: float | None = None,
    high: float | None = None,
    positive: bool = False,
    finite: bool = True,
) -> int: ...
@overload
def read_attr(
    f: h5py.File,
    group: str,
    name: str,
    *,
    kind: Literal["float"],
    meaning: str,
    low: float | None = None,
    high: float | None = None,
    positive: bool = False,
    finite: bool = True,
) -> float: ...
@overload
def read_attr(
    f: h5py.File,
    group: str,
    name: str,
    *,
    kind: Kind,
    meaning: str,
    low: float | None = None,
    high: float | None = None,
    positive: bool = False,
    finite: bool = True,
) -> float | int | bool: ...


def read_attr(
    f: h5py.File,
    group: str,
    name: str,
    *,
    kind: Kind,
    meaning: str,
    low: float | None = None,
    high: float | None = None,
    positive: bool = False,
    finite: bool = True,
) -> float | int | bool:
    """A scalar attribute of a group (``"/"`` for the root), checked like :func:`read_dataset`.

    Returns
    -------
    float, int or bool
        As a Python value.

    Raises
    ------
    RVEFileError
        Naming the file, the group and the attribute: missing, not a single value of
        ``kind``, or outside the rules.
    """
    path = f.filename
    where = f"root attribute {name}" if group.strip("/") == "" else f"attribute {name} of {group}"
    expected = _expected(meaning, kind, (), low, high, positive, finite)
    owner = f.get(group)
    if owner is None:
        raise file_error(path, where, f"is missing (no group {group}: an incomplete file)", expected)
    try:
        value = owner.attrs.get(name)
    except (OSError, RuntimeError, TypeError, ValueError) as err:
        raise file_error(path, where, f"cannot be read: damaged file? ({err})", expected) from None
    if value is None:
        raise file_error(path, where, "is missing (an incomplete file)", expected)
    raw = np.asarray(value)
    if raw.shape != () or raw.dtype.kind not in _DTYPE_KINDS[kind]:
        raise file_error(path, where, f"is {_show(value)}", expected)
    _check_values(raw, path, where, expected, kind, low, high, positive, finite)
    return raw.astype(_CAST[kind]).item()


def _shape_matches(found: tuple[int, ...] | None, shape: tuple[int | None, ...]) -> bool:
    return (
        found is not None
        and len(found) == len(shape)
        and all(want is None or want == got for got, want in zip(found, shape))
    )


def _check_values(
    raw: np.ndarray,
    path: str,
    where: str,
    expected: str,
    kind: Kind,
    low: float | None,
    high: float | None,
    positive: bool,
    finite: bool,
) -> None:
    """Raise naming the first value that breaks a rule, and its index."""
    if kind == "bool" or raw.size == 0:
        return
    rules = []
    if finite and kind == "float":
        rules.append((~np.isfinite(raw), "is not finite"))
    if low is not None:
        rules.append((raw < low, f"is below the minimum {low:g}"))
    if high is not None:
        rules.append((raw > high, f"is above the maximum {high:g}"))
    if positive:
        rules.append((raw <= 0, "is not > 0"))
    for bad, problem in rules:
        if np.any(bad):
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            at = f" at [{', '.join(map(str, index))}]" if index else ""
            raise file_error(path, where, f"holds {raw[index].item()!r}{at}, which {problem}", expected)


def _expected(
    meaning: str,
    kind: Kind,
    shape: tuple[int | None, ...],
    low: float | None,
    high: float | None,
    positive: bool,
    finite: bool,
) -> str:
    """The expected format, as messages state it."""
    values = ("finite " if finite and kind == "float" else "") + _KIND_TEXT[kind]
    if shape:
        dims = ", ".join("any" if n is None else str(n) for n in shape)
        words = [f"{meaning}: shape ({dims}{',' if len(shape) == 1 else ''}) of {values}s"]
    else:
        words = [f"{meaning}: one {values}"]
    if low is not None and high is not None:
        words.append(f"in [{low:g}, {high:g}]")
    elif low is not None:
        words.append(f">= {low:g}")
    elif high is not None:
        words.append(f"<= {high:g}")
    if positive:
        words.append("> 0")
    return " ".join(words)


def _dtype_text(dtype: np.dtype) -> str:
    if dtype.kind in "OSUT" or h5py.check_string_dtype(dtype) is not None:
        return "strings"
    return {"f": "floats", "i": "integers", "u": "integers", "b": "booleans", "c": "complex numbers"}.get(
        dtype.kind, f"values of type {dtype}"
    )
