"""Dask clusters on HPC batch systems (Slurm, PBS) for espin ensembles, via dask-jobqueue.

Each batch job starts ``workers_per_job`` Dask worker processes with one thread each and BLAS /
MKL / OpenMP limited to one thread, the same layout as espin's local process pool. Pass the
cluster's client to any study as ``scheduler``::

    from distributed import Client
    from espin.core.cluster import jobqueue_cluster

    cluster = jobqueue_cluster("slurm", workers_per_job=8, memory_per_worker="3GB",
                               walltime="04:00:00", queue="normal", account="my_project")
    print(cluster.job_script())          # the batch script each job runs: read it first
    cluster.scale(jobs=4)                # submit 4 jobs (32 workers)
    espin.studies.sweeps.sweep("plla", grid, realizations=10, folder="sweep", scheduler=Client(cluster))

A Dask scheduler and its workers run the pickled tasks they are sent: connect only to one you
trust. :func:`tls_security` gives the TLS settings of a ``tls://`` scheduler (encrypted, both
ends authenticated by certificates)::

    security = tls_security("ca.pem", "client-cert.pem", "client-key.pem")
    espin.studies.sweeps.sweep("plla", grid, scheduler="tls://host:8786", security=security)

"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from espin.core.errors import ConfigError
from espin.core.parallel import THREAD_VARIABLES  # exported as 1 in every job: one core per worker

__all__ = ["jobqueue_cluster", "tls_security", "BATCH_SYSTEMS", "THREAD_VARIABLES"]

BATCH_SYSTEMS = ("slurm", "pbs")
"""Batch systems espin configures (any other dask-jobqueue cluster works as a plain Client)."""


_MEMORY = re.compile(r"^\d+(\.\d+)?\s*(B|[KMGT]i?B)$", re.IGNORECASE)
_WALLTIME = re.compile(r"^(?:(?P<days>\d+)-)?(?P<hours>\d+):(?P<minutes>\d{2}):(?P<seconds>\d{2})$")


def _walltime(walltime: str, system: str) -> str:
    """The job time limit as ``system`` reads it, after checking its format.

    Parameters
    ----------
    walltime
        ``HH:MM:SS`` (hours may exceed 24, e.g. ``"36:00:00"``) or ``D-HH:MM:SS`` (days, hours
        0-23); minutes and seconds 00-59; the limit must be longer than zero. ``"04:00"`` is
        refused: Slurm reads ``MM:SS`` (4 minutes), where 4 hours was probably meant.
    system
        ``"slurm"`` or ``"pbs"``.

    Returns
    -------
    str
        Slurm: the walltime as given (``D-HH:MM:SS`` is Slurm syntax). PBS: always
        ``HH:MM:SS``, days converted to hours (``"1-02:00:00"`` -> ``"26:00:00"``).

    Raises
    ------
    ConfigError
        If the walltime is not in one of these formats, a field is out of range, or it is zero.
    """
    rule = "HH:MM:SS (hours may exceed 24) or D-HH:MM:SS (hours 0-23), minutes and seconds 00-59"
    found = _WALLTIME.match(walltime) if isinstance(walltime, str) else None
    if found is None:
        raise ConfigError(f"walltime: {rule} (got {walltime!r})")
    days = int(found["days"]) if found["days"] is not None else 0
    hours, minutes, seconds = int(found["hours"]), int(found["minutes"]), int(found["seconds"])
    if minutes > 59 or seconds > 59 or (found["days"] is not None and hours > 23):
        raise ConfigError(f"walltime: {rule} (got {walltime!r})")
    if days == hours == minutes == seconds == 0:
        raise ConfigError(f"walltime: must be longer than 00:00:00 (got {walltime!r})")
    if system == "pbs":
        return f"{24 * days + hours:02d}:{minutes:02d}:{seconds:02d}"
    return walltime


def jobqueue_cluster(
    system: str,
    *,
    workers_per_job: int = 1,
    memory_per_worker: str = "4GB",
    walltime: str = "01:00:00",
    queue: str | None = None,
    account: str | None = None,
    python: str | None = None,
    prologue: list[str] | None = None,
    **options: Any,
) -> Any:
    """A dask-jobqueue cluster that runs espin tasks on a batch system (no job submitted yet).

    Parameters
    ----------
    system
        ``"slurm"`` or ``"pbs"``.
    workers_per_job
        Worker processes (= cores) per job, one thread each.
    memory_per_worker
        Memory per worker, e.g. ``"3GB"`` (a plla-size tensile test needs about 0.5 GB).
    walltime
        Job time limit, ``HH:MM:SS`` (hours may exceed 24) or ``D-HH:MM:SS`` (hours 0-23);
        minutes and seconds 00-59. ``MM:SS`` and ``HH:MM`` are refused (Slurm would read
        ``"04:00"`` as 4 minutes). Slurm gets it as given; PBS, which has no days field, gets
        ``D-HH:MM:SS`` as hours (``"1-02:00:00"`` -> ``walltime=26:00:00``).
    queue, account
        Partition / queue and project account, if the site needs them.
    python
        The Python of the environment where espin is installed on the compute nodes
        (default: this interpreter).
    prologue
        Extra shell lines run before the workers start (e.g. ``module load python``,
        ``source ~/espin/env/bin/activate``).
    **options
        Passed on to the dask-jobqueue cluster class (``job_extra_directives`` ...).

    Returns
    -------
    dask_jobqueue.SLURMCluster or dask_jobqueue.PBSCluster
        ``.job_script()`` shows the batch script; ``.scale(jobs=n)`` submits n jobs.

    Raises
    ------
    ConfigError
        If ``system``, ``workers_per_job``, ``memory_per_worker`` or ``walltime`` is invalid
        (the message names the parameter and what it accepts).
    """
    if system not in BATCH_SYSTEMS:
        raise ConfigError(f"system: one of {', '.join(BATCH_SYSTEMS)} (got {system!r})")
    if not isinstance(workers_per_job, int) or workers_per_job < 1:
        raise ConfigError(f"workers_per_job: must be an integer >= 1 (got {workers_per_job!r})")
    if not _MEMORY.match(memory_per_worker):
        raise ConfigError(f"memory_per_worker: a size such as 3GB or 3GiB (got {memory_per_worker!r})")
    walltime = _walltime(walltime, system)
    import dask_jobqueue
    from dask.utils import format_bytes, parse_bytes

    kind = {"slurm": dask_jobqueue.SLURMCluster, "pbs": dask_jobqueue.PBSCluster}[system]
    return kind(
        cores=workers_per_job,
        processes=workers_per_job,
        memory=format_bytes(parse_bytes(memory_per_worker) * workers_per_job).replace(" ", ""),
        walltime=walltime,
        queue=queue,
        account=account,
        python=python,
        job_script_prologue=[*(prologue or []), *(f"export {v}=1" for v in THREAD_VARIABLES)],
        **options,
    )


def _readable_file(path: str | Path, option: str) -> str:
    """``path`` as text, after checking it names a readable file (its contents are never read)."""
    if not Path(path).is_file():
        raise ConfigError(f"{option}: no such file: {path}")
    if not os.access(path, os.R_OK):
        raise ConfigError(f"{option}: cannot read {path} (permission denied)")
    return str(path)


def tls_security(
    tls_ca_file: str | Path | None = None,
    tls_cert: str | Path | None = None,
    tls_key: str | Path | None = None,
) -> Any:
    """The TLS settings of a client of a ``tls://`` Dask scheduler, or None without TLS files.

    Dask's TLS is mutual: the client checks the scheduler's certificate against the CA, and
    shows its own certificate, signed by a CA the scheduler trusts. Encryption is required:
    the settings refuse a ``tcp://`` connection.

    Parameters
    ----------
    tls_ca_file
        PEM file of the certificate authority (``--tls-ca-file``).
    tls_cert
        PEM file of this client's certificate (``--tls-cert``); it may hold the key too.
    tls_key
        PEM file of the client's private key (``--tls-key``), unless ``tls_cert`` holds it.

    Returns
    -------
    distributed.security.Security or None
        None when no file is given; else ``Security(tls_ca_file=..., tls_client_cert=...,
        tls_client_key=..., require_encryption=True)``.

    Raises
    ------
    ConfigError
        If the CA file or the certificate is missing while another TLS file is given, or a
        file does not exist or cannot be read (the message names the option and the path,
        never a file's contents).
    """
    if tls_ca_file is None and tls_cert is None and tls_key is None:
        return None
    if tls_ca_file is None or tls_cert is None:
        raise ConfigError(
            "tls_ca_file, tls_cert (--tls-ca-file, --tls-cert): TLS needs both the CA file and "
            "the client certificate (and --tls-key unless the certificate file holds the key)"
        )
    from distributed.security import Security

    return Security(
        tls_ca_file=_readable_file(tls_ca_file, "tls_ca_file (--tls-ca-file)"),
        tls_client_cert=_readable_file(tls_cert, "tls_cert (--tls-cert)"),
        tls_client_key=None if tls_key is None else _readable_file(tls_key, "tls_key (--tls-key)"),
        require_encryption=True,
    )
