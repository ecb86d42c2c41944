"""How far the tip of a chain gets from its first joint: the sphere the task-space schemes
hold target positions in (:mod:`cr_control.schemes.impedance.base`).

The triangle inequality bounds it by the sum of the distances between successive joint
origins and from the last joint to the tip (:func:`reach_bound`); that bound is loose where
link offsets cancel (the UR5's shoulder and elbow offsets: 1.24 m against the 0.95 m its tip
gets from its first joint), so :func:`chain_reach` searches the farthest configuration
within the joint limits instead (seeded: the same every time; 0.04 s per chain, cached).

Near the first joint's axis an arm is singular too (the wrist over the base: the UR5's
shoulder singularity, where joint 1 must spin to move the tip sideways): :func:`off_the_axis`
holds a position at least a given distance from that axis (:func:`first_axis`).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cr_control.models.urdf import ChainModel

#: The farthest reach is searched from this many seeded random configurations, the best
#: REACH_STARTS of them refined by REACH_STEPS gradient steps (chain_reach).
REACH_SAMPLES = 2048
REACH_STARTS = 8
REACH_STEPS = 100
_REACHES: dict[int, tuple[ChainModel, tuple[np.ndarray, float]]] = {}


def chain_reach(chain_model: ChainModel) -> tuple[np.ndarray, float]:
    """(centre, radius): the first joint's origin (base frame) and the farthest the tip gets
    from it, searched numerically within the joint limits (:func:`farthest_reach`: seeded,
    the same every time) and never above the triangle inequality's :func:`reach_bound`.
    The bound alone is loose where link offsets cancel: 1.24 m on the UR5, whose tip gets
    0.95 m from its first joint at most (the Panda: 1.09 and 0.947 m). Cached per chain."""
    known = _REACHES.get(id(chain_model))
    if known is not None and known[0] is chain_model:
        return known[1]
    centre, bound = reach_bound(chain_model)
    radius = bound if not np.isfinite(bound) else min(bound, farthest_reach(chain_model, centre))
    _REACHES[id(chain_model)] = (chain_model, (centre, radius))
    return centre, radius


def farthest_reach(chain_model: ChainModel, centre: np.ndarray) -> float:
    """The largest distance of the tip from ``centre`` over the joint limits (continuous
    joints over one turn): REACH_SAMPLES seeded random configurations, then projected
    gradient ascent of |p(q) - c| from the REACH_STARTS best (the step halved whenever it
    does not gain)."""
    model, tip, lim = chain_model.model, chain_model.tip, chain_model.limits
    data = model.createData()
    lower, upper = np.maximum(lim.lower, -np.pi), np.minimum(lim.upper, np.pi)

    def distance(q: np.ndarray) -> tuple[float, np.ndarray]:
        qp = chain_model.configuration(q)
        pin.framesForwardKinematics(model, data, qp)
        return float(np.linalg.norm(data.oMf[tip].translation - centre)), qp

    rng = np.random.default_rng(0)
    samples = rng.uniform(lower, upper, (REACH_SAMPLES, chain_model.n))
    found = np.array([distance(q)[0] for q in samples])
    best = float(found.max())
    for q in samples[np.argsort(found)[-REACH_STARTS:]]:
        d, qp = distance(q)
        step = 0.1
        for _ in range(REACH_STEPS):
            J = pin.computeFrameJacobian(model, data, qp, tip, pin.LOCAL_WORLD_ALIGNED)[:3]
            away = data.oMf[tip].translation - centre
            gradient = J.T @ away / max(d, 1e-12)
            size = float(np.linalg.norm(gradient))
            if size < 1e-12:
                break
            trial = np.clip(q + step * gradient / size, lower, upper)
            d_trial, qp_trial = distance(trial)
            if d_trial > d:
                q, d, qp = trial, d_trial, qp_trial
            else:
                step *= 0.5
                distance(q)            # the data back at q for the next Jacobian
        best = max(best, d)
    return best


def reach_bound(chain_model: ChainModel) -> tuple[np.ndarray, float]:
    """(centre, bound): the first joint's origin (base frame) and a bound on the tip's
    distance from it that no configuration exceeds (triangle inequality): the distances
    between successive joint origins and from the last joint to the tip (constant across a
    revolute joint), plus each prismatic joint's largest travel (inf without limits)."""
    model = chain_model.model
    centre = np.array(model.jointPlacements[1].translation, dtype=float)
    radius = sum(float(np.linalg.norm(model.jointPlacements[j].translation))
                 for j in range(2, model.njoints))
    radius += float(np.linalg.norm(model.frames[chain_model.tip].placement.translation))
    lim = chain_model.limits
    for j, kind in enumerate(chain_model.kinds):
        if kind == "prismatic":
            radius += max(abs(float(lim.lower[j])), abs(float(lim.upper[j])))
    return centre, radius


def first_axis(chain_model: ChainModel) -> np.ndarray:
    """The first joint's axis (unit, base frame; it does not move with the joints) for a
    revolute or continuous joint; zeros for a prismatic one."""
    if chain_model.kinds[0] == "prismatic":
        return np.zeros(3)
    model = chain_model.model
    data = model.createData()
    pin.computeJointJacobians(model, data, chain_model.configuration(np.zeros(chain_model.n)))
    axis = np.array(pin.getJointJacobian(model, data, 1, pin.ReferenceFrame.WORLD)[3:, 0])
    return axis / np.linalg.norm(axis)


def off_the_axis(offset: np.ndarray, axis: np.ndarray, inner: float,
                 away: np.ndarray) -> tuple[np.ndarray, bool]:
    """(``offset`` from a point of the first joint's axis, moved out radially to at least
    ``inner`` from that axis; whether it moved). A point on the axis moves out along
    ``away`` (its part across the axis; any direction across it if none)."""
    along = float(offset @ axis)
    radial = offset - along * axis
    size = float(np.linalg.norm(radial))
    if size >= inner or not np.any(axis):
        return offset, False
    if size > 1e-9 * inner:
        direction = radial / size
    else:
        direction = away - float(away @ axis) * axis
        if np.linalg.norm(direction) <= 1e-9:
            direction = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
        direction = direction / np.linalg.norm(direction)
    return along * axis + inner * direction, True

