"""The engine that runs points: Ray, local by default, or an existing cluster (``--address``).

Network rule (everything on loopback, docs/experiments.md): out of the box Ray on Linux takes the
machine's interface address as node IP and connects through it. Kept on loopback here:
- local (default): ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` -> node IP 127.0.0.1, every
  listener on 127.0.0.1 (a single-node instance; multi-node is then refused); no dashboard;
- ``--address HOST:PORT``: a cluster someone started (``ray start``); a driver on a
  loopback address (127.x.y.z, e.g. a test cluster on 127.0.0.2/127.0.0.3) joins as that
  address, so it connects through loopback only.
Usage statistics are off (``RAY_USAGE_STATS_ENABLED=0``): nothing leaves the machine.

Points go out several per task (:func:`chunk_size`) so that Ray's per-task cost is spread
over them; a worker process imports the package and loads the numba kernels from their
cache once, then runs task after task. Tasks are retried (``max_retries``) when their worker
or node dies, so a killed node loses no point. Results come back per task, in whatever order
they finish; the table is sorted by point index afterwards, and each point's computation is
independent of the others, so the result does not depend on the number of workers.
"""

from __future__ import annotations

import math
import os
import socket
from collections.abc import Callable, Sequence
from typing import Any

from cr_control.experiments import evaluate

#: Environment of every Ray process started from here (read by ray at init).
LOCAL_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
COMMON_ENV = {"RAY_USAGE_STATS_ENABLED": "0"}
#: A task of a worker or node that dies is run again this many times.
MAX_RETRIES = 5
#: Aim for this many simulated seconds per task (a few wall seconds): Ray's per-task cost
#: (~ms) is then far below 5 % of it, and a killed sweep loses little.
TASK_SIMULATED_S = 16.0
#: Tasks per worker over a sweep at least (so the last tasks do not leave workers idle).
TASKS_PER_WORKER = 3
#: Seconds to wait for a TCP connection to ``--address`` before calling it unreachable.
CONNECT_TIMEOUT_S = 3.0
#: Object store of a local instance (bytes): results are small.
OBJECT_STORE_BYTES = 100 * 1024 * 1024

Job = tuple[int, dict[str, Any], dict[str, Any], dict[str, Any]]
Done = Callable[[list[dict[str, Any]]], None]


class EngineError(RuntimeError):
    """Ray cannot be started or joined, or tasks were lost; the message is one line."""


def run_chunk(scheme: str, robot: str | None, duration: float, jobs: Sequence[Job]
              ) -> list[dict[str, Any]]:
    """Run points ``(index, inputs, controller overrides, plant overrides)``: one record
    ``{"point", "inputs", "result"}`` each (the body of a Ray task; plain Python)."""
    return [{"point": index, "inputs": inputs,
             "result": evaluate.run_point(scheme, robot, duration, controller, plant)}
            for index, inputs, controller, plant in jobs]


def parse_address(address: str) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); EngineError if it is not of that form."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise EngineError(f"--address {address!r}: expected HOST:PORT (the head's GCS address, "
                          "as `ray start --head` prints it)")
    return host, int(port)


def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> tuple[str, int]:
    """EngineError (one line) unless a TCP connection to ``address`` opens within ``timeout``."""
    host, port = parse_address(address)
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        why = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise EngineError(f"--address {address}: cannot reach a Ray head there ({why})") from None
    return host, port


def _is_loopback(host: str) -> bool:
    try:
        return socket.gethostbyname(host).startswith("127.")
    except OSError:
        return False


def start(address: str | None = None, workers: int | None = None) -> int:
    """Start a local Ray instance of ``workers`` CPUs (default: this machine's cores) or
    join the cluster at ``address``; return the CPUs tasks may use. EngineError (one line)
    if it cannot."""
    _set_env(COMMON_ENV)
    # lazy: Ray takes seconds to import and only runs sweeps, tuning and the report
    import ray

    if ray.is_initialized():                # a caller (a test) started it
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        return cpus if workers is None else min(cpus, workers)
    options: dict[str, Any] = {"log_to_driver": False, "logging_level": "ERROR",
                               "configure_logging": True}
    try:
        if address is None:
            _set_env(LOCAL_ENV)
            # ray reads the variable once, when first imported: if that was before (in this
            # process), its constant is set here too (restored by stop())
            from ray._private import ray_constants

            _saved_constants.setdefault("ENABLE_RAY_CLUSTER", ray_constants.ENABLE_RAY_CLUSTER)
            ray_constants.ENABLE_RAY_CLUSTER = False
            ray.init(address="local", num_cpus=workers or os.cpu_count() or 1,
                     include_dashboard=False, object_store_memory=OBJECT_STORE_BYTES, **options)
            node_ip = ray.util.get_node_ip_address()
            if not node_ip.startswith("127."):
                ray.shutdown()
                raise EngineError(f"Ray took {node_ip} as this node's address, not loopback: "
                                  "refused (everything stays on loopback)")
        else:
            host, _ = check_reachable(address)
            if _is_loopback(host):
                options["_node_ip_address"] = socket.gethostbyname(host)
            ray.init(address=address, **options)
    except EngineError:
        raise
    except Exception as exc:                # noqa: BLE001 - Ray raises many kinds
        text = str(exc).strip().splitlines()
        raise EngineError(f"Ray: {type(exc).__name__}: {text[0] if text else ''}") from None
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if cpus < 1:
        raise EngineError(f"Ray at {address or 'local'} has no CPU to run tasks on")
    return cpus if workers is None else min(cpus, workers)


#: Environment variables start() set, with their values before (None: unset), and ray
#: constants it changed, with theirs.
_saved_env: dict[str, str | None] = {}
_saved_constants: dict[str, Any] = {}


def _set_env(values: dict[str, str]) -> None:
    """Set ``values`` in this process's environment (read by ray when it starts; undone by
    stop(), so that processes started later, e.g. a ``ray start``, do not inherit them)."""
    for key, value in values.items():
        _saved_env.setdefault(key, os.environ.get(key))
        os.environ[key] = value


def stop() -> None:
    """Leave Ray (a local instance stops with it); undo start()'s environment."""
    # lazy: Ray takes seconds to import and only runs sweeps, tuning and the report
    import ray

    if ray.is_initialized():
        ray.shutdown()
    for key, value in _saved_env.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    _saved_env.clear()
    if _saved_constants:
        # lazy: Ray takes seconds to import and only runs sweeps, tuning and the report
        from ray._private import ray_constants

        for key, value in _saved_constants.items():
            setattr(ray_constants, key, value)
        _saved_constants.clear()


def chunk_size(points: int, duration: float, capacity: int) -> int:
    """Points per task: about TASK_SIMULATED_S simulated seconds, and at least
    TASKS_PER_WORKER tasks per worker when there are enough points."""
    by_time = max(1, math.floor(TASK_SIMULATED_S / duration))
    by_spread = max(1, math.ceil(points / (capacity * TASKS_PER_WORKER)))
    return min(by_time, by_spread)


def run(scheme: str, robot: str | None, duration: float, jobs: Sequence[Job], capacity: int,
        done: Done, chunk: int | None = None) -> None:
    """Run ``jobs`` on Ray, ``capacity`` tasks in flight (2 per CPU would queue: one each),
    ``chunk`` points per task (default :func:`chunk_size`); ``done(records)`` is called in
    this process as each task finishes. EngineError if a task is lost after its retries."""
    # lazy: Ray takes seconds to import and only runs sweeps, tuning and the report
    import ray

    if not jobs:
        return
    size = chunk or chunk_size(len(jobs), duration, capacity)
    chunks = [list(jobs[i:i + size]) for i in range(0, len(jobs), size)]
    task = ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)(run_chunk)
    pending: dict[Any, list[Job]] = {}
    lost: list[str] = []
    queue = list(reversed(chunks))
    while queue or pending:
        while queue and len(pending) < capacity:
            batch = queue.pop()
            pending[task.remote(scheme, robot, duration, batch)] = batch
        ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
        for ref in ready:
            batch = pending.pop(ref)
            try:
                records = ray.get(ref)
            except Exception as exc:        # noqa: BLE001 - lost after its retries
                text = str(exc).strip().splitlines()
                lost.append(f"{len(batch)} points ({type(exc).__name__}: "
                            f"{text[0] if text else ''})")
                continue
            done(records)
    if lost:
        raise EngineError(f"tasks lost after {MAX_RETRIES} retries: {'; '.join(lost)[:400]}; "
                          "rerun the same command to compute them")

