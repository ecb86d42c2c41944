"""The robots ``cr_session --robot NAME`` knows, and their default task: wiping a table.

A robot profile is its URDF (from example-robot-data, which `make demo ROBOT=...` and
`make test` install: real kinematics and inertias), the chain's two links, a home pose and
what the real robot's ROS 2 driver does, which the plant imitates: who compensates gravity
and joint friction, the control rate, the transport delay (the cycles after which the
answer to a state acts: :attr:`Robot.command_delay_cycles`) and where the wrench comes from.

========== ==================== ======= ======== ====== ===== ================================
profile    driver               gravity friction rate   delay wrench
========== ==================== ======= ======== ====== ===== ================================
panda      franka_ros2          robot   --       1 kHz  1 ms  estimate O_F_ext_hat_K: base, reaction
panda_ft   franka_ros2 + F/T    robot   --       1 kHz  1 ms  wrist sensor: flange, tool, bias
ur5        ur_robot_driver      robot   robot    500 Hz 2 ms  TCP sensor: tool0, no payload, bias
ur5_ft     ur_robot_driver + F/T robot  robot    500 Hz 2 ms  wrist sensor: flange, tool, bias
========== ==================== ======= ======== ====== ===== ================================

The wiping task, the same for every profile and scheme: the table is a compliant plane
touching the tool at the home pose (normal +z), and the tool keeps 10 N on it while
tracking a circle of radius WIPE_RADIUS in it, starting where it stands. Its parameters are
generated into ``config/robots/<profile>/`` (``plant.yaml`` and one file per task-space
scheme) by ``python -m cr_control.tools.config_files --write config``; sessions and the
offline loop read those files, so what a test runs is what a user runs.

The wrist sensor (``*_ft``) sits at the flange (``sensor_frame``: ``panda_link8``,
``tool0``), reading in its own frame, carrying a 0.7 kg tool whose centre of mass is 6 cm
out along the flange axis, with a bias of a few newtons and 0.2 N of noise (:data:`SENSOR`).
The controllers know the tool (``tool_mass``, ``tool_com``: what ``cr_identify_tool``
estimates) and zero the bias on their first states (``zero_ft_at_start``: the task starts
touching at zero force). The thesis scenarios keep their ideal sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from cr_control.models.brake import MAX_BRAKE_STEP
from cr_control.models.urdf import load_chain

#: The plant node's default brake frequency (rad/s), brake_frequency.
BRAKE_FREQUENCY = 50.0


@dataclass(frozen=True)
class Robot:
    """A robot profile: the URDF chain base_link -> tip_link, a home pose, its source and the
    flange, and what the real robot's ROS 2 driver does (``driver``): who compensates gravity
    and joint friction, the control rate and where the wrench comes from (``wrench``: one of
    :data:`WRENCH_SOURCES`)."""

    name: str
    urdf_file: str
    base_link: str
    tip_link: str
    home: tuple[float, ...]
    source: str
    flange: str
    driver: str = ""
    rate_hz: float = 1000.0
    robot_compensates_gravity: bool = False
    robot_compensates_friction: bool = False
    wrench: str = "wrist"
    #: The guarded approach's speed (m/s): APPROACH.
    approach_speed: float = 0.03
    #: The driver's transport delay (control periods): the command answering the state of
    #: one cycle acts from the next cycle on (the plant node's ``command_delay_cycles``).
    #: libfranka: the torque the user's callback returns for the state of a 1 kHz cycle is
    #: applied in the next one (Franka Control Interface documentation, "Minimum system and
    #: network requirements": round trip, the control loop's execution and the robot's
    #: processing together within 1 ms) -> 1 cycle, 1 ms. ur_robot_driver's effort interface:
    #: the torque answering a 500 Hz RTDE state is executed by the robot's next 2 ms control
    #: step (ur_robot_driver's documentation, "Torque control") -> 1 cycle, 2 ms.
    command_delay_cycles: int = 0
    #: What the driver takes: ``effort`` (torques), or ``position`` / ``velocity`` through a
    #: forward_command_controller. Then the plant is the arm behind its joint servos
    #: (scenario ``joint_servo``) and the task-space laws run in the admittance outer loop
    #: (:mod:`cr_control.schemes.blocks.admittance_outer_loop`).
    command_interface: str = "effort"
    #: The joint servos behind a position or velocity interface: bandwidth (rad/s) and damping
    #: ratio (the plant's ``servo_bandwidth``, ``servo_damping``; sources at SERVOS).
    servo: tuple[float, float] = (0.0, 0.0)
    #: The joint acceleration (rad/s^2) and jerk (rad/s^3) limits the driver holds the command
    #: stream to, one per joint (empty: none); the outer loop keeps inside them too.
    acceleration_limit: tuple[float, ...] = ()
    jerk_limit: tuple[float, ...] = ()


#: Where a profile's wrench comes from:
#: - ``wrist``: a 6-axis F/T sensor on the flange through force_torque_sensor_broadcaster (its
#:   own frame, the tool's weight, a bias and noise: :data:`SENSOR`);
#: - ``estimated``: Franka's external wrench estimated from the joint torques, O_F_ext_hat_K:
#:   base frame, no tool weight (libfranka takes the configured load off), the sign of the
#:   reaction (franka users report it so: libfranka #26, franka_ros #254), estimation noise
#:   :data:`ESTIMATE_NOISE`;
#: - ``tcp``: UR's built-in TCP force/torque sensor (``ft_data``, ``tool0_controller``, which
#:   is tool0 here): the sensor's frame, the payload's weight removed by the robot, a bias
#:   that ``zero_ftsensor`` takes off (zeroed at start), noise.
WRENCH_SOURCES = ("wrist", "estimated", "tcp")

_PANDA = dict(
    urdf_file="package://example-robot-data/robots/panda_description/urdf/panda.urdf",
    base_link="panda_link0", tip_link="panda_hand_tcp",
    home=(0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4),
    source="Franka Emika Panda, 7 joints (+ 2 finger joints, locked): example-robot-data 6.0.0, "
           "from franka_ros's description with its identified inertias; home = franka_ros's "
           "ready pose", flange="panda_link8",
    driver="franka_ros2 (libfranka): effort interface, desired torques without gravity "
           "(libfranka adds g(q), no friction compensation), 1 kHz",
    rate_hz=1000.0, robot_compensates_gravity=True, command_delay_cycles=1)
_UR5 = dict(
    urdf_file="package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf",
    base_link="base_link", tip_link="tool0",
    home=(0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0),
    source="Universal Robots UR5, 6 joints: example-robot-data 6.0.0, from ur_description (UR's "
           "published kinematics and link masses); home: tool pointing down", flange="tool0",
    driver="ur_robot_driver >= 3.5.0 (PolyScope >= 5.23): effort interface, target torques "
           "without gravity; the robot also compensates joint friction; 500 Hz",
    rate_hz=500.0, robot_compensates_gravity=True, robot_compensates_friction=True,
    approach_speed=0.015, command_delay_cycles=1)

#: The joint servos of the position and velocity interfaces (bandwidth rad/s, damping ratio;
#: cr_sim.plants.joint_servo). UR publishes no servo bandwidth: ur_robot_driver's servoj runs
#: with servoj_gain 2000 and servoj_lookahead_time 0.03 s (its defaults), read as a PD with the
#: lookahead as derivative time: sqrt(2000) = 44.7 rad/s, 0.03 sqrt(2000) / 2 = 0.67 (our
#: reading, not UR's statement). Franka's joint position interface runs libfranka's joint
#: impedance (default stiffness 3000 N m/rad on the shoulder, ~2 kg m^2 at the ready pose):
#: ~40 rad/s, critically damped (assumed). UFactory publishes none: 40 rad/s, 0.7 assumed.
SERVOS = {"ur": (44.7, 0.67), "franka": (40.0, 1.0), "xarm": (40.0, 0.7)}
#: The reflected rotor inertia of every joint behind a servo (kg m^2): none of the makers
#: publishes it; MuJoCo Menagerie's UR5e model sets 0.1 on every joint. Without it the
#: wrists, whose links weigh 1e-4-1e-2 kg m^2 about their axes, would be servoed as softly
#: as their inertia times omega_s^2 (a few N m/rad): the table's friction twisted the
#: Panda's and the xArm's tool by 10-20 mrad.
ARMATURE = 0.1
#: The laws' gains on a position or velocity interface, where the contact acts on the law's
#: (virtual) arm through the servos (~45 rad/s), the driver's delay and the force sensor:
#: the admittance must stay well below the servos' bandwidth. Chapter 5: the impedance's
#: inertia m_m = 4 kg (section 5.3's 1.2 kg rang against the 5 kN/m table through the UR5's
#: servo at ~50 rad/s: 0.80 N RMS, the stability monitor twice), the normal damping 150 N s/m
#: (fuzzy: its sets 50/150/250 N s/m, lambda 0.4: k_m = 60 N/m at the middle one, as section
#: 5.3's), the tangential damping critical for m_m = 4 kg and k_t = 3000 N/m. Chapter 3: the
#: force admittance's damping 150 N s/m (50: the robust law erred by 1.55 N RMS on the UR5;
#: 400 lifted the reference 5 cm at the first touch and the start check gave up, on the
#: effort UR5 too).
SERVO_GAINS = {"ch5": {"m_m": 4.0, "tangential_damping": 2.0 * math.sqrt(4.0 * 3000.0)},
               "impedance": {"d_m": 150.0},
               "fuzzy_unidirectional": {"d_s": 50.0, "d_med": 150.0, "d_b": 250.0,
                                        "lambda": 0.4},
               "ch3": {"force_admittance_damping": 150.0}}
#: A profile's own gains beside SERVO_GAINS (profile -> family or scheme -> gains). The xArm
#: answers at 150 Hz, a cycle late, through a 40 rad/s servo: its contact loop lags more
#: than the UR5's and the Panda's, and the chapter 3 laws' force admittance at 150 N s/m
#: rang at ~15 Hz on the 30 kN/m table (peaks 14.8-15.4 N, 175 and 200 N s/m too); 300
#: halves the loop's crossover (K / d_a): peaks 10.4 N, and on the default table the force
#: error RMS 0.160 -> 0.142 N (250-500 N s/m peak at 10.2-10.5 N).
PROFILE_SERVO_GAINS = {"xarm7": {"ch3": {"force_admittance_damping": 300.0}}}
#: libfranka's joint limits for the Panda's command streams (rate_limiting.h: kMaxJointAcceleration,
#: kMaxJointJerk): a position or velocity stream beyond them is rejected (a "..._discontinuity"
#: reflex) unless rate-limited.
PANDA_ACCELERATION = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)
PANDA_JERK = (7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0)
#: The guarded approach's speed on a position or velocity interface (m/s): the robot follows
#: its command through the servo's lag and the driver's delay, and at 15 mm/s the first touch
#: of a 30 kN/m table bounced the tool off for 14-64 ms (UR5, Panda, xArm); at 5 mm/s it stays
#: on in every scheme (peaks 10.1-12.9 N).
SERVO_APPROACH_SPEED = 0.005
_UR5_SERVO = dict(_UR5, servo=SERVOS["ur"], acceleration_limit=(5.0,) * 6,
                  approach_speed=SERVO_APPROACH_SPEED)
_UR5_SERVO["driver"] = ("ur_robot_driver: forward_position_controller (servoj over RTDE, "
                        "servoj_gain 2000, lookahead 0.03 s), 500 Hz; no published joint "
                        "acceleration limits (ur_description's placeholder 5 rad/s^2)")
_UR5_VELOCITY = dict(_UR5_SERVO, driver="ur_robot_driver: forward_velocity_controller "
                     "(speedj over RTDE), 500 Hz; acceleration 5 rad/s^2 (ur_description's "
                     "placeholder)")
_PANDA_POSITION = dict(
    _PANDA, servo=SERVOS["franka"], acceleration_limit=PANDA_ACCELERATION,
    jerk_limit=PANDA_JERK, approach_speed=SERVO_APPROACH_SPEED,
    driver="franka_ros2 (libfranka): joint position interface at 1 kHz, the command held to "
           "libfranka's joint velocity, acceleration and jerk limits (franka::limitRate)")
_XARM7 = dict(
    urdf_file="package://example-robot-data/robots/xarm_description/urdf/xarm7.urdf",
    base_link="link_base", tip_link="link_eef", home=(0.0, 0.2, 0.0, 1.0, 0.0, 0.8, 0.0),
    source="UFACTORY xArm 7, 7 joints: example-robot-data 6.0.0, from xarm_ros2's "
           "xarm_description; home: tool pointing down 0.49 m in front of the base",
    flange="link_eef", rate_hz=150.0, command_delay_cycles=1, servo=SERVOS["xarm"],
    acceleration_limit=(20.0,) * 7, approach_speed=SERVO_APPROACH_SPEED,
    driver="xarm_ros2 (uf_robot_hardware/UFRobotSystemHardware): joint positions in servo "
           "mode (set_servo_angle_j) at its controller_manager's 150 Hz; joint acceleration "
           "20 rad/s^2 (xarm_moveit_config's joint_limits.yaml)")

ROBOTS = {
    "panda": Robot("panda", **_PANDA, wrench="estimated"),
    "panda_ft": Robot("panda_ft", **_PANDA, wrench="wrist"),
    "ur5": Robot("ur5", **_UR5, wrench="tcp"),
    "ur5_ft": Robot("ur5_ft", **_UR5, wrench="wrist"),
    "ur5_position": Robot("ur5_position", **_UR5_SERVO, wrench="tcp",
                          command_interface="position"),
    "ur5_velocity": Robot("ur5_velocity", **_UR5_VELOCITY, wrench="tcp",
                          command_interface="velocity"),
    "panda_position": Robot("panda_position", **_PANDA_POSITION, wrench="estimated",
                            command_interface="position"),
    "xarm7": Robot("xarm7", **_XARM7, wrench="wrist", command_interface="position"),
}

#: Wiping: circle radius (m), angular frequency (rad/s), contact force (N) and the table.
WIPE_RADIUS = 0.05
WIPE_FREQUENCY = 1.0
WIPE_FORCE = 10.0
#: The desired force is ramped in over this time (s): the tool starts touching at zero force.
FORCE_RAMP_TIME = 1.0
TABLE_STIFFNESS = 5000.0
TABLE_DAMPING = 20.0
#: Coulomb friction of the tool on the table: a real table is not frictionless (~0.3 for a
#: tool on a table), and the path in the table's plane must be held against it.
TABLE_FRICTION = 0.3
GRAVITY = [0.0, 0.0, -9.81]
#: The robust scheme's wrong model on a robot: 10 % light, and a bound on the gravity error
#: it makes. Section 3.5.2's 50 % on the 0.2 kg thesis arm is a few newtons; on a 20 kg arm it
#: is ~40 N at the tip, beyond what K_s s can carry (measured on the Panda: 55 N pressed
#: instead of 10, 16 degrees of orientation error).
ROBUST_MODEL = {"model_mass_scale": 0.9, "model_inertia_scale": 0.9, "delta_G": 5.0}
#: The NN scheme's adaptation gains on a robot. Section 3.5.3's (8, 6, 10) adapt the 256-node
#: networks of these arms far faster than the 16-node one of the thesis arm; under the plant
#: node's torque-rate limit (libfranka's 1000 N m/s) the learning transient then grows
#: unstable (measured: the Panda pressed 1700 N within 1 s, and 1/10 of them still diverges);
#: these keep it stable on both arms (90 and 67 commands clipped in the first second).
NN_GAINS = {"Gamma_M": 0.01, "Gamma_C": 0.01, "Gamma_G": 1.0, "nn_warm_start": True}
#: The wrist sensor of the robot scenarios (plant parameters; sensor_frame: the flange): a
#: 0.7 kg tool, its centre of mass 6 cm out along the flange axis (the inertia of a solid
#: cylinder of 3 cm radius and 12 cm length about it), a bias of a few newtons (3.9 N) and
#: tenths of a newton metre, and noise of 0.2 N and 0.01 N m (the class of an ATI Mini45 or
#: a Robotiq FT 300).
SENSOR = {"tool_mass": 0.7, "tool_com": [0.0, 0.0, 0.06],
          "tool_inertia": [1.0e-3, 0.0, 0.0, 1.0e-3, 0.0, 3.2e-4],
          "ft_bias": [2.0, -1.5, 3.0, 0.1, -0.05, 0.02], "ft_noise_std": [0.2, 0.01]}
#: Franka's estimated external wrench: its noise (N, std per component). The estimate comes
#: from the joint torque sensors through the model; ~0.3 N of scatter at rest.
ESTIMATE_NOISE = 0.3
#: The guarded approach on a robot (cr_control.schemes.blocks.contact_guard): down towards the
#: table until 2 N, at most 10 cm, at the profile's ``approach_speed``. An impact at speed v on
#: a contact of stiffness K through an apparent mass m peaks at v sqrt(m K) whatever the
#: controller does within the first milliseconds: on the 10x stiffer table (50 kN/m) the
#: Panda's tool (m ~ 2.5 kg) reaches 10.6 N at 3 cm/s, the UR5's (m ~ 5.3 kg) 15.4 N at 3 cm/s.
#: What the impact does next is the impact damping's (``impact_damping_scale``): with the law's
#: nominal damping the tool bounced off that table for 30-110 ms, with it it stays on, except
#: the robust scheme's on the UR5 at 2 cm/s (18 ms off: its switching term d sat(s / Delta)
#: answers the impact, and damping does not scale it); at 1.5 cm/s it stays on too. Started
#: 5 cm above the table (the plant's start_clearance) the tool touches after ~1.8 s (Panda)
#: or ~3.4 s (UR5).
APPROACH = {"contact_threshold": 2.0, "approach_distance": 0.1}
#: The chapter 5 laws on a table: stiff in the table's plane, compliant along the force. Their
#: impedance (5.6) has one k_m = 60 N/m on every axis, so the table's friction (mu f_n = 3 N at
#: 10 N) holds the tool ~50 mm behind its path (measured on the Panda: the circle shrank to a
#: 3.3 mm radius); k_t = 3000 N/m in the plane (1 mm per 3 N) with d_t = 120 N s/m (critical
#: for m_m = 1.2 kg) tracks it to 0.05 mm, the normal impedance unchanged.
TANGENTIAL = {"tangential_stiffness": 3000.0, "tangential_damping": 120.0}
#: The chapter 5 laws' damping along the normal on a robot. A force measured one cycle late on
#: a contact of stiffness K_e acts as a negative damping of about K_e dt / 2: 25 N s/m on the
#: 10x stiffer table (50 kN/m) at 1 kHz, 50 N s/m at the UR5's 500 Hz, beside section 5.3's
#: d_m = 12 N s/m (the force error RMS was 0.31 N on the Panda, 1.05 N on the UR5). Fixed
#: impedance: d_m = 30 N s/m; fuzzy: its output sets doubled, lambda halved so that
#: k_m = lambda d_m stays as in section 5.3 (0.16-0.19 N RMS on every profile then).
CH5_DAMPING = {"impedance": {"d_m": 30.0},
               "fuzzy_unidirectional": {"d_s": 10.0, "d_med": 30.0, "d_b": 50.0, "lambda": 2.5}}
#: The chapter 3 laws' impact damping scale: their damping in contact is already B_hat M_r
#: (~400 N s/m on the Panda's tool), and half the default scale keeps the tool on the 10x
#: stiffer table with joint torques that change half as fast at the impact (the default 10
#: asked up to 8.4 kN m/s of the UR5's joints, beyond the 1 kN m/s a robot's rate limit lets
#: through, so that limit, not the law, shaped the impact).
CH3_IMPACT_DAMPING = 5.0
#: The chapter 3 laws' initial estimate c_hat(0) on a robot: zero. Section 3.5.1's c_hat(0) =
#: [1, 1] is a task acceleration the law applies before it has adapted anything: on the Panda
#: it pushed the tool 10-15 mm sideways while it settled, and the circle was anchored there.
C_HAT_0 = 0.0
#: The chapter 5 laws are impedances about the reference (k_m = 60 N/m): pressing 2 N needs
#: the approach's reference 33 mm below the table; 1.5 N (25 mm) is still well above what the
#: wrist sensor reads while the tool accelerates in the air (0.7 kg x ~1 m/s^2 beside 0.2 N of
#: noise: 0.5 N took the UR5's approach start for a contact).
APPROACH_CH5_THRESHOLD = 1.5
#: The NN scheme's force ramp (s): its learning transient (the tool leaves the table and comes
#: back until 1.23 s on the Panda; its force rings at ~1 N RMS until 2 s) is over before the
#: contact-stability monitor is armed (it detects once the force is ramped in); with 1 s and
#: 1.5 s the monitor took its end for chatter.
NN_FORCE_RAMP_TIME = 2.0
#: The largest ~/target_wrench force the wiping task takes (N): 3x its 10 N, so that a law's
#: overshoot (at most 1.5x a target) stays below the plant's 50 N force reflex
#: (max_contact_force, as libfranka's); a larger one is scaled down to it
#: (cr_control.schemes.impedance.base). At 50 N a 1e6 N target tripped that reflex at 3.1 s.
MAX_TARGET_FORCE = 3.0 * WIPE_FORCE
#: The fastest the reference follows a ~/target_pose on the robots (m/s; the law's default
#: 0.5). A target streamed 10 m along the table for 2.5 s walked the Panda's tool out at
#: 0.2 m/s on average while the elbow caught up with the wrist in surges, the fourth at
#: 1.00 x joint 4's velocity limit (the plant's reflex, in real time and offline); with the
#: reference at 0.2 m/s the joints stay within 0.72 of their limits.
TARGET_MAX_SPEED = 0.2
#: The largest transport delay (cycles of the profile's period) each scheme tolerates on the
#: torque-interface profiles: wiping offline for 8 s with the plant node's command limits (a
#: lockstep session's), force error RMS <= 0.3 N, radial <= 2 mm, no joint above half its
#: velocity limit, no command at its effort limit for more than 10 cycles, no reflex, no
#: give-up (docs/safety.md, 'Gains a sampled, delayed loop takes'). The controller warns at
#: start when the round trip it measures goes beyond it (tolerated_delay_cycles). Beyond it the
#: Panda's joint 7 oscillates (the wrist's gains: the rule's edge is 7 cycles) or, with the
#: wrist sensor, the chapter 3 laws' force is lost; the UR5's start check gives up on its
#: position loop (the tip 0.15-0.16 m/s off its reference, joint 4 at 0.3 of its limit).
DELAY_MARGIN_CYCLES = {
    "panda": {"adaptive_impedance": 8, "robust_adaptive_impedance": 7,
              "nn_adaptive_impedance": 8, "impedance": 8, "fuzzy_unidirectional": 8},
    "panda_ft": {"adaptive_impedance": 8, "robust_adaptive_impedance": 5,
                 "nn_adaptive_impedance": 5, "impedance": 9, "fuzzy_unidirectional": 9},
    "ur5": {"adaptive_impedance": 3, "robust_adaptive_impedance": 4,
            "nn_adaptive_impedance": 5, "impedance": 5, "fuzzy_unidirectional": 5},
    "ur5_ft": {"adaptive_impedance": 3, "robust_adaptive_impedance": 6,
               "nn_adaptive_impedance": 6, "impedance": 4, "fuzzy_unidirectional": 5},
}
#: The task-space schemes (chapters 3 and 5) that run on a robot.
TASK_SPACE_SCHEMES = ("adaptive_impedance", "robust_adaptive_impedance", "nn_adaptive_impedance",
                      "impedance", "fuzzy_unidirectional")


def robot(name: str) -> Robot:
    """The robot called ``name`` (ValueError naming the known ones)."""
    if name not in ROBOTS:
        raise ValueError(f"unknown robot {name!r}; known: {sorted(ROBOTS)}")
    return ROBOTS[name]


def robot_parameters(r: Robot) -> dict[str, Any]:
    """The robot parameters every node on it takes: its chain, gravity and who compensates it."""
    return {"urdf_file": r.urdf_file, "base_link": r.base_link, "tip_link": r.tip_link,
            "gravity": list(GRAVITY), "robot_compensates_gravity": r.robot_compensates_gravity,
            "robot_compensates_friction": r.robot_compensates_friction}


def home_tip(r: Robot) -> np.ndarray:
    """The tool's position at the home pose (base frame): where the table touches it."""
    chain = load_chain("", r.urdf_file, r.base_link, r.tip_link)
    return np.array(chain.tip_pose(np.array(r.home)).translation)


def plant_wrench(r: Robot) -> dict[str, Any]:
    """The plant's wrench parameters imitating the profile's wrench source."""
    if r.wrench == "estimated":
        return {"wrench_sign": -1, "force_noise_std": ESTIMATE_NOISE}
    values = {"sensor_frame": r.flange, **SENSOR}
    if r.wrench == "tcp":
        values["sensor_removes_payload"] = True
    return values


def controller_wrench(r: Robot) -> dict[str, Any]:
    """What a controller on the profile is told of its wrench: frame, sign, the tool whose
    weight it must take off, whether it zeroes the sensor at start."""
    if r.wrench == "estimated":
        return {"sensor_frame": "", "wrench_sign": -1, "zero_ft_at_start": False}
    mass = 0.0 if r.wrench == "tcp" else SENSOR["tool_mass"]    # the robot removes the payload
    return {"sensor_frame": r.flange, "wrench_sign": 1, "tool_mass": mass,
            "tool_com": SENSOR["tool_com"], "zero_ft_at_start": True}


def plant_node_values(r: Robot) -> dict[str, Any]:
    """The plant node's settings that imitate the profile's driver: its rate and transport
    delay (:data:`Robot.command_delay_cycles`); at a rate below 200 Hz (the xArm's 150) the
    node's brake frequency lowered to what a held brake torque takes (MAX_BRAKE_STEP x
    rate_hz: the node refuses more, though a servo plant brakes with its own reference)."""
    values = {"rate_hz": r.rate_hz, "command_delay_cycles": r.command_delay_cycles}
    if r.rate_hz * MAX_BRAKE_STEP < BRAKE_FREQUENCY:
        values["brake_frequency"] = MAX_BRAKE_STEP * r.rate_hz
    return values


def plant_values(r: Robot) -> dict[str, Any]:
    """The plant scenario of the wiping task: the robot at home on a compliant table,
    compensating what the real robot compensates, with its wrench source (the plant node's
    ``rate_hz`` is the profile's ``rate_hz``); on a position or velocity interface, the arm
    behind its joint servos (:func:`servo_values`)."""
    values = {**robot_parameters(r), "scenario": "urdf_surface",
              "initial_joint_positions": list(r.home), "surface": "plane",
              "surface_normal": [0.0, 0.0, 1.0], "stiffness": TABLE_STIFFNESS,
              "damping": TABLE_DAMPING, "friction_coulomb": TABLE_FRICTION, **plant_wrench(r)}
    if r.command_interface == "effort":
        return values
    for name in ("robot_compensates_gravity", "robot_compensates_friction"):
        del values[name]            # the servos compensate both: they are the robot's controller
    return {**values, "scenario": "joint_servo", **servo_values(r)}


def servo_values(r: Robot) -> dict[str, Any]:
    """The joint servos of a position or velocity interface (plant parameters)."""
    return {"command_interface": r.command_interface, "servo_bandwidth": r.servo[0],
            "servo_damping": r.servo[1], "acceleration_limit": list(r.acceleration_limit),
            "jerk_limit": list(r.jerk_limit), "joint_armature": [ARMATURE]}


def outer_loop_values(r: Robot, scheme: str) -> dict[str, Any]:
    """On a position or velocity interface: the admittance outer loop's parameters (the
    command stream kept inside the driver's acceleration and jerk limits) and the laws' gains
    that keep the admittance well below the servos' bandwidth (SERVO_GAINS, and the
    profile's own PROFILE_SERVO_GAINS); none on effort."""
    if r.command_interface == "effort":
        return {}
    family = "ch5" if scheme in ("impedance", "fuzzy_unidirectional") else "ch3"
    own = PROFILE_SERVO_GAINS.get(r.name, {})
    return {"command_interface": r.command_interface,
            "command_acceleration_limit": list(r.acceleration_limit),
            "command_jerk_limit": list(r.jerk_limit), **SERVO_GAINS[family],
            **SERVO_GAINS.get(scheme, {}), **own.get(family, {}), **own.get(scheme, {})}


def controller_values(r: Robot, scheme: str) -> dict[str, Any]:
    """The parameters of ``scheme`` for the wiping task on ``r`` (beyond its defaults)."""
    if scheme not in TASK_SPACE_SCHEMES:
        raise ValueError(f"{scheme} is not a task-space scheme: it runs on its thesis plant only")
    a = WIPE_RADIUS
    values = {**robot_parameters(r), "reference_relative": True,
              "reference_offset": [a, 0.0, 0.0], "reference_amplitude": [a, a, 0.0],
              "reference_phase": [0.0, -math.pi / 2, 0.0],
              "reference_frequency": WIPE_FREQUENCY, "posture": list(r.home),
              "force_ramp_time": FORCE_RAMP_TIME, "max_target_force": MAX_TARGET_FORCE,
              "target_max_speed": TARGET_MAX_SPEED,
              "control_period": 1.0 / r.rate_hz, "command_delay_cycles": r.command_delay_cycles,
              "tolerated_delay_cycles": DELAY_MARGIN_CYCLES.get(r.name, {}).get(scheme, 0),
              "contact_stiffness": TABLE_STIFFNESS,
              **controller_wrench(r), **APPROACH, "approach_speed": r.approach_speed}
    if scheme in ("impedance", "fuzzy_unidirectional"):
        values.update(f_dm=WIPE_FORCE, surface="plane", surface_normal=[0.0, 0.0, 1.0],
                      surface_centre=[float(x) for x in home_tip(r)],
                      contact_threshold=APPROACH_CH5_THRESHOLD, **TANGENTIAL,
                      **CH5_DAMPING[scheme])
    else:       # chapter 3 laws regulate position: the force admittance holds the force
        values.update(desired_force=[0.0, 0.0, WIPE_FORCE], force_admittance_damping=50.0,
                      force_admittance_mass=1.0, impact_damping_scale=CH3_IMPACT_DAMPING)
    if scheme in ("adaptive_impedance", "robust_adaptive_impedance"):
        values["c_hat_0"] = [C_HAT_0] * 3
    if scheme == "robust_adaptive_impedance":
        values.update(ROBUST_MODEL)
    if scheme == "nn_adaptive_impedance":
        values.update(NN_GAINS, rbf_seed=list(r.home), force_ramp_time=NN_FORCE_RAMP_TIME)
    values.update(outer_loop_values(r, scheme))
    return values
