"""The topic contract of cr_control in one place (docs/usage.md lists it for users).

Labelled arrays: controller reference/status and plant timing are published as
``std_msgs/Float64MultiArray`` with a single layout dimension whose ``label`` is the
comma-separated list of field names and whose ``size`` is the number of values.
The first field is always ``stamp``: the time (s) of the joint state the values
belong to. Any MCAP reader can recover named columns with :func:`fields_of`.
"""

from __future__ import annotations

from collections.abc import Sequence

from cr_control.core import cdr

JOINT_STATES = "/joint_states"
WRENCH = "/force_torque_sensor_broadcaster/wrench"
JOINT_COMMANDS = "/joint_commands"
#: A /joint_commands message whose header.frame_id is this is a controller's brake (it was
#: deactivated, or gave up): it gives way, and the plant follows another expected commander
#: from that one's first valid command (a live switch, make before break).
BRAKE_FRAME_ID = "brake"
CLOCK = "/clock"
PLANT_TIMING = "/plant/timing"
PARAMETER_EVENTS = "/parameter_events"
RECORDER_READY = "/recorder/ready"
#: diagnostic_msgs/DiagnosticArray, 1 Hz, from the plant and every controller (as
#: ros2_control's diagnostic updaters; the levels' rules: cr_control.core.diagnostics).
DIAGNOSTICS = "/diagnostics"
#: visualization_msgs/MarkerArray, ~30 Hz: the plant's scene (surface or
#: constraint, links, tip trail, contact force) and each controller's desired path
#: (``/<controller>/markers``, :func:`markers_topic`).
PLANT_MARKERS = "/plant/markers"
MARKERS_SUFFIX = "markers"

REFERENCE_SUFFIX = "reference"
STATUS_SUFFIX = "status"
#: Inputs of the task-space controllers (geometry_msgs/PoseStamped, WrenchStamped), in the
#: controller's base_link frame: a pose to move to and a contact force to hold.
TARGET_POSE_SUFFIX = "target_pose"
TARGET_WRENCH_SUFFIX = "target_wrench"

#: Depth of the RELIABLE/KEEP_LAST queues on the 1 kHz topics (depth 1 dropped
#: messages across processes on these machines; 10 lost none).
QOS_DEPTH = 10
#: Reader history of a controller's /joint_states (nodes/qos.py STATE_QOS). The history of
#: a keyless topic is shared by its writers: a flood from a second publisher evicts the
#: plant's states unless they are taken first. 2048 holds 0.2 s of a 10 kHz flood (the
#: fuzz's 50 000 states came at ~4 kHz); memory is taken only as it fills. At 128 they
#: were evicted whenever the starved controller fell ~30 ms behind (the flood still
#: starves the 2 cores either way: docs/safety.md).
STATE_DEPTH = 2048
#: Depth of the writer history of the 1 kHz publishers (nodes/qos.py, PUBLISH_QOS).
PUBLISH_DEPTH = 500

LABEL_SEPARATOR = ","


def reference_topic(controller: str) -> str:
    """Topic of a controller's desired motion and force."""
    return f"/{controller}/{REFERENCE_SUFFIX}"


def status_topic(controller: str) -> str:
    """Topic of a controller's errors, estimates and compute time."""
    return f"/{controller}/{STATUS_SUFFIX}"


def markers_topic(controller: str) -> str:
    """Topic of a controller's markers (its desired path)."""
    return f"/{controller}/{MARKERS_SUFFIX}"


def layout_label(fields: Sequence[str]) -> str:
    """The layout label that names the values of a labelled array."""
    for name in fields:
        if LABEL_SEPARATOR in name or not name:
            raise ValueError(f"invalid field name {name!r}")
    return LABEL_SEPARATOR.join(fields)


def fields_of(layout_dim_label: str) -> list[str]:
    """Field names of a labelled array from its layout label."""
    return layout_dim_label.split(LABEL_SEPARATOR) if layout_dim_label else []


def labelled_array(msg_cls, dim_cls, fields: Sequence[str]):
    """A Float64MultiArray template whose layout names ``fields`` (fill ``data`` per cycle)."""
    msg = msg_cls()
    msg.layout.dim = [dim_cls(label=layout_label(fields), size=len(fields), stride=len(fields))]
    return msg


def labelled_writer(fields: Sequence[str]) -> cdr.Writer:
    """A Float64MultiArray whose layout names ``fields``, built once as CDR bytes: fill
    ``writer.array("data")`` per cycle and publish ``writer.message()``."""
    n = len(fields)
    return cdr.Writer(cdr.float64_multi_array, dim=[(layout_label(fields), n, n)], data=n)


#: Fields of the plant's per-second timing message (PLANT_TIMING). ``window_*`` cover
#: the last second; ``total_*`` the whole run so far. Ages are state-to-command round
#: trips measured in the plant: from publishing a state to receiving the command
#: computed from it. A cycle is "fresh" when the command applied at that tick was
#: computed from the state published at the previous tick. Appended later (issues 6, 7):
#: ``publish_time_us`` (window mean time building and publishing state, wrench, clock),
#: ``safe_stop`` (1 while the watchdog's safe stop is engaged), ``commands_clipped`` and
#: ``commands_refused`` (run totals), ``command_publishers`` / ``state_publishers``
#: (publishers seen on /joint_commands and /joint_states, the plant included; more than
#: one each means another participant is on the loop), ``window_max_missed_run`` (longest
#: run of consecutive ticks without a new command in the window); the reflexes:
#: ``safe_stop_reason`` (why the safe stop is engaged: 0 none, 1 watchdog, 2 contact force
#: reflex, 3 joint velocity reflex; ``safe_stop`` is 1 for each of them); hostile input (one
#: commander at a time, run totals): ``commands_foreign`` (commands refused unread because
#: another publisher is the commander), ``commands_oversized`` (commands refused unread for
#: their size) and ``commander_handovers`` (times another publisher took over after the
#: commander's silence; the first commander is not counted).
PLANT_TIMING_FIELDS = [
    "stamp",
    "rate_hz",
    "window_cycles",
    "window_fresh_share",
    "window_age_p50_ms",
    "window_age_p99_ms",
    "window_age_max_ms",
    "total_cycles",
    "total_fresh_share",
    "total_missed_cycles",
    "total_age_p50_ms",
    "total_age_p99_ms",
    "total_age_max_ms",
    "step_time_us",
    "publish_time_us",
    "safe_stop",
    "commands_clipped",
    "commands_refused",
    "command_publishers",
    "state_publishers",
    "window_max_missed_run",
    "safe_stop_reason",
    "commands_foreign",
    "commands_oversized",
    "commander_handovers",
]

#: Fields every controller publishes on its reference topic (task space, SI units).
REFERENCE_FIELDS = ["stamp", "r_d_x", "r_d_y", "v_d_x", "v_d_y", "a_d_x", "a_d_y", "f_d_x", "f_d_y"]

#: Fields every task-space controller publishes first on its status topic; scheme
#: specific fields (estimates, sliding variables, network norms) follow them.
STATUS_FIELDS = [
    "stamp",
    "r_x", "r_y",
    "v_x", "v_y",
    "f_x", "f_y",
    "e_x", "e_y",
    "f_err_x", "f_err_y",
    "tau_1", "tau_2",
    "compute_time_us",
    "held",
]

#: Fields the controller node appends after every controller's status fields (its own
#: timing, not the control law's): ``in_time_us`` from callback entry to the start of
#: the control computation, ``out_time_us`` building and publishing the previous
#: cycle's command, reference and status. Failure handling: ``commands_stopped`` (1 while the
#: law's output has failed too long and no command is published), and run totals:
#: ``states_foreign`` (states from another /joint_states publisher than the one followed,
#: ignored), ``source_handovers`` (times another publisher was followed after the
#: followed one's silence; the first is not counted), ``inputs_oversized`` (states,
#: wrenches and plant sensor messages dropped unread for their size) and
#: ``sensor_faults`` (wrenches above max_sensor_force or not finite: the last sane one
#: used). ``command_age``: how long, in control periods, the command in force had stood when
#: this state came (its stamp against the last state's: 1 when every state is answered; a
#: node that falls behind answers only the newest state, so the ones it skipped show here;
#: cr_control.schemes.command_gate stops commanding when it averages above 3; in the offline
#: loop its controller's ``gate.age`` is the same number). ``wrench_age_ms``: how much older
#: (stamp against stamp) the wrench the law read was than the state it answered: 0 when the
#: state's own wrench had come (the plant publishes it first), a period or more when it had
#: not (a wrench sample resent after a loss, a sensor slower than the states, a driver that
#: stamps them apart); -1 before any wrench. Not in the offline loop (no messages there).
NODE_STATUS_FIELDS = ["in_time_us", "out_time_us", "commands_stopped", "states_foreign",
                      "source_handovers", "inputs_oversized", "sensor_faults", "command_age",
                      "wrench_age_ms"]

#: The plant's command interface, ``std_msgs/String`` "effort" or "position", latched
#: (RELIABLE, TRANSIENT_LOCAL, depth 1; published once at start): a controller node whose
#: scheme commands the other kind refuses to drive the plant and exits.
PLANT_COMMAND_INTERFACE = "/plant/command_interface"

#: A plant's extra measurements (``Plant.sensor_fields``, e.g. the closed chain's lambda):
#: a labelled Float64MultiArray with the joint state's stamp first, published with every
#: state by plants that have any.
PLANT_SENSORS = "/plant/sensors"

#: The plant's true contact wrench (geometry_msgs/WrenchStamped, base frame, the joint state's
#: stamp), published by plants that have one (``urdf_surface``): for analysis and
#: tests only, no controller reads it (a real robot has no such topic). Judge force control
#: by it, never by the sensor's wrench alone.
CONTACT_WRENCH = "/plant/contact_wrench"
