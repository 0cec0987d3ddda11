"""The twin as a binary glTF (GLB) scene for viewers: each link's coloured points (or its visual
mesh) in the world frame at configuration A, and a red arrow along each estimated joint axis."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from artrecon.export.twin import ExportConfig, Twin, build_twin
from artrecon.files import write_files_atomic
from artrecon.geometry import pose, transform_points
from artrecon.model import ArticulatedModel

__all__ = ["AXIS_RGBA", "AXIS_RADIUS_FRACTION", "glb_scene", "export_glb"]

#: Colours of the GLB: estimated axes red (RGBA).
AXIS_RGBA = (230, 25, 25, 255)
#: Axis cylinder radius, as a fraction of the scene size.
AXIS_RADIUS_FRACTION = 0.006


def _axis_arrow(start: np.ndarray, end: np.ndarray, radius: float) -> trimesh.Trimesh:
    """A red cylinder from start to end with a cone at `end` (the positive direction)."""
    d = end - start
    length = float(np.linalg.norm(d))
    head = min(6 * radius, 0.3 * length)
    shaft = trimesh.creation.cylinder(radius=radius,
                                      segment=np.array([start, end - head * d / length]))
    cone = trimesh.creation.cone(radius=2.5 * radius, height=head)
    # the cone stands on z = 0 pointing +z: rotate +z onto d and put its base at the shaft's end
    T = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / length)
    T[:3, 3] = end - head * d / length
    cone.apply_transform(T)
    arrow = trimesh.util.concatenate([shaft, cone])
    arrow.visual.face_colors = AXIS_RGBA
    return arrow


def glb_scene(twin: Twin, geometry: str = "points") -> trimesh.Scene:
    """Scene of the twin in the world frame at configuration A: one node per link (coloured
    points or the visual mesh) and one red arrow per joint along its estimated axis."""
    scene = trimesh.Scene()
    all_pts = np.concatenate([twin.points_in_base(k) for k in range(len(twin.links))])
    size = float(np.median(np.linalg.norm(all_pts - np.median(all_pts, axis=0), axis=1))) or 1.0
    T = twin.T_world_base
    for lk in twin.links:
        T_world_link = T @ pose(np.eye(3), lk.origin)
        if geometry == "points":
            colours = (np.column_stack([lk.colours, np.full(len(lk.colours), 255, np.uint8)])
                       if lk.colours is not None else np.tile((lk.rgba * 255).astype(np.uint8),
                                                              (len(lk.points), 1)))
            geom = trimesh.PointCloud(lk.points, colors=colours)
        else:
            geom = lk.visual
        scene.add_geometry(geom, node_name=lk.name, geom_name=lk.name, transform=T_world_link)
    for j in twin.joints:
        child = twin.points_in_base(j.child)
        centre = child.mean(axis=0)
        a = twin.links[j.child].origin
        if j.type == "revolute":  # the axis line, centred where the child is, as long as the child
            proj = (child - a) @ j.axis
            half = max(0.5 * np.ptp(proj), 0.5 * float(np.max(np.ptp(child, axis=0))))
            mid = a + 0.5 * (proj.min() + proj.max()) * j.axis
        else:  # the slide direction through the child's centre, as long as the motion
            half = max(0.5 * abs(j.motion), 0.25 * float(np.max(np.ptp(child, axis=0))))
            mid = centre
        start, end = transform_points(T, np.array([mid - half * j.axis, mid + half * j.axis]))
        scene.add_geometry(_axis_arrow(start, end, AXIS_RADIUS_FRACTION * size),
                           node_name=f"axis_{j.name}", geom_name=f"axis_{j.name}")
    return scene


def export_glb(model: ArticulatedModel | Twin, path: str | Path,
               config: ExportConfig | None = None, *, overwrite: bool = True,
               protect=()) -> list[Path]:
    """Write a binary glTF (GLB) of the model with its axes drawn (red arrows pointing toward
    positive joint motion); see glb_scene. ``overwrite`` and ``protect`` as for
    :func:`artrecon.export.mjcf.export_mjcf`. Returns [path]."""
    config = config or ExportConfig()
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(path).stem)
    data = glb_scene(twin, config.glb_geometry).export(file_type="glb")
    return write_files_atomic([(Path(path), data)], overwrite=overwrite, protect=protect)
