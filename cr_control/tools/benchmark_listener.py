"""The benchmark's ROS side in its own process: a listener node that keeps every
``/plant/timing`` report and samples the CPU time of the run's processes on each, and a
sampler of CPU ticks in a thread.
"""

from __future__ import annotations

import struct
import threading
import time
from array import array
from collections.abc import Callable

from cr_control.core import topics
from cr_control.core.ros_env import (
    isolate_this_process,
)
from cr_control.tools.benchmark_figures import (
    LISTENER,
    MACHINE,
    STATUS_TIME_FIELDS,
    STEAL,
    last_double,
    offsets_from_end,
    read_cpu_ticks,
    read_machine_ticks,
    timing_dict,
)


# -- ROS side: a listener in this process ----------------------------------------------
class Listener:
    """One node on ``domain_id`` in its own context, spun by an EventsExecutor in a thread.

    Keeps every /plant/timing report and, on each, samples the CPU time of the
    processes ``pids()`` names (and of this process); optionally the controller's
    timing fields (:data:`STATUS_TIME_FIELDS`) from its status topic (best effort, raw
    CDR: cheap).
    """

    def __init__(self, domain_id: int, pids: Callable[[], dict[str, int]],
                 status_topic: str | None = None):
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        import rclpy
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from rclpy.task import Future
        from std_msgs.msg import Float64MultiArray

        # lazy: loaded when the command runs (cr_control.tools)
        from cr_control.nodes.qos import CONTROL_QOS

        self._rclpy = rclpy
        self.pids = pids
        self.timing: list[tuple[float, dict[str, float]]] = []
        self.cpu_samples: list[tuple[float, dict[str, int | None]]] = []
        self.wall_ns: list[int] = []  # time.time_ns() of each CPU sample
        self.status: dict[str, array] = {}
        self.status_received = 0
        self._offsets: dict[str, int] | None = None  # field -> position from the end of data
        self._status_raw_ok = True
        self._msg_cls = Float64MultiArray
        isolate_this_process(domain_id)  # localhost discovery for this process too
        self.context = Context()
        # No rclpy signal handlers: Ctrl-C must reach the benchmark as KeyboardInterrupt.
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node("cr_benchmark", context=self.context)
        self.node.create_subscription(Float64MultiArray, topics.PLANT_TIMING, self._on_timing,
                                      CONTROL_QOS)
        if status_topic:
            best_effort = QoSProfile(depth=topics.QOS_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.node.create_subscription(Float64MultiArray, status_topic, self._on_status, best_effort,
                                          raw=True)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = Future()
        self._thread = threading.Thread(target=self._spin, name="cr_benchmark_listener", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while self.context.ok() and not self._stop.done():
            try:
                self.executor.spin_until_future_complete(self._stop, timeout_sec=0.25)
            except Exception:  # noqa: BLE001 - shutting down
                break

    def _on_timing(self, msg) -> None:
        now = time.monotonic()
        label = msg.layout.dim[0].label if msg.layout.dim else ""
        self.timing.append((now, timing_dict(label, msg.data)))
        ticks: dict[str, int | None] = {name: read_cpu_ticks(pid) for name, pid in list(self.pids().items())}
        ticks[LISTENER] = read_cpu_ticks("self")
        ticks[MACHINE] = read_machine_ticks()
        ticks[STEAL] = read_machine_ticks(steal=True)
        self.cpu_samples.append((now, ticks))
        self.wall_ns.append(time.time_ns())

    def _on_status(self, buf: bytes) -> None:
        self.status_received += 1
        if self._offsets is None or not self._status_raw_ok:
            # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
            from rclpy.serialization import deserialize_message

            msg = deserialize_message(buf, self._msg_cls)
            fields = topics.fields_of(msg.layout.dim[0].label if msg.layout.dim else "")
            offsets = offsets_from_end(fields, STATUS_TIME_FIELDS)
            n = len(msg.data)
            if len(fields) != n:
                return
            values = {name: float(msg.data[n - k]) for name, k in offsets.items()}
            if self._offsets is None:
                self._offsets = offsets
                try:
                    self._status_raw_ok = all(
                        struct.pack("d", last_double(buf, k)) == struct.pack("d", values[name])
                        for name, k in offsets.items())
                except (struct.error, IndexError):
                    self._status_raw_ok = False
            for name, value in values.items():
                self.status.setdefault(name, array("d")).append(value)
            return
        for name, k in self._offsets.items():
            self.status.setdefault(name, array("d")).append(last_double(buf, k))

    def last_timing(self) -> dict[str, float] | None:
        return self.timing[-1][1] if self.timing else None

    def close(self) -> None:
        if not self._stop.done():
            self._stop.set_result(True)
        self._thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


class TickSampler:
    """Samples the CPU ticks of ``pids()`` every ``period`` s in a thread: [(wall ns, ticks)]."""

    def __init__(self, pids: Callable[[], dict[str, int]], period: float = 0.2):
        self.pids = pids
        self.period = period
        self.samples: list[tuple[int, dict[str, int | None]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cr_benchmark_sampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            ticks = {n: read_cpu_ticks(p) for n, p in list(self.pids().items())}
            self.samples.append((time.time_ns(), ticks))

    def of(self, name: str) -> list[tuple[int, int | None]]:
        """(wall ns, ticks) samples of one process."""
        return [(t, ticks.get(name)) for t, ticks in self.samples]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
