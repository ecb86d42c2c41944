"""Registry of control schemes: executable name -> controller class and its plant scenario."""

from __future__ import annotations

from typing import Any

from cr_control.core.parameters import resolve
from cr_control.schemes.closed_chain.moving_object_adaptive import MovingObjectAdaptiveController
from cr_control.schemes.closed_chain.moving_object_nn import MovingObjectNNController
from cr_control.schemes.controller import Controller
from cr_control.schemes.flexible_joint.fjr_robust_adaptive import FJRRobustAdaptiveController
from cr_control.schemes.flexible_joint.fjr_singular_perturbation import FJRSingularPerturbationController
from cr_control.schemes.force.backstepping_force import BacksteppingForceController
from cr_control.schemes.force.cmmsd_backstepping import CMMSDBacksteppingController
from cr_control.schemes.force.mrac_force import MRACForceController
from cr_control.schemes.impedance.adaptive_impedance import AdaptiveImpedanceController
from cr_control.schemes.impedance.fuzzy_unidirectional import FuzzyUnidirectionalController
from cr_control.schemes.impedance.impedance import ImpedanceController
from cr_control.schemes.impedance.nn_adaptive_impedance import NNAdaptiveImpedanceController
from cr_control.schemes.impedance.robust_adaptive_impedance import RobustAdaptiveImpedanceController

#: scheme name -> (controller class, default plant scenario)
SCHEMES: dict[str, tuple[type[Controller], str]] = {
    "adaptive_impedance": (AdaptiveImpedanceController, "compliant_plane"),
    "robust_adaptive_impedance": (RobustAdaptiveImpedanceController, "compliant_plane"),
    "nn_adaptive_impedance": (NNAdaptiveImpedanceController, "compliant_plane"),
    "impedance": (ImpedanceController, "circular_surface"),
    "fuzzy_unidirectional": (FuzzyUnidirectionalController, "circular_surface"),
    "moving_object_adaptive": (MovingObjectAdaptiveController, "moving_object"),
    "moving_object_nn": (MovingObjectNNController, "moving_object"),
    "backstepping_force": (BacksteppingForceController, "dynamic_constraint"),
    "mrac_force": (MRACForceController, "dynamic_constraint"),
    "cmmsd_backstepping": (CMMSDBacksteppingController, "cmmsd"),
    "fjr_robust_adaptive": (FJRRobustAdaptiveController, "flexible_joint_surface"),
    "fjr_singular_perturbation": (FJRSingularPerturbationController, "flexible_joint_surface"),
}


def controller_class(scheme: str) -> type[Controller]:
    """The controller class of ``scheme`` (ValueError naming the known ones if unknown)."""
    if scheme not in SCHEMES:
        raise ValueError(f"unknown scheme {scheme!r}; known: {sorted(SCHEMES)}")
    return SCHEMES[scheme][0]


def make_controller(scheme: str, overrides: dict[str, Any] | None = None) -> Controller:
    """A controller of ``scheme`` with thesis defaults and ``overrides`` (ROS-style values)."""
    cls = controller_class(scheme)
    return cls(resolve(cls.parameters(overrides), overrides))


#: Plant parameters a scheme's thesis runs set beyond the scenario's defaults (applied by
#: cr_session before any user override; the offline loop takes the scenario's own ones,
#: it has no plant node and so no command limiter).
PLANT_OVERRIDES: dict[str, dict[str, Any]] = {
    # The thesis gains at 1 kHz: the boundary layer (Delta = 0.002) moves the torque by
    # several N m per cycle and the start asks ~70 N m within ms; the plant node's default
    # torque-rate limit (libfranka's 1000 N m/s) turns that into divergence (lockstep and
    # offline with the limiter: |e_q| ~ 3 rad; 20 000 N m/s is the least that holds).
    "fjr_robust_adaptive": {"effort_rate_limit": 100000.0},
    # section 6.3.2: stiff joints, known to the scheme (its joint_stiffness, motor_inertia)
    "fjr_singular_perturbation": {"joint_stiffness": [300.0, 300.0], "motor_inertia": [1.0, 1.0]},
}


def default_plant_overrides(scheme: str) -> dict[str, Any]:
    """The plant parameters the thesis runs ``scheme`` with (beyond the scenario defaults)."""
    controller_class(scheme)
    return dict(PLANT_OVERRIDES.get(scheme, {}))


def default_scenario(scheme: str) -> str:
    """The plant scenario the thesis runs ``scheme`` on."""
    controller_class(scheme)
    return SCHEMES[scheme][1]
