"""What every simulated plant offers the plant node and the offline loop."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np


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


class Plant(ABC):
    """A simulated robot and its environment, stepped with a held command."""

    #: Names of the joints, in the order of every vector the plant takes or gives.
    joint_names: tuple[str, ...]
    #: "effort" (torque-commanded) or "position" (command-displacement plants, ch. 4).
    command_interface: str = "effort"

    @abstractmethod
    def step(self, command: np.ndarray, dt: float) -> None:
        """Advance the simulation by ``dt`` seconds with ``command`` held constant."""

    @abstractmethod
    def measurement(self) -> Measurement:
        """The current sensor readings."""

    @property
    @abstractmethod
    def time(self) -> float:
        """Simulation time (s)."""

    def accept(self, command: np.ndarray) -> bool:
        """True if ``command`` has one finite value per joint (the plant never lets NaN in)."""
        return command.shape == (len(self.joint_names),) and bool(np.all(np.isfinite(command)))
