"""cr_identify_tool: the mass, centre of mass and bias of a tool on a wrist force/torque
sensor, by least squares over a few static poses, written as a params file for
the controller.

At rest the sensor (frame S, rotation R_i: base <- S at pose i) reads the tool's weight and
its moment plus the bias:

    F_i = m g_i + b_F,             g_i = R_i^T g  (gravity in S)
    T_i = c x (m g_i) + b_T = -[g_i]x h + b_T,   h = m c

Both are linear in the unknowns: [m, b_F] (4) from the forces, [h, b_T] (6) from the
torques, stacked over the poses and solved by least squares (numpy ``lstsq``); c = h / m.
The forces need two gravity directions in S, the torques three (each pose gives two
equations across g_i): the poses tilt the flange by POSE_TILT_DEG about the base's x and y
axes from the home pose, and about both, keeping the tip where it is (POSES).

At each pose the arm settles for ``--settle`` s, then the wrench and g_i are averaged over
``--average`` s (the sensor's noise averages out as 1/sqrt(samples): 0.2 N over 1000
readings is 0.006 N). Static: the tool's inertial wrench is neglected (the arm is still).

Simulator (``--robot panda|ur5``, the default): the offline loop
(:mod:`cr_control.offline`) with the robot's plant (its wrist sensor: tool, bias,
noise, :data:`cr_control.robots.SENSOR`) in free space and ``adaptive_impedance``
holding each pose through :meth:`set_target_pose`, the law given no force (the pose hold
needs none); the truth is known there, so the errors are printed. R_i comes from the
measured joints through the controller's model (Pinocchio), as on a robot.

    cr_identify_tool --robot panda --out tool.yaml
    cr_session --robot panda --params-file tool.yaml

On a robot (``--controller NODE``): the same poses and least squares through the topics of
a running task-space controller (:mod:`cr_control.tools.identify_ros`): its URDF and
``sensor_frame`` from its parameters, the poses around where the tip is.

    cr_identify_tool --controller /adaptive_impedance --domain-id 12 --out tool.yaml

Bad input: one line on stderr, exit code 2, before anything runs (a ``--node`` ROS would
not accept as a node name, a ``--timeout`` not in (0, 3600] s, ...). The params file is
written by ``yaml.safe_dump``: no text from the command line becomes YAML structure.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

from cr_control import robots
from cr_control.core.parameters import ParameterError
from cr_control.core.ros_env import domain_id_arg
from cr_control.schemes.blocks.wrist_sensor import frame_rotation
from cr_control.tools.param_tool import full_node_name, timeout_seconds

#: Tilt of the flange from the home pose (degrees) for the poses.
POSE_TILT_DEG = 35.0
#: Rotation axes (base frame) of the poses' tilts: none (home), +-x, +-y, x and y together.
POSES = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
         (0.0, -1.0, 0.0), (1.0, 1.0, 0.0))
SCHEME = "adaptive_impedance"


@dataclass
class ToolEstimate:
    """The least-squares estimate: mass (kg), centre of mass (m, S), bias (6, S) and the
    RMS residuals of the force (N) and torque (N m) equations."""

    mass: float
    com: np.ndarray
    bias: np.ndarray
    force_residual: float
    torque_residual: float


def skew(v: np.ndarray) -> np.ndarray:
    """[v]x: [v]x w = v x w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def estimate(gravity_s: np.ndarray, wrenches: np.ndarray) -> ToolEstimate:
    """Least squares over k poses: ``gravity_s`` (k x 3) g_i in S, ``wrenches`` (k x 6) the
    mean wrench (force, torque in S). ValueError (one line) if the poses do not determine
    the tool (fewer than 3 distinct gravity directions, or no mass)."""
    g = np.asarray(gravity_s, dtype=float)
    w = np.asarray(wrenches, dtype=float)
    k = len(g)
    if k < 3 or w.shape != (k, 6) or not np.all(np.isfinite(g)) or not np.all(np.isfinite(w)):
        raise ValueError(f"need at least 3 poses with finite readings, got {k}")
    A_f = np.zeros((3 * k, 4))
    A_t = np.zeros((3 * k, 6))
    for i in range(k):
        A_f[3 * i:3 * i + 3, 0] = g[i]
        A_f[3 * i:3 * i + 3, 1:] = np.eye(3)
        A_t[3 * i:3 * i + 3, :3] = -skew(g[i])
        A_t[3 * i:3 * i + 3, 3:] = np.eye(3)
    if np.linalg.matrix_rank(A_t, tol=1e-3 * np.linalg.norm(A_t)) < 6:
        raise ValueError("the poses' gravity directions in the sensor frame span less than 3 "
                         "dimensions: tilt the tool differently")
    y_f, y_t = w[:, :3].reshape(-1), w[:, 3:].reshape(-1)
    x_f = np.linalg.lstsq(A_f, y_f, rcond=None)[0]
    x_t = np.linalg.lstsq(A_t, y_t, rcond=None)[0]
    mass = float(x_f[0])
    if not mass > 0.0:
        raise ValueError(f"the estimated tool mass is {mass:.3g} kg: no tool on the sensor?")
    rms = lambda r: float(np.sqrt(np.mean(r ** 2)))  # noqa: E731
    return ToolEstimate(mass, x_t[:3] / mass, np.concatenate([x_f[1:], x_t[3:]]),
                        rms(A_f @ x_f - y_f), rms(A_t @ x_t - y_t))


def tilted_poses(start: pin.SE3) -> list[tuple[np.ndarray, np.ndarray]]:
    """(tip position, quaternion [w, x, y, z]) of each pose: the tip where ``start`` has it,
    the orientation tilted by POSE_TILT_DEG about the axes of POSES (base frame)."""
    out = []
    for axis in POSES:
        a = np.array(axis, dtype=float)
        R = np.eye(3) if not a.any() else pin.AngleAxis(math.radians(POSE_TILT_DEG),
                                                         a / np.linalg.norm(a)).matrix()
        quat = pin.Quaternion(R @ start.rotation)
        out.append((start.translation.copy(), np.array([quat.w, quat.x, quat.y, quat.z])))
    return out


def pose_targets(r: robots.Robot) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`tilted_poses` around the robot's home pose."""
    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.models.urdf import load_chain

    chain = load_chain("", r.urdf_file, r.base_link, r.tip_link)
    return tilted_poses(chain.tip_pose(np.array(r.home)))


def identify_on_robot(controller: str, settle: float, average: float,
                      timeout_s: float) -> tuple[ToolEstimate, str]:
    """The poses through the ROS topics of a running controller (:mod:`identify_ros`); the
    estimate and the sensor frame."""
    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.models.urdf import load_chain
    from cr_control.tools.identify_ros import RobotPoses

    client = RobotPoses(controller, timeout_s)
    try:
        names = ["robot_description", "urdf_file", "base_link", "tip_link", "sensor_frame",
                 "gravity", "approach_speed", "desired_force"]
        p = client.parameters(names)
        if not p["sensor_frame"]:
            raise ValueError(f"{controller} has no sensor_frame: set the wrist sensor's link")
        if p["approach_speed"]:
            raise ValueError(f"{controller} runs a guarded approach (approach_speed "
                             f"{p['approach_speed']:g}): start it with approach_speed 0 for the "
                             "poses in free space")
        if any(p["desired_force"]):
            raise ValueError(f"{controller} asks a contact force (desired_force "
                             f"{list(p['desired_force'])}): start it with desired_force zero for "
                             "the poses in free space")
        chain = load_chain(p["robot_description"], p["urdf_file"], p["base_link"], p["tip_link"])
        g_s, wrenches = client.run(chain, p["sensor_frame"], np.array(p["gravity"], dtype=float),
                                   tilted_poses, settle, average)
    finally:
        client.close()
    return estimate(g_s, wrenches), p["sensor_frame"]


def identify_in_simulator(robot_name: str, settle: float, average: float,
                          plant_overrides: dict | None = None) -> tuple[ToolEstimate, dict]:
    """Run the poses on the robot's simulated wrist sensor (module docstring); the estimate
    and the plant's parameters (the truth)."""
    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.schemes.registry import make_controller
    from cr_sim.plants.registry import make_plant

    r = robots.robot(robot_name)
    if r.wrench != "wrist":
        raise ValueError(f"{robot_name}'s wrench ({r.wrench}) does not carry the tool's weight: "
                         f"identify on a wrist-sensor profile ({', '.join(wrist_profiles())})")
    values = robots.plant_values(r)
    scenario = values.pop("scenario")
    values = {**values, "surface": "none", **(plant_overrides or {})}
    plant = make_plant(scenario, values)
    controller = make_controller(SCHEME, {**robots.robot_parameters(r), "posture": list(r.home)})
    frame = values["sensor_frame"]
    chain_model = controller.model.chain_model
    gravity = np.array(values["gravity"], dtype=float)
    n = chain_model.n
    read = [list(plant.joint_names).index(j) for j in controller.state_joint_names]
    period, t = 1e-3, 0.0
    no_force = np.zeros(3)
    g_s, wrenches = [], []
    for position, quaternion in pose_targets(r):
        controller.set_target_pose(position, quaternion)
        g_sum, w_sum, count = np.zeros(3), np.zeros(6), 0
        for k in range(int(round((settle + average) / period))):
            m = plant.measurement()
            q, v = m.position[read], m.velocity[read]
            out = controller.step(round(t * 1e9) * 1e-9, q, v, no_force)
            plant.step(out.command, period)
            if k * period >= settle:
                R = frame_rotation(chain_model, q[:n], frame)
                g_sum += R.T @ gravity
                w_sum += np.concatenate([m.force, m.torque])
                count += 1
            t += period
        g_s.append(g_sum / count)
        wrenches.append(w_sum / count)
    return estimate(np.array(g_s), np.array(wrenches)), values


def wrist_profiles() -> list[str]:
    """The robot profiles with a wrist force/torque sensor (what this tool identifies on)."""
    return sorted(name for name, r in robots.ROBOTS.items() if r.wrench == "wrist")


def params_file(node: str, frame: str, est: ToolEstimate, note: str) -> str:
    """The estimate as a ROS params file for the controller node ``node`` (YAML by
    ``yaml.safe_dump``: the node and frame are quoted as needed, the note one comment line)."""
    short = lambda x: float(f"{x:.6g}")  # noqa: E731
    values = {"sensor_frame": str(frame), "tool_mass": short(est.mass),
              "tool_com": [short(x) for x in est.com], "ft_bias": [short(x) for x in est.bias]}
    body = yaml.safe_dump({node: {"ros__parameters": values}}, default_flow_style=None,
                          sort_keys=False, width=1 << 16)
    return (f"# cr_identify_tool: {' '.join(note.split())}\n"
            f"# residual RMS: force {est.force_residual:.3g} N, torque {est.torque_residual:.3g} N m\n"
            f"{body}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="cr_identify_tool", description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", default="panda_ft", help=f"robot to simulate (a profile with a "
                   f"wrist sensor): {wrist_profiles()}")
    p.add_argument("--node", default=SCHEME, help="controller node name in the params file")
    p.add_argument("--out", type=Path, default=Path("tool.yaml"), help="params file to write")
    p.add_argument("--settle", type=float, default=3.0, help="settling time per pose (s)")
    p.add_argument("--average", type=float, default=1.0, help="averaging time per pose (s)")
    p.add_argument("--noise-seed", type=int, default=None, help="the simulated sensor's seed")
    p.add_argument("--controller", metavar="NODE",
                   help="on a robot (or a session over ROS): the running task-space controller "
                        "that holds the poses, e.g. /adaptive_impedance")
    p.add_argument("--domain-id", type=domain_id_arg, help="ROS_DOMAIN_ID (with --controller)")
    p.add_argument("--timeout", type=timeout_seconds, default=30.0,
                   help="wait at most this for the controller and the topics (s, at most 3600)")
    args = p.parse_args(argv)
    try:
        full_node_name(args.node)
    except ValueError as exc:
        print(f"cr_identify_tool: --node: {exc}", file=sys.stderr)
        return 2
    if args.controller:
        return _main_on_robot(args)
    try:
        if args.robot not in robots.ROBOTS:
            raise ValueError(f"unknown robot {args.robot!r}; known: {sorted(robots.ROBOTS)}")
        if not (0.0 <= args.settle <= 60.0 and 0.01 <= args.average <= 60.0):
            raise ValueError("--settle must be in [0, 60] s and --average in [0.01, 60] s")
        overrides = {} if args.noise_seed is None else {"noise_seed": args.noise_seed}
        est, truth = identify_in_simulator(args.robot, args.settle, args.average, overrides)
        note = (f"{args.robot} in the simulator, {len(POSES)} poses, {args.settle:g} s settle, "
                f"{args.average:g} s average")
        text = params_file(args.node, truth["sensor_frame"], est, note)
        args.out.write_text(text)
    except (ValueError, ParameterError, OSError) as exc:
        print(f"cr_identify_tool: {exc}", file=sys.stderr)
        return 2
    mass_err = 100.0 * (est.mass - truth["tool_mass"]) / truth["tool_mass"]
    com_err = 1e3 * float(np.linalg.norm(est.com - np.array(truth["tool_com"])))
    bias_err = np.abs(est.bias - np.array(truth["ft_bias"]))
    print(f"tool mass {est.mass:.4f} kg ({mass_err:+.2f} % of the simulated {truth['tool_mass']:g}), "
          f"com {np.round(est.com, 4).tolist()} m ({com_err:.2f} mm off), bias "
          f"{np.round(est.bias, 3).tolist()} (force within {bias_err[:3].max():.3f} N, torque "
          f"within {bias_err[3:].max():.4f} N m); written to {args.out}")
    return 0


def _main_on_robot(args: argparse.Namespace) -> int:
    """``--controller``: the poses through the ROS topics; the estimate written and printed."""
    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.core.ros_env import isolate_this_process

    try:
        node = full_node_name(args.controller)
        if not (0.0 <= args.settle <= 60.0 and 0.01 <= args.average <= 60.0):
            raise ValueError("--settle must be in [0, 60] s and --average in [0.01, 60] s")
        isolate_this_process(args.domain_id)
        est, frame = identify_on_robot(node, args.settle, args.average, args.timeout)
        note = (f"{node} over ROS, {len(POSES)} poses, {args.settle:g} s settle, "
                f"{args.average:g} s average")
        args.out.write_text(params_file(node.rpartition("/")[2], frame, est, note))
    except (ValueError, ParameterError, OSError, TimeoutError) as exc:
        print(f"cr_identify_tool: {exc}", file=sys.stderr)
        return 2
    print(f"tool mass {est.mass:.4f} kg, com {np.round(est.com, 4).tolist()} m, bias "
          f"{np.round(est.bias, 3).tolist()} (residual RMS {est.force_residual:.3g} N, "
          f"{est.torque_residual:.3g} N m); written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
