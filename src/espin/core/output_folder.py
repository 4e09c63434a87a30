"""Output folders owned by one run: the ``run.json`` manifest and the overwrite policy.

Every command that writes a folder first writes ``run.json``::

    {"run_id": "...", "command": "simulate", "config_hash": "...", "espin_version": "...",
     "status": "running", "started_utc": "...", "finished_utc": null}

with status ``running`` before its first result, and ``complete``, ``partial`` (it ended but
some of its parts failed: images of a batch, tasks of a study) or ``failed`` when it ends; a
folder whose manifest still says ``running`` holds a partial result (the run was killed or is
still going). The policy, the same for every command:

- a missing or empty folder, or one holding none of the command's outputs and no manifest,
  is used as it is;
- a folder holding another run's manifest or any of the command's outputs is refused, unless
  ``overwrite`` (``--overwrite``): then the manifest is rewritten first, and every file the
  command writes (stale ``vtk/step_*.vtu`` included) and the temporary files of interrupted
  writes are removed; other files are left alone;
- a resumable command reuses a folder of its own, keeping what is there: ``fit`` one whose
  manifest has the same inputs (config, curves, options: the same fit, written again); a
  study (``sweep``, ``rve-size``) one of the same kind of study, or one without a manifest
  (written before manifests existed), since each of its task files is keyed by the task's
  whole config and files: a grown grid reuses the finished tasks (a study whose plan drops
  tasks of the folder's plan is another study, refused by :mod:`espin.studies.sweeps` like
  another command's results); a surrogate ``specimen`` run one with the same inputs (a failed
  or interrupted build resumes from its finished paths).

A run that fails before writing anything but the manifest leaves no folder behind.

A claim is exclusive: the claiming process holds a lock on the folder (``flock`` on the
folder itself, released when the run finishes or its process ends, even when killed) from
before it reads the folder until the run finishes. Another process claiming the folder
meanwhile, a second ``espin`` started on the same new folder at the same instant included, is
refused (:class:`~espin.core.errors.ConfigError`, exit 2) whatever ``overwrite`` or ``resume``
say; so the temporaries of interrupted writes a claim removes are never those of a live run.
Within one process a folder may be claimed again while claimed (a command that writes through
a function that claims it too).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Literal

from espin.core.atomic import atomic_write_bytes
from espin.core.errors import ConfigError, RVEFileError
from espin.core.version import __version__

__all__ = ["MANIFEST", "RunManifest", "OutputFolder", "read_manifest", "inputs_digest"]

MANIFEST = "run.json"
"""Name of the manifest file in every output folder."""
_TEMPORARY = ".*.tmp"  # what an interrupted atomic write leaves (espin.core.atomic)
_HELD: dict[tuple[int, int], tuple[int, int]] = {}
"""Folders this process holds a claim on: (device, inode) -> (lock file descriptor, claims)."""


@dataclass(frozen=True)
class RunManifest:
    """What ``run.json`` records about the run that owns a folder.

    Attributes
    ----------
    run_id : str
        Unique id of the run (also stored in its HDF5 files).
    command : str
        The command that wrote the folder (``generate``, ``simulate``, ``study``, ...).
    config_hash : str
        What identifies the run's inputs: for one config, its
        :func:`espin.core.config.config_digest` (the config and every file it references).
    espin_version : str
    status : str
        ``running``, ``complete``, ``partial`` (some parts failed) or ``failed``.
    started_utc, finished_utc : str
        ISO 8601 times; ``finished_utc`` is None while running.
    outputs : list of str
        Glob patterns (relative to the folder) of the files the run writes: what an
        ``--overwrite`` by a later run removes. While it runs (and if it fails), every file it
        may write; once complete, those it wrote (a converged simulation writes no
        ``solver.log``).
    """

    run_id: str
    command: str
    config_hash: str
    espin_version: str
    status: str
    started_utc: str
    finished_utc: str | None = None
    outputs: list[str] = field(default_factory=list)

    @property
    def partial(self) -> bool:
        """Whether the folder holds less than a complete result."""
        return self.status != "complete"


def inputs_digest(files: Iterable[str | Path], *parts: object) -> str:
    """SHA-256 of what a command starts from: the bytes of ``files`` (in order, each labelled by
    its path; one that is not a regular file counts by its path alone, since its reader will
    refuse it, and a pipe is never opened) and the ``repr`` of ``parts`` (config digests,
    options).
    """
    digest = hashlib.sha256()
    for path in files:
        digest.update(f"\n{path}: ".encode())
        if Path(path).is_file():
            with open(path, "rb") as fh:
                digest.update(hashlib.file_digest(fh, "sha256").digest())
    digest.update(repr(parts).encode())
    return digest.hexdigest()


def read_manifest(folder: str | Path) -> RunManifest | None:
    """The manifest of ``folder``; None if it has none.

    Raises
    ------
    ConfigError
        If ``run.json`` exists but is not a manifest espin wrote.
    """
    path = Path(folder) / MANIFEST
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text("utf-8"))
        manifest = RunManifest(**{key: data[key] for key in RunManifest.__dataclass_fields__ if key in data})
        if not all(isinstance(getattr(manifest, key), str) for key in ("run_id", "command", "status")):
            raise TypeError
        if not (isinstance(manifest.outputs, list) and all(map(_inside, manifest.outputs))):
            raise TypeError  # an --overwrite removes these: only patterns inside the folder
        return manifest
    except (OSError, UnicodeDecodeError, ValueError, TypeError):
        raise ConfigError(
            f"{path} is not an espin run manifest (JSON with run_id, command, config_hash, status ...)"
        ) from None


class OutputFolder:
    """A results folder claimed by one run (module docs for the policy).

    Use :meth:`claim` to create one; call :meth:`finish` when the run ends, or use it as a
    context manager, which finishes it ``complete``, or ``failed`` on an exception.
    """

    def __init__(
        self, path: Path, manifest: RunManifest, created: bool = False, lock: tuple[int, int] | None = None
    ) -> None:
        self.path = path
        self.manifest = manifest
        self._created = created
        self._lock = lock
        self._outcome = "complete"

    @property
    def run_id(self) -> str:
        """The run's id."""
        return self.manifest.run_id

    @classmethod
    def claim(
        cls,
        path: str | Path,
        command: str,
        digest: str,
        outputs: Sequence[str],
        *,
        overwrite: bool = False,
        resume: Literal["same-inputs", "same-command"] | None = None,
        inputs: Sequence[str | Path] = (),
    ) -> OutputFolder:
        """Check ``path`` against the policy and write a ``running`` manifest there.

        Parameters
        ----------
        path
            The folder (created if missing).
        command
            Name of the command writing it.
        digest
            What identifies the run's inputs (recorded; a resumable command reuses a folder
            only for the same digest).
        outputs
            Glob patterns, relative to the folder, of every file the command writes.
        overwrite
            Replace another run's results instead of refusing: remove ``outputs`` and the
            outputs the earlier run's manifest lists.
        resume
            Reuse, keeping its files, a folder whose manifest has the same command and
            ``digest`` (``"same-inputs"``), or the same command, or no manifest
            (``"same-command"``); None: never.
        inputs
            Files the run reads: refused inside the folder, which a later overwrite would
            clear (and whose run they belong to).

        Raises
        ------
        ConfigError
            If the folder belongs to another run and ``overwrite`` is False, is not a folder,
            holds one of ``inputs``, or another process is writing it now.
        RVEFileError
            If the folder or its manifest cannot be written.
        """
        path = Path(path)
        if path.exists() and not path.is_dir():
            raise ConfigError(f"output folder {path} exists and is not a folder")
        for name in inputs:
            if Path(name).resolve().parent == path.resolve():
                raise ConfigError(
                    f"output folder {path} holds the input {Path(name).name} of this run: choose another folder (--out)"
                )
        created = not path.exists()
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise RVEFileError(f"cannot create the output folder {path}: {err.strerror or err}") from None
        lock = _lock(path)
        try:
            folder = cls._claim_locked(path, command, digest, outputs, overwrite, resume, created, lock)
        except BaseException:
            if created and path.is_dir() and not any(path.iterdir()):
                path.rmdir()
            _unlock(lock)
            raise
        return folder

    @classmethod
    def _claim_locked(
        cls,
        path: Path,
        command: str,
        digest: str,
        outputs: Sequence[str],
        overwrite: bool,
        resume: str | None,
        created: bool,
        lock: tuple[int, int],
    ) -> OutputFolder:
        """:meth:`claim` once the folder exists and this process holds its lock."""
        try:
            previous = read_manifest(path)
        except ConfigError:
            if not overwrite:
                raise
            previous = None  # an unreadable run.json is replaced like any other run's
            if (path / MANIFEST).is_dir():
                raise ConfigError(f"{path / MANIFEST} is a folder: remove it first") from None
        found = _existing(path, [*outputs, *(previous.outputs if previous else [])])
        if resume == "same-inputs":
            reuse = previous is not None and (previous.command, previous.config_hash) == (command, digest)
        else:
            reuse = resume == "same-command" and (previous.command == command if previous else bool(found))
        if reuse and not overwrite:
            manifest = previous or RunManifest(uuid.uuid4().hex, command, digest, __version__, "running", _utc_now())
            folder = cls(
                path,
                replace(manifest, config_hash=digest, status="running", finished_utc=None, outputs=list(outputs)),
                lock=lock,
            )
            folder._write()
            return folder
        if (found or previous is not None) and not overwrite:
            owner = (
                "files"
                if previous is None
                else f"the results of another {previous.command} run ({previous.status}, started "
                f"{previous.started_utc})"
            )
            shown = ", ".join(found[:4]) + (" ..." if len(found) > 4 else "")
            raise ConfigError(
                f"output folder {path} already holds {owner}{': ' + shown if shown else ''}; "
                "pass --overwrite (overwrite=True in Python) to replace them, or choose another folder"
            )
        folder = cls(
            path,
            RunManifest(uuid.uuid4().hex, command, digest, __version__, "running", _utc_now(), outputs=list(outputs)),
            created=created,
            lock=lock,
        )
        folder._write()  # first, so that a kill while clearing leaves a folder marked partial
        for name in [*found, *(p.relative_to(path).as_posix() for p in path.rglob(_TEMPORARY))]:
            (path / name).unlink(missing_ok=True)
            if (path / name).parent != path and not any((path / name).parent.iterdir()):
                (path / name).parent.rmdir()  # e.g. an emptied vtk/
        return folder

    def __enter__(self) -> OutputFolder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        self.finish(self._outcome if exc_type is None else "failed")

    def mark(self, failed_parts: int, parts: int) -> None:
        """Record that ``failed_parts`` of the run's ``parts`` (images, tasks) failed: the status
        the context manager finishes with is then ``partial``, or ``failed`` when all did."""
        self._outcome = "complete" if failed_parts == 0 else "failed" if failed_parts >= parts else "partial"

    def finish(self, status: str = "complete") -> None:
        """Record the end of the run: ``complete``, ``partial`` or ``failed``.

        A failed run that wrote nothing but the manifest into a folder it created removes
        both.
        """
        try:
            if status == "failed" and self._created and [p.name for p in self.path.iterdir()] == [MANIFEST]:
                (self.path / MANIFEST).unlink()
                self.path.rmdir()
                return
            outputs = self.manifest.outputs
            if status == "complete":
                outputs = [p for p in dict.fromkeys(outputs) if _existing(self.path, [p])]
            self.manifest = replace(self.manifest, status=status, finished_utc=_utc_now(), outputs=outputs)
            self._write()
        finally:
            if self._lock is not None:
                _unlock(self._lock)
                self._lock = None

    def _write(self) -> None:
        atomic_write_bytes(self.path / MANIFEST, json.dumps(asdict(self.manifest), indent=1).encode("utf-8"))


def _lock(path: Path) -> tuple[int, int]:
    """Take this process's exclusive lock on the folder ``path``: its (device, inode) key.

    Raises
    ------
    ConfigError
        When another process holds it (a run writing the folder now).
    """
    info = path.stat()
    key = (info.st_dev, info.st_ino)
    if key in _HELD:
        fd, claims = _HELD[key]
        _HELD[key] = (fd, claims + 1)
        return key
    try:
        import fcntl
    except ImportError:  # no flock (Windows): claims are not exclusive there
        _HELD[key] = (-1, 1)
        return key
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        try:
            other = read_manifest(path)
        except ConfigError:
            other = None
        who = (
            f"another {other.command} run (started {other.started_utc})"
            if other is not None
            else "another espin run, starting at the same moment"
        )
        raise ConfigError(
            f"output folder {path} is being written by {who}: wait for it to finish, or choose another folder"
        ) from None
    except OSError:  # a file system without locks (some network mounts): claims are not exclusive there
        os.close(fd)
        fd = -1
    _HELD[key] = (fd, 1)
    return key


def _unlock(key: tuple[int, int]) -> None:
    """Release one claim of :func:`_lock` (the lock itself with the last one)."""
    fd, claims = _HELD.pop(key)
    if claims > 1:
        _HELD[key] = (fd, claims - 1)
    elif fd >= 0:
        os.close(fd)  # releases the flock


def _inside(pattern: object) -> bool:
    """Whether ``pattern`` is a glob pattern relative to a folder that stays inside it."""
    return (
        isinstance(pattern, str)
        and bool(pattern)
        and not Path(pattern).is_absolute()
        and ".." not in Path(pattern).parts
    )


def _existing(path: Path, outputs: Sequence[str]) -> list[str]:
    """The files under ``path`` that match ``outputs``, relative, sorted (never one outside it,
    whatever a pattern or a link says)."""
    if not path.is_dir():
        return []
    root = path.resolve()
    return sorted(
        {
            p.relative_to(path).as_posix()
            for pattern in outputs
            if _inside(pattern)
            for p in path.glob(pattern)
            if p.is_file() and p.resolve().is_relative_to(root)
        }
    )


def _utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
