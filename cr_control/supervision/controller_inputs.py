"""The controller's input guards, free of ROS: what happens to each message before the law.

The node (:mod:`cr_control.nodes.controller_node`) subscribes, hands each serialized message
to a :class:`ControllerInputs` and acts on its verdict: answer a state with the law's
command, publish the last command again, tell the law its time origin, or nothing. The
messages are read straight from their CDR bytes by readers the node hands in
(:class:`Readers`), so this module imports no middleware and a test drives it with bytes.

Guards on /joint_states, in order (each counted in the node's status,
:data:`cr_control.core.topics.NODE_STATUS_FIELDS`, and logged rate-limited):

1. **Size.** A state longer than a ``max_joints`` one, or of another length than the last
   state read and saying it has more than ``max_joints`` names, is dropped unread
   (``inputs_oversized``): a 10 MB state costs a length comparison, not a parse.
2. **One source, by rule** (:class:`~cr_control.supervision.single_source.SingleSource`):
   states of a publisher other than the followed one, or of a node other than the
   expected ``state_source``, are refused unread (``states_foreign``); a silent publisher
   is never followed; another is followed after the followed one has delivered no valid
   state for :data:`SOURCE_SILENCE_S` (``source_handovers``).
3. **Inactive** (lifecycle): the first state of the source is read (the law's time
   origin); later ones are only kept, the newest answered at activation.
4. **The plant's command interface** (the latched /plant/command_interface): refused, or
   advertised but not arrived yet: no command; in lockstep the last state waits for it.
5. **Readable**: bytes that are no JointState are ignored (logged).
6. **A repeated state** (same stamp, already answered): the same command again.
7. **Newest first** (real time): a state with a newer one of the same publisher queued
   behind it is skipped (``states_skipped``); the plant holds a command for its latest
   state only. Lockstep answers every state.
8. **Joints**: positions and velocities reordered by name into the law's joint order; a
   state lacking one of its joints, or whose lengths differ, reaches the law as empty
   arrays, which it holds on (logged).
9. **Plant sensors**: a law that reads /plant/sensors before any has come is told so
   (its inputs are NaN: it holds or uses its fallback).

The wrench (/force_torque_sensor_broadcaster/wrench) and the plant's sensors are guarded
too: sized, read, and a wrench of another frame than ``sensor_frame`` or whose force is above
``max_sensor_force`` (or not finite) is a sensor fault: the last sane one stays in use
(``sensor_faults``). Live targets must be in the base frame and finite.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from cr_control.core import topics
from cr_control.core.parameters import Param
from cr_control.core.rate_limited_log import RateLimitedLog
from cr_control.supervision.single_source import SingleSource

#: Another /joint_states publisher is followed only after the followed one has delivered
#: no valid state this long (s; 2000 cycles at 1 kHz): beyond the plant's watchdog (100
#: cycles) and its lockstep resend (1 s), so a plant still alive behind a flood of foreign
#: states has braked or sent its state again first; a restarted plant takes longer anyway.
SOURCE_SILENCE_S = 2.0

#: The controller's rule for its state source (module docstring, guard 2).
STATE_SOURCE_PARAMETER = Param(
    "state_source", "/plant",
    "The node whose /joint_states are followed (full name; comma-separated for several): "
    "/plant for cr_sim's plant, /joint_state_broadcaster for a ros2_control robot. States "
    "of any other node are refused and counted (states_foreign). Empty: the first publisher "
    "that delivers a valid state is followed, whatever its node.", "string", read_only=True)

#: Verdicts of :meth:`ControllerInputs.state`.
NOTHING, ANSWER, REPEAT, OBSERVE = 0, 1, 2, 3

#: A held message: (bytes or None, publisher GID or None, length or None).
Held = tuple[bytes | None, bytes | None, int | None]


class Readers(NamedTuple):
    """How the node reads its messages from their bytes (``None`` if unreadable)."""

    state: Callable[[bytes], Any]            # -> JointStateFields
    wrench: Callable[[bytes], Any]           # -> WrenchFields
    sensors: Callable[[bytes], Any]          # -> ArrayFields
    state_names: Callable[[bytes], int | None]   # names a JointState says it has
    max_state_bytes: int                     # a JointState of max_joints joints at most
    max_joints: int
    wrench_max_bytes: int
    array_max_bytes: int


class ControllerInputs:
    """The guards of one controller node (module docstring). ``source``: the single-source
    guard of /joint_states (None where publishers cannot be told apart); ``values``: the
    law's parameter values (read live: ``max_sensor_force``); ``plant_sensors``: the law's
    array the plant's sensor values are written into; ``plant_advertises()``: whether a
    plant advertises its command interface (a graph query the node rate-limits)."""

    def __init__(self, readers: Readers, state_joint_names: Sequence[str], values: dict,
                 plant_sensors: np.ndarray, sensor_fields: Sequence[str],
                 source: SingleSource | None, log: RateLimitedLog, lockstep: bool,
                 plant_advertises: Callable[[], bool], scheme: str = "") -> None:
        self.read, self.log, self.source = readers, log, source
        self.state_joint_names = tuple(state_joint_names)
        self.values, self.scheme, self.lockstep = values, scheme, lockstep
        self.plant_advertises = plant_advertises
        self.read_state = readers.state
        # counters (the node's status)
        self.inputs_oversized = self.states_skipped = self.sensor_faults = 0
        # lifecycle and the plant's interface ("unknown", "ok" or "refused")
        self.active = False
        self.interface = "unknown"
        self.held: Held | None = None          # the newest state seen while inactive
        self.awaiting: Held | None = None      # the last state before the interface came
        self.unnamed: Held | None = None       # lockstep: refused before its node was known
        # the last state read
        self.stamp: tuple[int, int] = (0, 0)
        self.last_stamp: tuple[int, int] | None = None
        self.answered = False
        self.t = 0.0
        self.position = self.velocity = np.empty(0)
        self._state_size = -1
        self._index_cache: tuple[tuple[str, ...], list[int] | None] = ((), None)
        # wrench: the last sane one (force, torque), its frame
        self.wrench = np.zeros(6)
        self.force = self.wrench[:3]
        self.wrench_seen = False
        self.wrench_time = 0.0                 # its stamp (s)
        self._sensor_fault = False
        self.sensor_frame = values.get("sensor_frame", "")
        # the plant's sensors the law reads
        self.plant_sensors = plant_sensors
        self.sensor_fields = tuple(sensor_fields)
        self.sensors_seen = not self.sensor_fields
        self._sensor_cache: tuple[str, list[int] | None] = ("", None)

    # -- counters of the single-source guard ----------------------------------------------
    @property
    def states_foreign(self) -> int:
        return self.source.refused if self.source is not None else 0

    @property
    def source_handovers(self) -> int:
        return self.source.handovers if self.source is not None else 0

    # -- /joint_states ------------------------------------------------------------------
    def state(self, data: bytes | None, sender: bytes | None, length: int | None, now: float,
              newer_queued: bool = False) -> int:
        """The verdict on one serialized state (``data`` None: ``length`` bytes, too long to
        be copied) of publisher ``sender`` at ``now`` (s): :data:`ANSWER` (``stamp``, ``t``,
        ``position``, ``velocity`` hold it), :data:`REPEAT`, :data:`OBSERVE` (``t``: the law's
        time origin) or :data:`NOTHING`."""
        if (data is None or len(data) != self._state_size) and self._oversized_state(data, length):
            return NOTHING
        source = self.source
        if source is not None and not source.admit(sender, now):
            if self.lockstep and source.source is None and source.name(sender) is None:
                # a lockstep plant's first state, before the graph named its publisher: the
                # plant waits for the answer, so it is judged again once names are known
                self.unnamed = (data, sender, length)
            return NOTHING
        followed = source is None or sender == source.source
        if not self.active and followed and self.held is not None:
            # inactive, the law's time origin already set: only the newest is kept (read at
            # activation); an inactive node costs the loop no parse per cycle
            self.held = (data, sender, length)
            if source is not None:
                source.heard(sender, now)
            return NOTHING
        if self.interface != "ok" and (self.interface == "refused" or self.plant_advertises()):
            if self.interface == "unknown" and self.lockstep:
                # a lockstep plant waits for this state's answer (it resends only after
                # lockstep_resend_s): answered once the interface is known
                self.awaiting = (data, sender, length)
            return NOTHING
        state = self.read_state(data)
        if state is None:
            self.unreadable(topics.JOINT_STATES)
            return NOTHING
        self._state_size = len(data)
        if source is not None:
            source.heard(sender, now)
        self.stamp = stamp = (state.sec, state.nanosec)
        self.t = stamp[0] + stamp[1] * 1e-9
        if not self.active:
            self.held = (data, sender, length)
            return OBSERVE
        if stamp == self.last_stamp and self.answered:
            return REPEAT
        if newer_queued and not self.lockstep:
            self.states_skipped += 1
            self.log("skipped", "warn", lambda: (
                f"fell behind the plant: {self.states_skipped} states so far answered only by "
                "the newest one queued behind them (each skipped state lengthens the law's "
                "next step)"))
            return NOTHING
        self.last_stamp = stamp
        self.position, self.velocity = self.joint_arrays(state)
        if not self.sensors_seen:
            self.log("sensors", "warn", lambda: (
                f"{self.scheme} reads {list(self.sensor_fields)} from {topics.PLANT_SENSORS} "
                "but none has arrived: those inputs are NaN (the law holds its command, or "
                "uses its fallback where it has one)"))
        self.answered = True
        return ANSWER

    def activate(self) -> Held | None:
        """Lifecycle activation: states are answered from now on, the law afresh; returns
        the state kept while inactive (to be answered at once: a lockstep plant waits)."""
        self.last_stamp, self.answered, self.active = None, False, True
        held, self.held = self.held, None
        return held

    def named(self) -> Held | None:
        """The graph named more publishers: the lockstep state refused before its node was
        known, to be judged again (None if there is none)."""
        held, self.unnamed = self.unnamed, None
        return held

    def interface_known(self, ok: bool) -> Held | None:
        """The plant's command interface arrived (``ok``: the one the law commands); returns
        the state that waited for it, to be answered now."""
        if not ok:
            self.interface = "refused"
            return None
        first = self.interface == "unknown"
        self.interface = "ok"
        waiting, self.awaiting = self.awaiting, None
        return waiting if first else None

    def _oversized_state(self, data: bytes | None, length: int | None) -> bool:
        """True (counted, logged) for a state dropped unread for its size (guard 1)."""
        size = len(data) if data is not None else length or 0
        read = self.read
        if data is not None and size <= read.max_state_bytes:
            if size == self._state_size:
                return False
            names = read.state_names(data)
            if names is None or names <= read.max_joints:
                return False
            why = f"{names} joint names, more than {read.max_joints}"
        else:
            why = f"a JointState of {read.max_joints} joints has at most {read.max_state_bytes}"
        self.oversized(topics.JOINT_STATES, size, why)
        return True

    def joint_arrays(self, state) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities in the law's joint order (empty arrays if unusable: the
        law holds its command)."""
        names, position, velocity = state.name, state.position, state.velocity
        n = len(names)
        if len(position) != n or len(velocity) != n:
            return np.empty(0), np.empty(0)
        if names != self.state_joint_names:
            if names != self._index_cache[0]:
                try:
                    order = [names.index(j) for j in self.state_joint_names]
                except ValueError:
                    order = None
                self._index_cache = (names, order)
            order = self._index_cache[1]
            if order is None:
                self.log("joints", "error", lambda: (
                    f"joint state lacks some of {list(self.state_joint_names)}: {list(names)}"))
                return np.empty(0), np.empty(0)
            position, velocity = [position[i] for i in order], [velocity[i] for i in order]
        return np.array(position), np.array(velocity)

    # -- the wrench and the plant's sensors ------------------------------------------------
    def oversized(self, topic: str, size: int, why: str) -> None:
        """Count a message dropped unread for its size; log (rate-limited)."""
        self.inputs_oversized += 1
        self.log(f"oversized {topic}", "error",
                 f"a message of {size} bytes on {topic} ({why}) dropped unread; counted in "
                 "inputs_oversized")

    def unreadable(self, topic: str) -> None:
        self.log(f"unreadable {topic}", "error",
                 f"a message on {topic} could not be read: ignored")

    def _read_bounded(self, topic: str, data: bytes, max_bytes: int,
                      read: Callable[[bytes], Any], bound: str) -> Any | None:
        """``read(data)``, or None (counted or logged) if longer than ``max_bytes`` or
        unreadable; ``bound`` names what is bounded in the log line."""
        if len(data) > max_bytes:
            self.oversized(topic, len(data), f"{bound}: at most {max_bytes} bytes read")
            return None
        fields = read(data)
        if fields is None:
            self.unreadable(topic)
        return fields

    def wrench_message(self, data: bytes) -> None:
        """A serialized wrench: its force and torque become the ones in use if sane."""
        wrench = self._read_bounded(topics.WRENCH, data, self.read.wrench_max_bytes,
                                    self.read.wrench, "a WrenchStamped")
        if wrench is None:
            return
        if self.sensor_frame and wrench.frame_id != self.sensor_frame:
            self.sensor_faults += 1
            self.log("sensor frame", "error", lambda: (
                f"a wrench in frame {wrench.frame_id!r}, not sensor_frame "
                f"{self.sensor_frame!r}: ignored (counted in sensor_faults)"))
            return
        fx, fy, fz = wrench.force
        limit = self.values["max_sensor_force"]
        if fx * fx + fy * fy + fz * fz <= limit * limit:     # False for NaN, inf, overflow
            self.force[:] = wrench.force
            self.wrench[3:] = wrench.torque
            self.wrench_time = wrench.sec + wrench.nanosec * 1e-9
            self.wrench_seen = True
            self._sensor_fault = False
            return
        self.sensor_faults += 1
        if not self._sensor_fault:
            self._sensor_fault = True
            self.log("sensor fault", "warn", lambda: (
                f"wrench force {list(wrench.force)} N: |f| above max_sensor_force {limit:g} N "
                f"or not finite: a sensor fault; the last sane force {self.force.tolist()} N "
                "stays in use (counted in sensor_faults)"))

    @property
    def wrench_age_ms(self) -> float:
        """How much older (ms, stamp against stamp) the wrench in use is than the state
        answered: 0 when the state's own wrench came first, as the plant publishes it; -1
        before any wrench."""
        return (self.t - self.wrench_time) * 1e3 if self.wrench_seen else -1.0

    def sensors_message(self, data: bytes) -> None:
        """The plant's extra measurements the law reads, found by label (published just
        before the state they belong to)."""
        sensors = self._read_bounded(topics.PLANT_SENSORS, data, self.read.array_max_bytes,
                                     self.read.sensors, "the plant's sensors")
        if sensors is None:
            return
        label = sensors.labels[0] if sensors.labels else ""
        if label != self._sensor_cache[0]:
            fields = topics.fields_of(label)
            missing = [f for f in self.sensor_fields if f not in fields]
            index = None if missing else [fields.index(f) for f in self.sensor_fields]
            if missing:
                self.log(f"sensors {label}", "error",
                         f"{topics.PLANT_SENSORS} lacks {missing} (it has {fields[1:]}): "
                         f"{self.scheme} reads them as NaN")
            self._sensor_cache = (label, index)
        index = self._sensor_cache[1]
        values = sensors.data
        if index is not None and len(values) > max(index):
            self.plant_sensors[:] = [values[i] for i in index]
            self.sensors_seen = True

    # -- live targets (task-space schemes) ------------------------------------------------
    def target_usable(self, topic: str, frame_id: str, values: Sequence[float],
                      base_link: str) -> bool:
        """A target is used if it is in the base frame (or names none) and finite."""
        if frame_id not in ("", base_link):
            self.log(f"target frame {topic}", "warn",
                     f"~/{topic} in frame {frame_id!r} ignored: targets must be in "
                     f"{base_link!r} (no tf here)")
            return False
        if not all(np.isfinite(values)):
            self.log(f"target finite {topic}", "warn",
                     f"~/{topic} with a non-finite value ignored")
            return False
        return True

    def orientation_usable(self, quaternion: Sequence[float]) -> bool:
        """A target orientation is used unless it is all zeros (its norm is not the test:
        1e-200 squared is 0)."""
        if np.max(np.abs(quaternion)) > 0.0:
            return True
        self.log("target quaternion", "warn", "~/target_pose with a zero quaternion ignored "
                 "(an orientation of [0, 0, 0, 1] means none)")
        return False
