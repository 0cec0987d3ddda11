"""Read an articulated object from a URDF (PartNet-Mobility's ``mobility.urdf`` layout and the
like): links with their ``<visual>`` and ``<collision>`` geometry, revolute, continuous and
prismatic joints; fixed joints merged into their parent link.

Meshes (OBJ, STL, PLY, DAE, GLB: whatever trimesh reads) are found relative to the URDF's
folder; ``package://NAME/...`` and ``file://`` prefixes are resolved there as well. Materials and
the meshes' own texture coordinates are not used (the import textures every part anew).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import trimesh
import yourdfpy

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

#: URDF joint types and what they become (``fixed``: merged into the parent link).
URDF_JOINTS = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic",
               "fixed": None}


def _resolve(urdf_path: Path, filename: str) -> Path:
    """The file a URDF ``<mesh filename>`` names, relative to the URDF's folder."""
    name = filename
    for prefix in ("file://",):
        if name.startswith(prefix):
            name = name[len(prefix):]
    candidates = []
    if name.startswith("package://"):
        rest = name[len("package://"):]
        parts = Path(rest).parts
        # package://PKG/sub/file.obj: try sub/file.obj and PKG/sub/file.obj from the URDF's
        # folder and its parents (a package's URDF usually sits one or two folders down)
        for base in [urdf_path.parent, *urdf_path.parent.parents[:3]]:
            candidates += [base / Path(*parts[1:]) if len(parts) > 1 else base / rest,
                           base / rest]
    else:
        p = Path(name)
        candidates = [p] if p.is_absolute() else [urdf_path.parent / p]
    for c in candidates:
        if c.is_file():
            return c
    raise AuthorError(f"{urdf_path}: <mesh filename=\"{filename}\"> not found (looked for "
                      f"{', '.join(str(c) for c in candidates[:4])}); fix: give the path relative "
                      f"to the URDF's folder, or put the mesh there")


def load_mesh(path: Path, where: str):
    """Vertices (n, 3), faces (m, 3), and the mesh's own texture if it has one: corner UVs
    (m, 3, 2) and image (h, w, 3) uint8, else None, None (all its pieces in one mesh)."""
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as err:  # trimesh raises many kinds for a bad file
        raise AuthorError(f"{where}: could not read the mesh {path}: {err}; fix: give an OBJ, "
                          f"STL or PLY file with triangles") from err
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise AuthorError(f"{where}: the mesh {path} has no triangles; fix: give a mesh with "
                          f"faces (points and lines cannot be textured)")
    faces = np.asarray(mesh.faces, np.int64)
    uv = image = None
    visual = mesh.visual
    if getattr(visual, "uv", None) is not None and len(visual.uv) == len(mesh.vertices):
        material = getattr(visual, "material", None)
        img = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
        if img is not None:
            uv = np.asarray(visual.uv, float)[faces]
            image = np.asarray(img.convert("RGB"), dtype=np.uint8)
    return np.asarray(mesh.vertices, float), faces, uv, image


def _origin(element) -> np.ndarray:
    o = getattr(element, "origin", None)
    return np.eye(4) if o is None else np.asarray(o, float)


def _geometry(urdf_path: Path, element, link: str, kind: str, index: int):
    """A Mesh (visual or mesh collision) or a Primitive (box/cylinder/sphere collision) in the
    link's frame, or None for an empty geometry."""
    g = element.geometry
    T = _origin(element)
    where = f"{urdf_path}: <link name=\"{link}\"> <{kind}> #{index + 1}"
    name = f"{link}/{kind}{index}"
    if g is None:
        return None
    if g.mesh is not None:
        v, f, uv, image = load_mesh(_resolve(urdf_path, g.mesh.filename), where)
        scale = g.mesh.scale
        if scale is not None:
            v = v * np.broadcast_to(np.asarray(scale, float), (3,))
        return Mesh(transform_points(T, v), f, f"{name} ({Path(g.mesh.filename).name})", uv,
                    image)
    if g.box is not None:
        size = np.asarray(g.box.size, float)
        prim, tm = ("box", size / 2), trimesh.creation.box(size)
    elif g.cylinder is not None:
        r, h = float(g.cylinder.radius), float(g.cylinder.length)
        prim, tm = ("cylinder", np.array([r, h / 2])), trimesh.creation.cylinder(r, h, 48)
    elif g.sphere is not None:
        r = float(g.sphere.radius)
        prim, tm = ("sphere", np.array([r])), trimesh.creation.icosphere(3, r)
    else:
        raise AuthorError(f"{where}: unknown geometry; fix: use <mesh>, <box>, <cylinder> or "
                          f"<sphere>")
    if kind == "collision":
        return Primitive(prim[0], prim[1], T, name)
    return Mesh(transform_points(T, tm.vertices), np.asarray(tm.faces, np.int64), name)


def read_urdf(path: str | Path) -> SourceObject:
    """Read a URDF into a :class:`SourceObject` (source units, usually metres).

    Raises
    ------
    AuthorError
        The file does not parse, has a floating or planar joint, a revolute or prismatic joint
        without limits, more than one root link, or a mesh that cannot be found or read.
    """
    path = Path(path).resolve()
    try:
        urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False,
                                  load_collision_meshes=False)
    except Exception as err:
        raise AuthorError(f"{path}: not a readable URDF: {err}; fix: check the XML") from err
    robot = urdf.robot
    links = {li.name: li for li in robot.links}
    if not links:
        raise AuthorError(f"{path}: the URDF has no <link>")
    children = {j.child for j in robot.joints}
    roots = [n for n in links if n not in children]
    if len(roots) != 1:
        raise AuthorError(f"{path}: {len(roots)} root links {roots} (links that are no joint's "
                          f"child); fix: join them into one tree with fixed joints")
    by_parent: dict[str, list] = {}
    for j in robot.joints:
        if j.type not in URDF_JOINTS:
            raise AuthorError(f"{path}: <joint name=\"{j.name}\" type=\"{j.type}\"> cannot be "
                              f"imported; fix: use revolute, continuous, prismatic or fixed (a "
                              f"floating or planar part is not an articulation)")
        by_parent.setdefault(j.parent, []).append(j)

    notes = []
    out_links: dict[str, SourceLink] = {}
    out_joints: list[SourceJoint] = []
    # walk the tree: every link joins the movable link it is fixed to (anchor, T_anchor_link)
    stack = [(roots[0], roots[0], np.eye(4))]
    while stack:
        name, anchor, T_anchor = stack.pop(0)
        if anchor not in out_links:
            out_links[anchor] = SourceLink(anchor)
        target = out_links[anchor]
        link = links[name]
        for k, vis in enumerate(link.visuals or []):
            m = _geometry(path, vis, name, "visual", k)
            if m is not None:
                target.visuals.append(Mesh(transform_points(T_anchor, m.vertices), m.faces,
                                           m.name, m.uv, m.image))
        for k, col in enumerate(link.collisions or []):
            g = _geometry(path, col, name, "collision", k)
            if isinstance(g, Mesh):
                target.collisions.append(Mesh(transform_points(T_anchor, g.vertices), g.faces,
                                              g.name))
            elif g is not None:
                target.collisions.append(Primitive(g.type, g.size, T_anchor @ g.T_link_geom,
                                                   g.name))
        for j in by_parent.get(name, []):
            T_origin = _origin(j)
            kind = URDF_JOINTS[j.type]
            if kind is None:
                notes.append(f"fixed joint {j.name!r}: link {j.child!r} merged into "
                             f"{anchor!r}")
                stack.append((j.child, anchor, T_anchor @ T_origin))
                continue
            axis = np.asarray(j.axis if j.axis is not None else [1.0, 0.0, 0.0], float)
            if np.linalg.norm(axis) == 0:
                raise AuthorError(f"{path}: <joint name=\"{j.name}\"> has a zero axis")
            rng = None
            if j.type != "continuous":
                lim = j.limit
                if lim is None or lim.lower is None or lim.upper is None:
                    raise AuthorError(f"{path}: <joint name=\"{j.name}\" type=\"{j.type}\"> "
                                      f"has no <limit lower upper>; fix: add its limits (or "
                                      f"make a revolute joint continuous)")
                rng = np.array([float(lim.lower), float(lim.upper)])
                if rng[1] <= rng[0]:
                    raise AuthorError(f"{path}: <joint name=\"{j.name}\"> limits "
                                      f"[{rng[0]:g}, {rng[1]:g}] leave no motion; fix: give "
                                      f"lower < upper, or make it a fixed joint")
            out_joints.append(SourceJoint(
                name=j.name, type=kind, parent=anchor, child=j.child,
                T_parent_child=T_anchor @ T_origin, axis=axis / np.linalg.norm(axis),
                anchor=np.zeros(3), range=rng, continuous=j.type == "continuous"))
            stack.append((j.child, j.child, np.eye(4)))
    log.info("%s: %d links, %d joints", path, len(out_links), len(out_joints))
    return SourceObject(robot.name or path.stem, path, roots[0], out_links, out_joints, notes)


__all__ = ["read_urdf", "load_mesh", "pose"]
