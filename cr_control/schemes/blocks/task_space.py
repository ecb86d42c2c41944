"""The task space of any serial arm from its URDF: the thesis's task-space model (3.2) on n joints.

Chapter 3 writes the arm seen from its end effector as (3.2)

    M_r r'' + C_r r' + G_r = J^-T tau + f,   M_r = J^-T M J^-1,
    C_r = J^-T (M d(J^-1)/dt + C J^-1),      G_r = J^-T G,

for a square Jacobian J (the planar 2-link arm). For n joints and an m-dimensional position
task (m = 2 on a planar arm, 3 on a spatial one) J^-1 becomes the dynamically consistent
generalised inverse (Khatib 1987) J_bar = M^-1 J^T Lambda, Lambda = (J M^-1 J^T)^-1, and

    M_r = Lambda
    C_r v = Lambda (J M^-1 C J_bar v - J' J_bar v)                 (d(J_bar)/dt ~ -J_bar J' J_bar)
    G_r = Lambda J M^-1 G
    tau = J^T (M_r a + C_r v + G_r + F) + N^T tau_0,   N = I - J_bar J,

which are exactly the thesis's expressions when n = m (J_bar = J^-1, N = 0): the planar
thesis arm is the special case of this one path. C is the Christoffel-form Coriolis matrix
(C v products from the compiled chain, :mod:`cr_control.models.spatial_chain`).

The scheme's law owns the position task: it chooses the task acceleration a, the velocity
v it is evaluated at and any extra task force F (3.32, 3.48, 3.76, 5.7). Everything else
acts in the dynamically consistent null space of the position task, so it never disturbs
the law's closed loop:

- a Cartesian orientation impedance m_o = K_o e_o + D_o (w_d - w), e_o = log(R_d R^T)
  (:mod:`cr_control.core.so3`), tau_o = J_o^T m_o, on the rotation axes the arm can turn
  (all three for a spatial arm, none for the 2-link arm);
- a posture task tau_p = K_n (q_p - q) - D_n q' in the null space of position and
  orientation together (redundant arms: the Panda's elbow);
- gravity: J^T G_r compensates only the task part of G, so N^T G is added.

Near singularities the generalised inverse is damped: Lambda = (J M^-1 J^T + lambda^2 I)^-1
with lambda^2 = max(0, 1/m_s - mu_min), mu_min the smallest eigenvalue of J M^-1 J^T, so the
task's apparent mass never exceeds ``singularity_mass`` m_s (default 100 kg: the thesis's
paths reach 14 kg on the chapter 3 arm and 25 kg on the chapter 5 arm, so they are never
damped; the Panda and UR5 sit at 2-10 kg away from singularities). ``singularity_damping``
in the status reports lambda^2. The stacked position/orientation Jacobian of the posture
projector has its rotation rows scaled by ORIENTATION_LENGTH (0.1 m) so one cap in kg holds
for both.

Joint limits from the URDF: each command is clipped to the joint's effort limit, and a
guard pushes back within ``joint_limit_margin`` of a position limit (stiffness
``joint_limit_stiffness``) and brakes a joint beyond VELOCITY_FRACTION of its velocity
limit (``joint_limit_damping``); the thesis runs never come near either.
A scheme that must not use a dynamics model (3.76) works with ``model_free``: M = I, no
gravity, so its projectors are the kinematic ones.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from cr_control.core.linalg import (
    cholesky_into,
    cholesky_solve_into,
    cholesky_solve_matrix,
    matmul,
    matvec,
    min_eigenvalue_sym,
    spd_inverse,
    tmatvec,
)
from cr_control.core.packing import Layout, take, views_layout
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.core.so3 import orientation_error
from cr_control.models import spatial_chain as sc
from cr_control.models.urdf import ChainModel, RobotModelError, Tool, load_chain
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks.references import (
    desired_motion,
    guard_gains_of,
    guard_state_of,
    reference_gains_size,
    reference_state_views,
    target_pace,
)

#: Rotation rows of the posture projector are scaled by this length (m), see the docstring.
ORIENTATION_LENGTH = 0.1
#: The velocity guard brakes a joint beyond this fraction of its URDF velocity limit.
VELOCITY_FRACTION = 0.8
AXES = "xyz"

#: The robot a task-space controller acts on (read-only: the model is built once).
ROBOT_PARAMETERS = [
    Param("robot_description", "", "The robot's URDF XML (as robot_state_publisher takes it); "
          "if empty, urdf_file is read.", "string", read_only=True),
    Param("urdf_file", "two_link_arm.urdf", "URDF file: a path, a file of cr_control's config "
          "directory, or package://PKG/path. Default: the thesis's 2-link arm (0.3 m links).",
          "string", read_only=True),
    Param("base_link", "base_link", "First link of the controlled chain: positions, the target "
          "pose and the wrench are expressed in its frame.", "string", read_only=True),
    Param("tip_link", "tool0", "End-effector link: the point whose motion and contact force "
          "the law controls.", "string", read_only=True),
    Param("gravity", [0.0, -9.8, 0.0], "Gravity in the base frame (m/s^2); the thesis arm moves "
          "in the vertical x-y plane (9.8 along -y), a URDF arm usually has [0, 0, -9.81].",
          "vector", 3, read_only=True, bound=Bound.GRAVITY),
    Param("robot_compensates_gravity", False, "The robot adds g(q) to every command itself, as "
          "torque-controlled arms' drivers do (franka_ros2: libfranka; ur_robot_driver's effort "
          "interface; KUKA FRI torque mode; CRISP's use_gravity_compensation is off by default "
          "for this reason): the command then leaves the arm's and the tool's gravity out. The "
          "wrist sensor's tool compensation, zeroing and cr_identify_tool still use gravity. "
          "Check this first on a real robot: a wrong value lifts the arm or lets it fall (the "
          "start check stops it).", "bool", read_only=True),
    Param("robot_compensates_friction", False, "The robot compensates its joints' friction "
          "itself (ur_robot_driver's effort interface does); false: the controller adds the "
          "URDF's <dynamics damping friction> torque D q' + F tanh(q'/0.01) to its command "
          "(zero where the URDF gives none).", "bool", read_only=True),
    Param("model_mass_scale", 1.0, "The controller's model: every link mass times this (1 = the "
          "URDF's; a deliberately wrong model shows robustness).", "positive", read_only=True,
          bound=Bound.SCALE),
    Param("model_inertia_scale", 1.0, "The controller's model: every rotational inertia about "
          "the centre of mass times this.", "positive", read_only=True, bound=Bound.SCALE),
]

#: Everything below the position task: orientation, posture, singularities, joint limits.
NULL_SPACE_PARAMETERS = [
    Param("orientation_stiffness", [30.0, 30.0, 30.0], "Cartesian orientation impedance: "
          "stiffness K_o per rotation axis of the base frame (N m/rad); acts on the axes the "
          "arm can turn beside its position task (none on the thesis's 2-link arm).",
          "nonnegative_vector", 3, bound=Bound.GAIN),
    Param("orientation_damping", [3.0, 3.0, 3.0], "Cartesian orientation impedance: damping "
          "D_o per rotation axis (N m s/rad).", "nonnegative_vector", 3, bound=Bound.GAIN),
    Param("posture", [], "Joint posture the null space is pulled to (one value per chain "
          "joint, rad or m); empty = the configuration of the first state.", "vector",
          read_only=True, bound=Bound.JOINT),
    Param("posture_stiffness", 10.0, "Null-space posture stiffness K_n (N m/rad), acting only "
          "where neither position nor orientation needs the joints.", "nonnegative", bound=Bound.GAIN),
    Param("posture_damping", 2.0, "Null-space posture damping D_n (N m s/rad).", "nonnegative",
          bound=Bound.GAIN),
    Param("singularity_mass", 100.0, "The generalised inverse is damped so that the task's "
          "apparent mass stays below this (kg): zero damping away from singularities.",
          "positive", bound=Bound.MASS),
    Param("joint_limit_margin", 0.1, "Within this of a URDF position limit (rad or m) the "
          "joint limit guard pushes back.", "nonnegative", bound=Bound.JOINT),
    Param("joint_limit_stiffness", 50.0, "Joint limit guard stiffness (N m/rad).", "nonnegative",
          bound=Bound.GAIN),
    Param("joint_limit_damping", 20.0, f"Joint limit guard: braking per rad/s beyond "
          f"{VELOCITY_FRACTION:g} of a URDF velocity limit (N m s/rad).", "nonnegative", bound=Bound.GAIN),
]

#: Packed form of the live NULL_SPACE_PARAMETERS (names = parameter names).
NULL_SPACE_GAINS = Layout(orientation_stiffness=3, orientation_damping=3, posture_stiffness=1,
                          posture_damping=1, singularity_mass=1, joint_limit_margin=1,
                          joint_limit_stiffness=1, joint_limit_damping=1)
_K_O, _D_O, _K_N, _D_N, _M_S, _MARGIN, _K_LIM, _D_LIM = (
    NULL_SPACE_GAINS.offset(name) for name in NULL_SPACE_GAINS.shapes)
NULL_SPACE_SIZE = NULL_SPACE_GAINS.size


# -- the model, built once ------------------------------------------------------------------------
@dataclass(frozen=True)
class TaskModel:
    """The chain and the task rows of one robot (Python side, made at start-up).

    ``task`` is the packed description the kernels read: [n, m, m_o, position rows (3),
    orientation rows (3), model_free]; rows index the 6 rows [v_x, v_y, v_z, w_x, w_y, w_z]
    of the tip's Jacobian, -1 where unused. ``limits`` packs lower, upper, velocity, effort.
    """

    chain_model: ChainModel
    chain: np.ndarray
    task: np.ndarray
    limits: np.ndarray
    position_axes: tuple[str, ...]
    orientation_axes: tuple[str, ...]

    @property
    def n(self) -> int:
        return self.chain_model.n

    @property
    def m(self) -> int:
        return len(self.position_axes)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.chain_model.joint_names

    @property
    def redundant(self) -> bool:
        """True if joints are left after position and orientation: a posture task acts."""
        return self.n > self.m + len(self.orientation_axes)


def moved_rows(chain: np.ndarray, chain_model: ChainModel, samples: int = 8) -> list[int]:
    """Rows of the 6-row tip Jacobian that are not zero everywhere: a planar arm moves the
    tip in its plane and turns it about the plane's normal only (sampled over random
    configurations within the joint limits, fixed seed)."""
    rng = np.random.default_rng(1)
    lim = chain_model.limits
    lower = np.where(np.isfinite(lim.lower), lim.lower, -np.pi)
    upper = np.where(np.isfinite(lim.upper), lim.upper, np.pi)
    peak = np.zeros(6)
    zero = np.zeros(chain_model.n)
    for _ in range(samples):
        _, _, J, _ = sc.tip_kinematics(chain, rng.uniform(lower, upper), zero)
        peak = np.maximum(peak, np.abs(J).max(axis=1))
    return [i for i in range(6) if peak[i] > 1e-9]


def scaled_chain(chain: np.ndarray, mass_scale: float, inertia_scale: float) -> np.ndarray:
    """A copy of a packed chain with every mass and rotational inertia scaled."""
    out = chain.copy()
    sc.scale_inertias(out, mass_scale, inertia_scale)
    return out


@lru_cache(maxsize=16)
def _task_model(urdf: str, urdf_file: str, base: str, tip: str, gravity: tuple[float, ...],
                mass_scale: float, inertia_scale: float, model_free: bool,
                tool: tuple | None = None) -> TaskModel:
    try:
        chain_model = load_chain(urdf, urdf_file, base, tip, np.array(gravity),
                                 tool=None if tool is None else Tool(*tool))
    except RobotModelError as exc:
        raise ParameterError(str(exc)) from None
    packed = sc.SpatialChain.from_chain(chain_model).chain
    rows = moved_rows(packed, chain_model)
    position = [r for r in rows if r < 3]
    rotation = [r - 3 for r in rows if r >= 3]
    n = chain_model.n
    if len(position) > n:
        raise ParameterError(f"{n} joints cannot move the tip in {len(position)} directions: "
                             "a position task needs at least as many joints")
    if len(position) + len(rotation) > n:
        rotation = []      # not enough joints to hold the orientation too: position only
    task = np.full(10, -1.0)
    task[0], task[1], task[2] = n, len(position), len(rotation)
    task[3:3 + len(position)] = position
    task[6:6 + len(rotation)] = rotation
    task[9] = 1.0 if model_free else 0.0
    model_chain = sc.kinematics_only(packed) if model_free else scaled_chain(packed, mass_scale,
                                                                              inertia_scale)
    lim = chain_model.limits
    limits = np.concatenate([lim.lower, lim.upper, lim.velocity, lim.effort])
    return TaskModel(chain_model, model_chain, task, limits,
                     tuple(AXES[r] for r in position), tuple(AXES[r] for r in rotation))


def task_model(values: dict, model_free: bool = False) -> TaskModel:
    """The task model of the robot named by the ROBOT_PARAMETERS ``values`` (cached;
    ParameterError with a one-line reason if the robot cannot be built). Its dynamics have no
    gravity where the robot adds g(q) itself (``robot_compensates_gravity``). With a wrist sensor
    carrying a tool (``sensor_frame`` and ``tool_mass`` > 0) the tool replaces what
    the URDF mounts beyond the sensor (:class:`cr_control.models.urdf.Tool`: a point mass at
    ``tool_com``), as on the arm it carries."""
    frame, mass = values.get("sensor_frame", ""), float(values.get("tool_mass", 0.0))
    tool = (frame, mass, tuple(float(c) for c in values["tool_com"])) if frame and mass > 0 else None
    gravity = (0.0, 0.0, 0.0) if values.get("robot_compensates_gravity", False) else tuple(
        float(g) for g in values["gravity"])
    return _task_model(values["robot_description"], values["urdf_file"], values["base_link"],
                       values["tip_link"], gravity,
                       float(values["model_mass_scale"]), float(values["model_inertia_scale"]),
                       model_free, tool)


def status_fields(model: TaskModel) -> tuple[list[str], list[str]]:
    """(reference fields, status fields) of a task-space scheme on ``model``, stamps first:
    per position axis r_d, v_d, a_d, f_d; r, v, f, e, f_err; tau per joint; then
    compute_time_us, held, singularity_damping, the orientation error per held rotation axis,
    on a redundant arm the posture error |N_s^T (q_p - q)| (what the posture task,
    projected beside position and orientation, still pulls at: 0 once the posture is as
    close to q_p as the task allows), then the guard's fields
    (:data:`contact_guard.GUARD_STATUS_FIELDS`: approach phase, stale targets, the
    monitor's oscillation RMS and impedance scales, the lightest joint's oscillation and the
    joint-space gains' scale).
    On the thesis arm the fields up to held are topics' 2-D ones."""
    ax = model.position_axes
    per = lambda names: [f"{name}_{a}" for name in names for a in ax]  # noqa: E731
    reference = ["stamp"] + per(["r_d", "v_d", "a_d", "f_d"])
    status = (["stamp"] + per(["r", "v", "f", "e", "f_err"])
              + [f"tau_{i + 1}" for i in range(model.n)] + ["compute_time_us", "held"])
    task = ["singularity_damping"] + [f"e_rot_{a}" for a in model.orientation_axes]
    if model.redundant:
        task.append("posture_error")
    return reference, status + task + guard.GUARD_STATUS_FIELDS


# -- compiled: one cycle's task frame -------------------------------------------------------------
TaskFrame = namedtuple("TaskFrame", [
    "q", "v", "r", "r_dot", "J", "J_dot", "R", "omega", "J_o", "M_chol", "h", "G",
    "Lam", "J_bar", "damping"])


@njit(cache=True, error_model="numpy")
def damped_inverse_mobility(J, M_chol, singularity_mass):
    """(Lambda, J_bar, lambda^2): Lambda = (J M^-1 J^T + lambda^2 I)^-1 with lambda^2 capping
    the apparent mass at singularity_mass, and J_bar = M^-1 J^T Lambda."""
    MinvJT = cholesky_solve_matrix(M_chol, J.T.copy())
    mobility = matmul(J, MinvJT)
    lam2 = max(0.0, 1.0 / singularity_mass - min_eigenvalue_sym(mobility))
    for i in range(mobility.shape[0]):
        mobility[i, i] += lam2
    Lam = spd_inverse(mobility)
    return Lam, matmul(MinvJT, Lam), lam2


@njit(cache=True, error_model="numpy")
def _rows(A, task, first, count):
    out = np.empty((count, A.shape[1]))
    for i in range(count):
        out[i] = A[int(task[first + i])]
    return out


@njit(cache=True, error_model="numpy")
def _entries(x, task, first, count):
    out = np.empty(count)
    for i in range(count):
        out[i] = x[int(task[first + i])]
    return out


@njit(cache=True, error_model="numpy")
def task_frame(chain, task, singularity_mass, q, v):
    """Everything a cycle needs at the measured (q, q'): the tip's position task r, r', J,
    J' (rows of the position axes), its rotation R and angular velocity w, the rows J_o of
    the held rotation axes, the Cholesky factor of M, h = C q' + G, G, the damped Lambda,
    J_bar and lambda^2 (identity M and no gravity for a model-free law)."""
    n, m, m_o = int(task[0]), int(task[1]), int(task[2])
    work = np.empty(sc.work_length(n))
    sc.tip_dynamics_into(chain, q, v, work)
    p, R, J6, _, M, h = sc.output_views(work, n)
    J6_dot = sc.jacobian_dot(chain, q, v)
    M_chol = np.zeros((n, n))
    if task[9] > 0.0:
        for i in range(n):
            M_chol[i, i] = 1.0
        h, G = np.zeros(n), np.zeros(n)
    else:
        if not cholesky_into(M, M_chol):
            M_chol[:, :] = np.nan
        zero = np.zeros(n)
        G = sc.rnea(chain, q, zero, zero, True)
    J = _rows(J6, task, 3, m)
    r_dot6 = matvec(J6, v)
    Lam, J_bar, lam2 = damped_inverse_mobility(J, M_chol, singularity_mass)
    return TaskFrame(q, v, _entries(p, task, 3, m), _entries(r_dot6, task, 3, m), J,
                     _rows(J6_dot, task, 3, m), R.copy(), r_dot6[3:].copy(),
                     _rows(J6[3:], task, 6, m_o), M_chol, h.copy(), G, Lam, J_bar, lam2)


@njit(cache=True, error_model="numpy")
def model_force(chain, frame, a, v_task):
    """M_r a + C_r v + G_r (3.2) at the frame's state, for task acceleration a and task
    velocity v: Lambda (a - J' J_bar v + J M^-1 (C(q, q') J_bar v + G))."""
    y = matvec(frame.J_bar, v_task)
    w = sc.coriolis_product(chain, frame.q, frame.v, y) + frame.G
    cholesky_solve_into(frame.M_chol, w, w)
    return matvec(frame.Lam, a - matvec(frame.J_dot, y) + matvec(frame.J, w))


@njit(cache=True, error_model="numpy")
def task_dynamics(chain, frame):
    """M_r, C_r, G_r of (3.2) as matrices at the frame's state (module docstring): for plots
    and tests; a law uses :func:`model_force`."""
    m, n = frame.J.shape
    CJ = np.empty((n, m))
    for j in range(m):
        CJ[:, j] = sc.coriolis_product(chain, frame.q, frame.v, frame.J_bar[:, j].copy())
    inner = matmul(frame.J, cholesky_solve_matrix(frame.M_chol, CJ)) - matmul(frame.J_dot, frame.J_bar)
    G = frame.G.copy()
    cholesky_solve_into(frame.M_chol, G, G)
    return frame.Lam.copy(), matmul(frame.Lam, inner), matvec(frame.Lam, matvec(frame.J, G))


@njit(cache=True, error_model="numpy")
def project_null(frame, tau0):
    """N^T tau_0 = tau_0 - J^T J_bar^T tau_0: what of tau_0 leaves the position task alone."""
    return tau0 - tmatvec(frame.J, tmatvec(frame.J_bar, tau0))


@njit(cache=True, error_model="numpy")
def null_space_torque(task, gains, frame, quat_d, omega_d, posture, scale=1.0):
    """N^T (G + J_o^T m_o + N_s^T tau_p) (module docstring): gravity beyond the task, the
    orientation impedance and the posture task; zero when the task takes every joint.
    ``gains`` is the packed NULL_SPACE_GAINS block, ``scale`` multiplies the orientation's
    and the posture's stiffness and damping (the contact-stability monitor's joint channel,
    :func:`contact_guard.joint_monitor`); returns (tau, e_o, posture error norm)."""
    n, m, m_o = int(task[0]), int(task[1]), int(task[2])
    e_o = _entries(orientation_error(quat_d, frame.R), task, 6, m_o)
    if n == m:
        return np.zeros(n), e_o, 0.0
    tau0 = frame.G.copy()
    if m_o > 0:
        w_err = _entries(omega_d - frame.omega, task, 6, m_o)
        m_rot = np.empty(m_o)
        for i in range(m_o):
            axis = int(task[6 + i])
            m_rot[i] = scale * (gains[_K_O + axis] * e_o[i] + gains[_D_O + axis] * w_err[i])
        tau0 += tmatvec(frame.J_o, m_rot)
    posture_error = 0.0
    if n > m + m_o:
        dq = posture - frame.q
        tau_p = scale * (gains[_K_N] * dq - gains[_D_N] * frame.v)
        stacked = np.empty((m + m_o, n))
        stacked[:m] = frame.J
        stacked[m:] = ORIENTATION_LENGTH * frame.J_o
        _, J_bar_s, _ = damped_inverse_mobility(stacked, frame.M_chol, gains[_M_S])
        tau0 += tau_p - tmatvec(stacked, tmatvec(J_bar_s, tau_p))
        dq_null = dq - tmatvec(stacked, tmatvec(J_bar_s, dq))  # N_s^T (q_p - q): what the
        posture_error = math.sqrt(np.sum(dq_null * dq_null))   # posture task still pulls at
    return project_null(frame, tau0), e_o, posture_error


@njit(cache=True, error_model="numpy")
def joint_limit_torque(limits, gains, q, v):
    """The joint limit guard (module docstring): push back within the margin of a position
    limit, brake beyond VELOCITY_FRACTION of a velocity limit."""
    n = q.shape[0]
    margin, k_lim, d_lim = gains[_MARGIN], gains[_K_LIM], gains[_D_LIM]
    tau = np.zeros(n)
    for i in range(n):
        lower, upper, v_max = limits[i], limits[n + i], limits[2 * n + i]
        if q[i] < lower + margin:
            tau[i] += k_lim * (lower + margin - q[i])
        elif q[i] > upper - margin:
            tau[i] -= k_lim * (q[i] - upper + margin)
        excess = abs(v[i]) - VELOCITY_FRACTION * v_max
        if excess > 0.0:
            tau[i] -= math.copysign(d_lim * excess, v[i])
    return tau


@njit(cache=True, error_model="numpy")
def clip_to_effort(limits, tau):
    """Each joint's command clipped to its URDF effort limit (in place)."""
    n = tau.shape[0]
    for i in range(n):
        e = limits[3 * n + i]
        tau[i] = min(max(tau[i], -e), e)


# -- a cycle's common front and back, for every task-space scheme ---------------------------------
#: The packed gains every task-space kernel starts with, block by block: the task
#: description (TASK_SIZE values, :class:`TaskModel`), the joint limits (4 n: lower, upper,
#: velocity, effort), the command order (n: command k is chain joint order[k]), the
#: null-space gains (NULL_SPACE_GAINS), the desired motion's
#: (:data:`references.ReferenceGains`). The scheme's own gains follow.
CommonGains = namedtuple("CommonGains", ["task", "limits", "order", "null_space", "reference"])
TASK_SIZE = 10


@njit(cache=True, error_model="numpy")
def common_gains_views(gains, n, m):
    """(:data:`CommonGains` views of ``gains`` for n joints and m axes, where they end)."""
    task, k = take(gains, 0, TASK_SIZE)
    limits, k = take(gains, k, 4 * n)
    order, k = take(gains, k, n)
    null_space, k = take(gains, k, NULL_SPACE_SIZE)
    reference, k = take(gains, k, reference_gains_size(m, n))
    return CommonGains(task, limits, order, null_space, reference), k


def common_gains_layout(n: int, m: int) -> Layout:
    """The Layout of :data:`CommonGains` for n joints and m axes."""
    return views_layout(common_gains_views, n, m)


@njit(cache=True, error_model="numpy")
def common_blocks(gains):
    """:func:`common_gains_views` of a packed gains vector (n and m read from its task block)."""
    return common_gains_views(gains, int(gains[0]), int(gains[1]))


@njit(cache=True, error_model="numpy")
def law_blocks(gains, state):
    """(the scheme's own packed gains, its own state): the views of what follows the common
    gains and the desired motion's state."""
    common, law_at = common_blocks(gains)
    m, n = int(common.task[1]), int(common.task[0])
    return gains[law_at:], state[reference_state_views(state, m, n)[1]:]


@njit(cache=True, error_model="numpy")
def task_front(chain, gains, state, targets, t, dt, q, v, force):
    """(the task frame at (q, q'), the measured force f on the position axes, the
    :data:`references.DesiredMotion` at t)."""
    common = common_blocks(gains)[0]
    task = common.task
    m = int(task[1])
    frame = task_frame(chain, task, common.null_space[_M_S], q, v)
    f = np.empty(m)
    for i in range(m):
        f[i] = force[int(task[3 + i])]
    pace = target_pace(common.limits[2 * q.shape[0]:3 * q.shape[0]], v)
    desired = desired_motion(task[3:6], common.reference, state, targets, t, dt, frame.r,
                             frame.R, q, f, pace)
    n = q.shape[0]
    guard.joint_monitor(guard_gains_of(common.reference, m, n), guard_state_of(state, m, n), v,
                        dt, m)
    return frame, f, desired


@njit(cache=True, error_model="numpy")
def task_back(gains, state, frame, tau_task, desired, f, e, out):
    """Complete the command (the null-space torque and the joint limit guard added, clipped
    to the URDF efforts, in command order) and write command, reference and the status up
    to the scheme's own fields into ``out`` ([command n | reference 4m | status]); returns
    the status from the scheme's first field on, for the scheme to fill."""
    common = common_blocks(gains)[0]
    task, limits, order, null_gains = common.task, common.limits, common.order, common.null_space
    n, m, m_o = int(task[0]), int(task[1]), int(task[2])
    guard_state = guard_state_of(state, m, n)
    tau_null, e_o, posture_error = null_space_torque(task, null_gains, frame, desired.quat,
                                                     desired.w, desired.posture,
                                                     guard.joint_scale(guard_state, m))
    tau = tau_task + tau_null + joint_limit_torque(limits, null_gains, frame.q, frame.v)
    clip_to_effort(limits, tau)
    for k in range(n):
        out[k] = tau[int(order[k])]
    f_d = desired.f
    reference = out[n:n + 4 * m]
    reference[:m], reference[m:2 * m] = desired.r, desired.v
    reference[2 * m:3 * m], reference[3 * m:] = desired.a, f_d
    status = out[n + 4 * m:]
    status[:] = 0.0
    for i in range(m):
        status[i], status[m + i], status[2 * m + i] = frame.r[i], frame.r_dot[i], f[i]
        status[3 * m + i], status[4 * m + i] = e[i], f_d[i] - f[i]
    for k in range(n):
        status[5 * m + k] = out[k]
    k = 5 * m + n + 2                      # after compute_time_us, held
    status[k] = frame.damping
    status[k + 1:k + 1 + m_o] = e_o
    k += 1 + m_o
    if n > m + m_o:
        status[k] = posture_error
        k += 1
    guard.write_status(guard_state, m, status[k:k + guard.GUARD_STATUS_SIZE])
    return status[k + guard.GUARD_STATUS_SIZE:]
