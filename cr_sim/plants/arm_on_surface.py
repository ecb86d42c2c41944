"""A planar arm pressing a compliant surface: the plant of chapters 3 and 5.

Robot (3.1, 3.35, 5.1): M q'' + C q' + G = tau + J^T (f + f_dist), f the unilateral contact
force of the surface (:mod:`cr_sim.models.surfaces`, 3.4), f_dist an external force on the
end effector. Classical RK4 with the command held over the period, the contact force
evaluated at every stage (``substeps`` RK4 steps per period where the contact is stiff).
One compiled call per control period advances the state and evaluates the sensors at the
new state, so the plant's share of the 1 kHz cycle stays a few microseconds.

The arm comes from the URDF through Pinocchio (:mod:`cr_control.models.arm_model`) and is packed
into a :class:`~cr_control.models.planar_chain.PlanarChain` for the compiled dynamics. Every
thesis scenario with an arm (chapters 2, 3, 5, 6) names it by the robot parameters
(:func:`robot_parameters`: ``robot_description`` or ``urdf_file``, ``base_link``,
``tip_link``, as the controllers do) and overrides its geometry and inertia by the ``link_*``
parameters (:func:`arm_parameters`, the thesis's values by default: the thesis URDFs carry the
same ones). The scenarios are defined for a planar 2-link arm (closed-form inverse
kinematics, the 2-link closures of chapters 2 and 6): any other chain is refused
(:func:`thesis_chain`) in favour of the scenario ``urdf_surface``. The plant's joint names
are the URDF's.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.arm_model import LinkParameters, NotTwoLinkArmError, TwoLinkArm, two_link_chain
from cr_control.models.planar_chain import (
    GEOMETRY_ROWS,
    PlanarChain,
    forward_dynamics_geo,
    geometry_into,
    matvec,
    tool_geo,
    tool_kinematics,
)
from cr_control.models.urdf import ChainModel
from cr_sim.models.surfaces import surface_contact
from cr_sim.plants.base import Measurement, Plant, take_command

#: Sensor values written by the step kernel: contact force, depth, tool position, velocity.
SENSORS = ("f_x", "f_y", "depth", "r_x", "r_y", "v_x", "v_y")


#: The scenario for an arm that is not a planar 2-link one.
ANY_ARM_SCENARIO = "urdf_surface"


def robot_parameters(urdf_file: str, arm: str) -> list[Param]:
    """The robot a thesis arm scenario simulates (the controllers' parameters of the same
    names, :data:`cr_control.schemes.blocks.task_space.ROBOT_PARAMETERS`); ``urdf_file`` is the
    scenario's default, ``arm`` says which arm that is."""
    return [
        Param("robot_description", "", "The arm's URDF XML (as robot_state_publisher takes it); "
              "if empty, urdf_file is read.", "string", read_only=True),
        Param("urdf_file", urdf_file, "URDF file: a path, a file of cr_control's config "
              f"directory, or package://PKG/path. Default: {arm}. The chain must be a planar "
              "2-link arm (two revolute joints about z; link_* override its geometry and "
              f"inertia); any other arm: the scenario {ANY_ARM_SCENARIO}.", "string",
              read_only=True),
        Param("base_link", "base_link", "First link of the arm's chain: the plant's frame (the "
              "arm's first joint at its origin, gravity along its -y).", "string",
              read_only=True),
        Param("tip_link", "tool0", "End-effector link: the point that touches the environment.",
              "string", read_only=True),
    ]


def arm_parameters(length: float, com: float) -> list[Param]:
    """The arm's geometric and inertial parameters with the given link length and centre of mass
    (m = 0.1 kg, I = 0.3 kg m^2 in every chapter); they override the URDF's values."""
    return [
        Param("link_length", [length, length], "Link lengths (m): joint 2 and the tip along the "
              "x axis of links 1 and 2 (override the URDF's).", "positive_vector", 2,
              read_only=True, bound=Bound.LENGTH),
        Param("link_com", [com, com], "Centre-of-mass distance from each joint along its link's "
              "x axis (m) (overrides the URDF's).", "positive_vector", 2, read_only=True, bound=Bound.LENGTH),
        Param("link_mass", [0.1, 0.1], "Link masses (kg) (override the URDF's).",
              "positive_vector", 2, read_only=True, bound=Bound.MASS),
        Param("link_inertia", [0.3, 0.3], "Link inertias about the centre of mass (kg m^2) "
              "(override the URDF's).", "positive_vector", 2, read_only=True, bound=Bound.INERTIA),
        Param("gravity", 9.8, "Gravitational acceleration along -y (m/s^2).", "nonnegative",
              read_only=True, bound=Bound.GRAVITY),
    ]


def link_parameters(values: dict) -> LinkParameters:
    """The LinkParameters of a scenario's ``link_*`` and ``gravity`` values."""
    return LinkParameters(length=list(values["link_length"]), com=list(values["link_com"]),
                          mass=list(values["link_mass"]), inertia=list(values["link_inertia"]),
                          gravity=values["gravity"])


def thesis_chain(values: dict, scenario: str) -> ChainModel:
    """The planar 2-link arm named by the robot parameters of ``values`` with its ``link_*``
    and ``gravity`` applied (:func:`cr_control.models.arm_model.two_link_chain`).
    ParameterError (one line): the URDF's own reason if it cannot be loaded; ``scenario``'s
    need of a planar 2-link arm if its chain is another one."""
    try:
        return two_link_chain(values["robot_description"], values["urdf_file"],
                              values["base_link"], values["tip_link"], link_parameters(values))
    except NotTwoLinkArmError as exc:
        raise ParameterError(f"{scenario} simulates a planar 2-link arm, but {exc}; the scenario "
                             f"{ANY_ARM_SCENARIO} simulates any other arm") from None
    except ValueError as exc:      # RobotModelError, or link parameters that are not physical
        raise ParameterError(str(exc)) from None


def disturbance_parameters(amplitude: list[float], frequency: float, start: float,
                           duration: float, what: str) -> list[Param]:
    """Parameters of the external force f_dist on the end effector with the given defaults."""
    return [
        Param("disturbance_amplitude", amplitude,
              f"External disturbance force f_dist on the end effector (N) ({what}); 0 = none.",
              "vector", 2, read_only=True, bound=Bound.FORCE),
        Param("disturbance_frequency", frequency,
              "f_dist = amplitude*sin(w (t - start)) with this w (rad/s); 0 = constant force.",
              "nonnegative", read_only=True, bound=Bound.BANDWIDTH),
        Param("disturbance_start", start, "Time the disturbance starts (s).", "nonnegative",
              read_only=True, bound=Bound.TIME),
        Param("disturbance_duration", duration, "How long it lasts (s); 0 = to the end.",
              "nonnegative", read_only=True, bound=Bound.TIME),
    ]


NOISE_PARAMETERS = [
    Param("position_noise_std", 0.0, "Joint position measurement noise, std (rad).",
          "nonnegative", read_only=True, bound=Bound.POSITION_NOISE),
    Param("velocity_noise_std", 0.0, "Joint velocity measurement noise, std (rad/s).",
          "nonnegative", read_only=True, bound=Bound.VELOCITY_NOISE),
    Param("force_noise_std", 0.0, "Force measurement noise, std (N).", "nonnegative",
          read_only=True, bound=Bound.FORCE),
    Param("noise_seed", 0, "Seed of the measurement noise.", "integer", read_only=True,
          bound=Bound.SEED),
]


@njit(cache=True, error_model="numpy")
def _disturbance(disturbance, t):
    amplitude_x, amplitude_y, omega, start, duration = (
        disturbance[0], disturbance[1], disturbance[2], disturbance[3], disturbance[4])
    if t < start or (duration > 0.0 and t >= start + duration):
        return 0.0, 0.0
    if omega > 0.0:
        s = math.sin(omega * (t - start))
        return amplitude_x * s, amplitude_y * s
    return amplitude_x, amplitude_y


def work_size(n: int) -> int:
    """Scratch floats of one plant step for an n-link arm (allocated once per plant)."""
    return GEOMETRY_ROWS * n + (6 * n + n * n) + 2 * n + 4 + n + 5 * 2 * n


@njit(cache=True, error_model="numpy")
def _derivative_into(chain, surface, disturbance, t, x, tau, work, out):
    """out = x' = [q', q''] with the contact and disturbance forces at the tool; ``work``
    holds work_size(n) floats (the RK4 buffers at its end are not touched)."""
    n = x.shape[0] // 2
    q, v = x[:n], x[n:]
    g = GEOMETRY_ROWS * n
    geo = work[:g].reshape((GEOMETRY_ROWS, n))
    fd_work = work[g:g + 6 * n + n * n]
    k = g + 6 * n + n * n
    J = work[k:k + 2 * n].reshape((2, n))
    tool = work[k + 2 * n:k + 2 * n + 4]
    total = work[k + 2 * n + 4:k + 3 * n + 4]
    geometry_into(chain, q, geo)
    tool_geo(chain, geo, v, J, tool)
    vx = vy = 0.0
    for j in range(n):
        vx += J[0, j] * v[j]
        vy += J[1, j] * v[j]
    fx, fy, _, _, _ = surface_contact(surface, tool[0], tool[1], vx, vy)
    dx, dy = _disturbance(disturbance, t)
    fx += dx
    fy += dy
    for j in range(n):
        total[j] = tau[j] + J[0, j] * fx + J[1, j] * fy
        out[j] = v[j]
    forward_dynamics_geo(chain, geo, v, total, fd_work, out[n:])


@njit(cache=True, error_model="numpy")
def _sensors(chain, surface, x, out):
    n = x.shape[0] // 2
    r, J, _ = tool_kinematics(chain, x[:n], x[n:])
    r_dot = matvec(J, x[n:])
    fx, fy, depth, _, _ = surface_contact(surface, r[0], r[1], r_dot[0], r_dot[1])
    out[0], out[1], out[2] = fx, fy, depth
    out[3], out[4], out[5], out[6] = r[0], r[1], r_dot[0], r_dot[1]


@njit(cache=True, error_model="numpy")
def arm_on_surface_step(chain, surface, disturbance, t, x, tau, command, dt, substeps, sensors,
                        work):
    """Take ``command`` as the held torque ``tau`` if it has one finite value per joint
    (else keep the last), advance x in place by ``dt``: ``substeps`` classical RK4 steps;
    write SENSORS at the new state into ``sensors``. Returns whether the command was taken."""
    accepted = take_command(tau, command)
    m = x.shape[0]
    rk = work.shape[0] - 5 * m
    k1, k2, k3 = work[rk:rk + m], work[rk + m:rk + 2 * m], work[rk + 2 * m:rk + 3 * m]
    k4, xs = work[rk + 3 * m:rk + 4 * m], work[rk + 4 * m:rk + 5 * m]
    h = dt / substeps
    for i in range(substeps):
        ti = t + i * h
        _derivative_into(chain, surface, disturbance, ti, x, tau, work, k1)
        for j in range(m):
            xs[j] = x[j] + 0.5 * h * k1[j]
        _derivative_into(chain, surface, disturbance, ti + 0.5 * h, xs, tau, work, k2)
        for j in range(m):
            xs[j] = x[j] + 0.5 * h * k2[j]
        _derivative_into(chain, surface, disturbance, ti + 0.5 * h, xs, tau, work, k3)
        for j in range(m):
            xs[j] = x[j] + h * k3[j]
        _derivative_into(chain, surface, disturbance, ti + h, xs, tau, work, k4)
        for j in range(m):
            x[j] = x[j] + (h / 6.0) * (k1[j] + k4[j] + 2.0 * (k2[j] + k3[j]))
    _sensors(chain, surface, x, sensors)
    return accepted


class ArmOnSurface(Plant):
    """A planar 2-link arm from the URDF pressing a packed compliant surface; scenario modules
    give the surface, the initial state and the defaults. State x = [q, q']."""

    command_interface = "effort"
    #: The scenario's name, for the refusal of an arm it does not simulate.
    scenario = "arm_on_surface"

    def __init__(self, values: dict, surface: np.ndarray, q0: np.ndarray):
        if values["substeps"] < 1:
            raise ParameterError("substeps must be >= 1")
        self.arm = TwoLinkArm(link_parameters(values), chain=thesis_chain(values, self.scenario))
        self.joint_names = self.arm.joint_names
        self.chain = PlanarChain.from_model(self.arm.model, values["tip_link"]).chain
        self.surface = surface
        self.substeps = int(values["substeps"])
        self.disturbance_packed = np.array([
            *values["disturbance_amplitude"], values["disturbance_frequency"],
            values["disturbance_start"], values["disturbance_duration"]], dtype=float)
        self._noise = (values["position_noise_std"], values["velocity_noise_std"],
                       values["force_noise_std"])
        self._noisy = any(self._noise)
        self._rng = np.random.default_rng(values["noise_seed"])
        n = len(self.joint_names)
        self._n = n
        self.max_contact_force = float(values["max_contact_force"])
        self._t = 0.0
        self._effort = np.zeros(n)
        self.sensors = np.zeros(len(SENSORS))
        self._work = np.empty(work_size(n))
        self.reset_state(q0)
        # Load the compiled step now (a zero-length step on copies), not in the first cycle.
        arm_on_surface_step(self.chain, self.surface, self.disturbance_packed, 0.0,
                            self._x.copy(), self._effort.copy(), self._effort, 0.0, 1,
                            self.sensors.copy(), self._work)

    def reset_state(self, q0, v0=None) -> None:
        """Put the arm at q0 (at rest unless v0 is given), time unchanged."""
        n = self._n
        self._x = np.concatenate([np.asarray(q0, dtype=float),
                                  np.zeros(n) if v0 is None else np.asarray(v0, dtype=float)])
        _sensors(self.chain, self.surface, self._x, self.sensors)

    def contact_force(self) -> np.ndarray:
        """Force of the surface on the end effector now (2 components)."""
        return self.sensors[:2].copy()

    def contact_force_magnitude(self) -> float:
        """|f| (N) of the surface's force on the end effector, without the measurement noise."""
        return math.hypot(self.sensors[0], self.sensors[1])

    def true_velocity(self) -> list[float]:
        """q' without the measurement noise."""
        return self._x[self._n:].tolist()

    def step(self, command: np.ndarray, dt: float) -> None:
        """Advance by dt with joint torques ``command`` held (a refused command keeps the last)."""
        arm_on_surface_step(self.chain, self.surface, self.disturbance_packed, self._t, self._x,
                            self._effort, command, dt, self.substeps, self.sensors, self._work)
        self._t += dt

    def measurement(self) -> Measurement:
        n, x, sensors = self._n, self._x, self.sensors
        q, v = x[:n].copy(), x[n:].copy()
        force = np.array([sensors[0], sensors[1], 0.0])
        if self._noisy:
            q_std, v_std, f_std = self._noise
            q += q_std * self._rng.standard_normal(n)
            v += v_std * self._rng.standard_normal(n)
            force[:2] += f_std * self._rng.standard_normal(2)
        return Measurement(self._t, q, v, self._effort.copy(), force)
