"""The object as read from a URDF or an MJCF: links with geometry, joints between them.

Both readers (:mod:`sim.author.urdf`, :mod:`sim.author.mjcf`) produce a :class:`SourceObject`
in the source's own units and frames; :mod:`sim.author.build` scales, places and textures it and
writes the scene. Fixed joints are already merged: every link here is a rigid group that moves as
one, every joint moves one link against its parent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class AuthorError(ValueError):
    """An object cannot be imported: the message names the file, the element and the fix."""


#: Joint types the harness's scenes take (continuous joints arrive as revolute without range).
JOINT_TYPES = ("revolute", "prismatic")
#: Primitive collision shapes kept as MuJoCo primitives (``size`` as MuJoCo reads it).
PRIMITIVES = ("box", "sphere", "capsule", "cylinder", "ellipsoid")


@dataclass
class Mesh:
    """A triangle mesh in its link's frame (source units).

    vertices : (n, 3) float; faces : (m, 3) int; name : what it came from (for messages);
    uv : (m, 3, 2) float or None, the source's own texture coordinates per face corner (OBJ
    convention, v up); image : (h, w, 3) uint8 or None, the source's own texture (rows from the
    top). Only ``--texture source`` uses the last two.
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = ""
    uv: np.ndarray | None = None
    image: np.ndarray | None = None


@dataclass
class Primitive:
    """A primitive collision shape: MuJoCo ``type`` and ``size`` (source units), placed in its
    link's frame by ``T_link_geom`` (4, 4)."""

    type: str
    size: np.ndarray
    T_link_geom: np.ndarray
    name: str = ""


@dataclass
class SourceLink:
    """A rigid link: its visible meshes and its collision shapes (empty: from the visuals)."""

    name: str
    visuals: list[Mesh] = field(default_factory=list)
    collisions: list[Mesh | Primitive] = field(default_factory=list)


@dataclass
class SourceJoint:
    """A joint that moves ``child`` against ``parent``.

    Attributes
    ----------
    name : str
    type : str
        ``"revolute"`` or ``"prismatic"``.
    parent, child : str
        Link names.
    T_parent_child : (4, 4) float
        The child link's frame in the parent link's frame at joint value 0.
    axis : (3,) float
        Unit axis in the child's frame.
    anchor : (3,) float
        A point of the axis in the child's frame (revolute joints turn about it).
    range : (2,) float or None
        Limits (rad or source length units); None for a continuous joint.
    continuous : bool
        A revolute joint without limits.
    """

    name: str
    type: str
    parent: str
    child: str
    T_parent_child: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray
    range: np.ndarray | None
    continuous: bool = False


@dataclass
class SourceObject:
    """An articulated object as read: ``links[root]`` is the base; ``joints`` in tree order
    (a joint's parent link is the root or the child of an earlier joint)."""

    name: str
    path: Path
    root: str
    links: dict[str, SourceLink]
    joints: list[SourceJoint]
    notes: list[str] = field(default_factory=list)
    """what the reader changed or left out (fixed joints merged, a free joint dropped, ...)"""
    R_world_root: np.ndarray = field(default_factory=lambda: np.eye(3))
    """(3, 3) orientation of the root link in the source's world (an MJCF root body may be
    turned; a URDF's root frame is its world)"""

    def link_poses(self, values: dict[str, float] | None = None) -> dict[str, np.ndarray]:
        """Poses ``{link: T_root_link (4, 4)}`` at joint values ``{joint: value}`` (default 0)."""
        values = values or {}
        poses = {self.root: np.eye(4)}
        for j in self.joints:
            q = float(values.get(j.name, 0.0))
            poses[j.child] = poses[j.parent] @ j.T_parent_child @ joint_motion(j, q)
        return poses


def pose(R: np.ndarray | None = None, t=None) -> np.ndarray:
    """A (4, 4) homogeneous transform from a rotation (3, 3) and a translation (3,)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) of ``angle`` rad about the unit ``axis`` (3,) (Rodrigues)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def joint_motion(j: SourceJoint, q: float) -> np.ndarray:
    """The child's displacement (4, 4) in its own frame at joint value ``q``."""
    if j.type == "prismatic":
        return pose(t=j.axis * q)
    R = rotation_about(j.axis, q)
    return pose(R, j.anchor - R @ j.anchor)


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points (n, 3) mapped by the transform T (4, 4)."""
    return np.asarray(p, float) @ T[:3, :3].T + T[:3, 3]
