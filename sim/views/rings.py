"""Rings of views around the object: its bounding sphere, the camera distance for a fill of the
image, the views of a ring and the order the rail sweeps them in."""

from __future__ import annotations

import mujoco
import numpy as np

from sim import robot
from sim.scene import body_subtree
from sim.views.records import Ring, View, ViewPlanConfig


def object_bodies(model: mujoco.MjModel, root: str = "object") -> list[int]:
    """Body ids of the object: ``root`` and every body below it, in model order."""
    root_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, root)
    if root_id < 0:
        raise ValueError(f"the model has no body named {root!r}; a scene's object must have its "
                         "root body named 'object' (scenes/stage.xml)")
    return body_subtree(model, root_id)


def object_bounding_sphere(model: mujoco.MjModel, data: mujoco.MjData,
                           root: str = "object", visible_groups=(0, 1, 2)):
    """Bounding sphere of the object's visible geoms in the current state (after ``mj_forward``).

    Returns
    -------
    centre : (3,) float
    radius : float
    """
    bodies = set(object_bodies(model, root))
    pts = []
    for g in range(model.ngeom):
        if (int(model.geom_bodyid[g]) not in bodies
                or int(model.geom_group[g]) not in visible_groups):
            continue
        R, p = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g]
        if int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_MESH):
            mid = int(model.geom_dataid[g])
            a, n = int(model.mesh_vertadr[mid]), int(model.mesh_vertnum[mid])
            pts.append(model.mesh_vert[a:a + n] @ R.T + p)
        else:
            # conservative for primitives: the corners of the geom's bounding box
            lo = model.geom_aabb[g, :3] - model.geom_aabb[g, 3:]
            hi = model.geom_aabb[g, :3] + model.geom_aabb[g, 3:]
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                for z in (lo[2], hi[2])])
            pts.append(corners @ R.T + p)
    if not pts:
        raise ValueError(f"the object {root!r} has no visible geom "
                         f"(groups {tuple(visible_groups)})")
    pts = np.concatenate(pts)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    return centre, float(np.max(np.linalg.norm(pts - centre, axis=1)))


def _half_fov(K: np.ndarray, width: int, height: int) -> float:
    """Half the field of view across the shorter image side (rad)."""
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"expected K of shape (3, 3), got {K.shape}")
    return float(min(np.arctan(0.5 * width / K[0, 0]), np.arctan(0.5 * height / K[1, 1])))


def ring_distance(radius: float, K: np.ndarray, width: int, height: int, fill: float,
                  min_distance: float = ViewPlanConfig.min_ring_distance) -> float:
    """Camera distance at which a sphere of ``radius`` spans ``fill`` of the shorter image side
    (at least ``min_distance``, m: :attr:`ViewPlanConfig.min_ring_distance` says why)."""
    # the sphere's silhouette has angular radius asin(r / d)
    d = radius / np.sin(np.arctan(fill * np.tan(_half_fov(K, width, height))))
    return float(max(d, min_distance))


def fill_at_distance(radius: float, K: np.ndarray, width: int, height: int,
                     distance: float) -> float:
    """Share of the shorter image side that a sphere of ``radius`` spans from ``distance``: the
    inverse of :func:`ring_distance`."""
    if distance <= radius:
        raise ValueError(f"distance {distance:.3f} m lies inside the sphere of radius "
                         f"{radius:.3f} m")
    return float(np.tan(np.arcsin(radius / distance)) / np.tan(_half_fov(K, width, height)))


def ring_size(elevation: float, views_per_ring: int, top: bool) -> int:
    """Views on a ring at ``elevation`` (rad): ``views_per_ring`` on a full ring; on a top ring
    as few as keep neighbours as close as on a full ring (at least 3)."""
    if not top:
        return views_per_ring
    step = 2.0 * np.pi / views_per_ring
    # neighbours on a ring of elevation el with n views are 2 asin(cos(el) sin(pi / n)) apart
    chord = np.sin(step / 2.0) / max(np.cos(elevation), 1e-9)
    n = views_per_ring if chord >= 1 else int(np.ceil(np.pi / np.arcsin(chord)))
    return max(3, min(n, views_per_ring))


def ring_sizes(config: ViewPlanConfig) -> list[tuple[float, int]]:
    """(desired elevation in radians, number of views) of every ring."""
    out = [(np.deg2rad(e), config.views_per_ring) for e in config.elevations_deg]
    for e in config.top_elevations_deg:
        out.append((np.deg2rad(e), ring_size(np.deg2rad(e), config.views_per_ring, True)))
    return out


def ring_views(centre, ring: Ring, first_index: int = 0) -> list[View]:
    """Target camera poses of ``ring`` around ``centre`` (not yet checked against the arm)."""
    centre = np.asarray(centre, dtype=float)
    if centre.shape != (3,):
        raise ValueError(f"expected centre of shape (3,), got {centre.shape}")
    out = []
    el = ring.elevation
    for k in range(ring.n_views):
        az = ring.azimuth0 + 2.0 * np.pi * k / ring.n_views
        eye = centre + ring.distance * np.array([np.cos(el) * np.cos(az),
                                                 np.cos(el) * np.sin(az), np.sin(el)])
        out.append(View(index=first_index + k, ring=ring.index, azimuth=float(az),
                        elevation=float(el), distance=float(ring.distance),
                        T_world_camera=robot.look_at_pose(eye, centre)))
    return out


def ring_phases(config: ViewPlanConfig) -> list[float]:
    """Azimuth of each ring's first view, seeded: one draw per ring in ring order."""
    rng = np.random.default_rng(config.seed)
    return [float(rng.uniform(0.0, 2.0 * np.pi / n)) for _, n in ring_sizes(config)]


def plan_views(centre, distance: float, config: ViewPlanConfig) -> list[View]:
    """Target camera poses on all rings at their desired elevations and one ``distance`` (not
    yet checked against the arm; :func:`plan_capture` chooses each ring's distance and
    elevation)."""
    out: list[View] = []
    n_full = len(config.elevations_deg)
    for i, ((el, n), az0) in enumerate(zip(ring_sizes(config), ring_phases(config),
                                           strict=True)):
        ring = Ring(index=i, desired_elevation=el, elevation=el, distance=float(distance),
                    fill=float("nan"), n_views=n, azimuth0=az0, top=i >= n_full)
        out.extend(ring_views(centre, ring, len(out)))
    return out


def order_for_rail(views: list[View], kin: robot.ArmKinematics) -> list[View]:
    """Capture order: ring by ring, each ring swept in one direction of the rail (alternating
    between rings), so that the rail never turns a full circle back between neighbouring views.
    Views are re-indexed in that order.
    """
    out = []
    for ring in sorted({v.ring for v in views}):
        members = [v for v in views if v.ring == ring]
        members.sort(key=lambda v: (kin.rail_angle_for_azimuth(v.azimuth), v.azimuth))
        if ring % 2:
            members.reverse()
        out.extend(members)
    for i, v in enumerate(out):
        v.index = i
    return out
