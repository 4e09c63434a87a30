"""The task pool: serial, local processes and Dask give the same outcomes; failures stay local."""

from __future__ import annotations

import sys

import pytest

from espin.core.errors import ConfigError
from espin.core.parallel import TaskPool, parallel_map


def square_or_fail(x: int) -> int:
    if x == 3:
        raise ValueError("three is refused")
    return x * x


def thread_counts(_: object) -> dict[str, int]:
    """Threads of every BLAS / MKL / OpenMP library loaded in the worker, as a task sees them."""
    from threadpoolctl import threadpool_info

    from espin.core.errors import EspinError
    from espin.core.mkl import load_mkl

    try:
        load_mkl()  # what a tensile task loads (PARDISO), loaded here inside the task
    except EspinError:
        pass
    return {pool["internal_api"]: pool["num_threads"] for pool in threadpool_info()}


def die_on_one(x: int) -> int:
    import os
    import time

    if x == 1:
        os._exit(9)  # a worker killed from outside (out of memory, say)
    time.sleep(0.2)
    return x


def sleep_unless_zero(x: int) -> int:
    import time

    if x:
        time.sleep(60)
    return x


@pytest.mark.parametrize("options", [
    {"workers": 1},
    {"workers": 2},
    pytest.param({"workers": 2, "scheduler": "local"}, id="dask-local"),
])
@pytest.mark.slow
def test_outcomes_in_order_and_failure_isolated(options):
    outcomes = parallel_map(square_or_fail, range(6), **options)
    assert [o.index for o in outcomes] == list(range(6))
    assert [o.value for o in outcomes if o.ok] == [0, 1, 4, 16, 25]
    failed = [o for o in outcomes if not o.ok]
    assert len(failed) == 1 and failed[0].index == 3
    assert failed[0].error == "ValueError: three is refused"
    assert "square_or_fail" in failed[0].traceback


@pytest.mark.slow
def test_one_blas_thread_per_worker_from_the_first_task():
    outcomes = parallel_map(thread_counts, range(4), workers=2)
    assert all(o.ok for o in outcomes)
    for outcome in outcomes:  # the first task of each worker included
        assert outcome.value and set(outcome.value.values()) == {1}, outcome.value


@pytest.mark.slow
def test_a_dying_worker_fails_only_its_task():
    outcomes = parallel_map(die_on_one, range(6), workers=2)
    assert [o.index for o in outcomes if not o.ok] == [1]
    assert "worker process died" in outcomes[1].error
    assert [o.value for o in outcomes if o.ok] == [0, 2, 3, 4, 5]


@pytest.mark.slow
def test_abandoned_run_stops_its_workers():
    import time

    with TaskPool(workers=2) as pool:
        outcomes = pool.map(sleep_unless_zero, [0, 1, 2, 3])
        assert next(outcomes).value == 0
        start = time.perf_counter()
        outcomes.close()  # as on Ctrl-C: the 60 s tasks are killed, not awaited
    assert time.perf_counter() - start < 10


@pytest.mark.slow
def test_pool_reused_across_maps():
    with TaskPool(workers=2) as pool:
        first = sorted(o.value for o in pool.map(square_or_fail, [1, 2]))
        second = sorted(o.value for o in pool.map(square_or_fail, [4, 5]))
    assert first == [1, 4] and second == [16, 25]


@pytest.mark.parametrize("kwargs, key", [
    ({"workers": 0}, "workers"),
    ({"blas_threads": 0}, "blas_threads"),
    ({"scheduler": "myhost:8786"}, "scheduler"),
])
def test_bad_options_named(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        TaskPool(**kwargs)


@pytest.mark.slow
def test_scheduler_address_of_a_running_cluster():
    """--scheduler tcp://host:port: the same code path as a remote Dask cluster."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://")
        outcomes = parallel_map(square_or_fail, range(4), scheduler=cluster.scheduler_address)
    assert [o.value for o in outcomes] == [0, 1, 4, None]
    assert outcomes[3].error == "ValueError: three is refused"


def temporaries_page_faults(_: object) -> tuple[int, str | None]:
    """Minor page faults of 300 numpy temporaries of 1.6 MB, one alive at a time, and the
    worker's MALLOC_TRIM_THRESHOLD_ (Dask's nanny sets it)."""
    import os
    import resource

    import numpy as np

    x = np.ones(200_000)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    total = 0.0
    for _ in range(300):
        total += float((x * 2.0)[0])
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before, os.environ.get("MALLOC_TRIM_THRESHOLD_")


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_dask_workers_reuse_freed_temporaries_as_local_workers_do():
    """With MALLOC_TRIM_THRESHOLD_ set (as by Dask) glibc maps and faults in every temporary
    over 128 KiB anew: about 118k faults here instead of about 2k. The task pool fixes the
    thresholds in every worker, so a Dask worker faults no more than twice a local one."""
    (local,) = parallel_map(temporaries_page_faults, [0], workers=2)
    (dask,) = parallel_map(temporaries_page_faults, [0], workers=1, scheduler="local")
    assert dask.value[1] is not None, "the Dask worker no longer sets MALLOC_TRIM_THRESHOLD_"
    assert dask.value[0] <= 2 * max(local.value[0], 1000), (dask.value, local.value)
