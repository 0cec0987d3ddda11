"""Grasp candidates: points of the link to move with their outward normals, and the grasp frame
the gripper takes at one.

:func:`model_grasp_candidates` takes them from the registered model (what the harness plans
with): one per voxel of the child link's points, on a surface of the model, inside its face, with
the normal of the plane fitted around it. :func:`scene_grasp_candidates` takes them from the true
collision geoms (demonstrations along the true joint only).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial import cKDTree

from artrecon.geometry import rotation_about
from sim.manipulate.planning_config import PlanningConfig
from sim.manipulate.world import World


@dataclass(frozen=True)
class GraspCandidate:
    """A point on the link to move, with its outward surface normal (world frame)."""

    point: np.ndarray
    normal: np.ndarray
    hidden: bool = False
    visibility: str = ""
    """``"visible"``, ``"occluded by <geom>"`` or ``"outside the image"``"""
    clearance: float = float("inf")
    """distance (m) to the nearest surface of the model that does not move with the grasped
    link (:meth:`PlanningWorld.fixed_clearance`; inf: not measured)"""



def grasp_frame(point, normal, roll_deg: float, standoff: float) -> np.ndarray:
    """``T_world_grasp``: approach along ``-normal``, ``standoff`` off the surface, rolled."""
    z = -np.asarray(normal, float)
    z /= np.linalg.norm(z)
    ref = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    x = rotation_about(z, np.deg2rad(roll_deg)) @ x
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    T[:3, 3] = np.asarray(point, float) + standoff * np.asarray(normal, float)
    return T


def _voxel_groups(points: np.ndarray, size: float) -> list[np.ndarray]:
    """Indices of ``points`` per occupied voxel of ``size``."""
    keys = np.floor(points / size).astype(np.int64)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    order = np.argsort(inv.reshape(-1), kind="stable")
    bounds = np.flatnonzero(np.diff(inv.reshape(-1)[order])) + 1
    return np.split(order, bounds)


def voxel_centres(points: np.ndarray, size: float, min_points: int = 1) -> np.ndarray:
    """The mean point of every voxel of ``size`` holding at least ``min_points`` (m, 3)."""
    points = np.asarray(points, float)
    if len(points) == 0:
        return np.zeros((0, 3))
    return np.array([points[g].mean(axis=0) for g in _voxel_groups(points, size)
                     if len(g) >= min_points]).reshape(-1, 3)


def model_grasp_candidates(model, joint: int, config: PlanningConfig | None = None
                           ) -> list[GraspCandidate]:
    """Grasp candidates on the child link of the registered model's joint ``joint``: one per
    voxel of its points (the point nearest the voxel's mean), with the normal of the surface
    around it (:func:`_plane_normal`); voxels whose normals disagree (edges, noise) are left
    out.

    The link's points cover its hidden sides too (points seen only in configuration B are
    brought to A by the link's motion): a candidate may lie where no camera sees it now.
    """
    config = config or PlanningConfig()
    link = model.links[model.joints[joint].child]
    pts = np.asarray(link.points, float)
    if link.normals is None or len(pts) == 0:
        raise ValueError(f"link {link.name!r} of the model has no points with normals: no grasp "
                         "candidates")
    nrm = np.asarray(link.normals, float)
    tree = cKDTree(pts)
    out = []
    for g in _voxel_groups(pts, config.candidate_voxel):
        n = nrm[g].mean(axis=0)
        length = float(np.linalg.norm(n))
        if length < config.min_normal_agreement:
            continue
        c = pts[g].mean(axis=0)
        p = pts[g][np.argmin(np.linalg.norm(pts[g] - c, axis=1))]
        if len(tree.query_ball_point(p, config.support_radius)) < config.min_support:
            continue
        n = _plane_normal(p, n / length, pts, nrm, tree, config)
        if not _surrounded(p, n, pts, nrm, tree, config):
            continue
        out.append(GraspCandidate(p, n))
    return out


def _plane_normal(p, n, pts, nrm, tree, config: PlanningConfig) -> np.ndarray:
    """The normal at ``p`` of the plane fitted (least squares) to the link's points within
    :attr:`PlanningConfig.normal_radius` whose normals face like ``n``, turned to ``n``'s side;
    ``n`` itself when fewer than three such points span a plane."""
    near = np.asarray(tree.query_ball_point(p, config.normal_radius), dtype=int)
    near = near[nrm[near] @ n > config.min_normal_agreement]
    if len(near) < 3:
        return n
    q = pts[near] - pts[near].mean(axis=0)
    w, v = np.linalg.eigh(q.T @ q)
    if w[1] <= 0:
        return n
    fitted = v[:, 0]
    return fitted if float(fitted @ n) >= 0 else -fitted


def _surrounded(p, n, pts, nrm, tree, config: PlanningConfig) -> bool:
    """``p`` lies inside its face, not at its rim: the link's points around it that face the
    same way (normals within ~37 deg) and lie in its tangent plane reach at least
    :attr:`PlanningConfig.edge_margin` beyond it in each of four directions of that plane."""
    near = np.asarray(tree.query_ball_point(p, 2.5 * config.edge_margin), dtype=int)
    if len(near) == 0:
        return False
    d = pts[near] - p
    on_face = (nrm[near] @ n > config.min_normal_agreement) & (np.abs(d @ n) < 0.5 *
                                                                config.edge_margin)
    d = d[on_face]
    u, v = tangents(n)
    reach = config.edge_margin
    return bool(len(d) and (d @ u).max() >= reach and (d @ u).min() <= -reach
                and (d @ v).max() >= reach and (d @ v).min() <= -reach)


def scene_grasp_candidates(world: World, data, body_ids, grid: int = 3,
                           inset: float = 0.6) -> list[GraspCandidate]:
    """Points on the faces of the collision boxes and cylinder caps of the true bodies
    ``body_ids``, with outward normals (demonstrations along the true joint only: this reads the
    true geometry); points buried in another collision geom are dropped."""
    m = world.model
    bodies = set(body_ids)
    collision = [g for g in range(m.ngeom) if int(m.geom_contype[g]) or int(m.geom_conaffinity[g])]
    out = []
    ticks = np.linspace(-inset, inset, grid)
    for g in collision:
        if int(m.geom_bodyid[g]) not in bodies:
            continue
        R, c, s = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g], m.geom_size[g]
        local = []
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            for ax in range(3):
                u, v = [k for k in range(3) if k != ax]
                for sign in (-1.0, 1.0):
                    n = np.zeros(3)
                    n[ax] = sign
                    for a in ticks:
                        for b in ticks:
                            p = n * s[ax]
                            p[u], p[v] = a * s[u], b * s[v]
                            local.append((p, n))
        elif m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER:
            for sign in (-1.0, 1.0):
                n = np.array([0.0, 0.0, sign])
                for a in ticks:
                    local.append((np.array([a * s[0], 0.0, sign * s[1]]), n))
        for p, n in local:
            pw, nw = c + R @ p, R @ n
            if any(_inside_geom(m, data, h, pw) for h in collision if h != g):
                continue
            out.append(GraspCandidate(pw, nw))
    return out


def _inside_geom(model, data, g: int, p: np.ndarray, margin: float = 1e-4) -> bool:
    local = data.geom_xmat[g].reshape(3, 3).T @ (p - data.geom_xpos[g])
    s = model.geom_size[g]
    t = model.geom_type[g]
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        return bool(np.all(np.abs(local) < s - margin))
    if t == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return bool(np.hypot(local[0], local[1]) < s[0] - margin and abs(local[2]) < s[1] - margin)
    if t == mujoco.mjtGeom.mjGEOM_SPHERE:
        return bool(np.linalg.norm(local) < s[0] - margin)
    return False


def tangents(normal) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``normal`` and to each other. : (3,), (3,)"""
    ref = (0.0, 0.0, 1.0) if abs(normal[2]) < 0.9 else (1.0, 0.0, 0.0)
    u = _cross(normal, ref)
    u /= np.linalg.norm(u)
    return u, _cross(normal, u)


def _cross(a, b) -> np.ndarray:
    """``np.cross`` of two 3-vectors, the same products and differences bit for bit, without
    its generic machinery (20 us a call; the planner takes ~20k tangent frames per joint)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]], dtype=float)



__all__ = ["GraspCandidate", "grasp_frame", "model_grasp_candidates", "scene_grasp_candidates",
           "tangents", "voxel_centres"]
