"""Scenes: load an MJCF scene and read the articulated object's ground truth from it.

A scene file (see ``scenes/README.md``) includes the shared stage and adds one object:

- the object's root body is named ``"object"``; it and its descendant bodies are the object's
  bodies. A *link* is a rigid group of them: the root body, or a descendant body that carries a
  joint, together with every descendant welded to it (no joint in between);
- each joint of those bodies is an object joint: ``hinge`` (revolute) or ``slide`` (prismatic),
  one per body, with a range;
- the two configurations of the object (before and after the interaction) are declared per joint
  by name as ``<custom><numeric name="config_a:JOINT" data="VALUE"/>`` (and ``config_b:JOINT``),
  in the joint's units (radians for hinges, metres for slides);
- optionally, reconstruction settings the scenario needs, as
  ``<numeric name="reconstruct:STAGE.FIELD" data="VALUE"/>`` naming a field of
  :class:`artrecon.reconstruct.ReconstructConfig` (e.g. ``reconstruct:dense.downsample`` 1 for
  full-resolution stereo of a thin object). They are what a user would choose for such an object,
  never ground truth; ``sim.evaluate`` reconstructs with them.

``load_scene`` compiles the file, checks all of the above and returns a :class:`Scene` with the
compiled model and the ground truth: links, and for each joint its type, axis direction and a
point on the axis in the world frame at configuration A, its parent and child link and its
values in both configurations. Any violation raises :class:`SceneError` naming the file, the
element and the fix.

Ground truth stays in the harness (``sim``); the reconstruction (``artrecon``) never sees it.

Rooms: :mod:`~sim.scene.records` (:class:`Scene`, :class:`Link`, :class:`Joint`,
:class:`Coupling`), :mod:`~sim.scene.load` (compiling and checking a file, :func:`load_scene`),
:mod:`~sim.scene.files` (where scenes and stages are, compile errors), :mod:`~sim.scene.holds`
(joint holds that keep the object still while the arm works).
"""

from sim.scene.files import (
    BUNDLED_SCENES_DIR,
    NON_SCENE_FILES,
    SCENES_DIR,
    STAGE_FILES,
    list_scenes,
    scene_path,
    stage_file,
)
from sim.scene.holds import (
    HOLD_PREFIX,
    HOLD_SOLIMP,
    HOLD_SOLREF,
    add_joint_holds,
    hold_joints,
    release_joints,
)
from sim.scene.load import (
    CONFIG_PREFIX,
    JOINT_TYPES,
    OBJECT_BODY,
    SETTINGS_PREFIX,
    body_subtree,
    load_scene,
    physics_warnings,
)
from sim.scene.records import (
    CONFIGURATIONS,
    STATIC_TOLERANCE,
    Coupling,
    Joint,
    Link,
    Scene,
    SceneError,
)

__all__ = [
    "BUNDLED_SCENES_DIR", "CONFIGURATIONS", "CONFIG_PREFIX", "HOLD_PREFIX", "HOLD_SOLIMP",
    "HOLD_SOLREF", "JOINT_TYPES", "NON_SCENE_FILES", "OBJECT_BODY", "SCENES_DIR",
    "SETTINGS_PREFIX", "STAGE_FILES", "STATIC_TOLERANCE", "Coupling", "Joint", "Link", "Scene",
    "SceneError", "add_joint_holds", "body_subtree", "hold_joints", "list_scenes", "load_scene",
    "physics_warnings", "release_joints", "scene_path", "stage_file",
]
