"""The cell as the robot knows it when it plans views: its stage, its own arm and, of the object,
only what its survey found.

The view plan's clearance checks (:mod:`sim.views.solve`) run MuJoCo's collision detection. Run
in the scene's own model they would keep the arm clear of the true object's geoms, which the
robot was never told: ground truth deciding the plan. :class:`KnownCell` is the scene file
compiled again for planning, with the object's geoms taken out of collision (contype and
conaffinity 0, geom group :data:`HIDDEN_GROUP`) and, once the survey has carved the object's
visual hull, one convex mesh geom standing for it: the convex hull of the hull's voxels (every
voxel whole and half a voxel wider), which holds the visual hull and so the object. Before the
survey the robot knows nothing of the object, and the survey's first views are checked against
the stage and the arm only.

Whether a pose the plan chose touches the true object is a question for the simulated world,
never for the plan: :func:`object_contacts` answers it for poses the simulator does not drive
through physics (the survey's teleported photographs), as a failure to report.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from sim import robot
from sim.views.clearance import _geom_name, arm_link_bodies
from sim.views.rings import object_bodies

#: Name of the body (and its geom) standing for the object in a :class:`KnownCell`.
HULL_BODY = "known_object_hull"
#: Group the true object's geoms are moved to (no ray of a plan sees them).
HIDDEN_GROUP = 5
#: Geom group of the hull geom: the collision group (scenes/stage.xml), never rendered.
COLLISION_GROUP = 3


def hull_vertices(centres: np.ndarray, voxel: float) -> np.ndarray:
    """Vertices (k, 3) of the convex hull of cubes of edge ``2 voxel`` centred at the voxel
    centres ``centres`` (n, 3): each voxel whole and half a voxel beyond (a carved voxel is kept
    by its centre, so the object's edge may reach half a voxel past its cube; measured on the
    pliers: a vertex 0.53 mm outside the hull of the cubes of edge ``voxel``, 3 mm)."""
    pts = np.asarray(centres, dtype=float).reshape(-1, 3)
    if len(pts) == 0:
        raise ValueError("hull_vertices: no voxels")
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * voxel
    try:
        pts = pts[ConvexHull(pts).vertices]
    except QhullError:  # flat or tiny sets of voxels: every voxel's corners below
        pass
    cloud = (pts[:, None, :] + corners[None]).reshape(-1, 3)
    return cloud[ConvexHull(cloud).vertices]


class KnownCell:
    """The scene file compiled for planning: the object out of collision and, with ``hull``,
    one convex mesh geom in its place (see the module docstring).

    ``model`` and ``data`` take the place of the scene's in :func:`sim.views.solve_views` and
    :func:`sim.views.check_paths`: the bodies, joints and their ids are the scene's (the hull
    is a body of its own, after all others), so ``qpos`` and the arm's kinematics carry over.
    """

    def __init__(self, path: str | Path, hull: np.ndarray | None = None):
        self.path = Path(path)
        self.hull = None if hull is None else np.asarray(hull, dtype=float).reshape(-1, 3)
        spec = mujoco.MjSpec.from_file(str(self.path))
        if self.hull is not None:
            spec.add_mesh(name=HULL_BODY, uservert=self.hull.ravel().tolist())
            body = spec.worldbody.add_body(name=HULL_BODY)
            body.add_geom(name=HULL_BODY, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=HULL_BODY,
                          contype=1, conaffinity=1, group=COLLISION_GROUP,
                          rgba=[0.9, 0.6, 0.1, 0.4])
        model = spec.compile()
        hidden = set(object_bodies(model))
        for g in range(model.ngeom):
            if int(model.geom_bodyid[g]) in hidden:
                model.geom_contype[g] = 0
                model.geom_conaffinity[g] = 0
                model.geom_group[g] = HIDDEN_GROUP
        self.model = model
        self.data = mujoco.MjData(model)
        mujoco.mj_forward(model, self.data)

    def with_hull(self, hull: np.ndarray) -> KnownCell:
        """The same cell with the object's hull (vertices, world frame, m) as an obstacle."""
        return KnownCell(self.path, hull)

    def at(self, qpos: np.ndarray) -> KnownCell:
        """Set the planning state's ``qpos`` (the scene's layout) and run the kinematics."""
        self.data.qpos[:] = qpos
        mujoco.mj_forward(self.model, self.data)
        return self


def object_contacts(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                    q: np.ndarray) -> list[str]:
    """Contacts of the arm links with the true object at joint angles ``q`` in the scene's own
    ``model`` (``data.qpos`` restored): the simulated world's answer, for reporting a plan that
    hit the object, never for choosing one."""
    saved = data.qpos.copy()
    try:
        data.qpos[robot.qpos_indices(model, kin)] = q
        mujoco.mj_forward(model, data)
        links = arm_link_bodies(model, kin)
        obj = set(object_bodies(model))
        n = data.ncon
        out = []
        for g1, g2 in data.contact.geom[:n][data.contact.dist[:n] < 0]:
            b = {int(model.geom_bodyid[g1]), int(model.geom_bodyid[g2])}
            if b & links and b & obj:
                out.append(f"{_geom_name(model, int(g1))}/{_geom_name(model, int(g2))}")
        return sorted(set(out))
    finally:
        data.qpos[:] = saved
        mujoco.mj_forward(model, data)
