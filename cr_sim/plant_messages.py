"""The plant's outgoing messages as CDR bytes, without ROS: built once and refilled in place
each state (:class:`cr_control.core.cdr.Writer`: numpy views onto their numbers), so the
node publishes bytes and builds no ROS message object per tick.

Nothing non-finite is sent: :meth:`PlantMessages.fill` and :meth:`PlantMessages.fill_contact`
say what is not finite instead of filling a message to send.
"""

from __future__ import annotations

from math import isfinite

from cr_control.core import cdr, topics
from cr_sim.plants.base import Plant


class PlantMessages:
    """The joint state, the sensor's wrench (in the plant's ``wrench_frame``), the plant's
    labelled sensors, the clock (``clock``) and, every ``contact_every`` states, the true contact wrench
    (base frame; for analysis only), all of one stamp."""

    def __init__(self, plant: Plant, contact_every: int = 1, clock: bool = True) -> None:
        self.plant = plant
        n = len(plant.joint_names)
        self.state = cdr.Writer(cdr.joint_state, name=list(plant.joint_names), position=n,
                                velocity=n, effort=n)
        self.position, self.velocity, self.effort = (self.state.array(f) for f in
                                                     ("position", "velocity", "effort"))
        self.wrench = cdr.Writer(cdr.wrench_stamped, frame_id=plant.wrench_frame)
        self.wrench_values = self.wrench.array("wrench")         # force, torque
        #: The plant's extra sensors, labelled, after the stamp (None: it has none).
        self.sensors = (topics.labelled_writer(["stamp", *plant.sensor_fields])
                        if plant.sensor_fields else None)
        self._sensor_values = self.sensors.array("data") if self.sensors is not None else None
        #: /clock (lockstep only; None otherwise).
        self.clock = cdr.Writer(cdr.clock) if clock else None
        truth = getattr(plant, "contact_wrench", None)
        #: The true contact wrench where the plant has one (None otherwise).
        self.truth = truth if callable(truth) else None
        self.contact = cdr.Writer(cdr.wrench_stamped, frame_id=getattr(plant, "base_frame", "world"))
        self._contact_values = self.contact.array("wrench")
        self._contact_every = contact_every
        self._contact_count = 0
        #: Whether the state just filled takes the true contact wrench along (every
        #: ``contact_every``; never without one).
        self.contact_due = False

    def fill(self, sec: int, nanosec: int) -> str:
        """Refill the state, wrench, clock and sensors from the plant now, stamped
        ``sec.nanosec``; what is not finite ("" if all is). Sets :attr:`contact_due`."""
        if self.truth is not None:
            self._contact_count += 1
            self.contact_due = self._contact_count >= self._contact_every
            if self.contact_due:
                self._contact_count = 0
        m = self.plant.measurement()
        wrench = self.wrench_values
        self.position[:] = m.position
        self.velocity[:] = m.velocity
        self.effort[:] = m.effort
        wrench[:3] = m.force
        wrench[3:] = m.torque
        if not isfinite(self.position.sum() + self.velocity.sum() + self.effort.sum()
                        + wrench.sum()):
            return "the joint state or wrench to publish"
        if self.sensors is not None:
            values = self._sensor_values
            values[0] = sec + nanosec * 1e-9
            values[1:] = self.plant.sensors()
            if not isfinite(values.sum()):
                return "a plant sensor to publish"
        self.state.set_stamp(sec, nanosec)
        self.wrench.set_stamp(sec, nanosec)
        if self.clock is not None:
            self.clock.set_stamp(sec, nanosec)
        return ""

    def fill_contact(self, sec: int, nanosec: int) -> str:
        """Refill the true contact wrench, stamped ``sec.nanosec``; what is not finite ("" if
        it is)."""
        truth = self.truth()
        values = self._contact_values
        values[:3] = truth.force
        values[3:] = truth.torque
        if not isfinite(values.sum()):
            return "the true contact wrench to publish"
        self.contact.set_stamp(sec, nanosec)
        return ""
