"""The task pool: serial, local processes and Dask give the same outcomes; failures stay local."""

from __future__ import annotations

import pytest

from espin.errors import ConfigError
from espin.parallel import TaskPool, parallel_map


def square_or_fail(x: int) -> int:
    if x == 3:
        raise ValueError("three is refused")
    return x * x


def blas_thread_count(_: object) -> int:
    from threadpoolctl import threadpool_info

    return max((pool["num_threads"] for pool in threadpool_info()), default=1)


@pytest.mark.parametrize("options", [
    {"workers": 1},
    {"workers": 2},
    pytest.param({"workers": 2, "scheduler": "local"}, id="dask-local"),
])
def test_outcomes_in_order_and_failure_isolated(options):
    outcomes = parallel_map(square_or_fail, range(6), **options)
    assert [o.index for o in outcomes] == list(range(6))
    assert [o.value for o in outcomes if o.ok] == [0, 1, 4, 16, 25]
    failed = [o for o in outcomes if not o.ok]
    assert len(failed) == 1 and failed[0].index == 3
    assert failed[0].error == "ValueError: three is refused"
    assert "square_or_fail" in failed[0].traceback


def test_one_blas_thread_per_worker():
    counts = [o.value for o in parallel_map(blas_thread_count, range(2), workers=2)]
    assert counts == [1, 1]


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
