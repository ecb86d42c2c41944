"""What every simulated plant offers the plant node and the offline loop.

Besides stepping and measuring, a plant says what its actuators may do
(:meth:`Plant.joint_limits`, from the URDF's ``<limit>`` tags where the plant has a
Pinocchio model) and how it brakes (:meth:`Plant.safe_stop_command`): the plant node
builds its command limits (:class:`CommandLimiter`) and its watchdog's safe stop on them
(issue 7, modelled on libfranka's limits and ``communication_constraints_violation``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass
class Measurement:
    """What the plant's sensors report at ``time`` (s).

    ``force`` is the measured contact force on the end effector in the world frame
    (3 components; planar plants leave z at 0).
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    force: np.ndarray


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
    #: Safe stop (brakes): viscous damping K_d (N m s/rad) of tau = G(q) - K_d q' - K_p (q - q_stop).
    brake_damping: float = 30.0
    #: Safe stop: holding stiffness K_p (N m/rad) about the position where braking began.
    brake_stiffness: float = 1000.0

    _brake_hold: np.ndarray | None = None

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

    def gravity_torque(self, q: np.ndarray) -> np.ndarray | None:
        """G(q) if the plant knows it (``self.gravity(q)`` or ``self.arm.gravity(q)``), else None."""
        gravity = getattr(self, "gravity", None)
        if not callable(gravity):
            gravity = getattr(getattr(self, "arm", None), "gravity", None)
        return np.asarray(gravity(q), dtype=float) if callable(gravity) else None

    def begin_safe_stop(self) -> None:
        """Engage the brakes: remember where the joints are, to hold them there."""
        self._brake_hold = self.measurement().position.copy()

    def safe_stop_command(self) -> np.ndarray:
        """The braking command while in safe stop (effort plants), from the measured state:

            tau = G(q) - K_d q' - K_p (q - q_stop)

        G(q) holds gravity (where the plant offers it), K_d = ``brake_damping`` brings the
        joints to rest and K_p = ``brake_stiffness`` (0 = damping only) holds them where
        braking began against contact forces, like a joint brake. Position plants hold the
        position where braking began. Override for plants that brake differently.
        """
        m = self.measurement()
        q, v = m.position, m.velocity
        hold = self._brake_hold if self._brake_hold is not None else q
        if self.command_interface == "position":
            return hold.copy()
        tau = -self.brake_damping * v - self.brake_stiffness * (q - hold)
        gravity = self.gravity_torque(q)
        return tau + gravity if gravity is not None else tau


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

    @property
    def constraint_error(self) -> tuple[float, float]:
        """(Phi (m), Phi' (m/s)) now."""
        phi, phi_dot = self.sensors()[1:3]
        return phi, phi_dot
