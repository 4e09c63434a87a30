"""Dask clusters on HPC batch systems (Slurm, PBS) for espin ensembles, via dask-jobqueue.

Each batch job starts ``workers_per_job`` Dask worker processes with one thread each and BLAS /
MKL / OpenMP limited to one thread, the same layout as espin's local process pool. Pass the
cluster's client to any study as ``scheduler``::

    from distributed import Client
    from espin.cluster import jobqueue_cluster

    cluster = jobqueue_cluster("slurm", workers_per_job=8, memory_per_worker="3GB",
                               walltime="04:00:00", queue="normal", account="my_project")
    print(cluster.job_script())          # the batch script each job runs: read it first
    cluster.scale(jobs=4)                # submit 4 jobs (32 workers)
    espin.studies.sweep("plla", grid, realizations=10, folder="sweep", scheduler=Client(cluster))

"""

from __future__ import annotations

import re
from typing import Any

from espin.errors import ConfigError

__all__ = ["jobqueue_cluster", "BATCH_SYSTEMS", "THREAD_VARIABLES"]

BATCH_SYSTEMS = ("slurm", "pbs")
"""Batch systems espin configures (any other dask-jobqueue cluster works as a plain Client)."""

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
"""Exported as 1 in every job, so each worker process uses one core."""

_MEMORY = re.compile(r"^\d+(\.\d+)?\s*(B|[KMGT]i?B)$", re.IGNORECASE)
_WALLTIME = re.compile(r"^(\d+-)?\d{1,3}:\d{2}(:\d{2})?$")


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
        Job time limit, ``HH:MM:SS`` (or ``D-HH:MM:SS``).
    queue, account
        Partition / queue and project account, if the site needs them.
    python
        The Python of the environment where espin is installed on the compute nodes
        (default: this interpreter).
    prologue
        Extra shell lines run before the workers start (e.g. ``module load python``,
        ``source .venv/bin/activate``).
    **options
        Passed on to the dask-jobqueue cluster class (``job_extra_directives`` ...).

    Returns
    -------
    dask_jobqueue.SLURMCluster or dask_jobqueue.PBSCluster
        ``.job_script()`` shows the batch script; ``.scale(jobs=n)`` submits n jobs.
    """
    if system not in BATCH_SYSTEMS:
        raise ConfigError(f"system: one of {', '.join(BATCH_SYSTEMS)} (got {system!r})")
    if not isinstance(workers_per_job, int) or workers_per_job < 1:
        raise ConfigError(f"workers_per_job: must be an integer >= 1 (got {workers_per_job!r})")
    if not _MEMORY.match(memory_per_worker):
        raise ConfigError(f"memory_per_worker: a size such as 3GB or 3GiB (got {memory_per_worker!r})")
    if not _WALLTIME.match(walltime):
        raise ConfigError(f"walltime: HH:MM:SS or D-HH:MM:SS (got {walltime!r})")
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
