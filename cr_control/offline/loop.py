"""The offline loop: a plant and a controller stepped in one Python loop, no ROS.

Bit-for-bit deterministic (same inputs, same numbers); equivalent to the plant's
lockstep mode: the command computed from the state at t_k is held over [t_k, t_k+1).
The plant is stepped through the plant node's own supervision
(:class:`cr_sim.supervisor.PlantSupervisor`, as in lockstep; with the node's command limits,
effort bounds and torque-rate limit, where ``limiter`` gives them: :func:`.build.run_scheme`
does, as the plant node would set them): a reflex (contact force, joint velocity) engages
the safe stop at the step a lockstep session would, the brakes act from then on (the
controller's commands are still recorded, as a session records them), and the run says so
(``safe_stop_reason``, ``safe_stop_at``, ``safe_stop_text``). A run that trips no reflex and
meets no limit is the loop without supervision, bit for bit. ``delay`` is the driver's
transport delay (:class:`cr_sim.transport_delay.TransportDelay`, stepped by the supervisor as
the node's is, so lockstep with the same ``command_delay_cycles`` and bursts agrees): the
command answering the state at t_k is then applied over [t_k+d, t_k+d+1); ``command`` keeps
what the controller sent.

A controller that reads the whole wrench (``reads_wrench``: a wrist sensor to compensate)
is given force and torque, as the node gives it a WrenchStamped's; the plant's true contact
force (``/plant/contact_wrench`` over ROS) is kept in ``true_force`` where the plant has
one. ``hook(k, t, controller, plant)``, called before each cycle, stands in for what a ROS
session does between cycles (a ``~/zero_ft`` call, a ``~/target_pose``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cr_control.schemes.controller import Controller
from cr_sim.plants.base import CommandLimiter, Plant
from cr_sim.supervisor import PlantSupervisor
from cr_sim.transport_delay import TransportDelay


@dataclass
class OfflineRun:
    """Everything one offline run produced, one row per control cycle."""

    time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    force: np.ndarray
    command: np.ndarray
    reference: np.ndarray
    status: np.ndarray
    reference_fields: list[str]
    status_fields: list[str]
    #: The plant's true (noise-free) contact force, base frame, where the plant has one
    #: (``contact_force``: urdf_surface, the thesis arms); NaN otherwise.
    true_force: np.ndarray | None = None
    #: The plant's safe stop: its reason (cr_sim.loop_stats.SAFE_STOP_*; 0: none), the
    #: simulated time it began (s; NaN: never) and its log line ("REFLEX: ...").
    safe_stop_reason: int = 0
    safe_stop_at: float = float("nan")
    safe_stop_text: str = ""

    def column(self, name: str) -> np.ndarray:
        """A named reference or status column (fields of topics.py)."""
        if name in self.status_fields:
            return self.status[:, self.status_fields.index(name) - 1]
        return self.reference[:, self.reference_fields.index(name) - 1]


def run(controller: Controller, plant: Plant, duration: float, period: float = 1e-3,
        hook: Callable[[int, float, Controller, Plant], None] | None = None,
        supervise: bool = True, limiter: CommandLimiter | None = None,
        delay: TransportDelay | None = None,
        wrench_ages: np.ndarray | None = None) -> OfflineRun:
    """Step ``plant`` and ``controller`` for ``duration`` s at ``period`` (module docstring);
    ``supervise`` False: without the plant's supervision (no reflex, no brakes, no limits;
    the delay still acts: it is the driver's); ``limiter``: the plant node's command limits
    (None: none); ``delay``: the driver's transport delay (None: none); ``wrench_ages``: per
    step, how many periods older than the state the wrench the controller reads is (a
    controller node's ``wrench_age_ms`` replayed: what it read over ROS; -1: none yet, zeros;
    None: every state's own, as a node reads it when the plant's wrench comes first)."""
    steps = int(round(duration / period))
    n = len(plant.joint_names)
    n_command = len(plant.command_joints)
    # joints by name, as the nodes match them: the controller reads its own joints of the
    # plant's state (a plant may publish more, e.g. locked fingers) and commands the plant's
    # commanded joints in its own order
    missing = [j for j in controller.state_joint_names if j not in plant.joint_names]
    commanded = list(controller.values["joint_names"])
    if missing or sorted(commanded) != sorted(plant.command_joints):
        raise ValueError(f"{controller.scheme} reads {controller.state_joint_names} and commands "
                         f"{commanded}; the plant gives {list(plant.joint_names)} and takes "
                         f"{list(plant.command_joints)}")
    read = [list(plant.joint_names).index(j) for j in controller.state_joint_names]
    read = None if read == list(range(n)) else read
    to_plant = [commanded.index(j) for j in plant.command_joints]
    to_plant = None if to_plant == list(range(n_command)) else to_plant
    sensor_index = None
    if controller.plant_sensor_fields:
        fields = list(plant.sensor_fields)
        missing = [f for f in controller.plant_sensor_fields if f not in fields]
        if missing:
            raise ValueError(f"{controller.scheme} reads plant sensors {missing}; the plant "
                             f"offers {fields}")
        sensor_index = [fields.index(f) for f in controller.plant_sensor_fields]
    rows = {
        "time": np.empty(steps), "position": np.empty((steps, n)), "velocity": np.empty((steps, n)),
        "force": np.empty((steps, 3)), "command": np.empty((steps, n_command)),
        "reference": np.empty((steps, len(controller.reference_fields) - 1)),
        "status": np.empty((steps, len(controller.status_fields) - 1)),
        "true_force": np.full((steps, 3), np.nan),
    }
    true_force = getattr(plant, "contact_force", None)
    supervisor = PlantSupervisor(plant, period, limiter, delay=delay) if supervise else None
    delayed = delay if delay is not None and not delay.passes_through else None
    wrenches: list[np.ndarray] = []         # each step's, for wrench_ages
    for k in range(steps):
        m = plant.measurement()
        if hook is not None:
            hook(k, m.time, controller, plant)
        if sensor_index is not None:
            sensors = plant.sensors()
            controller.plant_sensors[:] = [sensors[i] for i in sensor_index]
        # the stamp as the controller node sees it (integer nanoseconds in the header):
        # lockstep over ROS then reproduces this loop bit for bit, even where the closed
        # loop amplifies round-off (fjr_robust_adaptive's boundary layer at 1 kHz)
        if true_force is not None:
            f_true = true_force()
            rows["true_force"][k, :f_true.shape[0]] = f_true
        sec, nanosec = divmod(round(m.time * 1e9), 1_000_000_000)
        q, v = (m.position, m.velocity) if read is None else (m.position[read], m.velocity[read])
        force = (np.concatenate([m.force, m.torque]) if getattr(controller, "reads_wrench", False)
                 else m.force)
        if wrench_ages is not None:
            wrenches.append(force)
            age = int(wrench_ages[k])
            force = wrenches[max(0, k - age)] if age >= 0 else np.zeros_like(force)
        out = controller.step(sec + nanosec * 1e-9, q, v, force)
        command = out.command if to_plant is None else out.command[to_plant]
        if supervisor is None:
            plant.step(command if delayed is None else delayed(command), period)
        else:
            supervisor.hold(command)
            supervisor.step()
        rows["time"][k] = m.time
        rows["position"][k] = m.position
        rows["velocity"][k] = m.velocity
        rows["force"][k] = m.force
        rows["command"][k] = command
        rows["reference"][k] = out.reference
        rows["status"][k] = out.status
    stop = {} if supervisor is None or supervisor.stop_time is None else {
        "safe_stop_reason": supervisor.stop_reason, "safe_stop_at": supervisor.stop_time,
        "safe_stop_text": supervisor.stop_text}
    return OfflineRun(**rows, reference_fields=list(controller.reference_fields),
                      status_fields=list(controller.status_fields), **stop)
