"""Loading a scene: compile the file, check it against the conventions (:mod:`sim.scene`) and read
its object's ground truth (:func:`load_scene`); step its physics for MuJoCo's warnings
(:func:`physics_warnings`)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import mujoco
import numpy as np

from artrecon.errors import InputError
from artrecon.reconstruct import ReconstructConfig, with_settings
from sim.scene.files import compile_scene, scene_path
from sim.scene.records import CONFIGURATIONS, Coupling, Joint, Link, Scene, SceneError

log = logging.getLogger(__name__)

#: Name of the object's root body.
OBJECT_BODY = "object"

#: Prefix of the configurations' ``<numeric>`` elements.
CONFIG_PREFIX = "config_"
#: Prefix of the ``<numeric>`` elements that set reconstruction settings.
SETTINGS_PREFIX = "reconstruct:"

#: Slack when checking that a configuration value lies in its joint's range: the values are
#: written in decimal in the XML (e.g. 0.5236 for 30 deg) and MuJoCo stores ranges as float64,
#: so only a representation error, far below any physical meaning, is forgiven.
RANGE_TOLERANCE = 1e-9
#: Slack when checking that the configurations satisfy a joint coupling (``<equality><joint>``):
#: the polynomial is evaluated in float64 from decimal values, so a representation error only.
COUPLING_TOLERANCE = 1e-9

JOINT_TYPES = {int(mujoco.mjtJoint.mjJNT_HINGE): "revolute",
               int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic"}
_MJ_JOINT_NAMES = {int(mujoco.mjtJoint.mjJNT_FREE): "free",
                   int(mujoco.mjtJoint.mjJNT_BALL): "ball",
                   int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
                   int(mujoco.mjtJoint.mjJNT_HINGE): "hinge"}


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(model, obj, i) or ""


def body_subtree(model: mujoco.MjModel, root: int) -> list[int]:
    """Body ids of ``root`` and all its descendants, in body order (MuJoCo numbers a parent
    before its children)."""
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
    model = compile_scene(path)
    root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, OBJECT_BODY)
    if root < 0:
        raise SceneError(
            f'{path}: no body named "{OBJECT_BODY}"; fix: name the object\'s root body '
            f'"{OBJECT_BODY}" (<body name="{OBJECT_BODY}" pos="0 0 0.45"> on the table centre)')
    if root == 0:
        raise SceneError(f'{path}: "{OBJECT_BODY}" must be a body of the object, not the world')
    bodies = body_subtree(model, root)

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
