"""What the arm comes close to: the bodies of the arm and the robot, contacts of the arm links, and
the clearance the planned arm keeps from everything that is not the robot."""

from __future__ import annotations

import mujoco
import numpy as np

from sim import robot
from sim.scene import body_subtree
from sim.views.records import ViewPlanConfig


def arm_link_bodies(model: mujoco.MjModel, kin: robot.ArmKinematics) -> set[int]:
    """Bodies moved by the arm joints.

    Not the rail carriage and the arm's base on it: they ride on the floor by design.
    """
    return _bodies_moved_by(model, kin.joint_names[1])


def _bodies_moved_by(model: mujoco.MjModel, joint: str) -> set[int]:
    """The body of ``joint`` and every body below it."""
    root = int(model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)])
    return set(body_subtree(model, root))


def arm_collisions(model: mujoco.MjModel, data: mujoco.MjData, links: set[int]) -> list[str]:
    """Contacts of the arm links with anything (table, object, floor, other links), after
    ``mj_forward``; as readable ``"geom1/geom2"`` strings."""
    out = []
    for c in data.contact[: data.ncon]:
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        if int(model.geom_bodyid[g1]) in links or int(model.geom_bodyid[g2]) in links:
            out.append(f"{_geom_name(model, g1)}/{_geom_name(model, g2)}")
    return sorted(set(out))


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    return (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
            or f"geom{g}@{model.body(model.geom_bodyid[g]).name}")


def robot_bodies(model: mujoco.MjModel, kin: robot.ArmKinematics) -> set[int]:
    """Every body the rail joint carries: the carriage, the arm's base and its links."""
    return _bodies_moved_by(model, kin.joint_names[0])


def clearance_violations(model: mujoco.MjModel, data: mujoco.MjData, links: set[int],
                         robot_body_ids: set[int],
                         clearance: float = ViewPlanConfig.clearance_m) -> list[str]:
    """What the arm links come closer to than ``clearance`` at ``data.qpos``.

    Runs MuJoCo's collision detection itself (kinematics and collision, with the arm links'
    geom margins raised to ``clearance`` for the call and restored after). A link closer than
    ``clearance`` to anything outside the robot (object, table, floor), or touching another
    part of the robot, is a violation; as readable ``"geom1/geom2 (d mm)"`` strings.

    Parameters
    ----------
    links : set of int
        Bodies moved by the arm joints (:func:`arm_link_bodies`).
    robot_body_ids : set of int
        Bodies carried by the rail (:func:`robot_bodies`): near them only contact counts.
    clearance : float
        Metres (:attr:`ViewPlanConfig.clearance_m` by default, which says why).
    """
    return ClearanceCheck(model, links, robot_body_ids, clearance)(data)


class ClearanceCheck:
    """:func:`clearance_violations` with its masks and margins prepared once, and
    ``self_clearance`` (m, at most ``clearance``) between two parts of the robot (the function:
    contact only). Masks and margins once: a large object's
    plan checks ~10^5 configurations, and preparing them per call (body masks, the arm geoms'
    margins read and raised) was 60% of a check's CPU (28 of 47 us, drawer). The same contacts
    and strings as the function; the margins are restored after every call."""

    def __init__(self, model: mujoco.MjModel, links: set[int], robot_body_ids: set[int],
                 clearance: float = ViewPlanConfig.clearance_m, self_clearance: float = 0.0):
        if not 0.0 <= self_clearance <= clearance:
            raise ValueError(f"self_clearance must lie within [0, clearance = {clearance}], "
                             f"got {self_clearance}")
        self.model, self.clearance = model, float(clearance)
        self.self_clearance = float(self_clearance)
        self.is_link, self.is_robot = _body_masks(model, links, robot_body_ids)
        self.arm_geom = np.flatnonzero(self.is_link[model.geom_bodyid])
        self.saved = model.geom_margin[self.arm_geom].copy()
        self.raised = np.maximum(self.saved, self.clearance)

    def __call__(self, data: mujoco.MjData) -> list[str]:
        model, clearance = self.model, self.clearance
        model.geom_margin[self.arm_geom] = self.raised
        try:
            mujoco.mj_kinematics(model, data)
            mujoco.mj_collision(model, data)
            n = data.ncon
            if n == 0:
                return []
            geoms = data.contact.geom[:n]
            dist = data.contact.dist[:n]
            bodies = model.geom_bodyid[geoms]
            near = self.is_link[bodies].any(axis=1)
            limit = np.where(self.is_robot[bodies].all(axis=1), self.self_clearance, clearance)
            out = [f"{_geom_name(model, int(g1))}/{_geom_name(model, int(g2))} ({d * 1e3:.1f} mm)"
                   for (g1, g2), d in zip(geoms[near & (dist < limit)],
                                          dist[near & (dist < limit)], strict=True)]
        finally:
            model.geom_margin[self.arm_geom] = self.saved
        return sorted(set(out))


_BODY_MASKS: dict = {}


def _body_masks(model: mujoco.MjModel, links: set[int], robot_body_ids: set[int]
                ) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks over the bodies of ``model``: the arm links, the robot's bodies."""
    key = (model.nbody, frozenset(links), frozenset(robot_body_ids))  # all the masks hold
    masks = _BODY_MASKS.get(key)
    if masks is None:
        if len(_BODY_MASKS) > 64:
            _BODY_MASKS.clear()
        is_link = np.zeros(model.nbody, dtype=bool)
        is_link[sorted(links)] = True
        is_robot = np.zeros(model.nbody, dtype=bool)
        is_robot[sorted(robot_body_ids)] = True
        masks = _BODY_MASKS[key] = (is_link, is_robot)
    return masks
