"""The batch job script that dask-jobqueue generates for espin workers (no job is submitted)."""

from __future__ import annotations

import sys

import pytest

from espin.core.cluster import THREAD_VARIABLES, jobqueue_cluster
from espin.core.errors import ConfigError


@pytest.mark.parametrize("system, directives", [
    ("slurm", ["#SBATCH -p normal", "#SBATCH -A proj42", "#SBATCH --cpus-per-task=4", "#SBATCH -t 02:00:00"]),
    ("pbs", ["#PBS -q normal", "#PBS -A proj42", "#PBS -l walltime=02:00:00"]),
])
def test_job_script(system, directives):
    cluster = jobqueue_cluster(system, workers_per_job=4, memory_per_worker="3GB", walltime="02:00:00",
                               queue="normal", account="proj42", prologue=["source ~/espin/.venv/bin/activate"])
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    for line in directives:
        assert line in script, line
    for variable in THREAD_VARIABLES:
        assert f"export {variable}=1" in script
    assert script.index("source ~/espin/.venv/bin/activate") < script.index("dask_worker")
    assert f"{sys.executable} -m distributed.cli.dask_worker" in script
    assert "--nthreads 1" in script and "--nworkers 4" in script
    assert len(cluster.worker_spec) == 0  # nothing submitted


@pytest.mark.parametrize("kwargs, key", [
    ({"system": "lsf"}, "system"),
    ({"system": "slurm", "workers_per_job": 0}, "workers_per_job"),
    ({"system": "slurm", "memory_per_worker": "lots"}, "memory_per_worker"),
    ({"system": "slurm", "walltime": "2h"}, "walltime"),
])
def test_bad_options_named(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        jobqueue_cluster(**kwargs)


def script_of(system, walltime):
    cluster = jobqueue_cluster(system, walltime=walltime)
    try:
        return cluster.job_script()
    finally:
        cluster.close()


@pytest.mark.parametrize("system, walltime, directive", [
    ("slurm", "1-02:00:00", "#SBATCH -t 1-02:00:00"),     # Slurm's own days syntax, as given
    ("pbs", "1-02:00:00", "#PBS -l walltime=26:00:00"),   # PBS has no days field: hours
    ("pbs", "3-00:30:15", "#PBS -l walltime=72:30:15"),
    ("slurm", "36:00:00", "#SBATCH -t 36:00:00"),         # hours may exceed 24
    ("pbs", "36:00:00", "#PBS -l walltime=36:00:00"),
])
def test_walltime_directive(system, walltime, directive):
    lines = script_of(system, walltime).splitlines()
    time_lines = [line for line in lines if line.startswith(("#SBATCH -t", "#PBS -l walltime"))]
    assert time_lines == [directive]


@pytest.mark.parametrize("walltime", [
    "04:00",        # Slurm reads MM:SS: 4 minutes, not 4 hours
    "4",            # Slurm reads minutes
    "1-02:00",      # Slurm reads D-HH:MM
    "02:60:00",     # minutes out of range
    "02:00:75",     # seconds out of range
    "1-24:00:00",   # hours with days: 0-23
    "00:00:00",     # zero: no limit on Slurm
    "0-00:00:00",
    " 02:00:00",
])
@pytest.mark.parametrize("system", ["slurm", "pbs"])
def test_bad_walltime_refused(system, walltime):
    with pytest.raises(ConfigError, match=r"walltime: .*(HH:MM:SS|longer than)") as info:
        jobqueue_cluster(system, walltime=walltime)
    assert repr(walltime) in str(info.value)
