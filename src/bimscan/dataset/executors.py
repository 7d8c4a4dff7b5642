"""Where dataset tasks run: local processes (default), Ray tasks, or the calling process.

Every executor runs plain functions on picklable task objects and hands back results as they
finish; the build driver does not care where. ``EXECUTORS`` maps the names of ``--executor``:

- ``local``: a pool of ``workers`` processes started with ``spawn`` (Open3D and OpenMP are not
  fork-safe). Workers report scanned pulses through a queue for the progress bar, and end
  themselves within a second when the driver dies (a killed build leaves no process behind).
- ``ray``: one Ray task per job on a local Ray instance, or on a running cluster with
  ``address`` (the dataset folder must then be on storage every node sees). Ray is imported
  only here, inside the functions.
- ``serial``: runs every task in the calling process, one after the other (debugging, tests).
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from typing import Any, Protocol

from bimscan.errors import ConfigError, DatasetError
from bimscan.processes import die_with_parent, quiet_resource_tracker

TaskFunction = Callable[[Any], Any]

# Set in each worker process by the local executor's initializer.
_WORKER_STATE: dict[str, Any] = {"queue": None, "parent": None}


def report_pulses(n: int) -> None:
    """Called by tasks as they scan: forwards pulse counts to the driver's progress bar."""
    channel = _WORKER_STATE["queue"]
    if channel is not None:
        channel.put_nowait(n)


def driver_alive() -> bool:
    """False in a local worker whose driver process has died (the worker was re-parented)."""
    parent = _WORKER_STATE["parent"]
    return parent is None or os.getppid() == parent


def _init_worker(channel: Any, parent: int, environment: dict[str, str]) -> None:
    # Ctrl-C reaches the whole process group: the driver handles it (one line, and it ends the
    # workers), so a worker does not print a traceback of its own
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()
    _WORKER_STATE["queue"] = channel
    _WORKER_STATE["parent"] = parent
    os.environ.update(environment)
    threading.Thread(target=_exit_with_driver, args=(parent,), name="bimscan-driver-watch", daemon=True).start()


def _exit_with_driver(parent: int) -> None:
    """End this worker when the driver dies (kill -9): an idle worker would wait on its queue forever.

    A task it is running is cut short; its staging folder is swept by the next build.
    """
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)


class TaskExecutor(Protocol):
    """Runs ``fn(task)`` somewhere; ``wait`` returns finished (handle, result or exception) pairs."""

    name: str

    def submit(self, fn: TaskFunction, task: Any, *, cpus: int) -> Any: ...
    def wait(self, handles: list[Any], *, timeout: float) -> list[tuple[Any, Any, BaseException | None]]: ...
    def drain_pulses(self) -> int: ...
    def close(self, *, cancel: bool = False) -> None: ...


class SerialExecutor:
    """Runs each task in the calling process when it is waited for."""

    name = "serial"

    def __init__(self, *, workers: int = 1, environment: dict[str, str] | None = None, address: str | None = None) -> None:
        self._pending: dict[int, tuple[TaskFunction, Any]] = {}
        self._next = 0
        if environment:
            os.environ.update(environment)

    def submit(self, fn: TaskFunction, task: Any, *, cpus: int) -> int:
        handle = self._next
        self._next += 1
        self._pending[handle] = (fn, task)
        return handle

    def wait(self, handles: list[int], *, timeout: float) -> list[tuple[int, Any, BaseException | None]]:
        for handle in handles:
            if handle in self._pending:
                fn, task = self._pending.pop(handle)
                try:
                    return [(handle, fn(task), None)]
                except Exception as exc:  # the driver turns a task's crash into a failed unit
                    return [(handle, None, exc)]
        return []

    def drain_pulses(self) -> int:
        return 0

    def close(self, *, cancel: bool = False) -> None:
        self._pending.clear()


class LocalExecutor:
    """A pool of ``workers`` spawned processes."""

    name = "local"

    def __init__(self, *, workers: int, environment: dict[str, str] | None = None, address: str | None = None) -> None:
        if address:
            raise ConfigError(f"--ray-address {address!r} needs --executor ray; drop it or choose the ray executor")
        quiet_resource_tracker()  # the queues' semaphores of a killed build are removed without a raw warning
        context = multiprocessing.get_context("spawn")
        self._queue = context.Queue()
        self._pool = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_init_worker,
                                         initargs=(self._queue, os.getpid(), dict(environment or {})))

    def submit(self, fn: TaskFunction, task: Any, *, cpus: int) -> Future:
        return self._pool.submit(fn, task)

    def wait(self, handles: list[Future], *, timeout: float) -> list[tuple[Future, Any, BaseException | None]]:
        done, _ = wait_futures(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        out = []
        for future in done:
            error = future.exception()
            out.append((future, None if error else future.result(), error))
        return out

    def drain_pulses(self) -> int:
        total = 0
        while True:
            try:
                total += self._queue.get_nowait()
            except queue.Empty:
                return total
            except (OSError, ValueError, EOFError):
                return total  # the queue is gone with a broken pool; progress is cosmetic

    def close(self, *, cancel: bool = False) -> None:
        if cancel:  # stopped (Ctrl-C, SIGTERM): end the running units now; the driver then sweeps their staging
            for process in list(getattr(self._pool, "_processes", {}).values()):
                process.terminate()
        self._pool.shutdown(wait=True, cancel_futures=cancel)
        self._queue.close()


class RayExecutor:
    """Ray tasks on a local Ray instance (started and stopped here) or an existing cluster."""

    name = "ray"

    def __init__(self, *, workers: int, environment: dict[str, str] | None = None, address: str | None = None) -> None:
        try:
            import ray
        except ImportError as exc:
            raise ConfigError("--executor ray needs Ray; install it with pip install 'bimscan[ray]'") from exc
        self._ray = ray
        self._started = not ray.is_initialized()
        runtime_env = {"env_vars": dict(environment or {})}
        if self._started:
            try:
                if address:
                    ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
                else:
                    ray.init(num_cpus=max(1, os.cpu_count() or 1), include_dashboard=False, runtime_env=runtime_env,
                             log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise DatasetError(f"could not start or reach Ray{f' at {address}' if address else ''} ({exc}); "
                                   "check the address or use --executor local") from exc
        self._remote: dict[TaskFunction, Any] = {}

    def submit(self, fn: TaskFunction, task: Any, *, cpus: int) -> Any:
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(fn)
        return self._remote[fn].options(num_cpus=cpus, max_retries=0).remote(task)

    def wait(self, handles: list[Any], *, timeout: float) -> list[tuple[Any, Any, BaseException | None]]:
        done, _ = self._ray.wait(handles, num_returns=1, timeout=timeout)
        out = []
        for ref in done:
            try:
                out.append((ref, self._ray.get(ref), None))
            except Exception as exc:  # RayTaskError, WorkerCrashedError, ...: the unit fails, the build goes on
                out.append((ref, None, exc))
        return out

    def drain_pulses(self) -> int:
        return 0

    def close(self, *, cancel: bool = False) -> None:
        if self._started:
            self._ray.shutdown()


EXECUTORS: dict[str, Callable[..., TaskExecutor]] = {
    "local": LocalExecutor,
    "ray": RayExecutor,
    "serial": SerialExecutor,
}


def make_executor(name: str, *, workers: int, environment: dict[str, str] | None = None,
                  address: str | None = None) -> TaskExecutor:
    """The executor called ``name`` (see ``EXECUTORS``)."""
    if name not in EXECUTORS:
        raise ConfigError(f"unknown executor {name!r}; use one of {', '.join(EXECUTORS)}")
    return EXECUTORS[name](workers=workers, environment=environment, address=address)
