"""``map_tasks``: independent tasks in order, serially or on a pool of single-threaded-BLAS
workers (the face :mod:`lpv_sysid.parallel` documents the contract)."""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any, Callable, Iterable, Iterator, Optional, TypeVar

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
    items = list(tasks)
    n = resolve_workers(workers)
    if backend not in BACKENDS:
        raise ConfigError(f"parallel backend must be one of {BACKENDS}, got {backend!r}")
    if n == 1 or len(items) <= 1:
        out: list[R] = []
        with one_blas_thread():
            for i, t in enumerate(items):
                out.append(fn(t))
                if on_result is not None:
                    on_result(i, out[-1])
        return out
    if backend == "dask":
        results = _dask_map(fn, items, n)
        if on_result is not None:
            for i, r in enumerate(results):
                on_result(i, r)
        return results
    return _process_map(fn, items, min(n, len(items)), on_result)


def _process_map(
    fn: Callable[[T], R],
    items: list[T],
    n: int,
    on_result: Optional[Callable[[int, R], Any]],
) -> list[R]:
    log.debug("%d tasks on %d spawned single-threaded-BLAS workers", len(items), n)
    ctx = multiprocessing.get_context("spawn")  # a fresh interpreter reads the BLAS variables
    with single_thread_blas_environment():
        ex = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_limit_worker_blas)
        try:
            futures: list[Future[R]] = [ex.submit(fn, t) for t in items]
            out: list[R] = []
            for i, f in enumerate(futures):
                out.append(f.result())
                if on_result is not None:
                    on_result(i, out[-1])
        except BaseException:
            ex.shutdown(wait=True, cancel_futures=True)
            raise
        ex.shutdown(wait=True)
    return out


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
