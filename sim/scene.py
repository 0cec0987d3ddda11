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
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

log = logging.getLogger(__name__)

#: Folder of the scenes that come with the harness (the stage, its assets, the bundled scenes).
BUNDLED_SCENES_DIR = Path(__file__).resolve().parents[1] / "scenes"
#: Folder of the scenes found by name; ``ARTRECON_SCENES_DIR`` points elsewhere (a folder laid
#: out the same way: scene files beside ``stage.xml``).
SCENES_DIR = Path(os.environ.get("ARTRECON_SCENES_DIR", BUNDLED_SCENES_DIR))

#: The stage file of each arm (``<custom><text name="artrecon:arm">``): the floor, walls, table,
#: lights and the arm on its rail, included by every scene that the arm works in.
STAGE_FILES = {"puma560": "stage.xml", "panda": "stage_panda.xml"}
#: Files in the scenes folder that are not scenes themselves: the stages, included by scenes.
NON_SCENE_FILES = frozenset(STAGE_FILES.values())

#: Name of the object's root body.
OBJECT_BODY = "object"

#: Names of the two configurations and the prefix of their ``<numeric>`` elements.
CONFIGURATIONS = ("a", "b")
CONFIG_PREFIX = "config_"
#: Prefix of the ``<numeric>`` elements that set reconstruction settings.
SETTINGS_PREFIX = "reconstruct:"

#: Slack when checking that a configuration value lies in its joint's range: the values are
#: written in decimal in the XML (e.g. 0.5236 for 30 deg) and MuJoCo stores ranges as float64,
#: so only a representation error, far below any physical meaning, is forgiven.
RANGE_TOLERANCE = 1e-9
#: A joint whose two configuration values differ by no more than this did not move between the
#: configurations (it is "static"; the reconstruction must not invent it). Values are written in
#: decimal in the XML, so only a representation error is forgiven, as for RANGE_TOLERANCE.
STATIC_TOLERANCE = 1e-9
#: Slack when checking that the configurations satisfy a joint coupling (``<equality><joint>``):
#: the polynomial is evaluated in float64 from decimal values, so a representation error only.
COUPLING_TOLERANCE = 1e-9

#: Name prefix of the joint holds (:func:`add_joint_holds`): ``"hold:" + joint name``.
HOLD_PREFIX = "hold:"
#: Stiffness of a hold (MuJoCo ``solref``: time constant, damping ratio). The time constant is
#: MuJoCo's smallest stable one at the stage's 2 ms timestep (twice the step); with
#: HOLD_SOLIMP the loaded hinges of the bundled objects (truck bed, scraper boom) settle within
#: 1e-5 rad of the held value and stay there for minutes (their friction loss, MuJoCo's soft
#: constraint on velocity only, lets them creep by 1-3 mrad in 3 s).
HOLD_SOLREF = (0.004, 1.0)
#: Impedance of a hold (MuJoCo ``solimp``): near-rigid at any violation.
HOLD_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)

JOINT_TYPES = {int(mujoco.mjtJoint.mjJNT_HINGE): "revolute",
               int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic"}
_MJ_JOINT_NAMES = {int(mujoco.mjtJoint.mjJNT_FREE): "free",
                   int(mujoco.mjtJoint.mjJNT_BALL): "ball",
                   int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
                   int(mujoco.mjtJoint.mjJNT_HINGE): "hinge"}


class SceneError(ValueError):
    """A scene file is missing, does not compile, or breaks the scene conventions."""


@dataclass(frozen=True)
class Link:
    """A rigid link of the object.

    Attributes
    ----------
    name : str
        Name of the link's root body (``"object"`` for the base link).
    body_ids : tuple of int
        Ids of every MuJoCo body of the link, its root first.
    body_names : tuple of str
        Their names (a nameless body shows as ``""``).
    """

    name: str
    body_ids: tuple[int, ...]
    body_names: tuple[str, ...]

    @property
    def body_id(self) -> int:
        """Id of the link's root body."""
        return self.body_ids[0]


@dataclass(frozen=True, eq=False)
class Joint:
    """Ground truth of one object joint.

    Attributes
    ----------
    name : str
        MuJoCo joint name.
    type : str
        ``"revolute"`` (MuJoCo hinge) or ``"prismatic"`` (MuJoCo slide).
    joint_id, qpos_adr, dof_adr : int
        Indices into the compiled model.
    axis : (3,) float
        Unit axis direction in the world frame at configuration A (positive joint values turn
        the child right-handed about it / move the child along it).
    point : (3,) float
        A point on the axis in the world frame at configuration A (the joint's anchor; for a
        prismatic joint any point of the line is as good as this one).
    parent, child : str
        Names of the parent link (``"world"`` if the object's root itself moves) and child link.
    range : (2,) float
        Joint limits (rad or m).
    value_a, value_b : float
        Joint values in configurations A and B (rad or m).
    """

    name: str
    type: str
    joint_id: int
    qpos_adr: int
    dof_adr: int
    axis: np.ndarray
    point: np.ndarray
    parent: str
    child: str
    range: np.ndarray
    value_a: float
    value_b: float

    def value(self, configuration: str) -> float:
        """Joint value in configuration ``"a"`` or ``"b"``."""
        return self.value_a if _check_configuration(configuration) == "a" else self.value_b

    @property
    def motion(self) -> float:
        """``value_b - value_a``: the joint's motion between the configurations (rad or m)."""
        return self.value_b - self.value_a

    @property
    def static(self) -> bool:
        """True if the joint did not move between the configurations (``|motion|`` at most
        :data:`STATIC_TOLERANCE`): no relative motion of its child link to find."""
        return abs(self.motion) <= STATIC_TOLERANCE


@dataclass(frozen=True)
class Coupling:
    """Two object joints that move together (a MuJoCo ``<equality><joint>`` constraint):
    ``joint1 = c0 + c1 q2 + c2 q2^2 + c3 q2^3 + c4 q2^4`` with ``q2`` the value of ``joint2``.

    Attributes
    ----------
    name : str
        Name of the equality constraint (``""`` if it has none).
    joint1, joint2 : str
        The driven and the driving joint.
    polycoef : (5,) float
        ``c0 .. c4``.
    """

    name: str
    joint1: str
    joint2: str
    polycoef: tuple[float, ...]

    def value(self, q2: float) -> float:
        """``joint1``'s value implied by ``joint2`` at ``q2``."""
        return float(sum(c * q2 ** k for k, c in enumerate(self.polycoef)))


@dataclass(frozen=True, eq=False)
class Scene:
    """A compiled scene and the ground truth of its object.

    Attributes
    ----------
    name : str
        Scene name (file stem).
    path : pathlib.Path
        Absolute path of the scene file.
    model : mujoco.MjModel
        The compiled model (stage, arm and object).
    links : tuple of Link
        The object's links, base link (``"object"``) first, then in body order.
    joints : tuple of Joint
        The object's joints in model order.
    couplings : tuple of Coupling
        Pairs of object joints constrained to move together (empty for independent joints).
    reconstruct_settings : dict
        ``{"stage.field": value}``: the reconstruction settings the scene asks for (see the
        module docstring; artrecon.reconstruct.with_settings), empty for the defaults.
    """

    name: str
    path: Path
    model: mujoco.MjModel
    links: tuple[Link, ...]
    joints: tuple[Joint, ...]
    couplings: tuple[Coupling, ...] = ()
    reconstruct_settings: Mapping[str, float] = field(default_factory=dict)

    @property
    def moving_joints(self) -> tuple[Joint, ...]:
        """The joints that move between the configurations (not :attr:`Joint.static`)."""
        return tuple(j for j in self.joints if not j.static)

    def joint(self, name: str) -> Joint:
        """The object joint called ``name``."""
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"scene {self.name!r} has no object joint {name!r}; "
                       f"its joints are {[j.name for j in self.joints]}")

    def link(self, name: str) -> Link:
        """The object link whose root body is called ``name``."""
        for li in self.links:
            if li.name == name:
                return li
        raise KeyError(f"scene {self.name!r} has no object link {name!r}; "
                       f"its links are {[li.name for li in self.links]}")

    def configuration(self, configuration: str) -> dict[str, float]:
        """Joint values ``{joint name: value}`` of configuration ``"a"`` or ``"b"``."""
        return {j.name: j.value(configuration) for j in self.joints}

    def set_configuration(self, data: mujoco.MjData, configuration: str,
                          forward: bool = True) -> None:
        """Put the object of ``data`` in configuration ``"a"`` or ``"b"``.

        Sets the object joints' positions (and zeroes their velocities); the arm and rail are
        left as they are. With ``forward`` runs ``mj_forward`` so poses are up to date.
        """
        self.set_joint_values(data, self.configuration(configuration), forward=forward)

    def set_joint_values(self, data: mujoco.MjData, values: Mapping[str, float],
                         forward: bool = True) -> None:
        """Set object joints ``{name: value}`` in ``data`` (others unchanged), zero their
        velocities and, with ``forward``, run ``mj_forward``."""
        if data.qpos.shape != (self.model.nq,):
            raise ValueError(f"expected MjData of this scene's model with qpos of shape "
                             f"({self.model.nq},), got {data.qpos.shape}")
        for name, value in values.items():
            j = self.joint(name)
            data.qpos[j.qpos_adr] = float(value)
            data.qvel[j.dof_adr] = 0.0
        if forward:
            mujoco.mj_forward(self.model, data)

    def make_data(self, configuration: str = "a") -> mujoco.MjData:
        """A fresh ``MjData``: the model's first keyframe if it has one (the arm's ``home``,
        with its controls), else ``qpos0``; the object in ``configuration``; forwarded."""
        data = mujoco.MjData(self.model)
        if self.model.nkey > 0:
            mujoco.mj_resetDataKeyframe(self.model, data, 0)
        self.set_configuration(data, configuration)
        return data

    def link_poses(self, configuration: str) -> dict[str, np.ndarray]:
        """World poses ``{link name: T_world_link (4, 4)}`` of the links' root bodies in
        configuration ``"a"`` or ``"b"`` (arm at its keyframe; it does not move the object)."""
        data = self.make_data(configuration)
        poses = {}
        for li in self.links:
            T = np.eye(4)
            T[:3, :3] = data.xmat[li.body_id].reshape(3, 3)
            T[:3, 3] = data.xpos[li.body_id]
            poses[li.name] = T
        return poses

    @property
    def held_joints(self) -> tuple[str, ...]:
        """Names of the joints :meth:`with_joint_holds` holds: every object joint except those a
        coupling drives (its ``joint1``; the coupling already ties it to a held joint)."""
        driven = {c.joint1 for c in self.couplings}
        return tuple(j.name for j in self.joints if j.name not in driven)

    def with_joint_holds(self) -> Scene:
        """The same scene compiled with an inactive hold on each of :attr:`held_joints`.

        The returned scene's model has the same bodies, joints and geoms (same ids and
        addresses) and one more equality constraint per held joint (:func:`add_joint_holds`);
        switch the holds on with :meth:`hold`. The model is compiled anew from the file: it
        is the caller's own (:func:`hold_joints` writes the held values into it).
        """
        spec = mujoco.MjSpec.from_file(str(self.path))
        add_joint_holds(spec, self.held_joints)
        try:
            model = spec.compile()
        except ValueError as err:
            raise SceneError(f"{self.path}: MuJoCo could not compile the scene with joint "
                             f"holds: {err}") from err
        if (model.nq, model.nbody, model.ngeom, model.njnt) != (
                self.model.nq, self.model.nbody, self.model.ngeom, self.model.njnt):
            raise SceneError(f"{self.path}: adding the joint holds changed the model's layout; "
                             "report this bug (sim/scene.py)")
        return replace(self, model=model)

    def hold(self, data: mujoco.MjData, configuration: str | Mapping[str, float]) -> None:
        """Hold the object in ``configuration`` (``"a"``, ``"b"`` or ``{joint: value}``).

        Only for a scene from :meth:`with_joint_holds`. Sets the joints' positions (zero
        velocities) and switches their holds on at those values, see :func:`hold_joints`.
        """
        values = (self.configuration(configuration) if isinstance(configuration, str)
                  else dict(configuration))
        self.set_joint_values(data, values, forward=False)
        held = set(self.held_joints)
        hold_joints(self.model, data, {k: v for k, v in values.items() if k in held})
        mujoco.mj_forward(self.model, data)


def list_scenes(folder: str | os.PathLike | None = None) -> list[str]:
    """Names of the scenes in ``folder`` (default :data:`SCENES_DIR`), sorted."""
    folder = Path(folder) if folder is not None else SCENES_DIR
    return sorted(p.stem for p in folder.glob("*.xml") if p.name not in NON_SCENE_FILES)


def scene_path(name_or_path: str | os.PathLike) -> Path:
    """Absolute path of a bundled scene name (``"pliers"``) or of an MJCF file path."""
    text = os.fspath(name_or_path)
    looks_like_path = (isinstance(name_or_path, os.PathLike) or text.endswith(".xml")
                       or os.sep in text or (os.altsep is not None and os.altsep in text))
    if looks_like_path:
        path = Path(text).expanduser().resolve()
        if not path.is_file():
            raise SceneError(f"{path}: no such scene file; give an existing MJCF file or one of "
                             f"the bundled scenes {list_scenes()}")
        return path
    path = (SCENES_DIR / f"{text}.xml").resolve()
    if text in {Path(f).stem for f in NON_SCENE_FILES} or not path.is_file():
        raise SceneError(f"no bundled scene named {text!r} in {SCENES_DIR}; the scenes are "
                         f"{list_scenes()} (or give the path of an MJCF file)")
    return path


def _check_configuration(configuration: str) -> str:
    if configuration not in CONFIGURATIONS:
        raise ValueError(f"configuration must be one of {CONFIGURATIONS}, got {configuration!r}")
    return configuration


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(model, obj, i) or ""


def stage_file(arm: str = "puma560") -> Path:
    """Absolute path of the bundled stage that carries ``arm`` (a key of :data:`STAGE_FILES`).

    A scene anywhere on disk includes it by this path (``<include file="..."/>``): MuJoCo finds
    a file that an included file names relative to the scene's folder first and then relative
    to the included file's own folder, so the stage's assets and arm come from the harness and
    the scene's folder holds only the scene and its own assets.
    """
    if arm not in STAGE_FILES:
        raise ValueError(f"unknown arm {arm!r}; the stages carry {sorted(STAGE_FILES)}")
    return BUNDLED_SCENES_DIR / STAGE_FILES[arm]


def _missing_file_fix(path: Path, msg: str) -> str:
    """The fix for a file MuJoCo could not open while compiling the scene ``path``."""
    stages = sorted(STAGE_FILES.values())
    if any(f"'{name}'" in msg or f"/{name}'" in msg for name in stages) \
            and not (path.parent / "stage.xml").is_file():
        return (f"the scene includes a stage that is not beside it; include the bundled one by "
                f"its absolute path, <include file=\"{stage_file()}\"/> (or "
                f"{stage_file('panda')} for the Panda), as `python -m sim.author` writes scenes")
    if "robots" in msg:
        return ("MuJoCo 4.0 looks for the stage's arm (<model file=\"../robots/...\">) from the "
                "working directory first and, for a stage included from another folder, "
                "misplaces it when the working directory has a ../robots beside it; run from "
                "the repository root (or any folder without ../robots)")
    return (f"file= paths are relative to the scene file's folder {path.parent}, then to the "
            f"folder of the included file that names them; for the bundled assets run "
            f"`python scenes/make_assets.py`")


def _compile(path: Path) -> mujoco.MjModel:
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        msg = str(err).strip()
        if "opening file" in msg or "resource not found" in msg or "could not open" in msg:
            fix = _missing_file_fix(path, msg)
        else:
            fix = "fix the element MuJoCo names (see scenes/README.md for the conventions)"
        raise SceneError(f"{path}: MuJoCo could not compile the scene: {msg}. Fix: {fix}") \
            from err


def _object_bodies(model: mujoco.MjModel, root: int) -> list[int]:
    """``root`` and all its descendants, in body order (parents come before children)."""
    inside = {root}
    for b in range(root + 1, model.nbody):
        if int(model.body_parentid[b]) in inside:
            inside.add(b)
    return sorted(inside)


def _parse_configurations(model: mujoco.MjModel, path: Path,
                          joint_ids: dict[str, int]) -> dict[str, dict[str, float]]:
    """``{"a": {joint: value}, "b": {...}}`` from the ``config_*`` numerics, checked."""
    values: dict[str, dict[str, float]] = {c: {} for c in CONFIGURATIONS}
    for i in range(model.nnumeric):
        name = _name(model, mujoco.mjtObj.mjOBJ_NUMERIC, i)
        if not name.startswith(CONFIG_PREFIX):
            continue
        element = f'<numeric name="{name}">'
        config, sep, joint = name[len(CONFIG_PREFIX):].partition(":")
        if not sep or config not in CONFIGURATIONS or not joint:
            raise SceneError(
                f"{path}: {element} is not a configuration name; fix: name it "
                f"config_a:<joint name> or config_b:<joint name>")
        if joint not in joint_ids:
            raise SceneError(
                f"{path}: {element} names the unknown joint {joint!r}; fix: use one of the "
                f"object's joints {sorted(joint_ids)} (configurations cover the object's "
                f"joints only, not the arm's or the rail)")
        size = int(model.numeric_size[i])
        if size != 1:
            raise SceneError(f"{path}: {element} has {size} values; fix: give exactly one, "
                             f'data="VALUE" (radians for a hinge, metres for a slide)')
        value = float(model.numeric_data[model.numeric_adr[i]])
        lo, hi = (float(v) for v in model.jnt_range[joint_ids[joint]])
        if not lo - RANGE_TOLERANCE <= value <= hi + RANGE_TOLERANCE:
            raise SceneError(
                f"{path}: {element} value {value:g} lies outside the range [{lo:g}, {hi:g}] of "
                f"joint {joint!r}; fix: choose a value inside the range or widen the joint's "
                f"range (radians for a hinge, metres for a slide)")
        values[config][joint] = value
    for joint in joint_ids:
        for config in CONFIGURATIONS:
            if joint not in values[config]:
                raise SceneError(
                    f"{path}: joint {joint!r} has no value in configuration {config!r}; fix: add "
                    f'<numeric name="{CONFIG_PREFIX}{config}:{joint}" data="VALUE"/> inside '
                    f"<custom> (both config_a and config_b for every object joint)")
    return values


def _parse_settings(model: mujoco.MjModel, path: Path) -> dict[str, float]:
    """``{"stage.field": value}`` from the ``reconstruct:`` numerics, checked against
    artrecon's ReconstructConfig."""
    from artrecon.errors import InputError
    from artrecon.reconstruct import ReconstructConfig, with_settings

    settings = {}
    for i in range(model.nnumeric):
        name = _name(model, mujoco.mjtObj.mjOBJ_NUMERIC, i)
        if not name.startswith(SETTINGS_PREFIX):
            continue
        if int(model.numeric_size[i]) != 1:
            raise SceneError(f'{path}: <numeric name="{name}"> has {int(model.numeric_size[i])} '
                             f'values; fix: give exactly one, data="VALUE"')
        key, value = name[len(SETTINGS_PREFIX):], float(model.numeric_data[model.numeric_adr[i]])
        try:  # each element alone first, so that the message names it
            with_settings(ReconstructConfig(), {key: value})
        except InputError as exc:
            raise SceneError(f'{path}: <numeric name="{name}" data="{value:g}">: '
                             f"reconstruction {exc}; fix: name a field of "
                             f"artrecon.reconstruct.ReconstructConfig, as <numeric name=\""
                             f"{SETTINGS_PREFIX}STAGE.FIELD\" data=\"VALUE\"/> with a value in "
                             f"its range, or remove the element") from exc
        settings[key] = value
    try:
        with_settings(ReconstructConfig(), settings)
    except InputError as exc:
        raise SceneError(f"{path}: reconstruction {exc}; fix: name a field of "
                         f"artrecon.reconstruct.ReconstructConfig, as <numeric name=\""
                         f"{SETTINGS_PREFIX}STAGE.FIELD\" data=\"VALUE\"/> with a value of its "
                         f"kind, or remove the element") from exc
    return settings


def _parse_couplings(model: mujoco.MjModel, path: Path, joint_ids: dict[str, int],
                     configs: dict[str, dict[str, float]]) -> tuple[Coupling, ...]:
    """Joint equality constraints between object joints, checked against both configurations
    (a configuration that breaks a coupling would be pulled apart by the physics)."""
    by_id = {j: name for name, j in joint_ids.items()}
    out = []
    for e in range(model.neq):
        if int(model.eq_type[e]) != int(mujoco.mjtEq.mjEQ_JOINT):
            continue
        j1, j2 = int(model.eq_obj1id[e]), int(model.eq_obj2id[e])
        if j1 not in by_id and (j2 < 0 or j2 not in by_id):
            continue  # not about the object (e.g. the arm's gripper fingers)
        name = _name(model, mujoco.mjtObj.mjOBJ_EQUALITY, e)
        element = f'<equality><joint name="{name}">'
        if j1 not in by_id or j2 not in by_id:
            raise SceneError(
                f"{path}: {element} couples an object joint with something else; fix: couple "
                f"two object joints (joint1 and joint2 both among {sorted(joint_ids)})")
        coupling = Coupling(name, by_id[j1], by_id[j2],
                            tuple(float(c) for c in model.eq_data[e, :5]))
        for config in CONFIGURATIONS:
            want = coupling.value(configs[config][coupling.joint2])
            have = configs[config][coupling.joint1]
            if abs(want - have) > COUPLING_TOLERANCE:
                raise SceneError(
                    f"{path}: {element} requires {coupling.joint1} = {want:g} in configuration "
                    f"{config!r} ({coupling.joint2} = {configs[config][coupling.joint2]:g}), but "
                    f"config_{config}:{coupling.joint1} is {have:g}; fix: give values that "
                    f"satisfy the coupling's polycoef")
        out.append(coupling)
    return tuple(out)


def load_scene(name_or_path: str | os.PathLike) -> Scene:
    """Compile a scene and read its object's ground truth.

    Parameters
    ----------
    name_or_path : str or path-like
        A bundled scene name (see :func:`list_scenes`) or the path of an MJCF file.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        The file is missing or does not compile (MuJoCo's message with the file name), has no
        body ``"object"``, has an object joint that is not a hinge or slide, two joints on one
        body or a joint without range, or its configurations name an unknown joint, lie
        outside a joint's range, miss a joint or break a joint coupling (``<equality><joint>``).
    """
    path = scene_path(name_or_path)
    model = _compile(path)
    root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, OBJECT_BODY)
    if root < 0:
        raise SceneError(
            f'{path}: no body named "{OBJECT_BODY}"; fix: name the object\'s root body '
            f'"{OBJECT_BODY}" (<body name="{OBJECT_BODY}" pos="0 0 0.45"> on the table centre)')
    if root == 0:
        raise SceneError(f'{path}: "{OBJECT_BODY}" must be a body of the object, not the world')
    bodies = _object_bodies(model, root)

    # Joints of the object, checked one by one.
    joint_ids: dict[str, int] = {}
    for b in bodies:
        n_jnt = int(model.body_jntnum[b])
        body_name = _name(model, mujoco.mjtObj.mjOBJ_BODY, b)
        if n_jnt > 1:
            raise SceneError(
                f'{path}: <body name="{body_name}"> has {n_jnt} joints; fix: one joint per body '
                f"(nest bodies for compound motions) so that every joint has one child link")
        for j in range(int(model.body_jntadr[b]), int(model.body_jntadr[b]) + n_jnt):
            jname = _name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
            jtype = int(model.jnt_type[j])
            element = f'<joint name="{jname}"> in <body name="{body_name}">'
            if jtype not in JOINT_TYPES:
                raise SceneError(
                    f'{path}: {element} is a {_MJ_JOINT_NAMES.get(jtype, jtype)} joint; object '
                    f'joints must be type="hinge" (revolute) or type="slide" (prismatic); fix: '
                    f"change its type, split it into hinges on nested bodies, or remove it to "
                    f"fix the body to its parent")
            if not jname:
                raise SceneError(f"{path}: {element} has no name; fix: give it a unique name "
                                 f"(configurations refer to joints by name)")
            if not bool(model.jnt_limited[j]):
                raise SceneError(f'{path}: {element} has no range; fix: add range="LO HI" '
                                 f"(radians for a hinge, metres for a slide)")
            joint_ids[jname] = j

    # Links: a joint starts a new link, a jointless body joins its parent's link.
    link_of: dict[int, int] = {}
    for b in bodies:
        parent = int(model.body_parentid[b])
        starts = b == root or int(model.body_jntnum[b]) > 0
        link_of[b] = b if starts else link_of[parent]
    links = []
    for r in sorted(set(link_of.values())):
        members = tuple(b for b in bodies if link_of[b] == r)
        links.append(Link(_name(model, mujoco.mjtObj.mjOBJ_BODY, r), members,
                          tuple(_name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in members)))
    for li in links:
        if not li.name:
            raise SceneError(f"{path}: a moving body of the object (body id {li.body_id}) has "
                             f"no name; fix: name every body that carries a joint")

    configs = _parse_configurations(model, path, joint_ids)

    # Axes and anchors at configuration A, from the compiled model.
    data = mujoco.MjData(model)
    for name, j in joint_ids.items():
        data.qpos[model.jnt_qposadr[j]] = configs["a"][name]
    mujoco.mj_kinematics(model, data)
    joints = []
    for name, j in joint_ids.items():
        b = int(model.jnt_bodyid[j])
        parent_body = int(model.body_parentid[b])
        parent = (_name(model, mujoco.mjtObj.mjOBJ_BODY, link_of[parent_body])
                  if parent_body in link_of else "world")
        axis = np.array(data.xaxis[j], dtype=float)
        joints.append(Joint(
            name=name, type=JOINT_TYPES[int(model.jnt_type[j])], joint_id=j,
            qpos_adr=int(model.jnt_qposadr[j]), dof_adr=int(model.jnt_dofadr[j]),
            axis=axis / np.linalg.norm(axis), point=np.array(data.xanchor[j], dtype=float),
            parent=parent, child=_name(model, mujoco.mjtObj.mjOBJ_BODY, link_of[b]),
            range=np.array(model.jnt_range[j], dtype=float),
            value_a=configs["a"][name], value_b=configs["b"][name]))
    if not joints:
        log.warning("%s: the object has no joints (one rigid link)", path)
    couplings = _parse_couplings(model, path, joint_ids, configs)
    scene = Scene(path.stem, path, model, tuple(links), tuple(joints), couplings,
                  _parse_settings(model, path))
    log.debug("loaded scene %s: %d links, %d joints", path, len(links), len(joints))
    return scene


def physics_warnings(scene: Scene, seconds: float = 1.0, configuration: str = "a") -> dict:
    """Step ``seconds`` of physics from :meth:`Scene.make_data` and count MuJoCo warnings.

    Returns
    -------
    warnings : dict
        ``{warning name: count}`` of every warning MuJoCo raised (empty when clean), e.g.
        ``{"mjWARN_BADQACC": 1}``.
    """
    model = scene.model
    data = scene.make_data(configuration)
    steps = int(round(seconds / model.opt.timestep))
    mujoco.mj_step(model, data, nstep=steps)
    out = {}
    for name, w in mujoco.mjtWarning.__members__.items():
        if w == mujoco.mjtWarning.mjNWARNING:
            continue
        n = int(data.warning[int(w)].number)
        if n:
            out[name] = n
    return out


# ----------------------------------------------------------------------------------------------
# Joint holds: keep the object still while the arm works around it
# ----------------------------------------------------------------------------------------------


def add_joint_holds(spec: mujoco.MjSpec, joints: Iterable[str]) -> list[str]:
    """Add to ``spec`` one inactive hold per joint: a MuJoCo joint equality ``q = const``.

    A hold is a physical constraint, as stiff as MuJoCo allows (:data:`HOLD_SOLREF`,
    :data:`HOLD_SOLIMP`): switched on (:func:`hold_joints`) it keeps a joint where it was put
    against gravity for as long as the simulation runs, where the joints' friction loss lets a
    loaded joint creep. It is not a weld of the object to the world: contacts still act, so a
    collision of the arm with the object still shows as contacts (a hold only keeps the joint
    from giving way to it). Holds start inactive; the model behaves as without them until one is
    switched on.

    Parameters
    ----------
    spec : mujoco.MjSpec
        The scene's spec (e.g. ``mujoco.MjSpec.from_file(scene.path)``), before compiling.
    joints : iterable of str
        Joint names (hinges or slides) of the spec.

    Returns
    -------
    names : list of str
        Names of the added equality constraints, ``HOLD_PREFIX + joint``.
    """
    out = []
    for joint in joints:
        name = HOLD_PREFIX + joint
        spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, objtype=mujoco.mjtObj.mjOBJ_JOINT,
                          name=name, name1=joint, name2="", active=False,
                          data=[0.0] * 12, solref=list(HOLD_SOLREF), solimp=list(HOLD_SOLIMP))
        out.append(name)
    return out


def _hold_id(model: mujoco.MjModel, joint: str) -> int:
    e = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, HOLD_PREFIX + joint)
    if e < 0:
        raise KeyError(f"the model has no hold on joint {joint!r}; compile it with "
                       f"Scene.with_joint_holds() or add_joint_holds(spec, [...])")
    return e


def hold_joints(model: mujoco.MjModel, data: mujoco.MjData, values: Mapping[str, float]) -> None:
    """Switch on the holds of joints ``{name: value}`` at those values (rad or m).

    Writes each hold's target into ``model.eq_data`` (so the model should be the caller's own,
    e.g. from :meth:`Scene.with_joint_holds`) and sets ``data.eq_active``. Does not move the
    joints: put them at the values first (:meth:`Scene.set_joint_values`), or the hold pulls them
    there.

    Raises
    ------
    KeyError
        A joint has no hold in ``model``.
    """
    for joint, value in values.items():
        e = _hold_id(model, joint)
        j = int(model.eq_obj1id[e])
        # MuJoCo's joint equality is q - qpos0 = c0 + c1 (q2 - q2_0) + ...; one joint: c0 only
        model.eq_data[e, :5] = [float(value) - float(model.qpos0[model.jnt_qposadr[j]]),
                                0.0, 0.0, 0.0, 0.0]
        data.eq_active[e] = 1


def release_joints(model: mujoco.MjModel, data: mujoco.MjData,
                   joints: Iterable[str] | None = None) -> None:
    """Switch off the holds of ``joints`` (default: every hold of the model)."""
    if joints is None:
        ids = [e for e in range(model.neq)
               if _name(model, mujoco.mjtObj.mjOBJ_EQUALITY, e).startswith(HOLD_PREFIX)]
    else:
        ids = [_hold_id(model, j) for j in joints]
    for e in ids:
        data.eq_active[e] = 0
