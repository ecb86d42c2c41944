"""The offline runner: a plant and a controller stepped in one Python loop, no ROS.

What ``cr_sweep``, ``cr_tune``, ``cr_reproduce``, the chapter analyses and most tests run:
bit-for-bit deterministic and equivalent to a lockstep session over ROS (the command
computed from the state at t_k is held over [t_k, t_k+1)). :mod:`.loop` is the loop itself
(:func:`run`, :class:`OfflineRun`); :mod:`.build` makes a scheme's controller and plant from
the registries or a robot profile (:func:`build_scheme`, :func:`run_scheme`).

Example::

    from cr_control.offline import run_scheme

    run = run_scheme("adaptive_impedance", 10.0, controller_overrides={"Q_c": [50.0, 50.0]})
    run.time, run.force          # one row per control cycle
    run.column("e_x")            # any field of the scheme's reference or status, by name
"""

from cr_control.offline.build import build_scheme, robot_period, run_scheme, scheme_plant_overrides
from cr_control.offline.loop import OfflineRun, run

__all__ = ["OfflineRun", "build_scheme", "robot_period", "run", "run_scheme",
           "scheme_plant_overrides"]
