"""Independent tasks of the offline studies on every core (issue 27 item 4).

:func:`map_tasks` runs ``fn(task)`` for each task and returns the results in task order: in
this process when one worker is asked for (or there is one task), else in a process pool
(``concurrent.futures.ProcessPoolExecutor``; workers forked where the platform allows it, so
they start with the caller's modules loaded, else spawned) or, with ``backend="dask"``, on Dask
when a user has installed it (a ``dask.distributed`` client when one is active, else Dask's
local process scheduler). :func:`start_tasks` hands the tasks out and returns at once (a
:class:`Batch`): the caller does its own serial work while the workers run, then collects.

Every task runs with one BLAS thread: the pool's workers are started with
``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` = 1 in their environment
(read when a spawned worker loads numpy) and limit any BLAS already loaded with threadpoolctl;
the serial path runs its tasks under the same threadpoolctl limit. The studies' linear algebra
is many small problems where a second BLAS thread only spins, and a BLAS reduction split over
threads rounds differently: one thread everywhere is what makes the pooled numbers equal the
serial ones.

The results are bit-identical to the serial run: every task is a pure function of its
arguments (its own seeded random stream, no state shared between tasks), and the callers put
every random draw either in the task or before the tasks are handed out.
:func:`default_workers` is the number of cores this process may run on; :func:`resolve_workers`
checks a ``workers`` argument (``None``: every core). :func:`run_in_child` runs one call in a
spawned process so that Ctrl-C reaches the caller while a native solver holds SIGINT.
"""

from __future__ import annotations

from lpv_sysid.parallel.child import run_in_child
from lpv_sysid.parallel.pool import (
    BACKENDS,
    Batch,
    default_workers,
    map_tasks,
    resolve_workers,
    start_tasks,
)

__all__ = [
    "BACKENDS",
    "Batch",
    "default_workers",
    "map_tasks",
    "resolve_workers",
    "run_in_child",
    "start_tasks",
]
