"""Run independent tasks (RVE realizations, sweep points, fit evaluations) in parallel.

One code path for every back end: a :class:`concurrent.futures.Executor`. Locally it is a pool of
worker processes (all cores by default); on a Dask cluster it is the executor of a
``distributed.Client`` (``scheduler="tcp://host:8786"``, a ``Client``, or ``"local"`` for a
``LocalCluster`` of processes on this machine). Each worker limits BLAS / MKL to
``blas_threads`` threads (default 1), so N workers use N cores without oversubscription.

A task that raises is reported as a failed :class:`TaskOutcome` (with its traceback); the
others go on.
"""

from __future__ import annotations

import os
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from espin.errors import ConfigError

__all__ = ["TaskOutcome", "TaskPool", "parallel_map", "default_workers"]


@dataclass(frozen=True)
class TaskOutcome:
    """What became of one task.

    Attributes
    ----------
    index : int
        Position of the task in the submitted sequence.
    value : Any
        The task's return value (None if it failed).
    error : str or None
        ``"ExceptionType: message"`` if the task raised, else None.
    traceback : str or None
        The formatted traceback of a failed task.
    seconds : float [s]
        Wall time the task took in its worker.
    """

    index: int
    value: Any
    error: str | None = None
    traceback: str | None = None
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        """True when the task returned a value."""
        return self.error is None


def default_workers() -> int:
    """Cores this process may use (the affinity mask where the OS tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def _limit_threads(blas_threads: int | None) -> None:
    """Process initializer: cap BLAS / OpenMP / MKL threads for the life of the worker."""
    if blas_threads is None:
        return
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=blas_threads)


def _call(fn: Callable[[Any], Any], item: Any, blas_threads: int | None) -> tuple[Any, str | None, str | None, float]:
    """Run one task in a worker; exceptions come back as text, never as a raised error."""
    from threadpoolctl import threadpool_limits

    start = time.perf_counter()
    try:
        with threadpool_limits(limits=blas_threads):
            value = fn(item)
    except Exception as exc:  # noqa: BLE001 - a task's failure is data, reported to the caller
        return None, f"{type(exc).__name__}: {exc}", traceback.format_exc(), time.perf_counter() - start
    return value, None, None, time.perf_counter() - start


class TaskPool:
    """Workers that run tasks; a context manager, reusable for many :meth:`map` calls.

    Parameters
    ----------
    workers
        Local worker processes (default: all cores). ``1`` runs tasks one after another in
        this process (no pickling). Ignored by a Dask scheduler given as an address or Client;
        for ``scheduler="local"`` it is the number of Dask workers.
    scheduler
        None (local processes), ``"local"`` (a Dask ``LocalCluster`` of processes), a scheduler
        address such as ``"tcp://host:8786"``, or a ``distributed.Client``.
    blas_threads
        BLAS / MKL threads per task (default 1). None keeps the library's own choice.
    """

    def __init__(self, workers: int | None = None, scheduler: Any = None, blas_threads: int | None = 1):
        if workers is not None and workers < 1:
            raise ConfigError(f"workers: must be >= 1 (got {workers})")
        if blas_threads is not None and blas_threads < 1:
            raise ConfigError(f"blas_threads: must be >= 1 or None (got {blas_threads})")
        if isinstance(scheduler, str) and scheduler != "local" and "://" not in scheduler:
            raise ConfigError(
                f"scheduler: expected 'local' or an address such as tcp://host:8786 (got {scheduler!r})"
            )
        self.workers = workers if workers is not None else default_workers()
        self.scheduler = scheduler
        self.blas_threads = blas_threads
        self._executor: Executor | None = None
        self._closers: list[Callable[[], None]] = []

    @property
    def serial(self) -> bool:
        """True when tasks run in this process, one after another."""
        return self.scheduler is None and self.workers == 1

    @property
    def description(self) -> str:
        """Where the tasks run, for logs and reports."""
        if self.serial:
            return "serial (this process)"
        if self.scheduler is None:
            return f"{self.workers} local processes, {self.blas_threads or 'default'} BLAS thread(s) each"
        return f"Dask scheduler {self.scheduler}"

    def __enter__(self) -> TaskPool:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        """Shut the workers (and a cluster this pool started) down."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)  # pending futures were cancelled by map()
            self._executor = None
        while self._closers:
            self._closers.pop()()

    def _get_executor(self) -> Executor:
        if self._executor is None:
            if self.scheduler is None:
                import multiprocessing

                # spawn: no fork of a parent whose MKL / OpenMP threads are already running.
                self._executor = ProcessPoolExecutor(
                    max_workers=self.workers,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=_limit_threads,
                    initargs=(self.blas_threads,),
                )
            else:
                self._executor = self._dask_executor()
        return self._executor

    def _dask_executor(self) -> Executor:
        from distributed import Client

        client = self.scheduler
        if isinstance(client, str):
            if client == "local":
                from distributed import LocalCluster

                cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
                self._closers.append(cluster.close)
                client = Client(cluster)
            else:
                client = Client(client)
            self._closers.insert(0, client.close)
        return client.get_executor(pure=False)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[TaskOutcome]:
        """Run ``fn(item)`` for every item; yield outcomes as tasks finish (any order).

        ``fn`` must be a module-level function (it is pickled to the workers) unless the pool
        is serial.
        """
        items = list(items)
        if self.serial:
            for index, item in enumerate(items):
                yield TaskOutcome(index, *_call(fn, item, self.blas_threads))
            return
        executor = self._get_executor()
        futures: dict[Future, int] = {
            executor.submit(_call, fn, item, self.blas_threads): index for index, item in enumerate(items)
        }
        try:
            for future in as_completed(futures):
                index = futures[future]
                try:
                    value, error, tb, seconds = future.result()
                except BrokenProcessPool as exc:
                    # A worker died (killed, out of memory): its tasks fail, the pool is rebuilt.
                    self._executor = None
                    yield TaskOutcome(index, None, f"worker process died: {exc}", None)
                    continue
                except Exception as exc:  # noqa: BLE001 - a lost Dask worker, say
                    yield TaskOutcome(index, None, f"{type(exc).__name__}: {exc}", traceback.format_exc())
                    continue
                yield TaskOutcome(index, value, error, tb, seconds)
        finally:
            for future in futures:
                future.cancel()


def parallel_map(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    workers: int | None = None,
    scheduler: Any = None,
    blas_threads: int | None = 1,
) -> list[TaskOutcome]:
    """All outcomes of ``fn`` over ``items``, in the order of ``items`` (see :class:`TaskPool`)."""
    with TaskPool(workers, scheduler, blas_threads) as pool:
        return sorted(pool.map(fn, items), key=lambda outcome: outcome.index)
