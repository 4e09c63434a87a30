"""The surrogate's samples file, ``surrogate_samples.csv``: what it holds, whose mat it is, and
how it is read without trusting it.

The file is written again (atomically) each time an RVE path of a surrogate build finishes, so
it holds every finished path at any moment (a rerun resumes from them). Its first lines name
the mat and the build, as ``# key = value`` comments::

    # espin surrogate samples, schema 2
    # config_digest = 3f2a...   (SHA-256 of the mat: rve, fiber, solver and the strain rate)
    # law = taut_modulus_MPa=3000, slack_modulus_MPa=3, ...
    # strain_rate_per_s = 0.005
    # max_strain = 0.2          (the grip strain the paths were built for)
    # reach = 3                 (the paths reach this times max_strain)
    # steps = 24                (recorded steps per path)
    # directions = 20
    # speeds = 0.25 1 4 16      (over the strain rate)
    # data_sha256 = 91c0...     (of the data lines below, header line included)

then a CSV table of :data:`SAMPLE_COLUMNS`, one row per recorded step of each finished path
(``path`` = speed index x directions + direction index, its ``steps`` rows in order).

Reading checks the file as any input (a regular text file of bounded size, the header complete,
every value a finite number, each path whole and at its own speed, the checksum), then the
identity against the run's: another mat, law or strain rate, or a run pulling further than the
samples reach, is refused unless the caller allows it knowingly (``allow_mismatch``).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from espin.core.atomic import atomic_write_bytes
from espin.core.config import Config, LoadingConfig, OutputConfig, config_digest
from espin.core.errors import ConfigError
from espin.core.textfiles import TextFormat, parse_number, read_text, text_lines

__all__ = ["SAMPLE_COLUMNS", "SampleIdentity", "SampleFile", "mat_identity", "write_samples", "read_samples"]

SCHEMA_LINE = "# espin surrogate samples, schema 2"
SAMPLE_COLUMNS = (
    "path",
    "E11",
    "E22",
    "E12",
    "strain_rate_per_s",
    "S11_MPa",
    "S22_MPa",
    "S12_MPa",
    "yielded_fraction",
    "recruited_fraction",
)
"""Columns of ``surrogate_samples.csv``: the path (module docstring), the Green-Lagrange strain,
the path's speed as a strain rate [1/s], the second Piola-Kirchhoff stress [MPa] and the
fractions."""
MAX_BYTES = 64 * 2**20
"""Largest samples file read [bytes] (a default build writes about 0.3 MB)."""

_FORMAT = TextFormat(
    what="surrogate samples file",
    max_bytes=MAX_BYTES,
    max_line_chars=1000,
    key="surrogate_from",
    expected=(
        "expected the surrogate_samples.csv of an espin surrogate run (espin 0.x writes it with a header "
        "naming its mat)"
    ),
    size_hint="a surrogate's samples take well under a MB; is this the samples file?",
    line_hint="a row is ten numbers; is this the samples file?",
)


@dataclass(frozen=True)
class SampleIdentity:
    """Whose samples these are and how they were built (the header of the samples file).

    Attributes
    ----------
    config_digest : str
        SHA-256 of the mat (:func:`mat_identity`).
    law : str
        The fiber law's parameters, ``name=value`` joined by ``, `` (for messages).
    strain_rate_per_s : float [1/s]
        The loading's strain rate (the paths' speeds are relative to it).
    max_strain : float
        The grip strain the paths were built for.
    reach : float
        The paths reach ``reach`` times ``max_strain``.
    steps : int
        Recorded steps per path.
    directions : int
        Path directions.
    speeds : tuple of float
        Path speeds over the strain rate, increasing.
    """

    config_digest: str
    law: str
    strain_rate_per_s: float
    max_strain: float
    reach: float
    steps: int
    directions: int
    speeds: tuple[float, ...]

    @property
    def n_paths(self) -> int:
        """Paths of the build (directions x speeds)."""
        return self.directions * len(self.speeds)

    def header(self) -> dict[str, str]:
        """The header's ``key = value`` pairs (without the checksum)."""
        return {
            "config_digest": self.config_digest,
            "law": self.law,
            "strain_rate_per_s": f"{self.strain_rate_per_s:.12g}",
            "max_strain": f"{self.max_strain:.12g}",
            "reach": f"{self.reach:.12g}",
            "steps": str(self.steps),
            "directions": str(self.directions),
            "speeds": " ".join(f"{v:.12g}" for v in self.speeds),
        }

    def mismatches(self, other: SampleIdentity) -> list[str]:
        """What differs between these samples and a run that would use them (``other``), in words;
        empty when the samples fit the run (same mat and strain rate, reaching at least as far)."""
        found = []
        if self.law != other.law:
            found.append(f"the samples are of the fiber law {self.law}, this run's is {other.law}")
        elif self.config_digest != other.config_digest:
            found.append(
                "the samples are of another mat (its rve or solver settings differ: config digest "
                f"{self.config_digest[:12]}, this run's {other.config_digest[:12]})"
            )
        if not np.isclose(self.strain_rate_per_s, other.strain_rate_per_s, rtol=1e-9):
            found.append(
                f"the samples are at the strain rate {self.strain_rate_per_s:g} /s, this run's is "
                f"{other.strain_rate_per_s:g} /s"
            )
        if self.max_strain * (1.0 + 1e-9) < other.max_strain:
            found.append(
                f"the samples were built for a grip strain of {self.max_strain:g}, this run pulls to "
                f"{other.max_strain:g} (beyond them the surrogate extrapolates)"
            )
        return found


@dataclass(frozen=True)
class SampleFile:
    """The finished paths of a samples file.

    Attributes
    ----------
    identity : SampleIdentity
    runs : dict of int to (steps, 9) float64
        Per finished path, its rows of :data:`SAMPLE_COLUMNS` without the path column.
    """

    identity: SampleIdentity
    runs: dict[int, np.ndarray]

    @property
    def complete(self) -> bool:
        """Whether every path of the build is there."""
        return len(self.runs) == self.identity.n_paths


def mat_identity(config: Config) -> tuple[str, str]:
    """(config digest, law) of the mat a surrogate samples: the digest covers the ``rve``,
    ``fiber`` and ``solver`` sections and the loading's strain rate (the rest of ``[loading]``
    and ``[output]`` do not change the samples); the law lists the fiber parameters."""
    rate = config.loading.strain_rate_per_s
    mat = config.model_copy(
        update={"loading": LoadingConfig(strain_rate_per_s=rate), "output": OutputConfig(), "targets": None}
    )
    law = ", ".join(f"{name}={value:g}" for name, value in config.fiber.model_dump().items())
    return config_digest(mat), law


def _data_text(runs: Mapping[int, np.ndarray]) -> str:
    lines = [",".join(SAMPLE_COLUMNS)]
    for index in sorted(runs):
        lines += [f"{index}," + ",".join(f"{v:.17g}" for v in row) for row in runs[index]]
    return "\n".join(lines) + "\n"


def write_samples(path: Path, identity: SampleIdentity, runs: Mapping[int, np.ndarray]) -> Path:
    """Write the samples file (module docstring) atomically: the header and every finished path."""
    data = _data_text(runs)
    header = {**identity.header(), "data_sha256": hashlib.sha256(data.encode()).hexdigest()}
    text = SCHEMA_LINE + "\n" + "".join(f"# {key} = {value}\n" for key, value in header.items()) + data
    return atomic_write_bytes(path, text.encode("utf-8"))


def read_samples(path: str | Path) -> SampleFile:
    """The samples file at ``path``, checked (module docstring) but not yet against a run.

    Raises
    ------
    ConfigError
        When the file does not exist.
    InputError
        When it is not a regular file, too large, not text, has no or an incomplete header (a file
        written by espin before samples named their mat), a value that is not a finite number, a
        path cut short, out of order or at the wrong speed, or data that do not match its checksum
        (edited after it was written).
    """
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"surrogate_from: {path}: no such file (the surrogate_samples.csv of a surrogate run)")
    text = read_text(path, _FORMAT)
    lines = text.split("\n")
    if not lines or lines[0].strip() != SCHEMA_LINE:
        raise _FORMAT.fail(
            path,
            f"its first line is not {SCHEMA_LINE!r}: not a samples file, or one written "
            "by an espin that did not yet name the mat in it; build the surrogate again "
            "(without --surrogate-from)",
        )
    header: dict[str, str] = {}
    for line in lines[1:]:
        if not line.startswith("#"):
            break
        key, sep, value = line[1:].partition("=")
        if sep:
            header[key.strip()] = value.strip()
    identity = _identity(path, header)
    body = text[text.index("\n" + _data_head()) + 1 :] if ("\n" + _data_head()) in text else ""
    if not body:
        raise _FORMAT.fail(path, f"no header line {_data_head()!r} after the comments; {_FORMAT.expected}")
    if hashlib.sha256(body.encode()).hexdigest() != header.get("data_sha256"):
        raise _FORMAT.fail(
            path,
            "its data do not match its checksum (data_sha256): the file was edited or cut "
            "after espin wrote it; build the surrogate again, or restore the file",
        )
    rows = []
    for number, line in text_lines(path, body, _FORMAT, skip_rows=1):
        fields = line.split(",")
        parsed = [parse_number(v) for v in fields]
        values = [v for v in parsed if v is not None]
        if len(fields) != len(SAMPLE_COLUMNS) or len(values) != len(fields) or not np.all(np.isfinite(values)):
            raise _FORMAT.fail(path, f"expected {len(SAMPLE_COLUMNS)} finite numbers", number + _offset(text, body))
        rows.append(values)
    table = np.array(rows, dtype=float).reshape(-1, len(SAMPLE_COLUMNS))
    return SampleFile(identity, _paths(path, identity, table))


def _data_head() -> str:
    return ",".join(SAMPLE_COLUMNS) + "\n"


def _offset(text: str, body: str) -> int:
    """Lines of ``text`` before ``body`` (to number a body line as a line of the file)."""
    return text[: len(text) - len(body)].count("\n")


def _identity(path: Path, header: Mapping[str, str]) -> SampleIdentity:
    missing = [key for key in (*SampleIdentity.__dataclass_fields__, "data_sha256") if key not in header]
    if missing:
        raise _FORMAT.fail(path, f"its header has no {missing[0]} line; {_FORMAT.expected}")
    texts = [header[key] for key in ("strain_rate_per_s", "max_strain", "reach", "steps", "directions")]
    texts += header["speeds"].split()
    parsed = [parse_number(text) for text in texts]
    read = [value for value in parsed if value is not None]
    if len(read) != len(texts) or not (read[3].is_integer() and read[4].is_integer()):
        raise _FORMAT.fail(
            path,
            "its header holds a value that is not a number where one is expected "
            f"({', '.join(f'{k} = {v}' for k, v in header.items() if k != 'law')})",
        )
    rate, max_strain, reach, steps, directions, *speed_list = read
    speeds = tuple(speed_list)
    identity = SampleIdentity(
        header["config_digest"], header["law"], rate, max_strain, reach, int(steps), int(directions), speeds
    )
    numbers = (identity.strain_rate_per_s, identity.max_strain, identity.reach, *speeds)
    if (
        len(identity.config_digest) != 64
        or not all(np.isfinite(numbers))
        or min(numbers) <= 0.0
        or identity.steps < 2
        or identity.directions < 1
        or not speeds
        or list(speeds) != sorted(set(speeds))
    ):
        raise _FORMAT.fail(
            path,
            "its header is not that of a surrogate build (a 64-digit config_digest, positive "
            "strain rate, max_strain, reach and increasing speeds, steps >= 2)",
        )
    return identity


def _paths(path: Path, identity: SampleIdentity, table: np.ndarray) -> dict[int, np.ndarray]:
    """The rows of each path, checked: whole, contiguous, at the path's speed, starting away from
    zero strain."""
    runs: dict[int, np.ndarray] = {}
    index = table[:, 0]
    starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
    for start, end in zip(starts, np.r_[starts[1:], len(table)]):
        k = index[start]
        if k != int(k) or not 0 <= k < identity.n_paths or int(k) in runs:
            raise _FORMAT.fail(
                path,
                f"path {k:g} is out of range (0 to {identity.n_paths - 1}) or its rows are "
                "not together: the file was reordered or merged",
            )
        rows = table[start:end, 1:]
        speed = identity.speeds[int(k) // identity.directions] * identity.strain_rate_per_s
        if len(rows) != identity.steps:
            raise _FORMAT.fail(
                path, f"path {int(k)} has {len(rows)} rows, a path has {identity.steps}: the file was cut or edited"
            )
        if not np.allclose(rows[:, 3], speed, rtol=1e-9):
            raise _FORMAT.fail(path, f"path {int(k)} is not at its speed ({speed:g} /s)")
        if not np.all(np.isfinite(rows)) or np.any((rows[:, 7:] < -1e-9) | (rows[:, 7:] > 1.0 + 1e-9)):
            raise _FORMAT.fail(path, f"path {int(k)} has fractions outside [0, 1]")
        runs[int(k)] = rows
    return runs
