"""Composed mode: plant and controller nodes in one process on one executor.

Like a ROS 2 component container: the same node classes as the separate executables,
sharing one EventsExecutor, for the lowest state -> command latency. The process ends
when the plant finishes its ``duration``, or with code 1 when the controller refuses the
plant (a scenario of the other command interface, see controller_node).

    python -m cr_control.tools.container SCHEME [--ros-args --params-file FILE ...]
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.task import Future

from cr_control.nodes.controller_node import ControllerNode, wait_for_acks
from cr_control.nodes.spin import spin_nodes, start_nodes
from cr_control.schemes.registry import SCHEMES
from cr_sim.plant_node import PlantNode


def main(args: list[str] | None = None) -> int:
    """Run the plant and the controller of the scheme named first on the command line
    (exit 2 for an unknown scheme, 1 with one line on stderr if a node refuses to start,
    1 if the controller refuses the plant's command interface, else the plant's exit code)."""
    argv = list(sys.argv if args is None else args)
    if len(argv) < 2 or argv[1] not in SCHEMES:
        print(f"usage: container SCHEME [--ros-args ...]; schemes: {sorted(SCHEMES)}", file=sys.stderr)
        return 2
    scheme = argv.pop(1)
    np.seterr(all="ignore")     # Controller.step catches and logs non-finite results
    nodes = start_nodes("container", argv, lambda: [ControllerNode(scheme), PlantNode()])
    if nodes is None:
        return 1
    controller, plant = nodes
    done = Future()

    def end(_) -> None:
        if not done.done():
            wait_for_acks(controller)   # the last status and command reach the recorder
            done.set_result(True)

    for future in (plant.finished, controller.refused):
        future.add_done_callback(end)
    spin_nodes(nodes, until=done)
    return 1 if controller.refused.done() else plant.exit_code


if __name__ == "__main__":
    sys.exit(main())
