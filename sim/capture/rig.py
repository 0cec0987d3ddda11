"""What every capture starts from: the scene with its object held still, the arm's kinematics and
its wrist camera; and the error a capture raises."""

from __future__ import annotations

import os
from dataclasses import dataclass

import mujoco
import numpy as np

from sim import robot
from sim.camera import mujoco_camera_intrinsics, true_camera_pose  # noqa: F401 (re-exported)
from sim.scene import Scene, load_scene

#: The object configurations a capture photographs.
CONFIGS = ("a", "b")


class CaptureError(RuntimeError):
    """The capture cannot produce a usable image set (too few reachable views, the arm touched
    something on its way, the object moved)."""


def as_scene(scene) -> Scene:
    """A :class:`sim.scene.Scene` from a bundled name, an MJCF path or a loaded scene."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene)
    raise TypeError(f"scene must be a name, a path or a sim.scene.Scene, got {type(scene)}")


@dataclass
class Rig:
    """A scene ready to photograph: the object held in one configuration, the arm at its home
    keyframe, the wrist camera."""

    scene: Scene
    """the scene compiled with its joint holds (:meth:`sim.scene.Scene.with_joint_holds`)"""
    model: mujoco.MjModel
    data: mujoco.MjData
    """the state: arm at its home keyframe, object held in the configuration"""
    kin: robot.ArmKinematics
    cam_id: int
    """MuJoCo id of the wrist camera"""
    K: np.ndarray
    """(3, 3) wrist camera intrinsics (OpenCV)"""
    width: int
    height: int


def make_rig(scene, config: str) -> Rig:
    """The scene (name, path or :class:`~sim.scene.Scene`) with its object joints held still in
    ``config`` while the arm works (sim.scene joint holds), and the arm's wrist camera."""
    sc = as_scene(scene).with_joint_holds()
    model = sc.model
    data = sc.make_data(config)  # arm at its home keyframe, object in the configuration
    sc.hold(data, config)
    kin = robot.load_arm_kinematics(model)
    cam_name = kin.spec.prefix + kin.spec.camera
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, cam_name)
    K, (width, height) = mujoco_camera_intrinsics(model, cam_name)
    return Rig(sc, model, data, kin, cam_id, K, width, height)

