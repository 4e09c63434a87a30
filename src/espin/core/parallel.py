"""Run independent tasks (RVE realizations, sweep points, fit evaluations) in parallel.

One code path for every back end: a :class:`concurrent.futures.Executor`. Locally it is a pool of
worker processes (all cores by default); on a Dask cluster it is the executor of a
``distributed.Client`` (``scheduler="tcp://host:8786"``, ``"tls://host:8786"`` with a
``security``, a ``Client``, or ``"local"`` for a ``LocalCluster`` of processes on this machine).
Each worker limits BLAS / MKL to ``blas_threads`` threads (default 1), so N workers use N cores
without oversubscription. A local worker process exits as soon as the process that started it
is gone (killed included), so no worker outlives its study.

A Dask scheduler receives the tasks as pickles and its workers run them: it must be trusted.
Over ``tcp://`` the traffic is unencrypted and unauthenticated (a warning says so for a host
other than this machine); ``tls://`` with a ``distributed.security.Security`` (see
:func:`espin.core.cluster.tls_security`) encrypts it and authenticates both ends.

A task that raises is reported as a failed :class:`TaskOutcome` (with the exception itself
where it survives pickling, and its traceback); the others go on.
"""

from __future__ import annotations

import ipaddress
import logging
import os
import pickle
import re
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from espin.core.errors import ConfigError

log = logging.getLogger(__name__)

__all__ = ["TaskOutcome", "TaskPlace", "TaskPool", "parallel_map", "default_workers", "check_pool", "check_scheduler"]


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
    exception : BaseException or None
        The exception the task raised, of its own class (None if the task returned, or if
        the exception could not be carried back from its worker: see ``error``).
    """

    index: int
    value: Any
    error: str | None = None
    traceback: str | None = None
    seconds: float = 0.0
    exception: BaseException | None = None

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


THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


PARENT_POLL_S = 0.5
"""How often [s] a local worker process checks that the process that started it is alive."""


def _start_worker(blas_threads: int | None, parent_pid: int) -> None:
    """Process initializer: thread caps in the environment (read by BLAS / MKL / OpenMP at
    load), and a watchdog that ends this worker when its parent process is gone."""
    if blas_threads is not None:
        for variable in THREAD_VARIABLES:
            os.environ[variable] = str(blas_threads)
    threading.Thread(target=_exit_with_parent, args=(parent_pid,), name="espin-parent-watchdog", daemon=True).start()


def _exit_with_parent(parent_pid: int) -> None:
    """Exit the process (never return) once ``parent_pid`` is no longer its parent.

    A killed parent cannot stop its workers, and an idle worker waits for tasks forever (every
    worker holds the task queue open), so each worker watches for itself: on POSIX a dead
    parent's children are given to another process (``os.getppid()`` changes); everywhere the
    pipe (Windows: handle) that ``multiprocessing`` keeps to the parent reports its end.
    """
    import multiprocessing

    parent = multiprocessing.parent_process()
    while os.getppid() == parent_pid and (parent is None or parent.is_alive()):
        time.sleep(PARENT_POLL_S)
    os._exit(1)  # no cleanup: nothing is left to report the tasks to


def _load_threaded_libraries() -> None:
    """Load numpy's BLAS and MKL (PARDISO) now, so that a thread limit reaches them.

    ``threadpoolctl`` only limits libraries already loaded; MKL is otherwise loaded inside the
    first task, which would then run with all cores.
    """
    import numpy  # noqa: F401 - loads its BLAS

    from espin.core.errors import EspinError
    from espin.core.mkl import load_mkl

    try:
        load_mkl()
    except EspinError:  # no MKL on this machine: SuperLU needs no threads
        pass


_Result = tuple[Any, str | None, str | None, float, BaseException | None]
"""What a task brings back: value, error text, traceback text, seconds, exception."""


def _call(fn: Callable[[Any], Any], item: Any, blas_threads: int | None) -> _Result:
    """Run one task; an exception comes back as data (the object, its text and traceback),
    never as a raised error."""
    from threadpoolctl import threadpool_limits

    if blas_threads is not None:
        _load_threaded_libraries()
    start = time.perf_counter()
    try:
        with threadpool_limits(limits=blas_threads):
            value = fn(item)
    except Exception as exc:  # noqa: BLE001 - a task's failure is data, reported to the caller
        return None, f"{type(exc).__name__}: {exc}", traceback.format_exc(), time.perf_counter() - start, exc
    return value, None, None, time.perf_counter() - start, None


def _call_in_worker(fn: Callable[[Any], Any], item: Any, blas_threads: int | None) -> _Result:
    """:func:`_call` in a worker process (local or Dask), its allocator set for numpy first;
    an exception that does not survive pickling comes back as text only."""
    from espin.core.allocator import keep_freed_memory

    keep_freed_memory()
    value, error, tb, seconds, exc = _call(fn, item, blas_threads)
    if exc is not None:
        try:
            pickle.loads(pickle.dumps(exc))
        except Exception:  # noqa: BLE001 - any failure to pickle: the text is kept
            exc = None
    return value, error, tb, seconds, exc


_ADDRESS = re.compile(r"^(?P<scheme>tcp|tls)://(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):(?P<port>\d{1,5})$")
_ADDRESS_FORMS = "'local', tcp://host:port or tls://host:port"


def check_pool(workers: int | None, scheduler: Any, blas_threads: int | None, security: Any = None) -> None:
    """Refuse, before any work, task-pool options :class:`TaskPool` would refuse.

    Raises
    ------
    ConfigError
        For workers or blas_threads < 1, or a scheduler :func:`check_scheduler` refuses.
    """
    if workers is not None and workers < 1:
        raise ConfigError(f"workers: must be >= 1 (got {workers})")
    if blas_threads is not None and blas_threads < 1:
        raise ConfigError(f"blas_threads: must be >= 1 or None (got {blas_threads})")
    check_scheduler(scheduler, security)


def check_scheduler(scheduler: Any, security: Any = None) -> None:
    """Check a ``scheduler`` (and its ``security``) before any work; connect to nothing.

    Parameters
    ----------
    scheduler
        None, ``"local"``, ``"tcp://host:port"``, ``"tls://host:port"`` (host a name, an IPv4
        address or a bracketed IPv6 address; port 1-65535) or a ``distributed.Client``.
    security
        A ``distributed.security.Security`` (TLS files), required by a ``tls://`` address and
        refused with anything else (a ``Client`` brings its own).

    Raises
    ------
    ConfigError
        Naming ``scheduler`` or ``security`` and what they accept.
    """
    if isinstance(scheduler, str):
        if scheduler == "local":
            scheme = "local"
        else:
            found = _ADDRESS.match(scheduler)
            if found is None or not 1 <= int(found["port"]) <= 65535:
                raise ConfigError(f"scheduler: expected {_ADDRESS_FORMS} (got {scheduler!r})")
            scheme = found["scheme"]
    elif scheduler is None or hasattr(scheduler, "get_executor"):
        scheme = None
    else:
        raise ConfigError(
            f"scheduler: expected {_ADDRESS_FORMS} or a distributed.Client (got a {type(scheduler).__name__})"
        )
    if scheme == "tls" and security is None:
        raise ConfigError(
            f"scheduler {scheduler}: a tls:// address needs the TLS files (--tls-ca-file and "
            "--tls-cert, with --tls-key unless the certificate file holds the key; in Python "
            "security=espin.core.cluster.tls_security(...))"
        )
    if security is not None:
        _check_security(security, scheme)


def _check_security(security: Any, scheme: str | None) -> None:
    """``security`` is a Dask Security and goes with a ``tls://`` address."""
    from distributed.security import Security

    if not isinstance(security, Security):
        raise ConfigError(f"security: expected a distributed.security.Security (got a {type(security).__name__})")
    if scheme != "tls":
        raise ConfigError(
            "security: the TLS options need a tls://host:port scheduler address (a Client "
            "brings its own security; local processes and 'local' need none)"
        )


@dataclass(frozen=True)
class TaskPlace:
    """Where tasks run, checked when made (connects to nothing): the options of :class:`TaskPool`.

    Attributes
    ----------
    workers : int or None
        Local worker processes (None: all cores; 1: in this process), or the Dask workers of
        ``scheduler="local"``.
    scheduler
        None (local processes), ``"local"``, ``"tcp://host:port"``, ``"tls://host:port"`` or a
        ``distributed.Client``.
    blas_threads : int or None
        BLAS / MKL threads per task (None: the library's own choice).
    security
        The TLS files of a ``tls://`` scheduler.

    Raises
    ------
    ConfigError
        For an invalid option (:func:`check_pool`).
    """

    workers: int | None = None
    scheduler: Any = None
    blas_threads: int | None = 1
    security: Any = None

    def __post_init__(self) -> None:
        check_pool(self.workers, self.scheduler, self.blas_threads, self.security)

    def pool(self) -> TaskPool:
        """A new task pool here (start it with ``with``)."""
        return TaskPool(self.workers, self.scheduler, self.blas_threads, self.security)


def _is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _warn_if_unencrypted(scheduler: Any) -> None:
    """Log a warning for a ``tcp://`` address of another machine."""
    found = _ADDRESS.match(scheduler) if isinstance(scheduler, str) else None
    if found is not None and found["scheme"] == "tcp" and not _is_loopback(found["host"]):
        log.warning(
            "scheduler %s: tcp:// is unencrypted and unauthenticated, and the scheduler and its "
            "workers run whatever task they are sent (pickles): use only a scheduler you trust "
            "on a network you trust, or tls:// with --tls-ca-file, --tls-cert and --tls-key",
            scheduler,
        )


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
        address ``"tcp://host:port"`` or ``"tls://host:port"``, or a ``distributed.Client``.
        A Dask scheduler and its workers run the pickled tasks: use only one you trust.
    blas_threads
        BLAS / MKL threads per task (default 1). None keeps the library's own choice.
    security
        The TLS files of a ``tls://`` scheduler, a ``distributed.security.Security`` (see
        :func:`espin.core.cluster.tls_security`); required by ``tls://``, refused otherwise.

    Raises
    ------
    ConfigError
        For an invalid option (see :func:`check_scheduler`); nothing is started.
    """

    def __init__(
        self, workers: int | None = None, scheduler: Any = None, blas_threads: int | None = 1, security: Any = None
    ):
        check_pool(workers, scheduler, blas_threads, security)
        _warn_if_unencrypted(scheduler)
        self.workers = workers if workers is not None else default_workers()
        self.scheduler = scheduler
        self.blas_threads = blas_threads
        self.security = security
        self._executor: Executor | None = None
        self._closers: list[Callable[[], object]] = []

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
                    initializer=_start_worker,
                    initargs=(self.blas_threads, os.getpid()),
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

                cluster = LocalCluster(
                    n_workers=self.workers, threads_per_worker=1, processes=True, dashboard_address=None
                )
                self._closers.append(cluster.close)
                client = Client(cluster)
            else:
                try:
                    client = Client(client, security=self.security)
                except (OSError, TimeoutError) as err:
                    raise ConfigError(
                        f"scheduler {client}: cannot connect ({err}); check the address and "
                        "that the scheduler is running and reachable"
                    ) from None
            self._closers.insert(0, client.close)
        return client.get_executor(pure=False)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[TaskOutcome]:
        """Run ``fn(item)`` for every item; yield outcomes as tasks finish (any order).

        ``fn`` must be a module-level function (it is pickled to the workers) unless the pool
        is serial. If a local worker process dies (killed, out of memory), the tasks it took
        down with the pool run again, each in a process of its own, so that only the task that
        kills its worker fails. An interrupt (Ctrl-C) or an abandoned iteration stops the
        workers at once.
        """
        items = list(items)
        if self.serial:
            for index, item in enumerate(items):
                value, error, tb, seconds, exc = _call(fn, item, self.blas_threads)
                yield TaskOutcome(index, value, error, tb, seconds, exc)
            return
        suspects: list[int] = []
        try:
            yield from self._run_pooled(fn, items, suspects)
            if suspects:
                log.warning("a worker process died; running its %d unfinished task(s) one process each", len(suspects))
                yield from self._run_isolated(fn, items, suspects)
        except BaseException:
            self._abort()
            raise

    def _run_pooled(self, fn: Callable[[Any], Any], items: list[Any], suspects: list[int]) -> Iterator[TaskOutcome]:
        """All items through the shared executor; indices lost to a broken pool go to ``suspects``."""
        executor = self._get_executor()
        futures: dict[Future, int] = {
            executor.submit(_call_in_worker, fn, item, self.blas_threads): index for index, item in enumerate(items)
        }
        for future in as_completed(futures):
            index = futures[future]
            try:
                value, error, tb, seconds, raised = future.result()
            except BrokenProcessPool:
                suspects.append(index)
                continue
            except Exception as exc:  # noqa: BLE001 - e.g. a Dask worker lost for good
                yield TaskOutcome(index, None, f"{type(exc).__name__}: {exc}", traceback.format_exc())
                continue
            yield TaskOutcome(index, value, error, tb, seconds, raised)
        if suspects:
            self._abort()  # the broken pool; a new one is made when needed

    def _run_isolated(self, fn: Callable[[Any], Any], items: list[Any], indices: list[int]) -> Iterator[TaskOutcome]:
        """Each item in a fresh single-process executor, ``workers`` at a time."""
        import multiprocessing
        from concurrent.futures import FIRST_COMPLETED, wait

        context = multiprocessing.get_context("spawn")
        queue = list(indices)
        running: dict[Future, tuple[int, ProcessPoolExecutor]] = {}
        try:
            while queue or running:
                while queue and len(running) < self.workers:
                    index = queue.pop(0)
                    solo = ProcessPoolExecutor(
                        1, mp_context=context, initializer=_start_worker, initargs=(self.blas_threads, os.getpid())
                    )
                    running[solo.submit(_call_in_worker, fn, items[index], self.blas_threads)] = (index, solo)
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in done:
                    index, solo = running.pop(future)
                    solo.shutdown(wait=False)
                    try:
                        value, error, tb, seconds, raised = future.result()
                    except BrokenProcessPool:
                        yield TaskOutcome(index, None, WORKER_DIED, None)
                        continue
                    yield TaskOutcome(index, value, error, tb, seconds, raised)
        finally:
            for _, solo in running.values():
                _terminate(solo)

    def _abort(self) -> None:
        """Stop the workers now: queued tasks are cancelled, running ones are killed."""
        if self._executor is not None:
            _terminate(self._executor)
            self._executor = None


WORKER_DIED = (
    "worker process died while running this task (killed, or out of memory?); in a script, "
    'start studies under `if __name__ == "__main__":` (worker processes import the script)'
)


def _terminate(executor: Executor) -> None:
    """Shut an executor down without waiting; kill the processes of a local pool."""
    processes = list((getattr(executor, "_processes", None) or {}).values())
    if isinstance(executor, ProcessPoolExecutor):
        executor.shutdown(wait=False, cancel_futures=True)
    else:  # Dask's ClientExecutor
        executor.shutdown(wait=False)
    for process in processes:
        process.terminate()


def parallel_map(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    workers: int | None = None,
    scheduler: Any = None,
    blas_threads: int | None = 1,
    security: Any = None,
) -> list[TaskOutcome]:
    """All outcomes of ``fn`` over ``items``, in the order of ``items`` (see :class:`TaskPool`)."""
    with TaskPool(workers, scheduler, blas_threads, security) as pool:
        return sorted(pool.map(fn, items), key=lambda outcome: outcome.index)
