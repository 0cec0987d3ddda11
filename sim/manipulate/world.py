"""The simulated world the arm acts in: the scene compiled with one grasp weld per object body.

This is the simulator's side: physics, the true object. The robot's decisions are made in a
:class:`sim.manipulate.planning_world.PlanningWorld`, which knows the stage and the arm but sees the
object only through the registered model.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from sim import robot, views

#: Names of the grasp welds: ``grasp_weld:<body>``.
WELD_PREFIX = "grasp_weld:"


@dataclass
class World:
    """The scene compiled for manipulation (see :func:`build_world`)."""

    name: str
    """the scene's name"""
    path: Path
    """the scene file (the planning world is built from its stage and arm)"""
    model: mujoco.MjModel
    kin: robot.ArmKinematics
    qidx: np.ndarray
    """qpos indices of the arm's joints (rail first)"""
    vidx: np.ndarray
    """their dof indices"""
    aidx: np.ndarray
    """their actuators"""
    arm_links: set
    """bodies moved by the arm joints"""
    flange_body: int
    weld_of_body: dict
    """object body id -> id of its (inactive) grasp weld"""
    object_bodies: set
    """the bodies under the scene's ``object`` body"""
    object_joints: dict
    """object joint name -> qpos address (every hinge and slide under ``object``)"""
    qpos_start: np.ndarray
    """the state the manipulation starts from: the object as the capture of A left it, the arm
    at its keyframe"""


def build_world(scene) -> World:
    """Compile ``scene`` (a :class:`sim.scene.Scene`) with one inactive weld (flange body to
    object body) per object body, and remember the object's configuration A as the start.

    The welds are the gripper: :mod:`sim.manipulate.execute` switches one on when the fingers
    are at the grasp point and off when its force exceeds the grip's limit.
    """
    spec = mujoco.MjSpec.from_file(str(scene.path))
    arm = robot.arm_spec(scene.model)  # the scene's arm (PUMA 560, Panda, ...), not a fixed one
    flange = arm.prefix + arm.flange_body
    bodies = [scene.model.body(b).name for b in views.object_bodies(scene.model)]
    for name in bodies:
        if not name:
            continue
        eq = spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, objtype=mujoco.mjtObj.mjOBJ_BODY,
                               name=f"{WELD_PREFIX}{name}", name1=flange, name2=name,
                               active=False)
        eq.data = np.r_[np.zeros(3), np.zeros(3), [1.0, 0, 0, 0], 1.0,
                        np.zeros(len(eq.data) - 11)]
    model = spec.compile()
    if model.nq != scene.model.nq or model.nbody != scene.model.nbody:
        raise RuntimeError("adding the grasp welds changed the model's layout; report this bug")
    kin = robot.load_arm_kinematics(model)
    weld = {}
    for i in range(model.neq):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, i) or ""
        if name.startswith(WELD_PREFIX):
            weld[model.body(name[len(WELD_PREFIX):]).id] = i
    vidx = np.array([model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]
                     for n in kin.joint_names])
    obj = set(views.object_bodies(model))
    joints = {}
    for j in range(model.njnt):
        if int(model.jnt_bodyid[j]) in obj and int(model.jnt_type[j]) in (
                int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            joints[mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)] = int(
                model.jnt_qposadr[j])
    start = scene.make_data("a")  # the world as the capture of A left it
    return World(scene.name, Path(scene.path), model, kin, robot.qpos_indices(model, kin), vidx,
                 robot.actuator_indices(model, kin), views.arm_link_bodies(model, kin),
                 model.body(flange).id, weld, obj, joints, start.qpos.copy())


def fresh_data(world: World, q_start=None) -> mujoco.MjData:
    """A new state: :attr:`World.qpos_start`, the arm at ``q_start`` (and its servos holding it),
    every weld off."""
    m = world.model
    d = mujoco.MjData(m)
    if m.nkey > 0:
        mujoco.mj_resetDataKeyframe(m, d, 0)
    d.qpos[:] = world.qpos_start
    if q_start is not None:
        d.qpos[world.qidx] = q_start
        d.ctrl[world.aidx] = q_start
    d.eq_active[:] = 0
    mujoco.mj_forward(m, d)
    return d


def body_pose(data: mujoco.MjData, body: int) -> np.ndarray:
    """``T_world_body`` (4, 4) of a body in ``data`` (after ``mj_forward``)."""
    T = np.eye(4)
    T[:3, :3] = data.xmat[body].reshape(3, 3)
    T[:3, 3] = data.xpos[body]
    return T


def object_joint_values(world: World, data: mujoco.MjData) -> dict[str, float]:
    """``{joint name: qpos}`` of the object's joints in ``data`` (the physical state)."""
    return {n: float(data.qpos[a]) for n, a in world.object_joints.items()}
