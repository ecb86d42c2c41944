"""How far a pose target may lead the tip: any ``~/target_pose``, anywhere, leaves the normal
force loop in command.

A target pose is a wish for the tip's position and orientation; the force along the surface
normal belongs to the force loop (the chapter 3 laws' force admittance, the chapter 5 laws'
impedance about their plane). Each cycle, before the target filter of
:mod:`cr_control.schemes.blocks.references` is given the target, the target is bounded
relative to the *measured* tip (position r, orientation R), with u the unit direction into
the surface (the guarded approach's direction: ``approach_direction``, or against the
desired force; zero where none is known):

- **depth** (into the surface): the target's component along u is at most
  D_n = 2 v_a / w_f beyond the tip (v_a = ``approach_speed``, DEFAULT_DEPTH_SPEED where it is
  0; w_f = ``target_filter_frequency``). A step of D_n through the critically damped filter
  moves the reference at most w_f D_n / e = 0.74 v_a, so a target below the tool brings it
  down no faster than the guarded approach, and in contact the reference stands at most D_n
  past the contact point: the force admittance (``force_admittance_limit``, 5 cm on the
  robots, against 12 mm at 3 cm/s) or the chapter 5 impedance (60 N/m x 12 mm = 0.7 N)
  takes it back, so the force stays the force loop's. Away from the surface the target is
  not bounded by this (lifting the tool off is a pose target's right).
- **lead** (along the surface; in every direction where u is unknown): the component
  across u is at most D_t = LEAD_S v_max / w_f from the tip (v_max = ``target_max_speed``;
  0.2 m at the defaults): the lag of the critically damped filter behind a target moving at
  v_max, so a target the tip follows is not slowed, while a tip that cannot follow (held by
  friction, a joint limit, the reach) is never led farther than that: the tracking force
  the law builds, stiffness x error, stays what it is at full speed, whatever the target.
- **orientation**: the target orientation is at most MAX_LEAD_ANGLE from the measured one
  (along the shortest rotation between them): the orientation impedance's torque stays
  bounded by K_o x MAX_LEAD_ANGLE however far the target is turned, and a target the
  arm cannot turn to (its joint limits) does not wind the desired orientation beyond it.

Measured before (Panda with a wrist sensor, offline, the plant's supervision and the node's
limits): a target 10 m or 1e300 m along the table, or beside it, streamed at 10 Hz with the
home orientation: 48 N and the plant's 50 N force reflex in every chapter 3 scheme (the reach
sphere the target was moved onto lies 14 cm below the table there); 0.5 m into the table:
50.3 N, reflex at 0.33 s after the target.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.so3 import (
    quaternion_conjugate,
    quaternion_exp,
    quaternion_from_matrix,
    quaternion_multiply,
    rotation_vector,
)

#: The depth bound's speed where no guarded approach gives one (m/s): the robots' approach.
DEFAULT_DEPTH_SPEED = 0.03
#: The lead across u is LEAD_S x target_max_speed / w_f (m) from the tip.
LEAD_S = 2.0
#: The largest angle between the target orientation and the measured one (rad).
MAX_LEAD_ANGLE = 0.5


@njit(cache=True, error_model="numpy")
def bounded_position(target, r, u, depth, lead):
    """The target position (task rows) at most ``depth`` beyond the tip ``r`` along the unit
    ``u`` (zero: no surface known) and at most ``lead`` from it across u (module
    docstring); a new array."""
    m = r.shape[0]
    gap = target - r
    along = 0.0
    for i in range(m):
        along += gap[i] * u[i]
    across = gap - along * u
    scale = np.max(np.abs(across)) if m > 0 else 0.0
    if scale > lead:                  # |across| > lead (scaled first: no overflow at 1e300)
        across *= lead / (scale * math.sqrt(np.sum((across / scale) ** 2)))
    elif scale > 0.0:
        size = math.sqrt(np.sum(across * across))
        if size > lead:
            across *= lead / size
    return r + across + min(along, depth) * u


@njit(cache=True, error_model="numpy")
def bounded_orientation(target_q, R, max_angle):
    """The target orientation (quaternion [w, x, y, z]) at most ``max_angle`` from the
    measured orientation R, along the shortest rotation between them; a new array."""
    measured = quaternion_from_matrix(R)
    turn = rotation_vector(quaternion_multiply(target_q, quaternion_conjugate(measured)))
    angle = math.sqrt(turn[0] * turn[0] + turn[1] * turn[1] + turn[2] * turn[2])
    if angle <= max_angle:
        return target_q.copy()
    return quaternion_multiply(quaternion_exp(turn * (max_angle / angle)), measured)


@njit(cache=True, error_model="numpy")
def depth_bound(approach_speed, filter_frequency):
    """D_n = 2 v_a / w_f (module docstring)."""
    v_a = approach_speed if approach_speed > 0.0 else DEFAULT_DEPTH_SPEED
    return 2.0 * v_a / filter_frequency
