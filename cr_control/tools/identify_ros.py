"""cr_identify_tool on a robot: the same poses and least squares through the topics.

What a real robot (or a simulated plant over ROS, ``cr_session``) offers: a running
task-space controller, ``/joint_states`` and the wrist sensor's wrench
(``/force_torque_sensor_broadcaster/wrench``, in the sensor's frame). The tool

1. reads the controller's robot (``robot_description`` / ``urdf_file``, ``base_link``,
   ``tip_link``) and ``sensor_frame`` through its parameter services;
2. streams each pose of :func:`cr_control.tools.identify_tool.tilted_poses` around the tip's
   pose at the start to ``<controller>/target_pose`` at 100 Hz (so the controller's
   ``target_timeout`` never sees it stale), waits ``settle`` s, then averages the wrench
   and g_i = R_i^T g over ``average`` s, R_i from each measured state through the URDF
   (Pinocchio); the times are the states' stamps (the robot's clock: wall time on a
   robot, simulated time in a lockstep session);
3. goes back to the start pose and returns the averages for the least squares.

The arm must be in free space, the controller asking no contact force (``desired_force``
zero from its start: a force target in free space pushes the tip off its reference and the
controller's start check stops it; a ``target_wrench`` of zero is also sent with each pose)
and running no guarded approach (``approach_speed`` 0); a pose that ends more than
POSE_REACHED_DEG from its target stops the tool. The controller's own compensation does not
matter: the raw sensor reading is used.
"""

from __future__ import annotations

import time

import numpy as np
import pinocchio as pin

from cr_control.core import topics

#: Targets are sent this often (s): well inside any target_timeout.
TARGET_PERIOD_S = 0.01
#: A pose whose measured tip orientation ends farther than this from its target (degrees)
#: was not reached: the controller is not commanding (braking, inactive) or cannot hold it.
#: The poses are 35 deg apart; an impedance law's wrist lags a few degrees under the tool's
#: weight (6.6 deg on the simulated Panda's fifth pose), which costs the estimate nothing (g_i
#: comes from the measured state).
POSE_REACHED_DEG = 15.0


def orientation_error_deg(R: np.ndarray, quaternion_wxyz) -> float:
    """The angle (degrees) between the rotation R and the unit quaternion [w, x, y, z]:
    |log(R_target^T R)|. Pinocchio's, not the controllers' compiled ``so3`` kernel: its first
    call from Python compiles for seconds, between two poses, while the controller's target
    timeout runs."""
    w, x, y, z = map(float, quaternion_wxyz)
    R_target = pin.Quaternion(w, x, y, z).normalized().matrix()
    return float(np.degrees(np.linalg.norm(pin.log3(R_target.T @ R))))


class RobotPoses:
    """A ROS client that runs the poses on the controller node ``controller``."""

    def __init__(self, controller: str, timeout_s: float):
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        rclpy.init(args=["cr_identify_tool"])
        self.node = rclpy.create_node("cr_identify_tool")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.controller = controller
        self.timeout_s = timeout_s
        self.q: dict[str, float] = {}
        self.stamp = float("nan")           # of the latest joint state (s)
        self.wrench: tuple[str, np.ndarray] | None = None

    def close(self) -> None:
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()

    def parameters(self, names: list[str]) -> dict:
        """The controller's values of ``names`` (TimeoutError if it does not answer)."""
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        # lazy: loaded when the command runs (cr_control.tools)
        from cr_control.tools.param_tool import call_service

        result = call_service(self.node, self.executor, GetParameters,
                              f"{self.controller}/get_parameters",
                              GetParameters.Request(names=names), self.timeout_s)
        return {n: parameter_value_to_python(v) for n, v in zip(names, result.values, strict=True)}

    def _spin_until(self, done, what: str) -> None:
        deadline = time.monotonic() + self.timeout_s
        while not done():
            if time.monotonic() > deadline:
                raise TimeoutError(f"no {what} within {self.timeout_s:g} s (see --timeout)")
            self.executor.spin_once(timeout_sec=0.01)

    def run(self, chain_model, sensor_frame: str, gravity: np.ndarray, poses, settle: float,
            average: float) -> tuple[np.ndarray, np.ndarray]:
        """(g_i in S, mean wrench in S) per pose; ``poses(start_pose)`` gives the targets."""
        # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from sensor_msgs.msg import JointState

        # lazy: loaded when the command runs (cr_control.tools)
        from cr_control.nodes.qos import CONTROL_QOS, TARGET_QOS
        from cr_control.schemes.blocks.wrist_sensor import frame_rotation

        def on_state(msg: JointState) -> None:
            self.q.update(zip(msg.name, msg.position, strict=False))
            self.stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

        def on_wrench(msg: WrenchStamped) -> None:
            f, t = msg.wrench.force, msg.wrench.torque
            self.wrench = (msg.header.frame_id, np.array([f.x, f.y, f.z, t.x, t.y, t.z]))

        self.node.create_subscription(JointState, topics.JOINT_STATES, on_state, CONTROL_QOS)
        self.node.create_subscription(WrenchStamped, topics.WRENCH, on_wrench, CONTROL_QOS)
        pose_pub = self.node.create_publisher(
            PoseStamped, f"{self.controller}/{topics.TARGET_POSE_SUFFIX}", TARGET_QOS)
        wrench_pub = self.node.create_publisher(
            WrenchStamped, f"{self.controller}/{topics.TARGET_WRENCH_SUFFIX}", TARGET_QOS)
        joints = list(chain_model.joint_names)
        self._spin_until(lambda: all(j in self.q for j in joints) and self.wrench is not None,
                         f"joint states of {joints} and wrench")
        if self.wrench[0] and self.wrench[0] != sensor_frame:
            raise ValueError(f"the wrench is in frame {self.wrench[0]!r}, not the controller's "
                             f"sensor_frame {sensor_frame!r}")
        q = lambda: np.array([self.q[j] for j in joints])      # noqa: E731
        start = chain_model.tip_pose(q())
        base = chain_model.base_link

        def send(position, quaternion) -> None:
            msg = PoseStamped()
            msg.header.frame_id = base
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, position)
            o = msg.pose.orientation
            o.w, o.x, o.y, o.z = map(float, quaternion)
            pose_pub.publish(msg)
            zero = WrenchStamped()
            zero.header.frame_id = base
            wrench_pub.publish(zero)

        g_s, wrenches = [], []
        targets = poses(start)
        for i, (position, quaternion) in enumerate([*targets, targets[0]]):
            g_sum, w_sum, count = np.zeros(3), np.zeros(6), 0
            t0, last_sent, last_wrench = self.stamp, -np.inf, None
            deadline = time.monotonic() + self.timeout_s + 10.0 * (settle + average)
            while self.stamp - t0 < settle + (average if i < len(targets) else 0.0):
                now = time.monotonic()
                if now > deadline:
                    raise TimeoutError(f"the joint states stopped during pose {i + 1}")
                if now - last_sent >= TARGET_PERIOD_S:
                    send(position, quaternion)
                    last_sent = now
                self.executor.spin_once(timeout_sec=TARGET_PERIOD_S / 2)
                if self.stamp - t0 >= settle and self.wrench[1] is not last_wrench:
                    last_wrench = self.wrench[1]
                    g_sum += frame_rotation(chain_model, q(), sensor_frame).T @ gravity
                    w_sum += last_wrench
                    count += 1
            if i < len(targets):
                off = orientation_error_deg(chain_model.tip_pose(q()).rotation, quaternion)
                if off > POSE_REACHED_DEG:
                    raise ValueError(f"pose {i + 1} not reached: the tip's orientation is "
                                       f"{off:.1f} deg from its target after {settle:g} s; is "
                                       f"{self.controller} commanding? (its log says why not)")
                if count == 0:
                    raise TimeoutError(f"no wrench during pose {i + 1}'s {average:g} s average")
                g_s.append(g_sum / count)
                wrenches.append(w_sum / count)
        return np.array(g_s), np.array(wrenches)
