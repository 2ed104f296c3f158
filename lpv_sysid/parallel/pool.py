"""``map_tasks``: independent tasks in order, serially or on a pool of single-threaded-BLAS
workers (the face :mod:`lpv_sysid.parallel` documents the contract)."""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any, Callable, Generic, Iterable, Iterator, Optional, TypeVar

from lpv_sysid.errors import ConfigError

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")

#: where the tasks run when more than one worker is asked for
BACKENDS = ("process", "dask")

#: the thread-count variables of OpenBLAS, OpenMP builds and MKL (read when BLAS loads)
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def default_workers() -> int:
    """Cores this process may run on (its CPU affinity; ``os.cpu_count()`` where the platform
    has no affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def resolve_workers(workers: Optional[int]) -> int:
    """``workers`` checked (an integer >= 1), ``None`` -> :func:`default_workers`."""
    if workers is None:
        return default_workers()
    if isinstance(workers, bool) or int(workers) != workers or workers < 1:
        raise ConfigError(f"workers must be an integer >= 1, got {workers!r}")
    return int(workers)


@contextlib.contextmanager
def single_thread_blas_environment() -> Iterator[None]:
    """:data:`BLAS_THREAD_VARIABLES` = 1 in ``os.environ`` while the block runs (processes
    started in it inherit them), restored afterwards."""
    saved = {k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES}
    os.environ.update({k: "1" for k in BLAS_THREAD_VARIABLES})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS of the numpy/scipy already loaded in this process limited to one thread while the
    block runs (threadpoolctl, requirements.txt); without threadpoolctl the block runs as is
    (the CLI's studies start with ``OPENBLAS_NUM_THREADS=1``, lpv_sysid.cli.main)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is in requirements.txt
        log.debug("threadpoolctl not installed: BLAS threads of this process left as they are")
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def _limit_worker_blas() -> None:
    """Worker initializer: one BLAS thread also for a BLAS loaded before the environment was
    read (a ``__main__`` that imported numpy); the environment covers the rest."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is in requirements.txt
        return
    threadpool_limits(limits=1, user_api="blas")


def start_method() -> str:
    """``fork`` where the platform has it and this process runs no other Python thread (the
    workers start with every module already loaded: no second import of numpy/scipy per worker;
    a fork copies only the calling thread), else ``spawn`` (a fresh interpreter, which reads
    the BLAS variables of :func:`single_thread_blas_environment` when it loads numpy)."""
    if "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1:
        return "fork"
    return "spawn"


class Batch(Generic[R]):
    """Tasks handed out by :func:`start_tasks`; :meth:`results` collects them in task order.

    A context manager: leaving the block without :meth:`results` (an exception in the work done
    meanwhile) cancels the tasks not yet started and stops the workers."""

    def __init__(
        self,
        fn: Callable[[T], R],
        items: list[T],
        n: int,
        backend: str,
    ) -> None:
        self._fn: Callable[[Any], R] = fn
        self._items: list[Any] = items
        self._n = n
        self._backend = backend
        self._ex: Optional[ProcessPoolExecutor] = None
        self._futures: list[Future[R]] = []
        if n > 1 and backend == "process":
            method = start_method()
            log.debug("%d tasks on %d %sed one-BLAS-thread workers", len(items), n, method)
            with single_thread_blas_environment():
                self._ex = ProcessPoolExecutor(
                    max_workers=n,
                    mp_context=multiprocessing.get_context(method),
                    initializer=_limit_worker_blas,
                )
                try:
                    self._futures = [self._ex.submit(fn, t) for t in items]
                except BaseException:
                    self.cancel()
                    raise

    def results(self, on_result: Optional[Callable[[int, R], Any]] = None) -> list[R]:
        """Every task's result in task order (``on_result(i, result)`` called here as each
        arrives); a task's exception is raised here and the tasks not yet started cancelled."""
        out: list[R] = []
        try:
            if self._ex is not None:
                for f in self._futures:
                    out.append(f.result())
                    if on_result is not None:
                        on_result(len(out) - 1, out[-1])
                self._ex.shutdown(wait=True)
                self._ex = None
                return out
            if self._backend == "dask" and self._n > 1:
                out = _dask_map(self._fn, self._items, self._n)
            else:
                with one_blas_thread():
                    for t in self._items:
                        out.append(self._fn(t))
                        if on_result is not None:
                            on_result(len(out) - 1, out[-1])
                return out
            if on_result is not None:
                for i, r in enumerate(out):
                    on_result(i, r)
            return out
        except BaseException:
            self.cancel()
            raise

    def cancel(self) -> None:
        """Cancel the tasks not yet started and stop the workers (waits for running ones)."""
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None

    def __del__(self) -> None:  # dropped without results(): an exception in between
        if getattr(self, "_ex", None) is not None:
            self._ex.shutdown(wait=False, cancel_futures=True)  # type: ignore[union-attr]

    def __enter__(self) -> "Batch[R]":
        return self

    def __exit__(self, *exc: object) -> None:
        self.cancel()


def start_tasks(
    fn: Callable[[T], R],
    tasks: Iterable[T],
    workers: Optional[int] = None,
    backend: str = "process",
) -> Batch[R]:
    """Hand ``fn(t)`` for each task to ``workers`` processes (``None``: every core) and return
    at once: the caller does other work while they run, then calls :meth:`Batch.results`.
    With one worker (or one task) nothing runs until :meth:`Batch.results`, which computes the
    tasks here in order. Contract of :func:`map_tasks`."""
    items = list(tasks)
    n = resolve_workers(workers)
    if backend not in BACKENDS:
        raise ConfigError(f"parallel backend must be one of {BACKENDS}, got {backend!r}")
    return Batch(fn, items, 1 if len(items) <= 1 else min(n, len(items)), backend)


def map_tasks(
    fn: Callable[[T], R],
    tasks: Iterable[T],
    workers: Optional[int] = None,
    backend: str = "process",
    on_result: Optional[Callable[[int, R], Any]] = None,
) -> list[R]:
    """``[fn(t) for t in tasks]``, on ``workers`` processes (``None``: every core).

    ``fn`` must be a module-level function and tasks and results picklable (they cross process
    boundaries). One worker or one task: run here, in order, with one BLAS thread
    (:func:`one_blas_thread`) like every worker -- so the numbers do not depend on
    ``workers``. ``on_result(i, result)`` is called here for each task in task order as the
    results arrive (progress lines). A task's exception is raised here; the tasks not yet
    started are cancelled."""
    with start_tasks(fn, tasks, workers, backend) as batch:
        return batch.results(on_result)


def _dask_map(fn: Callable[[T], R], items: list[T], n: int) -> list[R]:
    """The tasks as ``dask.delayed`` calls: on the active ``dask.distributed`` client when there
    is one (a cluster a user started), else Dask's local process scheduler with ``n`` workers."""
    try:
        import dask
    except ImportError:
        raise ConfigError(
            "parallel backend 'dask': dask is not installed (pip install dask, or use the "
            "default 'process' backend)"
        ) from None
    kwargs: dict[str, Any] = {"scheduler": "processes", "num_workers": n}
    try:
        from distributed import default_client

        default_client()
        kwargs = {}
    except (ImportError, ValueError):
        pass
    with single_thread_blas_environment():
        return list(dask.compute(*[dask.delayed(fn)(t) for t in items], **kwargs))
