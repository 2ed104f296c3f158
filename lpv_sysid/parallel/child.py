"""``run_in_child``: one call in a spawned process, so that Ctrl-C reaches the caller.

The native LMI solvers take SIGINT for themselves while they solve: SCS installs its own
handler and ends the solve as "failed" (cvxpy's SolverError), Clarabel finishes and the signal
is gone. In ``lpv-sysid chain`` the vehicle hovers in HOLD while the synthesis runs (minutes on
the rate plant's 128 systems); an operator's Ctrl-C there was lost and the chain went on to
phase 2 (seen on PX4 SITL: two SIGINTs during the region search, then "phase-2 flight under the
LPV law"). Run in a child, the solver keeps its handler in the child and the caller, waiting on
a pipe in Python, gets its KeyboardInterrupt, ends the child and re-raises it.

>>> run_in_child(divmod, 7, 2)
(3, 1)
"""

from __future__ import annotations

import logging
import multiprocessing
from typing import Any, Callable

log = logging.getLogger(__name__)

#: seconds between the caller's looks at the pipe (it is interruptible in between)
POLL_S = 0.2
#: seconds a terminated child is given before it is killed
TERMINATE_S = 5.0


def run_in_child(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a spawned process (``fn`` importable by name, arguments and result
    picklable); its exception is raised here. A KeyboardInterrupt (or any exception) in the
    caller while it waits terminates the child (SIGTERM, SIGKILL after :data:`TERMINATE_S`) and
    is re-raised. The child logs at the caller's root level to the same stderr."""
    ctx = multiprocessing.get_context("spawn")
    receive, send = ctx.Pipe(duplex=False)
    child = ctx.Process(
        target=_child_main,
        args=(send, fn, args, logging.getLogger().getEffectiveLevel()),
        name=f"lpv_sysid child: {getattr(fn, '__qualname__', fn)}",
        daemon=True,
    )
    child.start()
    send.close()
    try:
        while not receive.poll(POLL_S):
            if not child.is_alive() and not receive.poll(0):
                raise RuntimeError(
                    f"{child.name} ended (exit code {child.exitcode}) without a result"
                )
        ok, payload = receive.recv()
    except BaseException:
        _stop(child)
        raise
    finally:
        receive.close()
    child.join(TERMINATE_S)
    if ok:
        return payload
    raise payload


def _stop(child) -> None:
    if child.is_alive():
        log.info("stopping %s (pid %s)", child.name, child.pid)
        child.terminate()
        child.join(TERMINATE_S)
        if child.is_alive():
            child.kill()
            child.join(TERMINATE_S)


def _child_main(send, fn, args, level: int) -> None:
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        out = (True, fn(*args))
    except BaseException as exc:  # the caller raises it (a KeyboardInterrupt of the group too)
        out = (False, _picklable(exc))
    try:
        send.send(out)
    except Exception as exc:  # an unpicklable result
        send.send((False, RuntimeError(f"{fn!r}: result not transferable: {exc}")))
    finally:
        send.close()


def _picklable(exc: BaseException) -> BaseException:
    import pickle

    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
