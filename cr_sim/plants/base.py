"""What every simulated plant offers the plant node and the offline loop.

Besides stepping and measuring, a plant says what its actuators may do
(:meth:`Plant.joint_limits`, from the URDF's ``<limit>`` tags where the plant has a
Pinocchio model) and how it brakes (:meth:`Plant.safe_stop_command`): the plant node
builds its command limits (:class:`CommandLimiter`) and its watchdog's safe stop on them
(modelled on libfranka's limits and ``communication_constraints_violation``).
It also reports what the node's reflexes watch (libfranka's Cartesian and joint
reflexes): the true contact force (:meth:`Plant.contact_force_magnitude`, against the
scenario's ``max_contact_force``) and the true joint velocities
(:meth:`Plant.true_velocity`, against the URDF's ``<limit velocity>``:
:meth:`Plant.velocity_limits`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from cr_control.core.parameters import Bound, Param
from cr_control.models.brake import brake_torque, stop_position


@dataclass
class Measurement:
    """What the plant's sensors report at ``time`` (s).

    ``force`` is the measured contact force on the end effector in the world frame
    (3 components; planar plants leave z at 0); ``torque`` the measured torque (3, zero for
    every plant but ``urdf_surface`` with a wrist sensor, whose ``force`` and ``torque`` are
    then the sensor's wrench in its own frame: the plant's ``wrench_frame``).
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    force: np.ndarray
    torque: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class JointLimits:
    """Per-joint limits in the plant's joint order (URDF ``<limit>``; inf = none given)."""

    effort: np.ndarray
    velocity: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def unlimited(cls, n: int) -> JointLimits:
        """No limits at all (plants without a model)."""
        inf = np.full(n, np.inf)
        return cls(inf.copy(), inf.copy(), -inf, inf.copy())


def max_contact_force_parameter(default: float, why: str) -> Param:
    """The scenario parameter ``max_contact_force`` (N, > 0, read-only) of the force reflex
    with its default and the reason for it (which task force it is a multiple of)."""
    return Param("max_contact_force", default, "Force reflex (libfranka's Cartesian reflex): "
                 "a contact force above this (N) safe-stops the plant until resume is set; "
                 f"{why}", "positive", read_only=True, bound=Bound.FORCE)


@njit(cache=True, error_model="numpy")
def take_command(held, command):
    """Copy ``command`` into ``held`` if it has one finite value per entry of ``held``; else
    leave ``held`` as it is (the plant keeps the last good input). Returns whether it did:
    the check every plant kernel makes before it integrates (no NaN ever gets in)."""
    if command.shape[0] != held.shape[0]:
        return False
    for j in range(held.shape[0]):
        if not math.isfinite(command[j]):
            return False
    held[:] = command
    return True


class Plant(ABC):
    """A simulated robot and its environment, stepped with a held command.

    A plant keeps its simulation time in ``_t`` (s) and its true (noise-free) state vector
    in ``_x`` (layout in the plant's own docstring); :attr:`time` and :attr:`state` read
    them.
    """

    _t: float
    _x: np.ndarray

    #: Names of the joints, in the order of every state vector the plant gives.
    joint_names: tuple[str, ...]
    #: Names of the commanded joints, in the order of the command :meth:`step` takes; None:
    #: every joint of ``joint_names`` (flexible-joint plants command only their motors).
    command_joint_names: tuple[str, ...] | None = None

    @property
    def command_joints(self) -> tuple[str, ...]:
        """The commanded joints (``command_joint_names``, else ``joint_names``)."""
        return tuple(self.command_joint_names or self.joint_names)
    #: "effort" (torque-commanded) or "position" (command-displacement plants, ch. 4).
    command_interface: str = "effort"
    #: The frame the measured wrench is in (the published frame_id): the thesis plants'
    #: world frame; urdf_surface's base link or wrist-sensor link.
    wrench_frame: str = "world"
    #: Safe stop (brakes) of effort plants: natural frequency w_b (rad/s) of
    #: tau = G(q) - M(q) (2 w_b q' + w_b^2 (q - q_stop)) (:mod:`cr_control.models.brake`);
    #: the plant node sets it from its parameter ``brake_frequency``.
    brake_frequency: float = 50.0

    #: Force reflex (libfranka's Cartesian contact reflex): the plant node safe-stops the plant when
    #: :meth:`contact_force_magnitude` exceeds this (N); scenarios set it from their
    #: ``max_contact_force`` parameter (:func:`max_contact_force_parameter`), inf = never.
    max_contact_force: float = math.inf
    #: Position plants: speed (m/s or rad/s, per joint) at which the safe stop moves the
    #: command to :meth:`contact_free_position` where the URDF gives no velocity limit.
    retract_speed: float = 0.1

    _brake_hold: np.ndarray | None = None
    #: Position plants' retract in a safe stop: (start time, start, target, speeds) or None.
    _retract: tuple[float, list[float], list[float], list[float]] | None = None

    @abstractmethod
    def step(self, command: np.ndarray, dt: float) -> None:
        """Advance the simulation by ``dt`` seconds with ``command`` held constant."""

    @abstractmethod
    def measurement(self) -> Measurement:
        """The current sensor readings."""

    @property
    def time(self) -> float:
        """Simulation time (s)."""
        return self._t

    @property
    def state(self) -> np.ndarray:
        """The true (noise-free) state vector, a copy."""
        return self._x.copy()

    #: Names of extra measurements a plant offers beyond the joint state and the wrench
    #: (published by the plant node on topics.PLANT_SENSORS, labelled); none by default.
    sensor_fields: tuple[str, ...] = ()

    def sensors(self) -> list[float]:
        """Values of ``sensor_fields`` now."""
        return []

    def state_is_finite(self) -> bool:
        """Whether every value of the true state is finite (a sum: a state whose values add up
        beyond 1e308 counts as non-finite too). The plant node checks it after every step and
        stops at the first non-finite state: no brake can act on it, and nothing non-finite
        may leave the plant. Called every cycle: keep it cheap."""
        return math.isfinite(self._x.sum())

    def accept(self, command: np.ndarray) -> bool:
        """True if ``command`` has one finite value per commanded joint (never NaN in)."""
        return command.shape == (len(self.command_joints),) and bool(np.all(np.isfinite(command)))

    def joint_limits(self) -> JointLimits:
        """Limits of the commanded joints: from the Pinocchio model (built from the URDF)
        where the plant has one as ``self.arm.model``, else none (override for other plants)."""
        model = getattr(getattr(self, "arm", None), "model", None)
        n = len(self.command_joints)
        if model is None:
            return JointLimits.unlimited(n)
        try:
            idx = [model.joints[model.getJointId(name)].idx_v for name in self.command_joints]
        except (IndexError, AttributeError):
            return JointLimits.unlimited(n)
        pick = lambda values: np.array([float(values[i]) for i in idx])  # noqa: E731
        return JointLimits(pick(model.effortLimit), pick(model.velocityLimit),
                           pick(model.lowerPositionLimit), pick(model.upperPositionLimit))

    def brake_inertia(self, q: np.ndarray) -> np.ndarray:
        """M(q) of the commanded joints (positions ``q`` in ``joint_names`` order), which the
        brakes of an effort plant scale by: ``self.mass_matrix(q)`` or ``self.arm.mass_matrix(q)``
        (override where the commanded joints are not those). NotImplementedError if the plant
        has neither: an effort plant must say how heavy its joints are to be braked."""
        mass_matrix = getattr(self, "mass_matrix", None)
        if not callable(mass_matrix):
            mass_matrix = getattr(getattr(self, "arm", None), "mass_matrix", None)
        if not callable(mass_matrix):
            raise NotImplementedError(f"{type(self).__name__} has no mass matrix to brake with")
        return np.asarray(mass_matrix(np.asarray(q, dtype=float)), dtype=float)

    def gravity_torque(self, q: np.ndarray) -> np.ndarray | None:
        """G(q) if the plant knows it (``self.gravity(q)`` or ``self.arm.gravity(q)``), else None."""
        gravity = getattr(self, "gravity", None)
        if not callable(gravity):
            gravity = getattr(getattr(self, "arm", None), "gravity", None)
        return np.asarray(gravity(q), dtype=float) if callable(gravity) else None

    # -- what the reflexes watch (the plant node, after every step) ---------------------------
    def contact_force_magnitude(self) -> float:
        """|f| (N): the contact force the force reflex compares with ``max_contact_force``,
        true (no measurement noise: noise must not trip the reflex, and drawing it here would
        change the measurements' noise sequence). By default the norm of the plant's true
        ``contact_force()`` where it has one, else of the measured wrench force; plants whose
        contact force is not the wrench (a constraint's lambda) override it. Called every
        cycle: keep it cheap."""
        contact = getattr(self, "contact_force", None)
        force = contact() if callable(contact) else self.measurement().force
        return math.sqrt(sum(float(f) * float(f) for f in force))

    def true_velocity(self) -> Sequence[float]:
        """The joint velocities in ``joint_names`` order, true (no measurement noise), for the
        joint velocity reflex. By default the measured ones; plants with velocity noise
        override it (as every thesis plant does). Called every cycle on plants with velocity
        limits: keep it cheap."""
        return self.measurement().velocity.tolist()

    def velocity_limits(self) -> list[tuple[int, float]]:
        """(index into :meth:`true_velocity`, limit) of every joint with a URDF
        ``<limit velocity>``: the commanded joints' finite :meth:`joint_limits` velocities by
        default (override to add uncommanded joints that have one)."""
        names = list(self.joint_names)
        return [(names.index(name), float(limit))
                for name, limit in zip(self.command_joints, self.joint_limits().velocity, strict=True)
                if 0.0 < limit < math.inf]

    # -- safe stop ----------------------------------------------------------------------------
    def contact_free_position(self) -> np.ndarray | None:
        """Position plants: the command at which the end effector is out of contact (at most
        touching at zero force), where the safe stop retracts to; None (the default): hold
        the position where braking began."""
        return None

    def brake_stop_position(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Where the brakes hold the commanded joints braking from (q, q'):
        q + q'/w_b (:func:`cr_control.models.brake.stop_position`: each joint's speed then
        falls as e^{-w_b t}), clipped into the joints' position limits."""
        limits = self.joint_limits()
        lower, upper = np.asarray(limits.lower, dtype=float), np.asarray(limits.upper, dtype=float)
        target = stop_position(q, v, self.brake_frequency)
        inside = lower <= upper                      # checked limits (load_chain); else unclipped
        target[inside] = np.clip(target[inside], lower[inside], upper[inside])
        return target

    def begin_safe_stop(self) -> None:
        """Engage the brakes. Effort plants: remember where the brakes bring the joints to
        rest (:meth:`brake_stop_position` from the measured state), to hold them there.
        Position plants hold the position where braking began, or, with a
        :meth:`contact_free_position`, start retracting the command (from the held one) to
        it, at the URDF's velocity limit (else ``retract_speed``)."""
        m = self.measurement()
        self._retract = None
        if self.command_interface != "position":
            self._brake_hold = self.brake_stop_position(m.position, m.velocity)
            return
        self._brake_hold = m.position.copy()
        target = self.contact_free_position()
        if target is None:
            return
        held = getattr(self, "held", None)
        start = held if held is not None and np.shape(held) == np.shape(target) else self._brake_hold
        speeds = [float(v) if 0.0 < v < math.inf else self.retract_speed
                  for v in self.joint_limits().velocity]
        self._retract = (self._t, [float(x) for x in start], [float(x) for x in target], speeds)

    def retract_command(self) -> np.ndarray:
        """Position plants in a safe stop: the command moving from where it was to the
        contact-free position at constant speed (per joint), then held there."""
        t0, start, target, speeds = self._retract
        travel = self._t - t0
        return np.array([b if abs(b - a) <= v * travel else a + math.copysign(v * travel, b - a)
                         for a, b, v in zip(start, target, speeds, strict=True)])

    def safe_stop_command(self) -> np.ndarray:
        """The braking command while in safe stop, from the measured state. Effort plants:

            tau = G(q) - M(q) (2 w_b q' + w_b^2 (q - q_stop))

        (:func:`cr_control.models.brake.brake_torque`): G(q) holds gravity (where the plant
        offers it, :meth:`gravity_torque`), and every joint, scaled by the mass matrix
        (:meth:`brake_inertia`), is a critically damped system of natural frequency
        w_b = ``brake_frequency`` whatever its inertia, brought to rest at q_stop
        (:meth:`brake_stop_position`: q + q'/w_b when braking began) with its speed falling
        as e^{-w_b t}, and held there against contact forces, like a joint brake. Held for
        a period dt it is stable and never alternates for w_b dt <= 0.5 (the plant node asks
        at most :data:`cr_control.models.brake.MAX_BRAKE_STEP`). Position plants cannot be
        braked with torques: they retract the command to :meth:`contact_free_position` and
        hold it there (:meth:`retract_command`), or hold the position where braking began if
        the plant names none. Override for plants that brake differently.
        """
        if self._retract is not None:
            return self.retract_command()
        m = self.measurement()
        q, v = m.position, m.velocity
        if self.command_interface == "position":
            return (self._brake_hold if self._brake_hold is not None else q).copy()
        hold = self._brake_hold if self._brake_hold is not None else self.brake_stop_position(q, v)
        return brake_torque(self.brake_inertia(q), self.gravity_torque(q), q, v, hold,
                            self.brake_frequency)

    def describe_safe_stop(self) -> str:
        """The brakes in words, for the plant node's log line when a safe stop begins."""
        if self.command_interface == "position":
            if self._retract is None:
                return "holding the position where braking began"
            _, start, target, speeds = self._retract
            return (f"retracting the command from {[round(x, 4) for x in start]} to the "
                    f"contact-free position {[round(x, 4) for x in target]} at "
                    f"{[round(v, 4) for v in speeds]} per s, then holding it")
        w = self.brake_frequency
        return (f"gravity held, joints braked at w_b = {w:g} rad/s, scaled by the mass matrix "
                f"(every joint's speed falls as e^(-{w:g} t)), and held where they come to rest")


class CommandLimiter:
    """Clips commands into per-joint bounds and a rate limit; the plant node applies it to
    every command before it reaches :meth:`Plant.step` (libfranka: torque limits and a
    1000 N m/s torque-rate limit; position plants: position limits and a velocity limit).

    The rate limit acts between consecutive commands, each allowed to move at most
    ``rate * period`` from the one before; the first command is only bounded.
    Pure Python over the few joints: cheaper than numpy at this size (1 kHz hot path).
    """

    def __init__(self, lower: Sequence[float], upper: Sequence[float], rate: Sequence[float],
                 period: float):
        self.lower = [float(x) for x in lower]
        self.upper = [float(x) for x in upper]
        self.max_step = [float(r) * period for r in rate]
        if not all(lo <= hi for lo, hi in zip(self.lower, self.upper, strict=True)):
            raise ValueError("lower limits must not exceed upper limits")
        self.clipped = 0

    def limit(self, values: Sequence[float], previous: Sequence[float] | None) -> list[float] | None:
        """``values`` clipped into the bounds and to within the rate limit of ``previous``
        (counted in ``clipped`` if anything was), or None if a value is not finite (the
        caller refuses the command)."""
        out = []
        clipped = False
        steps = self.max_step
        for i, x in enumerate(values):
            if not math.isfinite(x):
                return None
            lo, hi = self.lower[i], self.upper[i]
            if previous is not None:
                p, s = previous[i], steps[i]
                lo, hi = max(lo, p - s), min(hi, p + s)
            if x < lo:
                x, clipped = lo, True
            elif x > hi:
                x, clipped = hi, True
            out.append(x)
        self.clipped += clipped
        return out

    def bound(self, values: Sequence[float]) -> list[float]:
        """``values`` clipped into the bounds only (no rate limit, not counted): brakes."""
        return [min(max(float(x), lo), hi) for x, lo, hi in zip(values, self.lower, self.upper,
                                                                  strict=True)]


class ConstrainedPlant(Plant):
    """A plant held on a holonomic constraint Phi(q) = 0 (chapter 2): its first sensors
    are lambda (2.11-2.13) and the drift Phi, Phi' (Baumgarte, 2.94), read back here."""

    sensor_fields: tuple[str, ...] = ("lambda", "phi", "phi_dot")

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if tuple(cls.sensor_fields[:3]) != ("lambda", "phi", "phi_dot"):
            raise TypeError(f"{cls.__name__}: a constrained plant's sensors begin with lambda, phi, phi_dot")

    @property
    def constraint_force(self) -> float:
        """lambda (N): the contact force along the constraint normal (> 0: pressing)."""
        return self.sensors()[0]

    def contact_force_magnitude(self) -> float:
        """|lambda| (N): the constraint force, true (the sensors carry no noise), either sign
        (the contact is bilateral: a large pull is as wrong as a large push)."""
        return abs(self.constraint_force)

    @property
    def constraint_error(self) -> tuple[float, float]:
        """(Phi (m), Phi' (m/s)) now."""
        phi, phi_dot = self.sensors()[1:3]
        return phi, phi_dot
