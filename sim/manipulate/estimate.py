"""What the arm follows: a joint in the world frame (:class:`JointEstimate`), from a registered
model (the robot's view) or, for demonstrations only, from the scene's ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artrecon.geometry import rotation_about

#: Tilt of the deliberately wrong axis used by the tests and the command's comparison (deg).
WRONG_AXIS_TILT_DEG = 20.0


class ManipulationError(RuntimeError):
    """No grasp could be planned, or the grasp could not be made."""


class GraspMissed(ManipulationError):
    """The gripper reached the grasp pose and closed on nothing: the model's surface is not
    where the object is there (a dense surface widened beyond a rim). What the robot feels, not
    the truth: the fingers close without resistance. ``point`` is the candidate that missed,
    ``physics`` the simulation after the arm backed out the way it came (its ``contacts``: what
    the arm touched; :func:`sim.manipulate.execute.execute` goes on in it: whatever the attempt
    touched stays as it left it)."""

    def __init__(self, message: str, point, physics):
        super().__init__(message)
        self.point = np.asarray(point, dtype=float)
        self.physics = physics


@dataclass(frozen=True)
class JointEstimate:
    """A joint in the world frame (metres, radians).

    Attributes
    ----------
    type : str
        ``"revolute"`` or ``"prismatic"``.
    axis : (3,) float
        Unit direction; positive motion is right-handed about it / along it.
    point : (3,) float
        A point on the axis.
    source : str
        Where it came from (``"ground truth"``, ``"model"``, ``"tilted ..."``).
    name : str
    """

    type: str
    axis: np.ndarray
    point: np.ndarray
    source: str = "ground truth"
    name: str = ""

    def __post_init__(self):
        if self.type not in ("revolute", "prismatic"):
            raise ValueError(f"JointEstimate.type must be 'revolute' or 'prismatic', got "
                             f"{self.type!r}")
        axis = np.asarray(self.axis, dtype=float).reshape(-1)
        point = np.asarray(self.point, dtype=float).reshape(-1)
        if axis.shape != (3,) or point.shape != (3,):
            raise ValueError(f"axis and point must have shape (3,), got {axis.shape} and "
                             f"{point.shape}")
        n = np.linalg.norm(axis)
        if not np.isfinite(n) or n == 0:
            raise ValueError("JointEstimate.axis must be a non-zero finite vector")
        object.__setattr__(self, "axis", axis / n)
        object.__setattr__(self, "point", point)

    def tilted(self, degrees: float = WRONG_AXIS_TILT_DEG) -> JointEstimate:
        """The same joint with its axis turned by ``degrees`` about a fixed perpendicular
        (world z x axis, or world x if the axis is vertical), through the same point."""
        perp = np.cross(self.axis, [0.0, 0.0, 1.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(self.axis, [1.0, 0.0, 0.0])
        perp /= np.linalg.norm(perp)
        axis = rotation_about(perp, np.deg2rad(degrees)) @ self.axis
        return JointEstimate(self.type, axis, self.point, f"{self.source}, tilted {degrees:g} deg",
                             self.name)

    def motion(self, amount: float) -> np.ndarray:
        """``T_world`` (4, 4) of the motion by ``amount`` (rad or m) about/along the axis."""
        T = np.eye(4)
        if self.type == "revolute":
            R = rotation_about(self.axis, amount)
            T[:3, :3], T[:3, 3] = R, self.point - R @ self.point
        else:
            T[:3, 3] = amount * self.axis
        return T


def default_joint(scene):
    """The scene joint moved when none is named: the first one that moves between the two
    configurations (:attr:`sim.scene.Scene.moving_joints`). A static joint did not move, so no
    reconstruction estimates it and there is nothing to follow (cabinet_door_only's drawer); only
    a scene whose joints are all static falls back to its first joint.

    Raises
    ------
    ManipulationError
        The scene has no object joint.
    """
    if not scene.joints:
        raise ManipulationError(f"scene {scene.name!r} has no object joint: nothing to move")
    return (scene.moving_joints or scene.joints)[0]


def joint_estimate_from_scene(scene, joint: str | None = None) -> JointEstimate:
    """The ground-truth joint of a scene (configuration A) as a :class:`JointEstimate`; default
    :func:`default_joint`."""
    j = default_joint(scene) if joint is None else scene.joint(joint)
    return JointEstimate(j.type, j.axis, j.point, "ground truth", j.name)


def joint_estimate_from_model(model, joint: int = 0) -> JointEstimate:
    """Joint ``joint`` of a *registered* ArticulatedModel (robot frame, metres) as a
    :class:`JointEstimate`: its axis, a point on it, its name; positive motion moves the
    model's child link as the model's motion A -> B does."""
    if not model.scale_known:
        raise ValueError("the model is not registered (scale_known is False): register it "
                         "(artrecon.register) so it is in the robot frame, in metres")
    if not model.joints:
        raise ValueError("the model has no joints: nothing to move")
    j = model.joints[joint]
    return JointEstimate(j.type, j.axis_direction, j.axis_point, "model", j.name)
