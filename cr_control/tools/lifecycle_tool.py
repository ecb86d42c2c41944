"""cr_lifecycle: get and change a managed node's lifecycle state, where there is no ``ros2 lifecycle``.

Calls the standard lifecycle services (``<node>/get_state``, ``<node>/change_state``, what
``ros2 lifecycle get/set`` calls), so it works with any managed ROS 2 node. Every
controller of cr_control is one (parameter ``autostart``, default true: configured and
active at start).

    cr_lifecycle get /adaptive_impedance
    cr_lifecycle set /robust_adaptive_impedance configure
    cr_lifecycle set /adaptive_impedance deactivate
    cr_lifecycle switch /adaptive_impedance /robust_adaptive_impedance --at 5

``switch`` is a live change of controllers (``cr_session --switch-to`` runs it): it
configures the second node if needed, waits until the plant's state is stamped ``--at``
seconds after the first state it saw, deactivates the first and activates the second,
which starts its law from the state it holds. Deactivated, a controller with a brake (the
task-space schemes) answers the states with it, marked as giving way, and the plant
follows the second from its first command: make before break, the robot never left with
a stale command. A controller without a brake stops commanding: the plant takes another
only after the first has been silent for its ``command_handover_cycles`` (50 ms by
default), so ``--handover`` (seconds between the two transitions, default 0) should then
be at least that. Start it before the plant runs: its clock starts
with the first state it sees; with ``--plant-time``, ``--at`` is the states' own stamp (a
lockstep plant stamps its time from 0: ``cr_session`` passes it in lockstep, so the switch
lands at ``--switch-at`` however late the tool subscribes). Node names and
``--domain-id``/``--timeout`` as in cr_param.
Exit status: 0 done, 1 a transition refused, 2 usage or connection error.
"""

from __future__ import annotations

import argparse
import struct
import sys
import time

from cr_control.core import topics
from cr_control.core.ros_env import domain_id_arg, isolate_this_process, use_visitor_dds_profile
from cr_control.tools.param_tool import (
    TIMEOUT_S,
    call_service,
    full_node_name,
    timeout_seconds,
    wait_for_service,
)

#: The transitions ``set`` takes (their labels in the standard lifecycle state machine).
TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")
#: Default of ``--handover``: none, the first controller brakes and gives way (module
#: docstring). 0.05 s (the plant's command_handover_cycles at 1 kHz) for one without a brake.
HANDOVER_S = 0.0


class TransitionRefusedError(RuntimeError):
    """A node answered that it cannot make a transition now."""


class Lifecycle:
    """A client of the lifecycle services of nodes on this process's ROS domain."""

    def __init__(self, timeout_s: float):
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        rclpy.init(args=[sys.argv[0]])
        self.node = rclpy.create_node("cr_lifecycle")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.timeout_s = timeout_s
        self._clients: dict[str, object] = {}

    def close(self) -> None:
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()

    def _call(self, srv_type, service: str, request):
        return call_service(self.node, self.executor, srv_type, service, request, self.timeout_s,
                            what="its lifecycle services", client=self._client(srv_type, service))

    def _client(self, srv_type, service: str):
        """One client per service, kept: a new client must first be matched by discovery
        (tens of ms on a loaded machine), which a live switch cannot wait for."""
        if service not in self._clients:
            self._clients[service] = self.node.create_client(srv_type, service)
        return self._clients[service]

    def prepare(self, *targets: str) -> None:
        """Make and match the change_state clients of ``targets`` now, before they are needed."""
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        from lifecycle_msgs.srv import ChangeState

        for target in targets:
            wait_for_service(self.node, self.executor, self._client(
                ChangeState, f"{target}/change_state"), self.timeout_s, "its lifecycle services")

    def state(self, target: str) -> str:
        """The node's current state label (unconfigured, inactive, active, finalized)."""
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        from lifecycle_msgs.srv import GetState

        return self._call(GetState, f"{target}/get_state", GetState.Request()).current_state.label

    def change(self, target: str, transition: str) -> None:
        """Make ``transition``; TransitionRefusedError if the node refuses it."""
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        request = ChangeState.Request(transition=Transition(label=transition))
        if not self._call(ChangeState, f"{target}/change_state", request).success:
            raise TransitionRefusedError(f"{target} refused {transition} (it is {self.state(target)})")

    def wait_for_time(self, at_s: float, absolute: bool = False) -> float:
        """Block until a /joint_states stamp is ``at_s`` after the first one seen (or, with
        ``absolute``, at least ``at_s``: a lockstep plant stamps its states from 0); that
        stamp's offset (s; its stamp with ``absolute``)."""
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        from sensor_msgs.msg import JointState

        # lazy: loaded when the command runs (cr_control.tools)
        from cr_control.nodes.qos import CONTROL_QOS

        seen: list[float] = []

        def on_state(data: bytes) -> None:
            if len(data) >= 12:     # CDR: 4-byte encapsulation, then header.stamp
                sec, nanosec = struct.unpack_from("<iI" if data[1] & 1 else ">iI", data, 4)
                seen.append(sec + nanosec * 1e-9)
                del seen[1:-1]      # the first and the latest

        def time_now() -> float:
            return seen[-1] - (0.0 if absolute else seen[0])

        sub = self.node.create_subscription(JointState, topics.JOINT_STATES, on_state,
                                            CONTROL_QOS, raw=True)
        try:
            while not seen or time_now() < at_s:
                self.executor.spin_once(timeout_sec=0.05)
        finally:
            self.node.destroy_subscription(sub)
        return time_now()


def switch(life: Lifecycle, old: str, new: str, at_s: float, handover_s: float,
           absolute: bool = False) -> None:
    """The live switch of the module docstring; prints each step (``absolute``: ``at_s`` is
    the plant's time, :meth:`Lifecycle.wait_for_time`)."""
    if life.state(new) == "unconfigured":
        life.change(new, "configure")
    life.prepare(old, new)
    print(f"{new} configured; switching at t = {at_s:g} s", flush=True)
    reached = life.wait_for_time(at_s, absolute)
    life.change(old, "deactivate")
    stopped = time.monotonic()
    time.sleep(handover_s)
    life.change(new, "activate")
    print(f"switched at t = {reached:.3f} s: {old} inactive, {new} active "
          f"({(time.monotonic() - stopped) * 1e3:.0f} ms between the two transitions)", flush=True)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cr_lifecycle", description=__doc__.split("\n\n")[0])
    p.add_argument("--domain-id", type=domain_id_arg, help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID)")
    p.add_argument("--timeout", type=timeout_seconds, default=TIMEOUT_S, metavar="S",
                   help=f"wait at most S seconds for a node and each answer (default {TIMEOUT_S:g})")
    sub = p.add_subparsers(dest="command", required=True)
    get = sub.add_parser("get", help="a node's lifecycle state")
    get.add_argument("node")
    change = sub.add_parser("set", help="make a transition")
    change.add_argument("node")
    change.add_argument("transition", choices=TRANSITIONS)
    sw = sub.add_parser("switch", help="deactivate one controller and activate another at a time")
    sw.add_argument("old")
    sw.add_argument("new")
    sw.add_argument("--at", type=float, default=0.0, metavar="T",
                    help="seconds after the first state seen (default 0: now)")
    sw.add_argument("--plant-time", action="store_true",
                    help="--at is the plant's time, the states' stamps (a lockstep plant "
                         "stamps from 0), not seconds after the first state this tool sees")
    sw.add_argument("--handover", type=float, default=HANDOVER_S, metavar="S",
                    help=f"seconds between deactivating and activating (default {HANDOVER_S:g})")
    return p


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    args = build_parser().parse_args(argv)
    try:
        names = [full_node_name(n) for n in (
            (args.old, args.new) if args.command == "switch" else (args.node,))]
        if args.command == "switch" and not (0.0 <= args.at < float("inf")
                                             and 0.0 <= args.handover <= 10.0):
            raise ValueError("--at must be >= 0 and --handover within 0..10 s")
    except ValueError as exc:
        print(f"cr_lifecycle: {exc}", file=sys.stderr)
        return 2
    isolate_this_process(args.domain_id)
    use_visitor_dds_profile()   # never sent to through shared memory: no join stall
    life = Lifecycle(args.timeout)
    try:
        if args.command == "get":
            print(life.state(names[0]))
        elif args.command == "set":
            life.change(names[0], args.transition)
            print(f"{names[0]}: {args.transition} done, now {life.state(names[0])}")
        else:
            switch(life, *names, args.at, args.handover, args.plant_time)
        return 0
    except TransitionRefusedError as exc:
        print(f"cr_lifecycle: {exc}", file=sys.stderr)
        return 1
    except TimeoutError as exc:
        print(f"cr_lifecycle: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cr_lifecycle: interrupted", file=sys.stderr)
        return 130
    finally:
        life.close()


if __name__ == "__main__":
    sys.exit(main())
