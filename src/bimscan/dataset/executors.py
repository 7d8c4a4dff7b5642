"""Where dataset tasks run: local processes (default), Ray tasks, or the calling process.

Every executor runs plain functions on picklable task objects and hands back results as they
finish; the build driver does not care where. ``EXECUTORS`` maps the names of ``--executor``:

- ``local``: a pool of ``workers`` processes started with ``spawn`` (Open3D and OpenMP are not
  fork-safe). Workers report the pulses each unit has scanned through a queue (progress and the
  time left), and end themselves within a second when the driver dies (a killed build leaves no
  process behind).
- ``ray``: one Ray task per job on a local Ray instance, or on a running cluster with
  ``address`` (the dataset folder must then be on storage every node sees). A task whose worker
  or node dies is run again on another node (``RAY_TASK_RETRIES``): tasks write under staging
  names and rename when whole, so a rerun gives the same bytes and a half-written unit is never
  seen. Ray is imported only here, inside the functions.
- ``serial``: runs every task in the calling process, one after the other (debugging, tests).
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import secrets
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from typing import Any, Protocol

from bimscan.errors import ConfigError, DatasetError
from bimscan.processes import die_with_parent, quiet_resource_tracker

TaskFunction = Callable[[Any], Any]

# Times Ray runs a task again when its worker process or its node dies (killed, out of memory, a
# machine lost): the build then loses no unit. A task that raises is not run again (its unit fails
# with the reason).
RAY_TASK_RETRIES = 3
# Names the Ray actor that counts the pulses of a build's Ray tasks (set in their environment).
PULSE_COUNTER_ENV = "BIMSCAN_PULSE_COUNTER"

# Set in each worker process by the local executor's initializer (queue, parent), or by the first
# report of a Ray task (counter: the build's pulse counter actor).
_WORKER_STATE: dict[str, Any] = {"queue": None, "parent": None, "counter": None}


def report_pulses(n: int, *, unit: str = "") -> None:
    """Called by tasks as they scan: forwards the pulses ``unit`` has just scanned to the driver
    (its progress bar and time left): through the local pool's queue, or the build's Ray actor."""
    channel = _WORKER_STATE["queue"]
    if channel is not None:
        channel.put_nowait((unit, n))
        return
    name = os.environ.get(PULSE_COUNTER_ENV)
    if name:
        counter = _WORKER_STATE["counter"]
        if counter is None:
            import ray  # only ever set on a Ray worker

            try:
                counter = _WORKER_STATE["counter"] = ray.get_actor(name)
            except ValueError:  # the build's driver is gone: progress is cosmetic
                return
        counter.add.remote(unit, n)  # fire and forget


class PulseCounter:
    """Pulses scanned per unit, summed between two ``drain`` calls (a Ray actor of the build)."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def add(self, unit: str, n: int) -> None:
        self.counts[unit] = self.counts.get(unit, 0) + n

    def drain(self) -> dict[str, int]:
        counts, self.counts = self.counts, {}
        return counts


def worker_node() -> dict[str, str]:
    """Where this task runs, for the unit's timings: the host name, and the Ray node id on Ray."""
    place = {"host": socket.gethostname()}
    ray = sys.modules.get("ray")  # imported by Ray in its workers; never imported here
    if ray is not None and ray.is_initialized():
        place["ray_node"] = ray.get_runtime_context().get_node_id()
    return place


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
    def drain_pulses(self) -> dict[str, int]: ...
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

    def drain_pulses(self) -> dict[str, int]:
        return {}

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

    def drain_pulses(self) -> dict[str, int]:
        scanned: dict[str, int] = {}
        while True:
            try:
                unit, n = self._queue.get_nowait()
            except queue.Empty:
                return scanned
            except (OSError, ValueError, EOFError):
                return scanned  # the queue is gone with a broken pool; progress is cosmetic
            scanned[unit] = scanned.get(unit, 0) + n

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
        counter_name = f"bimscan-pulses-{os.getpid()}-{secrets.token_hex(4)}"
        runtime_env = {"env_vars": dict(environment or {}) | {PULSE_COUNTER_ENV: counter_name}}
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
        # The driver sizes tasks by its own cores; a task asking for more CPUs than any node has
        # would wait forever, so it asks for at most the largest node's.
        self._largest_node_cpus = max((int(node["Resources"].get("CPU", 0)) for node in ray.nodes() if node["Alive"]),
                                      default=0)
        # Tasks report their pulses to an actor on the driver's node (it takes no CPU); tasks of a
        # Ray session the caller started report nothing (their environment is not ours).
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        here = NodeAffinitySchedulingStrategy(node_id=ray.get_runtime_context().get_node_id(), soft=True)
        self._counter = ray.remote(PulseCounter).options(name=counter_name, num_cpus=0,
                                                         scheduling_strategy=here).remote()

    def submit(self, fn: TaskFunction, task: Any, *, cpus: int) -> Any:
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(fn)
        if self._largest_node_cpus >= 1:
            cpus = min(cpus, self._largest_node_cpus)
        return self._remote[fn].options(num_cpus=cpus, max_retries=RAY_TASK_RETRIES).remote(task)

    def wait(self, handles: list[Any], *, timeout: float) -> list[tuple[Any, Any, BaseException | None]]:
        done, _ = self._ray.wait(handles, num_returns=1, timeout=timeout)
        out = []
        for ref in done:
            try:
                out.append((ref, self._ray.get(ref), None))
            except Exception as exc:  # RayTaskError, WorkerCrashedError, ...: the unit fails, the build goes on
                out.append((ref, None, exc))
        return out

    def drain_pulses(self) -> dict[str, int]:
        try:
            return self._ray.get(self._counter.drain.remote(), timeout=5)
        except Exception:  # the actor lost or slow (RayActorError, GetTimeoutError): progress is cosmetic
            return {}

    def close(self, *, cancel: bool = False) -> None:
        if self._started:
            self._ray.shutdown()


EXECUTORS: dict[str, Callable[..., TaskExecutor]] = {
    "local": LocalExecutor,
    "ray": RayExecutor,
    "serial": SerialExecutor,
}
USER_EXECUTORS = ("local", "ray")  # what --executor offers ("serial": one process, for tests and debugging)


def make_executor(name: str, *, workers: int, environment: dict[str, str] | None = None,
                  address: str | None = None) -> TaskExecutor:
    """The executor called ``name`` (see ``EXECUTORS``)."""
    if name not in EXECUTORS:
        raise ConfigError(f"unknown executor {name!r}; use one of {', '.join(EXECUTORS)}")
    return EXECUTORS[name](workers=workers, environment=environment, address=address)
