"""Read an articulated object from an MJCF file (Gymnasium-Robotics' kitchen cabinets,
Meta-World's drawers and windows, any MuJoCo model of one object).

The file is compiled by MuJoCo itself, so every form MuJoCo accepts is read as MuJoCo reads it:
orientations (quat, euler in any ``eulerseq``, axisangle, xyaxes, zaxis), the compiler's angle
unit, mesh ``scale``, defaults classes, ``<frame>``, included files. The object is the subtree of
one top-level body (``body=``, default: the only top-level body with geoms). Hinge and slide
joints become the scene's joints (a joint's ``ref`` is folded into the body's pose); a body
without a joint joins its parent's link; a free joint on the object's root is dropped (the
object stands on the table). Visible geoms (group 0-2, not transparent) are the parts' surfaces,
geoms that collide give the collision shapes.
"""

from __future__ import annotations

import logging
from pathlib import Path

import mujoco
import numpy as np
import trimesh

from sim.author.source import (
    AuthorError,
    Mesh,
    Primitive,
    SourceJoint,
    SourceLink,
    SourceObject,
    pose,
    transform_points,
)

log = logging.getLogger(__name__)

_GEOM = mujoco.mjtGeom
_PRIMITIVE_TYPES = {int(_GEOM.mjGEOM_BOX): "box", int(_GEOM.mjGEOM_SPHERE): "sphere",
                    int(_GEOM.mjGEOM_CAPSULE): "capsule", int(_GEOM.mjGEOM_CYLINDER): "cylinder",
                    int(_GEOM.mjGEOM_ELLIPSOID): "ellipsoid"}
#: Geom groups drawn by the harness's renderer (group 3 is collision only, as in the stage).
VISIBLE_GROUPS = (0, 1, 2)


def _name(model, obj, i: int) -> str:
    return mujoco.mj_id2name(model, obj, i) or ""


def _primitive_mesh(gtype: int, size: np.ndarray):
    """A triangle mesh of a primitive geom in its own frame (for visible primitives)."""
    if gtype == int(_GEOM.mjGEOM_BOX):
        return trimesh.creation.box(2 * size[:3])
    if gtype == int(_GEOM.mjGEOM_SPHERE):
        return trimesh.creation.icosphere(3, size[0])
    if gtype == int(_GEOM.mjGEOM_CYLINDER):
        return trimesh.creation.cylinder(size[0], 2 * size[1], 48)
    if gtype == int(_GEOM.mjGEOM_CAPSULE):
        return trimesh.creation.capsule(2 * size[1], size[0], [24, 24])
    if gtype == int(_GEOM.mjGEOM_ELLIPSOID):
        m = trimesh.creation.icosphere(3, 1.0)
        m.vertices = m.vertices * size[:3]
        return m
    return None


def read_mjcf(path: str | Path, body: str | None = None) -> SourceObject:
    """Read the object of an MJCF file into a :class:`SourceObject` (metres, radians).

    Parameters
    ----------
    path : path
        The MJCF file.
    body : str, optional
        The object's root body (default: the only top-level body that has geoms).

    Raises
    ------
    AuthorError
        MuJoCo cannot compile the file, the root body is missing or ambiguous, or a body of the
        object has a ball joint, a free joint below the root, or more than one joint.
    """
    path = Path(path).resolve()
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        raise AuthorError(f"{path}: MuJoCo could not compile the file: {str(err).strip()}; fix: "
                          f"open it in MuJoCo's viewer and fix what it names") from err
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    B = mujoco.mjtObj.mjOBJ_BODY
    subtree_geoms = np.zeros(model.nbody, int)
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        while b > 0:
            subtree_geoms[b] += 1
            b = int(model.body_parentid[b])
    top = [b for b in range(1, model.nbody) if int(model.body_parentid[b]) == 0]
    if body is not None:
        root = mujoco.mj_name2id(model, B, body)
        if root <= 0:
            raise AuthorError(f"{path}: no body named {body!r}; the top-level bodies are "
                              f"{[_name(model, B, b) for b in top]}")
    else:
        cands = [b for b in top if subtree_geoms[b] > 0]
        if len(cands) != 1:
            raise AuthorError(f"{path}: {len(cands)} top-level bodies with geoms "
                              f"{[_name(model, B, b) for b in cands]}; fix: choose the object "
                              f"with --body NAME")
        root = cands[0]
    bodies = [b for b in range(model.nbody) if _in_subtree(model, b, root)]

    notes: list[str] = []
    link_of: dict[int, int] = {}
    joints: list[SourceJoint] = []
    names: dict[int, str] = {}
    for b in bodies:
        bname = _name(model, B, b) or f"body{b}"
        jnts = list(range(int(model.body_jntadr[b]),
                          int(model.body_jntadr[b]) + int(model.body_jntnum[b])))
        kinds = [int(model.jnt_type[j]) for j in jnts]
        if b == root and kinds == [int(mujoco.mjtJoint.mjJNT_FREE)]:
            notes.append(f"free joint of {bname!r} dropped: the object stands on the table")
            jnts, kinds = [], []
        for j, k in zip(jnts, kinds, strict=True):
            if k not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                kind = {int(mujoco.mjtJoint.mjJNT_FREE): "free",
                        int(mujoco.mjtJoint.mjJNT_BALL): "ball"}[k]
                raise AuthorError(f"{path}: <body name=\"{bname}\"> has a {kind} joint "
                                  f"{_name(model, mujoco.mjtObj.mjOBJ_JOINT, j)!r}; fix: use "
                                  f"hinge or slide joints (split a ball into hinges on nested "
                                  f"bodies)")
        if len(jnts) > 1:
            raise AuthorError(f"{path}: <body name=\"{bname}\"> has {len(jnts)} joints; fix: one "
                              f"joint per body (nest bodies for compound motions)")
        if b == root or jnts:
            link_of[b] = b
            names[b] = bname
        else:
            link_of[b] = link_of[int(model.body_parentid[b])]
        if jnts and b != root:
            j = jnts[0]
            parent = link_of[int(model.body_parentid[b])]
            T_w_parent = _body_pose(data, parent)
            T_w_child = _body_pose(data, b)
            lim = bool(model.jnt_limited[j])
            ref = float(model.qpos0[model.jnt_qposadr[j]])
            jname = _name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"{bname}_joint"
            hinge = int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE)
            if ref != 0.0:
                notes.append(f"joint {jname!r}: ref {ref:g} folded into the body's pose (values "
                             f"and limits shifted by it)")
            joints.append(SourceJoint(
                name=jname, type="revolute" if hinge else "prismatic",
                parent=names[parent], child=bname,
                T_parent_child=np.linalg.inv(T_w_parent) @ T_w_child,
                axis=np.asarray(model.jnt_axis[j], float), anchor=np.asarray(
                    model.jnt_pos[j], float),
                range=(np.asarray(model.jnt_range[j], float) - ref) if lim else None,
                continuous=hinge and not lim))
            if not lim and not hinge:
                raise AuthorError(f"{path}: slide joint {jname!r} has no range; fix: add "
                                  f"range=\"LO HI\"")
        elif jnts and b == root:
            raise AuthorError(f"{path}: the object's root body {bname!r} has a hinge or slide "
                              f"joint to the world; fix: choose the body below it with --body, "
                              f"or fix it to the world")

    links = {names[b]: SourceLink(names[b]) for b in link_of.values()}
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if b not in link_of:
            continue
        link = links[names[link_of[b]]]
        T_link_geom = np.linalg.inv(_body_pose(data, link_of[b])) @ pose(
            data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g])
        gname = _name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
        gtype = int(model.geom_type[g])
        visible = int(model.geom_group[g]) in VISIBLE_GROUPS and _alpha(model, g) > 0
        collides = bool(model.geom_contype[g] or model.geom_conaffinity[g])
        if gtype == int(_GEOM.mjGEOM_MESH):
            m = int(model.geom_dataid[g])
            va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
            fa, fn = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
            v = transform_points(T_link_geom, model.mesh_vert[va:va + vn])
            f = np.asarray(model.mesh_face[fa:fa + fn], np.int64)
            if visible:
                link.visuals.append(Mesh(v, f, gname, *_own_texture(model, g, m)))
            if collides:
                link.collisions.append(Mesh(v, f, gname))
        elif gtype in _PRIMITIVE_TYPES:
            size = np.asarray(model.geom_size[g], float)
            if visible:
                tm = _primitive_mesh(gtype, size)
                link.visuals.append(Mesh(transform_points(T_link_geom, tm.vertices),
                                         np.asarray(tm.faces, np.int64), gname))
            if collides:
                link.collisions.append(Primitive(_PRIMITIVE_TYPES[gtype], size, T_link_geom,
                                                 gname))
        else:
            notes.append(f"geom {gname!r} of type {gtype} left out (planes, height fields and "
                         f"SDFs are not object surfaces)")
    log.info("%s: %d links, %d joints", path, len(links), len(joints))
    return SourceObject(path.stem, path, names[root], links, joints, notes,
                        np.asarray(data.xmat[root], float).reshape(3, 3).copy())


def _own_texture(model, g: int, m: int):
    """A mesh geom's own texture: corner UVs (f, 3, 2) (OBJ convention) and its material's RGB
    image (h, w, 3) uint8, or None, None."""
    from sim.render import material_texture, texture_image  # pyrender (1 s, EGL): on use

    tex = material_texture(model, int(model.geom_matid[g]))
    if tex < 0 or int(model.mesh_texcoordnum[m]) == 0 or int(model.tex_type[tex]) != int(
            mujoco.mjtTexture.mjTEXTURE_2D):
        return None, None
    ta, fa, fn = (int(model.mesh_texcoordadr[m]), int(model.mesh_faceadr[m]),
                  int(model.mesh_facenum[m]))
    uv = np.asarray(model.mesh_texcoord[ta + model.mesh_facetexcoord[fa:fa + fn]], float)
    uv[..., 1] = 1.0 - uv[..., 1]  # MuJoCo flips the OBJ v on loading; back to OBJ's
    return uv, texture_image(model, tex)


def _alpha(model, g: int) -> float:
    rgba = model.geom_rgba[g]
    mat = int(model.geom_matid[g])
    if mat >= 0 and np.allclose(rgba, [0.5, 0.5, 0.5, 1.0]):
        return float(model.mat_rgba[mat, 3])
    return float(rgba[3])


def _body_pose(data, b: int) -> np.ndarray:
    return pose(data.xmat[b].reshape(3, 3), data.xpos[b])


def _in_subtree(model, b: int, root: int) -> bool:
    while b > 0 and b != root:
        b = int(model.body_parentid[b])
    return b == root
